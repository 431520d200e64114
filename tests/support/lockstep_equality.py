"""The lockstep's node shells against the in-process simulator, without Zenoh.

:func:`wire_in_memory` wires a scenario's plant, coordinator and agents (or one agent host)
through an in-memory bus: every message encoded and decoded, delivered in publication order, as
Zenoh does within one priority. :func:`lockstep_equals_simulate` runs them and compares their
log, bit for bit, with ``formation.sim.simulate``. ``bench/bench_lockstep_handlers.py`` times
the same wiring's handlers."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import runtime as rt
from bus_schemas import (
    Clock,
    Truth,
    Wheels,
    keys,
)
from scenario import load

FLEET = "demo"
SCENARIO = load("paper-exp2")


@dataclass
class InMemoryFleet:
    """The nodes :func:`wire_in_memory` wired (``agents``: one per robot; empty with an agent
    host, which only the plant and the coordinator talk to)."""

    plant: Any
    coord: Any
    agents: list[Any] = field(default_factory=list)


def wire_in_memory(
    scenario: Any,
    duration_s: float,
    *,
    fleet: str = FLEET,
    hosts: bool = False,
    record: Callable[[str, bytes], None] | None = None,
) -> InMemoryFleet:
    """A lockstep plant, coordinator and agents (or, with ``hosts``, one agent host) wired
    through an in-memory bus (module docstring), the plant ending after ``duration_s`` of sim;
    ``record(key, payload)`` sees every message before it is delivered. Every robot and the
    coordinator are announced alive; the caller runs the plant's loop (``run_lockstep`` or
    ``run_lockstep_blocking``)."""
    from coordinator.node.coordinator import CoordinatorNode
    from robot_agent.node.agent import AgentNode
    from robot_agent.node.host import HostNode
    from sim_plant.node.plant import PlantNode

    routes: list[tuple[Callable[[str], bool], Callable[[rt.Received], None]]] = []

    def publish(key: str, payload: bytes, qos: rt.QoS) -> None:
        if record is not None:
            record(key, payload)
        for match, handler in routes:
            if match(key):
                handler(rt.Received(key, payload, time.monotonic()))

    plant = PlantNode(scenario, fleet, publish, lockstep=True, duration_s=duration_s, batch=hosts)
    coord = CoordinatorNode(scenario, "main", fleet, publish, lockstep=True, batch=hosts)
    wired = InMemoryFleet(plant, coord)
    if hosts:
        host = HostNode("h1", plant.ids, fleet, scenario.agent, publish, lockstep=True)
        routes.append(
            (lambda k: k.endswith("/wheels") and "/host/" in k, plant.inputs.on_host_wheels)
        )
        routes.append((host.setpoints_key.__eq__, host.on_setpoints))
        routes.append((host.poses_key.__eq__, host.on_poses))
        routes.append((host.clock_key.__eq__, host.on_clock))
    else:
        wired.agents = [
            AgentNode(r, fleet, scenario.agent, publish, lockstep=True) for r in plant.ids
        ]
        routes.append((lambda k: k.endswith("/wheels"), plant.inputs.on_wheels))
        for a in wired.agents:
            for key, handler in (
                (a.setpoint_key, a.on_setpoint),
                (a.poses_key, a.on_poses),
                (a.pose_key, a.on_pose),
                (a.clock_key, a.on_clock),
            ):
                routes.append((key.__eq__, handler))
    routes.append((lambda k: k == plant.leader_key, plant.inputs.on_leader))
    # every lockstep node reads the plant's frames as batches (the agents take their own pose
    # from them): the coordinator reads the batches, as `formation coordinator --lockstep` does
    routes.append((lambda k: k == plant.outputs.poses_key, coord.on_poses))
    routes.append((lambda k: k == coord.clock_key, coord.on_clock))
    for rid in plant.ids:
        plant.inputs.on_alive_robot(keys.alive_robot_key(fleet, rid), True)
        coord.on_alive(keys.alive_robot_key(fleet, rid), True)
    plant.inputs.on_alive_coordinator(keys.alive_coordinator_key(fleet, "main"), True)
    return wired


def lockstep_equals_simulate(
    scenario: Any, duration: float, *, hosts: bool = False
) -> dict[str, Any]:
    """Plant, coordinator and agents (or one agent host) wired in memory (:func:`wire_in_memory`)
    run the lockstep protocol; asserts the wheel commands and the truth equal
    ``formation.sim.simulate.run``'s exactly. Returns what the test may look at further."""
    import asyncio

    from bus_schemas import TruthBatch, WheelsBatch, decode
    from formation.sim.simulate import run

    wheels: dict[tuple[int, str], tuple[float, float]] = {}
    truth: dict[tuple[float, str], tuple[float, float, float]] = {}
    clocks: list[Clock] = []

    def record(key: str, payload: bytes) -> None:
        if key.endswith("/wheels") and "/host/" in key:
            b = decode(payload, WheelsBatch)
            assert isinstance(b, WheelsBatch) and b.tick is not None
            for rid, pr, pl in zip(b.robots, b.power_r, b.power_l, strict=True):
                wheels[(b.tick, rid)] = (pr, pl)
        elif key.endswith("/wheels"):
            w = decode(payload, Wheels)
            assert isinstance(w, Wheels) and w.tick is not None
            wheels[(w.tick, key.split("/")[3])] = (w.power_r, w.power_l)
        elif key.endswith("/truth"):
            tr = decode(payload, Truth)
            assert isinstance(tr, Truth) and tr.robot is not None
            truth[(tr.t, tr.robot)] = (tr.x, tr.y, tr.theta)
        elif key == keys.truths_key(FLEET):
            tb = decode(payload, TruthBatch)
            assert isinstance(tb, TruthBatch)
            for rid, x, y, th in zip(tb.robots, tb.x, tb.y, tb.theta, strict=True):
                truth[(tb.stamp, rid)] = (x, y, th)
        elif key.endswith("/clock"):
            c = decode(payload, Clock)
            assert isinstance(c, Clock)
            clocks.append(c)

    wired = wire_in_memory(scenario, duration, hosts=hosts, record=record)
    plant, coord = wired.plant, wired.coord
    assert asyncio.run(plant.run_lockstep(asyncio.Event())) is True
    assert plant.timeouts == 0 and plant.faults.rejected == coord.rejected == 0

    res = run(scenario, duration_s=duration)
    log = res.log
    ticks = round(duration / scenario.dt_s) + 1
    assert len(wheels) == ticks * len(plant.ids)
    for (k, rid), power in wheels.items():
        j = plant.ids.index(rid)
        assert power == (log.power[k, j, 0], log.power[k, j, 1]), (k, rid)
    assert len(truth) == ticks * len(plant.ids)  # lockstep: truth at every tick
    for (t, rid), pose in truth.items():
        k, j = round(t / scenario.dt_s), plant.ids.index(rid)
        assert pose == tuple(log.truth[k, j]), (t, rid)
    firmwares = [] if hosts else [a.firmware for a in wired.agents]
    return {"clocks": clocks, "result": res, "ids": plant.ids, "firmwares": firmwares}
