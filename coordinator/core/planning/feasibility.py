"""Can the robots follow every slot of a trajectory? A pure check for ANY trajectory.

The coordinator commands each slot's position and feed-forward velocity (eqs 3-5 and their
derivative; a planned squeeze adds its own rate, ``coordinator.core.formation.morphed_slot_rows``).
For a rigid formation the outer slots of a turn move faster than the leader (``|v_i| = |v_L +
omega x o_i|``), and a scripted trajectory can ask for more than a robot can do. This check
samples the trajectory every ``step_s`` over the run and reports, per slot and per limit, the
FIRST instant where the slot exceeds the robots' limits (``SlotLimits``):

* ``speed``: ``|v_i|`` above ``speed_mps``;
* ``turn``: the formation's heading rate (every slot's heading is the leader's) or, for a slot
  moving at more than half ``speed_mps``, the turn rate of its velocity, above ``turn_radps``;
* ``accel``: the change of ``v_i`` over :data:`ACCEL_WINDOW_S`, divided by it, above
  ``accel_mps2`` (over a window: the tracking law absorbs a small velocity step, such as a
  scripted leader that starts at its cruise speed).

Planned trajectories are timed within these limits by construction (``planner``); the check is
what ``formation check`` and ``formation sim`` print before a run for every trajectory.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Final

import numpy as np

from coordinator.core.formation import FormationSpec, morphed_slot_rows, slot_rows
from coordinator.core.trajectory import Trajectory, make_trajectory

from .limits import SlotLimits

__all__ = ["ACCEL_WINDOW_S", "Infeasible", "slot_feasibility", "trajectory_of"]

ACCEL_WINDOW_S: Final = 1.0
"""Window (s) over which a slot's acceleration is measured."""
TOLERANCE: Final = 1.02
"""A limit counts as exceeded above this multiple of it (sampling and rounding)."""


@dataclass(frozen=True, slots=True)
class Infeasible:
    """Slot ``slot`` first exceeds the ``what`` limit (``"speed"``, ``"turn"``, ``"accel"``)
    at ``t_s``, asking for ``value`` against ``limit`` (m/s, rad/s or m/s^2); ``peak`` is the
    most it asks for over the run."""

    slot: int
    what: str
    t_s: float
    value: float
    limit: float
    peak: float

    def message(self) -> str:
        unit = {"speed": "m/s", "turn": "rad/s", "accel": "m/s^2"}[self.what]
        return (
            f"slot {self.slot} is infeasible: its {self.what} {self.value:.3f} {unit} exceeds "
            f"the robots' {self.limit:.3f} {unit} at t = {self.t_s:.1f} s (peak "
            f"{self.peak:.3f} {unit}): the robot on it cannot follow"
        )


def trajectory_of(table: Mapping[str, Any]) -> Trajectory:
    """A scenario's trajectory table built (``kind`` and its parameters)."""
    params = {k: v for k, v in table.items() if k != "kind"}
    return make_trajectory(str(table["kind"]), params)


def slot_feasibility(
    trajectory: Trajectory,
    formation: FormationSpec,
    limits: SlotLimits,
    duration_s: float,
    *,
    step_s: float = 0.05,
) -> list[Infeasible]:
    """Every (slot, limit) the slots of ``formation`` on ``trajectory`` exceed over
    ``[0, duration_s]``, in slot order then time (module docstring)."""
    if not (math.isfinite(duration_s) and duration_s >= 0.0 and step_s > 0.0):
        raise ValueError("duration_s must be >= 0 and step_s > 0")
    n_t = math.floor(duration_s / step_s + 1e-9) + 1
    t = np.arange(n_t) * step_s
    offsets_at = getattr(trajectory, "slot_offsets", None)
    n = len(formation)
    vel = np.empty((n_t, n, 2))
    omega = np.empty(n_t)
    for k in range(n_t):
        leader = trajectory.sample(float(t[k]))
        offs = None if offsets_at is None else offsets_at(float(t[k]))
        _, rows = slot_rows(formation, leader) if offs is None else morphed_slot_rows(leader, offs)
        vel[k] = [(r[2], r[3]) for r in rows]
        omega[k] = leader.omega_radps
    speed = np.hypot(vel[..., 0], vel[..., 1])
    w = max(1, round(ACCEL_WINDOW_S / step_s))
    accel = np.zeros_like(speed)
    if n_t > w:
        dv = vel[w:] - vel[:-w]
        accel[w:] = np.hypot(dv[..., 0], dv[..., 1]) / (w * step_s)
    # turn rate of a moving slot's velocity, and the formation's heading rate
    turn = np.repeat(np.abs(omega)[:, None], n, axis=1)
    if n_t > 1:
        heading = np.unwrap(np.arctan2(vel[..., 1], vel[..., 0]), axis=0)
        rate = np.zeros_like(speed)
        rate[1:] = np.abs(np.diff(heading, axis=0)) / step_s
        moving = (speed > 0.5 * limits.speed_mps) & np.vstack(
            [[False] * n, speed[:-1] > 0.5 * limits.speed_mps]
        )
        turn = np.maximum(turn, np.where(moving, rate, 0.0))
    out: list[Infeasible] = []
    for j, spec in enumerate(formation.slots):
        for what, series, lim in (
            ("speed", speed[:, j], limits.speed_mps),
            ("turn", turn[:, j], limits.turn_radps),
            ("accel", accel[:, j], limits.accel_mps2),
        ):
            over = np.flatnonzero(series > lim * TOLERANCE)
            if len(over):
                k = int(over[0])
                out.append(
                    Infeasible(
                        spec.slot, what, float(t[k]), float(series[k]), lim, float(series.max())
                    )
                )
    return out
