"""Issue 16: with the plant's encoder emulation the shells equal the in-process simulator.

The in-process simulator hands each firmware its emulated encoder speeds every tick
(``Firmware.step(wheel_speeds=...)``); over the bus the lockstep clock carries them
(``Clock.enc_robots`` / ``enc_wr`` / ``enc_wl``, docs/bus.md), and the agent and the agent host
pass them on. The harness (``lockstep_equals_simulate`` of tests/bus/test_node_plant.py) wires
plant,
coordinator and agents (or one agent host) through an in-memory bus (every message encoded and
decoded) and asserts the wheel commands and the truth equal ``formation.sim.simulate.run``'s
exactly.
"""

from __future__ import annotations

from dataclasses import replace

import pytest
from support.lockstep_equality import SCENARIO, lockstep_equals_simulate

from bus_schemas import Clock
from robot_agent.core.params import EstimatorParams
from scenario import Disturbance as ScheduledDisturbance


def _scenario() -> object:
    """The estimator on, encoders with quantisation and slip, 60 ms camera latency, r2's camera
    lost for 0.4 s (the estimator rides through on odometry) and a drag of r1."""
    agent = replace(SCENARIO.agent, estimator=replace(EstimatorParams(), enabled=True))
    loss = ScheduledDisturbance(t_s=0.3, robot="r2", kind="camera_loss", duration_s=0.4)
    drag = ScheduledDisturbance(t_s=0.2, robot="r1", kind="drag", dx=-0.15, duration_s=0.4)
    return SCENARIO.with_overrides(
        agent=agent,
        camera=replace(SCENARIO.camera, latency_s=0.06),
        plant=replace(SCENARIO.plant, encoder_counts_per_rev=1000.0, encoder_slip_std=0.02),
        disturbances=(drag, loss),
    )


@pytest.mark.parametrize("hosts", [False, True], ids=["agents", "agent-host"])
def test_lockstep_with_encoder_emulation_equals_the_simulator(hosts: bool) -> None:
    scenario = _scenario()
    got = lockstep_equals_simulate(scenario, 1.2, hosts=hosts)
    clocks: list[Clock] = got["clocks"]
    ids = tuple(got["ids"])
    # tick 0 has no reading yet (the encoders need two reads); every later clock carries one
    # per robot, and they are not all zero (the robots move)
    first = {c.tick: c for c in clocks}
    assert first[0].enc_robots is None
    later = [c for c in clocks if c.tick > 0]
    assert later and all(c.enc_robots == ids for c in later)
    assert any(any(w != 0.0 for w in (c.enc_wr or ())) for c in later)
    status = got["result"].firmware_status
    assert all(s["mode"] == "tracking" for s in status.values()), status  # rode through


def test_without_the_encoders_on_the_bus_the_runtimes_differ() -> None:
    """The property the test above checks is not vacuous: an agent that ignores the clock's
    encoder speeds (as before they were carried) drives differently from the simulator."""
    import robot_agent.node.agent as agent_node

    original = agent_node.clock_wheels
    agent_node.clock_wheels = lambda msg: {}  # type: ignore[assignment]
    try:
        with pytest.raises(AssertionError):
            lockstep_equals_simulate(_scenario(), 0.6)
    finally:
        agent_node.clock_wheels = original
