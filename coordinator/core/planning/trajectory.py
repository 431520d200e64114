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

import bisect
import functools
import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from coordinator.core.formation import FormationSpec
from coordinator.core.trajectory import LeaderState, wrap_angle

from .footprint import Footprint
from .limits import SlotLimits
from .planner import PlanResult, plan
from .search import NoPlan
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
    _t: tuple[float, ...] = field(init=False, repr=False, compare=False)
    _morph: bool = field(init=False, repr=False, compare=False)
    _q: tuple[float, ...] = field(init=False, repr=False, compare=False)
    _v: tuple[float, ...] = field(init=False, repr=False, compare=False)
    _dq: tuple[float, ...] = field(init=False, repr=False, compare=False)
    _s: tuple[float, ...] = field(init=False, repr=False, compare=False)
    _nominal: tuple[tuple[float, float], ...] = field(init=False, repr=False, compare=False)
    _zeros: tuple[tuple[float, float], ...] = field(init=False, repr=False, compare=False)

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
        object.__setattr__(self, "_t", tuple(float(v) for v in result.t_s))
        object.__setattr__(self, "_morph", bool(np.any(result.q > 0.0)))
        object.__setattr__(self, "_q", tuple(float(v) for v in result.q))
        object.__setattr__(self, "_v", tuple(float(v) for v in result.v_mps))
        object.__setattr__(self, "_dq", tuple(float(v) for v in result.dq_per_m))
        object.__setattr__(self, "_s", tuple(float(v) for v in result.s_m))
        fp = result.footprint
        object.__setattr__(self, "_nominal", tuple((float(a), float(b)) for a, b in fp.nominal_m))
        object.__setattr__(self, "_zeros", tuple((0.0, 0.0) for _ in range(fp.n)))
        object.__setattr__(self, "t_start_s", t0)

    @property
    def duration_s(self) -> float:
        """Time from the start to the goal (s), excluding ``t_start_s``."""
        return self._t[-1]

    def _where(self, t_s: float) -> tuple[float, float, int, float]:
        """(arc length s_m, speed v_mps, sample index k, position u in [k, k+1]) at ``t_s``."""
        tau = t_s - self.t_start_s
        if tau <= 0.0:
            return 0.0, 0.0, 0, 0.0
        if tau >= self._t[-1]:
            return self._s[-1], 0.0, len(self._t) - 2, 1.0
        k = bisect.bisect_right(self._t, tau) - 1
        dt = self._t[k + 1] - self._t[k]
        v0, v1 = self._v[k], self._v[k + 1]
        a = (v1 - v0) / dt
        u = tau - self._t[k]
        ds = self._s[k + 1] - self._s[k]
        s_in = min(v0 * u + 0.5 * a * u * u, ds)
        return self._s[k] + s_in, v0 + a * u, k, s_in / ds if ds > 0 else 0.0

    def sample(self, t_s: float) -> LeaderState:
        """Leader state at ``t_s`` (s): eqs 1-2 along the planned path."""
        if isinstance(t_s, bool) or not isinstance(t_s, int | float) or not math.isfinite(t_s):
            raise ValueError(f"{_OWNER}.sample: t_s must be a finite number, got {t_s!r}")
        t = float(t_s)
        s, v, _, _ = self._where(t)
        x, y, th, kappa = self.result.pose_at(s)
        return LeaderState(t, x, y, wrap_angle(th), v, v * kappa)

    def slot_offsets(self, t_s: float) -> tuple[tuple[float, float, float, float], ...] | None:
        """The slots' body-frame offsets from the leader and their rates at ``t_s``: per slot
        (definition order) ``(ox, oy, dox, doy)`` in m and m/s; None when the formation never
        squeezes on this plan (the rigid offsets of the formation hold)."""
        if not self._morph:
            return None
        r = self.result
        s, v, k, u = self._where(float(t_s))
        q0, q1 = self._q[k], self._q[k + 1]
        if q0 == 0.0 and q1 == 0.0:
            return None  # not squeezed here: the rigid formation (its exact arithmetic)
        q = q0 + (q1 - q0) * u
        dq_ds = self._dq[k] + (self._dq[k + 1] - self._dq[k]) * u
        fp = r.footprint
        # the squeeze of Footprint.offsets_many in plain floats (the per-tick path)
        qa = min(max(q, 0.0), fp.q_max)
        u1 = min(max(qa, 0.0), 1.0)
        sc = 1.0 - (1.0 - fp.s_min) * u1 * u1 * (3.0 - 2.0 * u1)
        dsc = -(1.0 - fp.s_min) * 6.0 * u1 * (1.0 - u1)
        ux = min(max(2.0 * (qa - 1.0), 0.0), 1.0)
        uy = min(max(2.0 * (qa - 1.5), 0.0), 1.0)
        lx, dlx = ux * ux * (3.0 - 2.0 * ux), 12.0 * ux * (1.0 - ux)
        ly, dly = uy * uy * (3.0 - 2.0 * uy), 12.0 * uy * (1.0 - uy)
        col: Sequence[tuple[float, float]] = self._zeros
        dcol: Sequence[tuple[float, float]] = self._zeros
        if lx > 0.0 or ly > 0.0 or dlx > 0.0 or dly > 0.0:
            col, dcol = r.column_at(s)
        out = []
        for (dx, dy), (cx, cy), (gx, gy) in zip(self._nominal, col, dcol, strict=True):
            ox = (1.0 - lx) * sc * dx + lx * cx
            oy = (1.0 - ly) * sc * dy + ly * cy
            dox = -dlx * sc * dx + (1.0 - lx) * dsc * dx + dlx * cx
            doy = -dly * sc * dy + (1.0 - ly) * dsc * dy + dly * cy
            # d/dt: the squeeze's rate and the column moving along the path
            out.append((ox, oy, (dox * dq_ds + lx * gx) * v, (doy * dq_ds + ly * gy) * v))
        return tuple(out)
