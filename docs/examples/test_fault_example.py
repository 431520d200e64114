"""Fault-injection tests as a user writes them (docs/testing.md, docs/tutorial.md).

Copy this file next to your scenario and run ``pytest``: the ``fleet`` fixture comes with the
formation package (its pytest plugin) and starts a real fleet, ``formation up``, per test.
"""

from __future__ import annotations

import pytest

from formation.testing import FleetRun

pytestmark = [pytest.mark.slow, pytest.mark.zenoh]


@pytest.mark.fleet("leader-kill", lockstep=True, duration_s=14)
async def test_the_scripted_leader_kill_is_survived(fleet: FleetRun) -> None:
    """The scenario's own [[fault]] kills the leader once the fleet is in formation."""
    await fleet.finish()
    (kill,) = fleet.recovery()
    assert kill["kind"] == "kill" and kill["robot"] == "r1"
    assert kill["new_leader"] not in (None, "r1")  # somebody took over at once
    assert kill["detection_s"] < 0.1
    assert kill["min_separation_m"] > 0.15  # nobody ran into anybody


@pytest.mark.fleet("paper-exp2", lockstep=True, duration_s=34)
async def test_a_leader_killed_at_a_chosen_time_is_replaced(fleet: FleetRun) -> None:
    """``kill_leader(at=T)``: the coordinator applies it at sim time T, the same tick in every
    lockstep run (without ``at``: now, a real SIGKILL)."""
    await fleet.kill_leader(at=30.0)
    await fleet.finish()
    (kill,) = fleet.recovery()
    assert kill["t_s"] == pytest.approx(30.0)
    assert kill["reassignment_s"] is not None and kill["reassignment_s"] < 0.1
    assert kill["new_leader"] != kill["robot"]
