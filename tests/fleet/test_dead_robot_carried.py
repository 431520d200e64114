"""A dead robot carried through the formation (``dead_robot_carried.toml``): the leader's agent
is killed at 2 s (the plant stops its wheels), and from 4 s a hand drags its robot 0.6 m back
over 3 s (0.2 m/s). Its pose is still tracked, so the coordinator gives it to the mover detector
as an object: dragged, it is a mover (the others make room and their filters see its
velocity: coordinator.core.movers). ``formation up --lockstep`` as real processes equals
``formation sim`` bit for bit (the coordinator node and the in-process simulator take the same
robots as objects). tests/unit/formation/test_sim_faults.py tries more kill times in-process."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from support.lockstep_pair import lockstep_and_sim
from support.spawn import Spawner

pytestmark = pytest.mark.shares_cpu

SCENARIO = Path(__file__).with_name("dead_robot_carried.toml")
RUN_TIMEOUT_S = 120.0
SEPARATED_M = 0.21


@pytest.mark.zenoh
def test_a_dead_robot_carried_over_zenoh_behaves_as_in_process(
    spawn: Spawner, tmp_path: Path
) -> None:
    m, m_sim, up_log, sim_log = lockstep_and_sim(spawn, SCENARIO, tmp_path, "0", RUN_TIMEOUT_S)
    # (not "power": the recording holds a dead agent's last wheels message, the simulator
    # logs the zero wheels the plant applies)
    for key in ("t_s", "truth", "ref", "slot_of"):
        assert np.array_equal(up_log[key], sim_log[key]), key
    assert m["robots"] == m_sim["robots"]
    assert m["run"] == m_sim["run"]
    assert m["run"]["collisions"] == 0
    # the others made room: 0.229 m; without the dead robot among the objects 0.193 m
    assert m["run"]["min_separation_m"] > SEPARATED_M
    t = np.asarray(sim_log["t_s"]) - sim_log["t_s"][0]
    dragged = np.asarray(sim_log["truth"])[(t >= 4.0) & (t <= 7.5), 0, 0]
    assert np.ptp(dragged) > 0.55  # r1 was dragged
