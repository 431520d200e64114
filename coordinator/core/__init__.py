"""Coordinator core: virtual-leader trajectories, formation geometry and role assignment.

Pure (numpy/scipy, no I/O, no clock): time is always passed in. See docs/architecture.md.

The per-tick modules may run compiled (mypyc) when a build of exactly these sources exists:
``_accel.activate`` decides before anything of the core is imported (see ``_accel.py``).
"""

from . import _accel

_accel.activate(__name__, __path__)

from coordinator.core.assignment import (
    RoleAssigner,
    SlotLike,
    assign_greedy,
    assign_optimal,
    assignment_cost,
    natural_key,
)
from coordinator.core.formation import (
    FORMATION_KINDS,
    LEADER_SLOT,
    ROLES,
    FormationSpec,
    SlotSpec,
    SlotState,
    slot_arrays,
    slot_states,
)
from coordinator.core.trajectory import (
    TRAJECTORY_KINDS,
    Circle,
    FigureEight,
    LeaderState,
    StraightLine,
    Trajectory,
    Waypoints,
    make_trajectory,
    wrap_angle,
)

__all__ = [
    "FORMATION_KINDS",
    "LEADER_SLOT",
    "ROLES",
    "TRAJECTORY_KINDS",
    "Circle",
    "FigureEight",
    "FormationSpec",
    "LeaderState",
    "RoleAssigner",
    "SlotLike",
    "SlotSpec",
    "SlotState",
    "StraightLine",
    "Trajectory",
    "Waypoints",
    "assign_greedy",
    "assign_optimal",
    "assignment_cost",
    "make_trajectory",
    "natural_key",
    "slot_arrays",
    "slot_states",
    "wrap_angle",
]
