"""What the safety filter takes and reports: ``Neighbour`` (another robot as this robot knows
it) and ``SafetyFilterStatus`` (the counters and last-tick figures of ``SafetyFilter``).

Split out of safety_filter.py (issue 12) so the filter itself reads as constraint geometry plus
the QP (``qp.py``); both names are still importable from ``robot_agent.core.safety_filter``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Final, NamedTuple

_isfinite: Final = math.isfinite


_NAN: Final = math.nan


class Neighbour(NamedTuple):
    """What a robot knows of another robot. A plain ``(x, y)`` tuple means ``Neighbour(x, y)``.

    Attributes:
        x, y: the neighbour's measured axle centre (m).
        theta: its heading (rad), NaN if unknown (needed for ``cooperative``).
        age_s: age of the measurement (s, >= 0): capture time to now on this robot's clock.
        vx, vy: the centre's velocity if known (m/s), used for a non-cooperative neighbour; a
            component beyond 10 x the neighbour top speed is rejected (counted, taken as 0).
        cooperative: it is TRACKING and runs this filter (fresh status): half responsibility.
        radius_m: extra radius for the neighbour's own uncertainty (m).
        motion: what its motion claims say (``robot_agent.core.neighbour_motion.motion_view``),
            None for the worst case (``neighbour_speed_mps`` times the age). An entry built
            with eight fields has none.
    """

    x: float
    y: float
    theta: float = _NAN
    age_s: float = 0.0
    vx: float = 0.0
    vy: float = 0.0
    cooperative: bool = False
    radius_m: float = 0.0
    motion: tuple[float, float, float, float, float, float, float, float, float] | None = None


@dataclass(frozen=True, slots=True)
class SafetyFilterStatus:
    """Counters of the filter (for the status message, logs and run metrics).

    Attributes:
        ticks: calls to ``filter``.
        active_ticks: ticks whose output differs from the nominal command.
        violations: ticks on which some barrier was already below zero at the input (the
            robot was inside a boundary it should keep: noise, a neighbour that moved in, a
            start inside; Robotarium counts these as violations).
        infeasible: ticks with no feasible command: the least-violation fallback ran (it
            moves out of the violated barriers as fast as the cap allows, and stops only when
            nothing can move out: safety_filter.py, "Leaving a barrier").
        tiebreaks: deadlock tie-breaks triggered.
        tiebreak_active: a tie-break is running now.
        rescaled: ticks on which the firmware rescaled saturated wheels uniformly to keep the
            constraints (see ``admissible``).
        rejected: neighbour / obstacle entries skipped as non-finite.
        min_clearance_m: the least barrier value ``h`` seen (m, inf if none in range).
        constraints: constraints in range on the last tick.
    """

    ticks: int
    active_ticks: int
    violations: int
    infeasible: int
    tiebreaks: int
    tiebreak_active: bool
    rescaled: int
    rejected: int
    min_clearance_m: float
    constraints: int

    def as_dict(self) -> dict[str, Any]:
        """msgpack-friendly dict (``min_clearance_m`` is None while infinite)."""
        return {
            "ticks": self.ticks,
            "active": self.active_ticks,
            "violations": self.violations,
            "infeasible": self.infeasible,
            "tiebreaks": self.tiebreaks,
            "tiebreak_active": self.tiebreak_active,
            "rescaled": self.rescaled,
            "rejected": self.rejected,
            "min_clearance_m": self.min_clearance_m if _isfinite(self.min_clearance_m) else None,
            "constraints": self.constraints,
        }
