"""``kind = "plan"``: a planned virtual-leader trajectory, a pure function of time.

A scenario's ``[trajectory]`` table with ``kind = "plan"`` gives the mission::

    [trajectory]
    kind = "plan"
    goal = [3.8, 0.0]            # m, required
    goal_heading = 0.0           # rad, optional: arrive along this heading
    via = [[1.0, 0.5]]           # m, optional: pass through these points in order
    speed_mps = 0.05             # optional: cruise speed of the leader (default 0.05)
    clearance_m = 0.02           # optional: planning clearance beyond the filter's margin

and ``scenario.load`` adds what the plan depends on from the rest of the scenario (the
``context`` key: the obstacles and arena, the formation table, the robot geometry and limits,
the start pose of the first robot unless ``x0``, ``y0``, ``heading`` are given). The plan is
made once, when the trajectory is built (``planner.plan``; cached on its inputs, so the
coordinator, the path check and the figures share it), and :meth:`PlannedTrajectory.sample`
then reads it like any other trajectory (eqs 1-2: ``v_mps`` along the heading, ``omega_radps =
v kappa``). A plan in which the formation squeezes also gives :meth:`slot_offsets`, the slots'
time-varying body-frame offsets that ``coordinator.core.formation.morphed_slot_rows`` turns into
setpoints.

Refused with ``ValueError`` naming the field: a bad parameter; ``trajectory.goal`` (or
``start``, ``via[k]``) inside an obstacle or outside the arena; an unreachable goal.
"""

from __future__ import annotations

import functools
import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from coordinator.core.formation import FormationSpec
from coordinator.core.trajectory import LeaderState, wrap_angle

from .footprint import Footprint
from .limits import SlotLimits
from .planner import PlanResult, plan
from .search import NoPlan
from .timed import TimedPlan
from .world import PlanWorld

__all__ = ["DEFAULT_CLEARANCE_M", "DEFAULT_SPEED_MPS", "PlannedTrajectory", "plan_from_context"]

DEFAULT_SPEED_MPS = 0.05
"""Default cruise speed of a planned leader (m/s): the paper's leaders run 0.02-0.1 m/s."""
DEFAULT_CLEARANCE_M = 0.02
"""Default planning clearance (m) beyond the safety filter's margin: room for tracking error."""
SEPARATION_SLACK_M = 0.05
"""Slack (m) on the least slot-to-slot distance of a squeezed formation (see
:func:`min_separation_m`): the neighbour barrier's inflation by the neighbour's speed times the
age of its pose (0.3 m/s x 0.03-0.07 s) and a little room for tracking error."""


def min_separation_m(safety_distance_m: float, ref_offset_m: float) -> float:
    """The least distance (m) between two slots of a squeezed formation: ``Ds + 2 l + slack``.

    The safety filter keeps two robots' REFERENCE POINTS ``Ds + 2 l`` apart (plus the age
    inflation; ``robot_agent.core.safety_filter``, cooperative neighbour row), so slots closer than
    that would put the filter between the robots and their slots for the whole passage (it
    measured 2 cm of formation error on the corridor with 0.277 m spacing). Never below the
    safety distance ``Ds`` itself."""
    return safety_distance_m + 2.0 * ref_offset_m + SEPARATION_SLACK_M


_OWNER = "PlannedTrajectory"


def _real(name: str, v: object) -> float:
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
        raise ValueError(f"trajectory.{name}: expected a finite number, got {v!r}")
    return float(v)


def _pair(name: str, v: object) -> tuple[float, float]:
    if isinstance(v, str | bytes) or not isinstance(v, Sequence) or len(v) != 2:
        raise ValueError(f"trajectory.{name}: expected an [x, y] pair, got {v!r}")
    return _real(f"{name}[0]", v[0]), _real(f"{name}[1]", v[1])


@functools.lru_cache(maxsize=16)
def _plan_cached(key: str) -> PlanResult:
    return plan_from_context(json.loads(key))


def plan_from_context(p: Mapping[str, Any]) -> PlanResult:
    """Plan from the canonical inputs (the trajectory table with its ``context``)."""
    ctx = p["context"]
    geom = ctx["geometry"]
    spec = FormationSpec.from_dict(dict(ctx["formation"]))
    slot_radius = (
        float(geom["body_radius_m"]) + float(geom["ref_offset_m"]) + float(ctx["margin_m"])
        + float(p["clearance_m"])
    )  # fmt: skip
    footprint = Footprint(
        spec.body_offsets_m,
        slot_radius,
        min_separation_m(float(ctx["safety_distance_m"]), float(geom["ref_offset_m"])),
    )
    world = PlanWorld(list(ctx.get("obstacles", [])), ctx.get("arena"))
    limits = SlotLimits.from_robot(
        wheel_radius_m=float(geom["wheel_radius_m"]),
        half_track_m=float(geom["half_track_m"]),
        max_wheel_radps=float(geom["max_wheel_radps"]),
        max_ref_speed_mps=float(ctx["max_ref_speed_mps"]),
    )
    start = (float(p["x0"]), float(p["y0"]), float(p["heading"]))
    goal = (float(p["goal"][0]), float(p["goal"][1]))
    try:
        return plan(
            world,
            footprint,
            start,
            goal,
            via=[(float(a), float(b)) for a, b in p["via"]],
            goal_heading=p["goal_heading"],
            cruise_mps=float(p["speed_mps"]),
            limits=limits,
            min_pair_m=float(ctx["safety_distance_m"]),  # never below the safety distance
            # and preferably not inside the filter's neighbour distance (Ds + 2 l)
            soft_pair_m=float(ctx["safety_distance_m"]) + 2.0 * float(geom["ref_offset_m"]),
        )
    except NoPlan as exc:
        raise NoPlan(f"trajectory.goal: no plan: {exc}") from None


