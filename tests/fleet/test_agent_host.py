"""Agent hosts and the batched bus (issue 7: many robots per host process, docs/scale.md).

* in-process: id ranges; the host's spatial-hash neighbours equal the full neighbour list within
  the repulsion distance, in frame order; garbage on every input is counted, never raised;
  the plant and the coordinator take the batched forms;
* real processes: ``formation up --hosts`` in lockstep produces bit-for-bit the run of one agent
  process per robot; a 30-robot realtime run with two hosts holds the formation without a
  collision; a realtime agent host on a router rejects hostile bytes on each of its keys, keeps
  stepping, reports the rejects in its status batches and exits within a second of SIGINT.
"""

from __future__ import annotations

import gc
import json
import math
import os
import random
import signal
import sys
import time
from pathlib import Path
from typing import Any

import msgpack
import numpy as np
import pytest
from support.routers import RouterHandle
from support.spawn import Spawner, free_port

import runtime as rt
from bus_schemas import (
    Estop,
    PoseBatch,
    SetpointBatch,
    StatusBatch,
    WheelsBatch,
    decode,
    encode,
    keys,
)
from robot_agent.core.params import AgentConfig
from robot_agent.core.safety_filter import SafetyFilter
from robot_agent.node.host import (
    GC_MAX_GAP_S,
    STATUS_STEP,
    WATCHDOG_CHUNK,
    WATCHDOG_YIELD_S,
    HostNode,
)
from robot_agent.node.host_main import expand_ids
from runtime.lifecycle import GC_FULL_EVERY, GC_MIDDLE_EVERY
from scenario import load

pytestmark = pytest.mark.shares_cpu

FLEET = "demo"


def _rx(key: str, payload: bytes, rx_s: float | None = None) -> rt.Received:
    return rt.Received(key=key, payload=payload, rx_s=time.monotonic() if rx_s is None else rx_s)


class _Bus:
    """What a node published, in order (the ``publish`` callable of the Zenoh-free nodes)."""

    def __init__(self) -> None:
        self.out: list[tuple[str, bytes]] = []

    def __call__(self, key: str, payload: bytes, qos: Any) -> None:
        self.out.append((key, payload))


# ---------------------------------------------------------------------------------------------
# In-process
# ---------------------------------------------------------------------------------------------


def test_expand_ids() -> None:
    assert expand_ids("r1..r3,x7") == ["r1", "r2", "r3", "x7"]
    assert expand_ids("r9..12") == ["r9", "r10", "r11", "r12"]
    for bad in ("", "R1", "r3..r1", "r1,r1", "a/b"):
        with pytest.raises(ValueError):
            expand_ids(bad)


def _frame(ids: list[str], xy: np.ndarray, stamp: float = 1.0) -> bytes:
    return encode(
        PoseBatch(
            t=stamp,
            seq=1,
            robots=tuple(ids),
            x=tuple(float(v) for v in xy[:, 0]),
            y=tuple(float(v) for v in xy[:, 1]),
            theta=(0.0,) * len(ids),
            stamp=stamp,
        )
    )


def test_spatial_hash_neighbours_equal_the_full_list_within_d0() -> None:
    rng = np.random.default_rng(5)
    n = 200
    ids = [f"r{i + 1}" for i in range(n)]
    xy = rng.uniform(-2.0, 2.0, size=(n, 2))
    cfg = AgentConfig()
    d0 = cfg.repulsion.d0_m
    host = HostNode("h1", ids[:50], FLEET, cfg, _Bus(), lockstep=False)
    host.on_poses(_rx(keys.poses_key(FLEET), _frame(ids, xy)))
    now = time.monotonic()
    for j, rid in enumerate(ids[:50]):
        got = [(n.x, n.y) for n in host._neighbours_of(host.nodes[rid], now)]
        # what `formation agent` passes: every other robot, frame order; the firmware ignores
        # those beyond d0 and the safety filter's range, so the host may leave them out but
        # must keep the order
        reach = max(d0, SafetyFilter(cfg).neighbour_range_m)
        assert host.cell_m == reach
        full = [(float(x), float(y)) for k, (x, y) in enumerate(xy) if k != j]
        near = [p for p in full if math.dist(p, xy[j]) < reach]
        assert [p for p in got if math.dist(p, xy[j]) < reach] == near
        assert all(math.dist(p, xy[j]) < 3 * reach for p in got)  # only the 3 x 3 cells


