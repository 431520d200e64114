"""The coordinator's planning layer (issue 27): collision-free virtual-leader trajectories.

The first of the paper's two collision-avoidance layers ("one collision avoidance layer lies on
the motion planning which is designed at the trajectories generation, and the other is on the
low level controller"): the formation's whole footprint is planned clear of every obstacle and
inside the arena, squeezing through narrow passages, and timed within every slot's limits; the
robots' safety filter stays as the second layer. Pure: numpy, scipy and shapely, no clock, no
I/O. See docs/planning.md.
"""

from __future__ import annotations

from .footprint import Footprint
from .limits import SlotLimits
from .planner import PlanResult, PlanStats, plan
from .search import NoPlan
from .world import PlanWorld

__all__ = ["Footprint", "NoPlan", "PlanResult", "PlanStats", "PlanWorld", "SlotLimits", "plan"]
