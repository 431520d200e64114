"""Issue 30 over the bus: an idle spare carried head-on through a triangle's leader at 0.3 m/s
(the robots' top speed), then a follower carried across the formation at 0.45 m/s while it
tracks its slot, ``formation up --lockstep`` as real processes (plant, coordinator, agents or an
agent host), 5 s. The coordinator detects the carried robots, publishes them on
``formation/<fleet>/movers`` and sends the formation aside; the agents take each as a
non-cooperative neighbour with its velocity (that changes the run: checked in-process). The run
equals ``formation sim``'s for the same scenario (the in-process simulator applies the same
movers one tick late, as the agents do), nobody touches, the spare never takes a slot.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from support.lockstep_pair import lockstep_and_sim
from support.spawn import Spawner

import scenario

pytestmark = pytest.mark.shares_cpu

SCENARIO = Path(__file__).with_name("carried_robots.toml")
RUN_TIMEOUT_S = 120.0
TOUCH_M = 0.150  # two bodies of 0.075 m radius


@pytest.mark.zenoh
@pytest.mark.parametrize("hosts", ["0", "1"], ids=["agents", "agent-host"])
def test_a_carried_spare_over_zenoh_behaves_as_in_process(
    spawn: Spawner, tmp_path: Path, hosts: str
) -> None:
    """Per-robot agents and one agent host (the batched bus; the host reads ``movers`` once
    for its robots) both reproduce the in-process run bit for bit: true poses, wheel powers,
    slots. (With the batched bus the recording rebuilds the slot targets from the setpoint
    batches, which carry the refuges, and the modes from the less frequent host status: the
    formation-error metrics differ there, not the motion.)"""
    m, m_sim, up_log, sim_log = lockstep_and_sim(spawn, SCENARIO, tmp_path, hosts, RUN_TIMEOUT_S)
    for key in ("t_s", "truth", "ref", "power", "slot_of"):
        assert np.array_equal(up_log[key], sim_log[key]), key
    if hosts == "0":
        assert m["robots"] == m_sim["robots"]
        assert m["run"] == m_sim["run"]
    assert m["run"]["collisions"] == 0
    assert m["run"]["min_separation_m"] > TOUCH_M
    assert m["robots"]["r4"]["final_slot"] is None
    assert (np.asarray(sim_log["slot_of"])[:, 3] == -1).all()


def test_the_movers_velocities_change_this_run(monkeypatch: pytest.MonkeyPatch) -> None:
    """What makes the comparison above cover the ``movers`` message: in-process, the same
    scenario with the movers NOT applied to the robots' neighbours moves the robots
    differently (the follower carried while it tracks was a cooperative neighbour)."""
    from formation.sim import simulate

    sc = scenario.load(str(SCENARIO))
    with_movers = np.asarray(simulate.run(sc).log.truth)
    monkeypatch.setattr(simulate, "mover", lambda entry, _vx, _vy: entry)
    without = np.asarray(simulate.run(sc).log.truth)
    assert not np.array_equal(with_movers, without)