def test_host_steps_on_a_frame_and_answers_in_one_batch() -> None:
    bus = _Bus()
    ids = ["r1", "r2", "r3"]
    host = HostNode("h1", ids, FLEET, AgentConfig(), bus, lockstep=False)
    sp = SetpointBatch(
        t=1.0, seq=1, robots=("r1", "r2", "r3"), slot=(0, 1, 2),
        role=("leader", "subleader", "subleader"), stage=(0, 1, 1), x=(0.5, 0.1, 0.1),
        y=(0.0, 0.2, -0.2), theta=0.0, vx=(0.02,) * 3, vy=(0.0,) * 3,
    )  # fmt: skip
    host.on_setpoints(_rx(keys.setpoints_key(FLEET), encode(sp)))
    xy = np.array([[0.3, 0.0], [-0.1, 0.3], [-0.1, -0.3]])
    host.on_poses(_rx(keys.poses_key(FLEET), _frame(ids, xy, stamp=2.0)))
    batches = [decode(p, WheelsBatch) for k, p in bus.out if k == host.wheels_key]
    assert len(batches) == 1
    wb = batches[0]
    assert isinstance(wb, WheelsBatch)
    assert wb.robots == ("r1", "r2", "r3") and wb.pose_t == (2.0, 2.0, 2.0)
    assert all(abs(w) > 0.0 for w in wb.omega_r)  # tracking: the wheels move
    status = [decode(p, StatusBatch) for p in _status_payloads(host)]
    assert status[0].mode == ("tracking",) * 3 and status[0].slot == (0, 1, 2)


def test_watchdog_steps_a_chunk_per_turn_and_skips_robots_a_frame_stepped() -> None:
    # the realtime watchdog steps at most WATCHDOG_CHUNK robots per call and asks to be called
    # again at once; a frame arriving between two calls steps its robots, which are then no
    # longer due (explicit times: nothing here depends on the wall clock)
    bus = _Bus()
    ids = [f"r{i + 1}" for i in range(2 * WATCHDOG_CHUNK + 5)]
    host = HostNode("h1", ids, FLEET, AgentConfig(), bus, lockstep=False)

    def sent() -> list[str]:
        got = [decode(p, WheelsBatch) for k, p in bus.out if k == host.wheels_key]
        bus.out.clear()
        return [r for b in got if isinstance(b, WheelsBatch) for r in b.robots]

    t0 = time.monotonic()
    before = time.monotonic()
    again = host.control_timer(t0)
    assert sent() == ids[:WATCHDOG_CHUNK]  # never stepped: due, the first chunk only
    assert again <= time.monotonic() + WATCHDOG_YIELD_S and again >= before
    xy = np.array([[0.5 * i, 0.0] for i in range(len(ids))])
    host.on_poses(_rx(keys.poses_key(FLEET), _frame(ids, xy)))  # the frame steps everyone
    assert sent() == ids
    t1 = min(n.last_step_s for n in host.nodes.values()) + 0.5 * host.period_s
    host.control_timer(t1)
    assert sent() == []  # stepped by the frame: nobody is due
    t2 = max(n.last_step_s for n in host.nodes.values()) + host.period_s
    host.control_timer(t2)
    assert sent() == ids[:WATCHDOG_CHUNK]  # a period later: the watchdog again, in chunks