@dataclass(frozen=True)
class PlannedTrajectory:
    """The virtual leader on a planned path (module docstring). ``sample(t_s)`` as every
    trajectory: before ``t_start_s`` at rest at the start, after the goal at rest there."""

    goal: Sequence[float]
    context: Mapping[str, Any]
    goal_heading: float | None = None
    via: Sequence[Sequence[float]] = ()
    speed_mps: float = DEFAULT_SPEED_MPS
    clearance_m: float = DEFAULT_CLEARANCE_M
    x0: float | None = None
    y0: float | None = None
    heading: float | None = None
    t_start_s: float = 0.0
    result: PlanResult = field(init=False, repr=False, compare=False)
    _timed: TimedPlan = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        goal = _pair("goal", self.goal)
        if isinstance(self.via, str | bytes) or not isinstance(self.via, Sequence):
            raise ValueError(f"trajectory.via: expected a list of [x, y] pairs, got {self.via!r}")
        via = [_pair(f"via[{i}]", v) for i, v in enumerate(self.via)]
        gh = None if self.goal_heading is None else _real("goal_heading", self.goal_heading)
        speed = _real("speed_mps", self.speed_mps)
        if speed <= 0.0:
            raise ValueError(f"trajectory.speed_mps: must be > 0, got {speed}")
        clear = _real("clearance_m", self.clearance_m)
        if clear < 0.0:
            raise ValueError(f"trajectory.clearance_m: must be >= 0, got {clear}")
        t0 = _real("t_start_s", self.t_start_s)
        if t0 < 0.0:
            raise ValueError(f"trajectory.t_start_s: must be >= 0, got {t0}")
        if not isinstance(self.context, Mapping) or "geometry" not in self.context:
            raise ValueError(
                "trajectory.context: missing; a plan needs the scenario's obstacles, formation "
                "and robots (scenario.load adds them)"
            )
        start = self.context.get("start", (0.0, 0.0, 0.0))
        x0 = _real("x0", start[0] if self.x0 is None else self.x0)
        y0 = _real("y0", start[1] if self.y0 is None else self.y0)
        h0 = _real("heading", start[2] if self.heading is None else self.heading)
        canon = {
            "goal": list(goal), "via": [list(v) for v in via], "goal_heading": gh,
            "speed_mps": speed, "clearance_m": clear, "x0": x0, "y0": y0, "heading": h0,
            "context": self.context,
        }  # fmt: skip
        try:
            key = json.dumps(canon, sort_keys=True, allow_nan=False)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"trajectory.context: not plain data ({exc})") from None
        result = _plan_cached(key)
        object.__setattr__(self, "result", result)
        object.__setattr__(self, "_timed", TimedPlan(result))
        object.__setattr__(self, "t_start_s", t0)

    @property
    def timed(self) -> TimedPlan:
        """The plan read at plan time (``t_s - t_start_s``): a replan's bridge follows it
        (``plan_bridge.PlanBridge``)."""
        return self._timed

    @property
    def duration_s(self) -> float:
        """Time from the start to the goal (s), excluding ``t_start_s``."""
        return self._timed.duration_s

    def where(self, t_s: float) -> tuple[float, float, int, float]:
        """(arc length s_m, speed v_mps, sample index k, position u in [k, k+1]) at ``t_s``."""
        return self._timed.where(t_s - self.t_start_s)

    def sample(self, t_s: float) -> LeaderState:
        """Leader state at ``t_s`` (s): eqs 1-2 along the planned path."""
        if isinstance(t_s, bool) or not isinstance(t_s, int | float) or not math.isfinite(t_s):
            raise ValueError(f"{_OWNER}.sample: t_s must be a finite number, got {t_s!r}")
        t = float(t_s)
        x, y, th, v, w = self._timed.state(t - self.t_start_s)
        return LeaderState(t, x, y, wrap_angle(th), v, w)

    def slot_offsets(self, t_s: float) -> tuple[tuple[float, float, float, float], ...] | None:
        """The slots' body-frame offsets from the leader and their rates at ``t_s``: per slot
        (definition order) ``(ox, oy, dox, doy)`` in m and m/s; None when the formation is not
        squeezed there (the rigid offsets of the formation hold)."""
        return self._timed.slot_offsets(float(t_s) - self.t_start_s)
