"""Does a slot's planned path cross an obstacle or leave the arena? (a pure check, no planning)

A scripted trajectory is not planned around obstacles (a ``kind = "plan"`` one is:
``coordinator.core.planning``, and has no conflict here by construction); the robots' safety filter
keeps them clear of what they know (``robot_agent.core.safety_filter``). This check warns when the
formation the coordinator will command asks for the impossible: a slot whose path, sampled
over the run, brings a robot's body onto an obstacle or over the arena's edge. A robot on such a
slot is held off by its filter and cannot reach the slot (tracking error, maybe a tie-break),
which is worth one line in the log rather than a surprise in the metrics. A planned squeeze's
time-varying slot offsets (``slot_offsets``) are checked as the coordinator commands them.

The slot positions are where each robot's REFERENCE POINT should be (eqs 10-11); the body is a
disc of ``body_radius_m`` around the axle centre, ``ref_offset_m`` behind, so the check takes
the body as a disc of ``body_radius_m + ref_offset_m`` around the slot (conservative, whatever
the heading). Pure: the trajectory and the formation are sampled at ``t0_s + k * step_s``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from coordinator.core.formation import (
    FormationSpec,
    morphed_slot_rows,
    slot_states,
    states_from_rows,
)
from coordinator.core.trajectory import make_trajectory
from robot_agent.core.params import CircleObstacle, SegmentObstacle, WorldMap

__all__ = ["PathConflict", "slot_path_conflicts", "trajectory_conflicts"]


@dataclass(frozen=True, slots=True)
class PathConflict:
    """Slot ``slot``'s path meets ``what`` (``"obstacle[k]"`` or ``"arena"``) first at ``t_s``,
    with the least clearance ``clearance_m`` (< 0: overlap, m) over the run at ``t_worst_s``."""

    slot: int
    what: str
    t_s: float
    clearance_m: float
    t_worst_s: float

    def message(self) -> str:
        return (
            f"slot {self.slot}'s path crosses {self.what} at t = {self.t_s:.1f} s "
            f"(worst clearance {self.clearance_m:+.3f} m at t = {self.t_worst_s:.1f} s): "
            "the robot on it will be held off by its safety filter"
        )


def _clearance(x: float, y: float, o: CircleObstacle | SegmentObstacle, radius_m: float) -> float:
    """Gap between a disc of ``radius_m`` at ``(x, y)`` and obstacle ``o`` (m, < 0: overlap)."""
    if isinstance(o, CircleObstacle):
        return math.hypot(x - o.x, y - o.y) - o.radius_m - radius_m
    sx, sy = o.x2 - o.x1, o.y2 - o.y1
    len2 = sx * sx + sy * sy
    t = ((x - o.x1) * sx + (y - o.y1) * sy) / len2 if len2 > 0.0 else 0.0
    t = min(1.0, max(0.0, t))
    return math.hypot(x - (o.x1 + t * sx), y - (o.y1 + t * sy)) - o.radius_m - radius_m


def slot_path_conflicts(
    trajectory: Mapping[str, Any],
    formation: Mapping[str, Any],
    world: WorldMap,
    duration_s: float,
    *,
    body_radius_m: float,
    ref_offset_m: float,
    step_s: float = 0.1,
    t0_s: float = 0.0,
) -> list[PathConflict]:
    """Every (slot, obstacle or arena) pair whose sampled path conflicts, in slot order.

    Args:
        trajectory, formation: the scenario tables (``kind`` and parameters).
        world: obstacles and arena (``AgentConfig.world``).
        duration_s: how long the run lasts (s); samples every ``step_s`` from ``t0_s``.
        body_radius_m, ref_offset_m: the robot geometry (the body is taken as a disc of their
            sum around the slot: conservative).
    """
    if not world.obstacles and world.arena is None:
        return []
    params = {k: v for k, v in trajectory.items() if k != "kind"}
    traj = make_trajectory(str(trajectory["kind"]), params)
    return trajectory_conflicts(
        traj, FormationSpec.from_dict(dict(formation)), world, duration_s,
        body_radius_m=body_radius_m, ref_offset_m=ref_offset_m, step_s=step_s, t0_s=t0_s,
    )  # fmt: skip


def trajectory_conflicts(
    traj: Any,
    spec: FormationSpec,
    world: WorldMap,
    duration_s: float,
    *,
    body_radius_m: float,
    ref_offset_m: float,
    step_s: float = 0.1,
    t0_s: float = 0.0,
) -> list[PathConflict]:
    """:func:`slot_path_conflicts` of a trajectory object (``sample(t)``, and
    ``slot_offsets(t)`` if its formation squeezes: a run-time plan, coordinator.core.planning)."""
    if not world.obstacles and world.arena is None:
        return []
    if not (duration_s >= 0.0 and step_s > 0.0):
        raise ValueError("duration_s must be >= 0 and step_s > 0")
    radius = body_radius_m + ref_offset_m
    first: dict[tuple[int, str], float] = {}
    worst: dict[tuple[int, str], tuple[float, float]] = {}
    n = math.floor(duration_s / step_s + 1e-9) + 1
    a = world.arena
    offsets_at = getattr(
        traj, "slot_offsets", None
    )  # a planned squeeze (coordinator.core.planning)
    for k in range(n):
        t = t0_s + k * step_s
        leader = traj.sample(t)
        offsets = None if offsets_at is None else offsets_at(t)
        states = (
            slot_states(spec, leader)
            if offsets is None
            else states_from_rows(spec, *morphed_slot_rows(leader, offsets))
        )
        for s in states:
            checks: list[tuple[str, float]] = [
                (f"obstacle[{j}]", _clearance(s.x, s.y, o, radius))
                for j, o in enumerate(world.obstacles)
            ]
            if a is not None:
                gap = min(s.x - a.x_min, a.x_max - s.x, s.y - a.y_min, a.y_max - s.y) - radius
                checks.append(("arena", gap))
            for what, gap in checks:
                if gap < 0.0:
                    key = (s.slot, what)
                    first.setdefault(key, t - t0_s)
                    if key not in worst or gap < worst[key][0]:
                        worst[key] = (gap, t - t0_s)
    return [
        PathConflict(slot, what, first[(slot, what)], *worst[(slot, what)])
        for slot, what in sorted(first, key=lambda kw: (kw[0], first[kw]))
    ]
