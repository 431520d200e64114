"""Check that a scenario's trajectory and formation tables build (the cores validate them).

``scenario.load`` checks every key it owns without numpy (an agent loads scenarios); the
trajectory and formation tables are validated by the cores that read them
(``coordinator.core.trajectory.make_trajectory``, ``coordinator.core.formation``). The tools call
:func:`check_cores` right after loading, so a misspelt trajectory key or a bad formation angle is
one ``ScenarioError`` naming the field before anything starts, not a traceback mid-run.
"""

from __future__ import annotations

from scenario.load import Scenario, ScenarioError

__all__ = ["check_cores"]


def check_cores(scn: Scenario) -> None:
    """Build the coordinator core of ``scn`` once; raise ``ScenarioError`` if it is invalid."""
    from scenario.assemble import coordinator_core  # numpy: only on a machine that runs one

    try:
        coordinator_core(scn)
    except (ValueError, TypeError, KeyError) as exc:
        where = f"{scn.source}: " if scn.source else ""
        raise ScenarioError(f"{where}{exc}") from exc