def test_manual_gc_collects_at_the_end_of_a_watchdog_round_never_inside_a_frame() -> None:
    # realtime host_main turns the automatic collection off; the host collects once a watchdog
    # round is complete (between frames) and, with no round, at least every GC_MAX_GAP_S
    ids = [f"r{i + 1}" for i in range(WATCHDOG_CHUNK + 5)]
    host = HostNode("h1", ids, FLEET, AgentConfig(), _Bus(), lockstep=False)
    host.manual_gc = True
    gens: list[int] = []

    def seen(phase: str, info: dict[str, int]) -> None:
        if phase == "start":
            gens.append(info["generation"])

    gc.callbacks.append(seen)
    enabled = gc.isenabled()
    gc.disable()
    try:
        t0 = time.monotonic()
        host.control_timer(t0)  # the first chunk: the round goes on, no collection
        assert gens == [] and host.gc_rounds == 0
        host.control_timer(t0)  # the last chunk: the round is complete
        assert gens == [0] and host.gc_rounds == 1
        xy = np.array([[0.5 * i, 0.0] for i in range(len(ids))])
        host.on_poses(_rx(keys.poses_key(FLEET), _frame(ids, xy)))
        assert gens == [0]  # a frame's steps never collect
        t1 = min(n.last_step_s for n in host.nodes.values()) + 0.5 * host.period_s
        host.gc_s = t1
        host.control_timer(t1)  # nobody due, the last collection recent: nothing
        assert gens == [0]
        t2 = t1 + GC_MAX_GAP_S
        for n in host.nodes.values():
            n.last_step_s = t2
        host.control_timer(t2)  # nobody due, no collection for GC_MAX_GAP_S: collect anyway
        assert gens == [0, 0]
        host.gc_rounds = GC_MIDDLE_EVERY - 1
        host.collect_garbage(t0)
        host.gc_rounds = GC_FULL_EVERY - 1
        host.collect_garbage(t0)
        assert gens == [0, 0, 1, 2]
    finally:
        gc.callbacks.remove(seen)
        if enabled:
            gc.enable()


def test_status_round_in_pieces_publishes_one_batch_of_every_robot() -> None:
    bus = _Bus()
    ids = [f"r{i + 1}" for i in range(2 * STATUS_STEP + 3)]
    host = HostNode("h1", ids, FLEET, AgentConfig(), bus, lockstep=False)
    calls = 1
    while host.publish_status() is not None:  # realtime: STATUS_STEP robots per call
        assert not [k for k, _ in bus.out if k == host.status_key]  # nothing before the end
        calls += 1
    assert calls == 3
    (batch,) = [decode(p, StatusBatch) for k, p in bus.out if k == host.status_key]
    assert isinstance(batch, StatusBatch) and batch.robots == tuple(ids)
    lock = HostNode("h2", ids, FLEET, AgentConfig(), _Bus(), lockstep=True)
    assert lock.publish_status() is None  # lockstep: all at once


def _status_payloads(host: HostNode) -> list[bytes]:
    return [encode(m) for m in host.status_batches(time.monotonic())]


def _garbage(rng: random.Random) -> list[bytes]:
    good = _frame(["r1"], np.zeros((1, 2)))
    m = msgpack.unpackb(good)
    return [
        b"",
        b"\xc1",
        bytes(rng.getrandbits(8) for _ in range(64)),
        msgpack.packb([1, 2, 3]),
        msgpack.packb({**m, "v": 99}),
        msgpack.packb({**m, "x": [float("nan")]}),
        msgpack.packb({**m, "x": [1e300, 2.0]}),
        msgpack.packb({**m, "robots": ["R1"]}),
        msgpack.packb({**m, "stamp": "now"}),
    ]


def test_garbage_on_every_host_input_is_counted_and_never_raised() -> None:
    bus = _Bus()
    host = HostNode("h1", ["r1", "r2"], FLEET, AgentConfig(), bus, lockstep=True)
    rng = random.Random(3)
    handlers = [host.on_poses, host.on_setpoints, host.estop.on_estop, host.on_clock]
    sent = 0
    for handler in handlers:
        for payload in _garbage(rng):
            handler(_rx("formation/demo/x", payload))
            sent += 1
    assert host.faults.internal_errors == 0
    assert host.faults.rejected == sent
    assert all(n.rejected == sent for n in host.nodes.values())
    assert not [k for k, _ in bus.out if k == host.wheels_key]  # nothing stepped on garbage


