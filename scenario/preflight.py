"""Every check of a scenario before anything moves: what ``formation check`` prints.

1. **schema**: the file loads (``scenario.load``, one line naming the field) and its trajectory
   and formation build (``scenario.check.check_cores``; a ``kind = "plan"`` trajectory is
   planned here, so an unreachable goal, a goal or start inside an obstacle or outside the
   arena is this line);
2. **path conflicts**: a slot whose sampled path crosses an obstacle or leaves the arena
   (``coordinator.core.path_check``; a planned trajectory has none by construction);
3. **slot feasibility**: a slot that moves, turns or accelerates faster than the robots can
   follow (``coordinator.core.planning.feasibility``), first instant per slot and limit.

Schema problems raise ``ScenarioError``; the other two are warnings (the run can go ahead, the
safety filter keeps the robots safe, but the formation will not be what was asked).
"""

from __future__ import annotations

from coordinator.core.path_check import PathConflict, slot_path_conflicts
from scenario.load import Scenario

__all__ = ["FEASIBILITY_HORIZON_S", "PATH_CHECK_HORIZON_S", "path_conflicts", "preflight_warnings"]

PATH_CHECK_HORIZON_S = 3600.0
"""The slot-path conflict check samples the first hour of a run at most (36,000 instants): the
scenario of a real fleet's file runs "for ever" (``scenario.fleet.RUN_FOREVER_S``) and a check
of all of it would take hours before the coordinator started."""


def path_conflicts(scenario: Scenario, duration_s: float | None = None) -> list[PathConflict]:
    """The slots whose paths cross an obstacle of ``scenario.agent.world`` or leave its arena
    over ``duration_s`` (default: the scenario's; at most :data:`PATH_CHECK_HORIZON_S`); what
    the coordinator warns about."""
    geom = scenario.agent.geometry
    duration = scenario.duration_s if duration_s is None else duration_s
    return slot_path_conflicts(
        scenario.trajectory,
        scenario.formation,
        scenario.agent.world,
        min(duration, PATH_CHECK_HORIZON_S),
        body_radius_m=geom.body_radius_m,
        ref_offset_m=geom.ref_offset_m,
    )


FEASIBILITY_HORIZON_S = 3600.0
"""The slot-feasibility check samples the first hour of a run at most (72,000 instants, about a
second): a deployed fleet's file runs "for ever" (``duration_s`` 1e6 s) and a check that walked
all of it took minutes before the coordinator started."""


def preflight_warnings(scn: Scenario, duration_s: float | None = None) -> list[str]:
    """The path-conflict and slot-feasibility warnings of ``scn`` over ``duration_s`` (default:
    the scenario's), path conflicts first; empty when the run asks for nothing impossible."""
    from coordinator.core.formation import FormationSpec
    from coordinator.core.planning.feasibility import slot_feasibility, trajectory_of
    from coordinator.core.planning.limits import SlotLimits

    duration = scn.duration_s if duration_s is None else duration_s
    out = [c.message() for c in path_conflicts(scn, duration)]
    found = slot_feasibility(
        trajectory_of(scn.trajectory),
        FormationSpec.from_dict(dict(scn.formation)),
        SlotLimits.from_agent(scn.agent),
        min(duration, FEASIBILITY_HORIZON_S),
    )
    out += [f.message() for f in found]
    return out
