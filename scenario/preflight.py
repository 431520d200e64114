"""Every check of a scenario before anything moves: what ``formation check`` prints.

1. **schema**: the file loads (``scenario.load``, one line naming the field) and its trajectory
   and formation build (``scenario.check.check_cores``; a ``kind = "plan"`` trajectory is
   planned here, so an unreachable goal, a goal or start inside an obstacle or outside the
   arena is this line);
2. **path conflicts**: a slot whose sampled path crosses an obstacle or leaves the arena
   (``coordinator.path_check``; a planned trajectory has none by construction);
3. **slot feasibility**: a slot that moves, turns or accelerates faster than the robots can
   follow (``coordinator.planning.feasibility``), first instant per slot and limit.

Schema problems raise ``ScenarioError``; the other two are warnings (the run can go ahead, the
safety filter keeps the robots safe, but the formation will not be what was asked).
"""

from __future__ import annotations

from scenario.load import Scenario

__all__ = ["preflight_warnings"]


def preflight_warnings(scn: Scenario, duration_s: float | None = None) -> list[str]:
    """The path-conflict and slot-feasibility warnings of ``scn`` over ``duration_s`` (default:
    the scenario's), path conflicts first; empty when the run asks for nothing impossible."""
    from coordinator.formation import FormationSpec
    from coordinator.planning.feasibility import slot_feasibility, trajectory_of
    from coordinator.planning.limits import SlotLimits
    from scenario.assemble import path_conflicts

    duration = scn.duration_s if duration_s is None else duration_s
    out = [c.message() for c in path_conflicts(scn, duration)]
    found = slot_feasibility(
        trajectory_of(scn.trajectory),
        FormationSpec.from_dict(dict(scn.formation)),
        SlotLimits.from_agent(scn.agent),
        duration,
    )
    out += [f.message() for f in found]
    return out