def test_plant_and_coordinator_take_the_batched_forms() -> None:
    from coordinator.node.coordinator import CoordinatorNode
    from sim_plant.node.plant import PlantNode

    scn = load("chevron7")
    plant = PlantNode(scn, FLEET, _Bus(), lockstep=True, batch=True)
    wb = WheelsBatch(
        t=0.0, seq=1, robots=("r1", "r2", "zz"), omega_r=(1.0, 2.0, 3.0),
        omega_l=(1.5, 2.5, 3.5), power_r=(0.1, 0.2, 0.3), power_l=(0.1, 0.2, 0.3),
        pose_t=(0.0, -1.0, 0.0), tick=0,
    )  # fmt: skip
    plant.inputs.on_host_wheels(_rx(keys.host_wheels_key(FLEET, "h1"), encode(wb)))
    cmd = plant.inputs.last_cmd
    assert cmd[0].tolist() == [1.0, 1.5] and cmd[1].tolist() == [2.0, 2.5]
    assert (
        plant.inputs.answer_tick[:2] == [0, 0] and plant.inputs.ignored == 1
    )  # zz is not simulated
    for payload in _garbage(random.Random(1)):
        plant.inputs.on_host_wheels(_rx(keys.host_wheels_key(FLEET, "h1"), payload))
    assert plant.internal_errors == 0 and plant.rejected == len(_garbage(random.Random(1)))

    coord = CoordinatorNode(scn, "main", FLEET, _Bus(), lockstep=False, batch=True)
    ids = list(scn.robot_ids)
    coord.on_poses(_rx(keys.poses_key(FLEET), _frame(ids, np.array(scn.initial)[:, :2])))
    assert set(coord.poses) == set(ids)
    # 20 km: beyond the contract's position bound (and the coordinator's own limit)
    good = msgpack.unpackb(_frame(["r1", "r2"], np.zeros((2, 2))))
    bad = msgpack.packb({**good, "x": [2e4, 0.0]})
    coord.on_poses(_rx(keys.poses_key(FLEET), bad))
    assert coord.rejected == 1 and coord.faults.internal_errors == 0


# ---------------------------------------------------------------------------------------------
# Real processes
# ---------------------------------------------------------------------------------------------


def _up(spawn: Spawner, out: Path, *args: str, timeout_s: float = 90.0) -> dict[str, Any]:
    # a free port and a fleet of its own: the default 7447 may be another run's on a shared box
    child = spawn(
        "up", "--endpoint", f"tcp/127.0.0.1:{free_port()}", "--fleet", f"t{os.getpid()}{out.name}",
        "--out", str(out), "--quiet", "--no-figures", *args,
    )  # fmt: skip
    child.proc.wait(timeout=timeout_s)
    assert child.proc.returncode == 0, child.describe()
    metrics: dict[str, Any] = json.loads((out / "metrics.json").read_text())
    return metrics


def test_lockstep_agent_hosts_reproduce_per_robot_agents_bit_for_bit(
    spawn: Spawner, tmp_path: Path
) -> None:
    common = ("--scenario", "chevron7", "--lockstep", "--duration", "3")
    a = _up(spawn, tmp_path / "agents", *common, "--hosts", "0")  # one process per robot
    b = _up(spawn, tmp_path / "hosts", *common, "--hosts", "2")
    assert set(b["meta"]["children"]) >= {"agent-host-h1", "agent-host-h2"}
    assert b["meta"]["collector"]["received"].get("host_wheels", 0) > 0
    assert a["run"] == b["run"] and a["robots"] == b["robots"]
    ra, rb = np.load(tmp_path / "agents" / "run.npz"), np.load(tmp_path / "hosts" / "run.npz")
    for name in ("t_s", "truth", "power", "slot_of", "target"):
        assert np.array_equal(ra[name], rb[name], equal_nan=True), name
    # A --batch coordinator sends the assigned slots every tick (setpoint batches) and every slot
    # at 1 Hz: before the first assignment (ticks 0-1, truth is logged at every tick) the hosts
    # run's slot_xy holds tick 0's slots. Once every slot is held, slot_xy is equal.
    held = (ra["slot_of"] >= 0).all(axis=1)
    assert held.sum() > 0.9 * held.size
    assert np.array_equal(ra["slot_xy"][held], rb["slot_xy"][held]), "slot_xy"


@pytest.mark.alone
def test_thirty_robots_on_two_hosts_hold_the_formation_in_realtime(
    spawn: Spawner, tmp_path: Path
) -> None:
    m = _up(
        spawn, tmp_path / "rt", "--scenario", "lattice", "--robots", "30", "--hosts", "2",
        "--duration", "6",
    )  # fmt: skip
    run = m["run"]
    assert run["collisions"] == 0 and run["min_separation_m"] > 0.15
    assert run["final_leader"] == "r1"
    assert len({c["robot"] for c in run["initial_assignments"]}) == 30  # everyone got a slot
    errors = [r["formation_error_rms_m"] for r in m["robots"].values()]
    assert max(e for e in errors if e is not None) < 0.05


@pytest.mark.alone
def test_agent_host_process_rejects_hostile_bytes_and_exits_on_sigint(
    spawn: Spawner, router: RouterHandle, session: Any
) -> None:
    host = spawn(
        "agent-host", "--ids", "r1..r3", "--name", "h1", "--endpoint", router.endpoint,
        ready="agent-host h1 ready",
    )  # fmt: skip
    s = session()
    status: list[StatusBatch] = []
    wheels: list[WheelsBatch] = []

    def on_status(sample: Any) -> None:
        msg = decode(sample.payload.to_bytes(), StatusBatch)
        if isinstance(msg, StatusBatch):
            status.append(msg)

    def on_wheels(sample: Any) -> None:
        msg = decode(sample.payload.to_bytes(), WheelsBatch)
        if isinstance(msg, WheelsBatch):
            wheels.append(msg)

    s.declare_subscriber(keys.host_status_key(FLEET, "h1"), on_status)
    s.declare_subscriber(keys.host_wheels_key(FLEET, "h1"), on_wheels)
    tokens: list[str] = []
    s.liveliness().declare_subscriber(
        keys.alive_robots_pattern(FLEET), lambda smp: tokens.append(str(smp.key_expr)), history=True
    )
    deadline = time.monotonic() + 5.0
    while len(set(tokens)) < 3 and time.monotonic() < deadline:
        time.sleep(0.05)
    assert len(set(tokens)) == 3  # one liveliness token per hosted robot
    rng = random.Random(7)
    garbage = _garbage(rng)
    for key in (keys.poses_key(FLEET), keys.setpoints_key(FLEET), keys.estop_key(FLEET)):
        for payload in garbage:
            s.put(key, payload)
    s.put(keys.estop_key(FLEET), encode(Estop(t=1.0, engage=True, robot="r2")))
    want = 3 * len(garbage)
    deadline = time.monotonic() + 5.0
    while time.monotonic() < deadline:
        if status and min(status[-1].rejected) >= want and "estop" in status[-1].mode:
            break
        time.sleep(0.05)
    last = status[-1]
    assert min(last.rejected) >= want, last
    assert last.mode[last.robots.index("r2")] == "estop"
    assert wheels and all(w == 0.0 for b in wheels[-3:] for w in b.omega_r)  # idle / estop
    assert host.proc.poll() is None
    t0 = time.monotonic()
    host.send_signal(signal.SIGINT)
    host.proc.wait(timeout=2.0)
    assert host.proc.returncode == 0 and time.monotonic() - t0 < 1.5, host.describe()


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(pytest.main([__file__, *sys.argv[1:]]))
