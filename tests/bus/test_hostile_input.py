"""Hostile input on every key each node subscribes to: the node survives, keeps working, counts.

For each node (agent, coordinator, plant; in lockstep, so the clock / leader keys are subscribed
too) the test session publishes on every subscribed key: random bytes, an empty and a truncated
payload, msgpack that is not a map, wrong types, a bool for an int, NaN and inf, a missing field,
huge values, an unknown version, an oversized payload (beyond ``MAX_PAYLOAD_BYTES``) and a
misaddressed message. Each must be rejected and counted (the agent's ``status.rejected``, the
coordinator's and plant's status maps). Values beyond the contract's plausibility bounds (1e300 m,
t = 1e300) are rejected and counted like the rest; values at the bounds (1 km away, far-future
ticks) are valid for the decoder and must not crash anything either. Afterwards each node still
answers: the agent publishes status and answers a clock, the coordinator answers a clock with its
leader message, the plant re-announces its clock and advances when the tick is answered.

Delivery is confirmed by the nodes' own per-input receive counters (``rx``) before the rejected
counts are compared, so nothing here depends on timing.
"""

from __future__ import annotations

import math
import random
import time
from collections.abc import Callable, Mapping
from dataclasses import replace
from typing import Any

import msgpack
import pytest
import zenoh
from support.agent_io import setpoint_msg
from support.bus_watch import Recorder, decoder_of
from support.routers import RouterHandle
from support.spawn import Child, Spawner

import runtime as rt
from bus_schemas import (
    MAX_PAYLOAD_BYTES,
    Clock,
    Disturbance,
    Estop,
    Leader,
    Message,
    PoseBatch,
    Status,
    Wheels,
    encode,
    keys,
    to_map,
)
from bus_schemas.spec import POSITION_MAX_M as POS
from bus_schemas.spec import TIME_MAX_S, WHEEL_RATE_MAX_RADPS

pytestmark = pytest.mark.shares_cpu


def _ticked(msg, tick):  # type: ignore[no-untyped-def]
    """``msg`` encoded with its lockstep ``tick`` (a declared field of setpoint/slot/leader)."""
    return encode(replace(msg, tick=tick))


FLEET = "demo"
Payloads = list[tuple[str, bytes]]


def pack(obj: Any) -> bytes:
    data: bytes = msgpack.packb(obj, use_bin_type=True)
    return data


def forged(payload: bytes, **fields: Any) -> bytes:
    """A valid payload with some fields overwritten (beyond what ``encode`` would accept)."""
    return pack({**msgpack.unpackb(payload), **fields})


def hostile(
    valid: Message, field: str, huge: Mapping[str, Any], extra: Payloads | None = None
) -> Payloads:
    """Payloads a strict decoder of ``valid``'s type must reject (``field`` is a required one),
    plus ``extra`` ones the node itself must reject."""
    base = to_map(valid)
    rnd = random.Random(f"{type(valid).__name__}-{field}")
    out: Payloads = [
        ("random bytes", bytes(rnd.getrandbits(8) for _ in range(64))),
        ("empty", b""),
        ("truncated", pack(base)[:-3]),
        ("array", pack([1, 2, 3])),
        ("int", pack(7)),
        ("wrong type t", pack({**base, "t": "now"})),
        ("wrong type field", pack({**base, field: [1]})),
        ("bool for int", pack({**base, "v": True})),
        ("nan", pack({**base, "t": math.nan})),
        ("inf", pack({**base, "t": math.inf})),
        ("negative t", pack({**base, "t": -1.0})),
        ("missing field", pack({k: v for k, v in base.items() if k != field})),
        ("huge", pack({**base, **huge})),
        ("unknown version", pack({**base, "v": 2})),
        ("oversized", pack({**base, "pad": b"x" * (MAX_PAYLOAD_BYTES + 1000)})),
    ]
    return out + list(extra or ())


def publish_all(pubs: rt.Publishers, key: str, payloads: Payloads) -> int:
    for _, payload in payloads:
        pubs.put(key, payload, rt.QOS_CRITICAL)
    return len(payloads)


def warm_up(
    rec: Recorder,
    counts: Callable[[Any], Mapping[str, int]],
    names: tuple[str, ...],
    publish_once: Callable[[], object],
    timeout_s: float = 10.0,
) -> None:
    """Publish valid messages until the node's status shows one received on every input."""
    deadline = time.monotonic() + timeout_s
    while True:
        publish_once()
        time.sleep(0.05)
        items = rec.snapshot()
        if items and all(counts(items[-1][2]).get(n, 0) > 0 for n in names):
            return
        assert time.monotonic() < deadline, f"inputs {names} never all counted"


def wait_counts(
    rec: Recorder, counts: Callable[[Any], Mapping[str, int]], want: Mapping[str, int]
) -> Any:
    """The first status whose receive counters reached ``want`` (every injection delivered)."""
    _, _, st = rec.wait_for(
        lambda _r, _k, s: all(counts(s).get(k, 0) >= n for k, n in want.items()), timeout_s=10.0
    )
    return st


@pytest.fixture
def client(session: Callable[..., zenoh.Session]) -> zenoh.Session:
    return session()


def assert_alive(child: Child) -> None:
    """Still running, and no handler hit an internal error (a bug) on the way."""
    assert child.proc.poll() is None, child.describe()
    assert "internal error" not in child.stderr(), child.describe()


# ---------------------------------------------------------------------------------------------


def test_agent_survives_counts_and_keeps_answering(
    spawn: Spawner, router: RouterHandle, client: zenoh.Session
) -> None:
    pubs = rt.Publishers(client)
    status = Recorder(client, keys.status_key(FLEET, "r1"), decoder_of(Status))
    wheels = Recorder(client, keys.wheels_key(FLEET, "r1"), decoder_of(Wheels))
    child = spawn(
        "agent", "--id", "r1", "--lockstep", "--endpoint", router.endpoint, ready="agent r1"
    )
    # a lockstep agent takes its own pose from the plant's frames (`poses`, its own entry): the
    # plant puts each robot's `pose` only while someone subscribes to it
    k_sp = keys.setpoint_key(FLEET, "r1")
    k_batch, k_estop, k_clock = keys.poses_key(FLEET), keys.estop_key(FLEET), keys.clock_key(FLEET)
    sp = setpoint_msg("r1", 0.45, 0.0, t=0.0)
    batch = PoseBatch(
        t=0.0, seq=1, robots=("r1", "r2"), x=(0.0, 0.5), y=(0.0, 0.5), theta=(0.0, 0.0), stamp=0.0
    )
    release = Estop(t=0.0, engage=False, robot=None)

    def clock(k: int) -> bytes:
        return encode(Clock(t=k * 0.02, seq=k + 1, tick=k))

    def valid_once() -> None:
        for key, payload in (
            (k_sp, _ticked(sp, 0)),
            (k_batch, encode(batch)),
            (k_estop, encode(release)),
            (k_clock, clock(0)),
        ):
            pubs.put(key, payload, rt.QOS_CRITICAL)

    warm_up(status, lambda s: s.rx, ("setpoint", "poses", "estop", "clock"), valid_once)
    status.clear()
    _, _, before = status.wait_for(lambda *_: True)
    assert before.rejected == 0

    no_tick = encode(sp)  # lockstep setpoints must carry their tick
    must = {
        "setpoint": hostile(
            sp,
            "slot",
            {"slot": 10**9},
            [
                ("no tick", no_tick),
                ("fast", forged(_ticked(sp, 2**63), x=1e300, t=1e300)),
            ],
        ),
        "poses": hostile(
            batch,
            "robots",
            {"robots": ["r2"] * 2000},
            [
                ("far stamp", forged(encode(batch), stamp=1e300)),
                ("own pose far away", forged(encode(batch), x=[1e300, 0.5], y=[-1e300, 0.5])),
            ],
        ),
        "estop": hostile(release, "engage", {"robot": "r" * 1000}),
        "clock": hostile(Clock(t=0.0, seq=1, tick=0), "tick", {"tick": -1}),
    }
    absurd = {  # valid for the decoder (at the plausibility bounds); the firmware must cope
        "setpoint": [("fast", _ticked(setpoint_msg("r1", POS, 0.0, t=TIME_MAX_S), 2**63))],
        "poses": [
            (
                "own pose far away",
                encode(
                    PoseBatch(
                        t=0.0,
                        seq=3,
                        robots=("r1",),
                        x=(POS,),
                        y=(-POS,),
                        theta=(0.0,),
                        stamp=TIME_MAX_S,
                    )
                ),
            ),
            (
                "far neighbour",
                encode(
                    PoseBatch(
                        t=0.0,
                        seq=2,
                        robots=("r3",),
                        x=(1e-300,),
                        y=(0.0,),
                        theta=(0.0,),
                        stamp=TIME_MAX_S,
                    )
                ),
            ),
        ],
        "estop": [],
        "clock": [],
    }
    key_of = {
        "setpoint": k_sp,
        "poses": k_batch,
        "estop": k_estop,
        "clock": k_clock,
    }
    want = dict(before.rx)
    for name, key in key_of.items():
        want[name] += publish_all(pubs, key, must[name] + absurd[name])
    after = wait_counts(status, lambda s: s.rx, want)
    n_must = sum(len(v) for v in must.values())
    assert after.rejected - before.rejected >= n_must
    assert_alive(child)

    # Still answering: a valid clock gets its wheels, the status keeps coming.
    for k in range(1, 50):
        pubs.put(k_clock, clock(k), rt.QOS_CRITICAL)
        if [w for _, _, w in wheels.snapshot() if w.tick == k]:
            break
    wheels.wait_for(lambda _r, _k, w: w.tick is not None and w.tick >= 1, timeout_s=2.0)
    status.clear()
    status.wait_for(lambda *_: True, timeout_s=1.0)
    assert_alive(child)


def test_coordinator_survives_counts_and_keeps_answering(
    spawn: Spawner, router: RouterHandle, client: zenoh.Session
) -> None:
    pubs = rt.Publishers(client)
    token = rt.declare_token(client, keys.alive_robot_key(FLEET, "r1"))
    status = Recorder(client, f"formation/{FLEET}/coordinator/main/status", msgpack.unpackb)
    leaders = Recorder(client, keys.leader_key(FLEET), msgpack.unpackb)
    child = spawn(
        "coordinator",
        "--scenario",
        "paper-exp2",
        "--lockstep",
        "--endpoint",
        router.endpoint,
        ready="coordinator ready",
    )
    # a lockstep coordinator reads the plant's frames as `poses` batches (the plant puts each
    # robot's `pose` only while someone subscribes to it): those are its pose input here
    k_poses, k_clock = keys.poses_key(FLEET), keys.clock_key(FLEET)
    frame = PoseBatch(t=0.0, seq=1, robots=("r1",), x=(0.4,), y=(0.0,), theta=(0.0,), stamp=0.0)

    def valid_once() -> None:
        pubs.put(k_poses, encode(frame), rt.QOS_CRITICAL)
        pubs.put(k_clock, encode(Clock(t=0.0, seq=1, tick=0)), rt.QOS_CRITICAL)

    warm_up(status, lambda s: s["rx"], ("poses", "clock"), valid_once)
    status.clear()
    _, _, before = status.wait_for(lambda *_: True)
    assert before["rejected"] == 0

    base = to_map(frame)
    must_poses = hostile(
        frame,
        "stamp",
        {"stamp": 1e300},
        [
            ("bad robot id", pack({**base, "robots": ["R1"]})),
            ("lengths differ", pack({**base, "x": [0.4, 0.5]})),
            ("far", forged(encode(frame), x=[1e300], y=[1e300])),
        ],
    )
    must_clock = hostile(Clock(t=0.0, seq=1, tick=0), "tick", {"tick": -1})
    sent_poses = publish_all(pubs, k_poses, must_poses)
    sent_clock = publish_all(pubs, k_clock, must_clock)
    want = {
        "poses": before["rx"]["poses"] + sent_poses,
        "clock": before["rx"]["clock"] + sent_clock,
    }
    after = wait_counts(status, lambda s: s["rx"], want)
    assert after["rejected"] - before["rejected"] >= len(must_poses) + len(must_clock)
    assert after["internal_errors"] == 0
    assert_alive(child)

    k = 10_000  # still answering: a fresh clock gets its leader message, with its tick
    pubs.put(k_clock, encode(Clock(t=k * 0.02, seq=k, tick=k)), rt.QOS_CRITICAL)
    leaders.wait_for(lambda _r, _k, m: m.get("tick") == k, timeout_s=2.0)
    assert_alive(child)
    del token


def test_plant_survives_counts_and_keeps_answering(
    spawn: Spawner, router: RouterHandle, client: zenoh.Session
) -> None:
    pubs = rt.Publishers(client)
    robots = ("r1", "r2", "r3")
    tokens = [rt.declare_token(client, keys.alive_robot_key(FLEET, r)) for r in robots]
    tokens.append(rt.declare_token(client, keys.alive_coordinator_key(FLEET, "test")))
    status = Recorder(client, f"formation/{FLEET}/plant/status", msgpack.unpackb)
    clocks = Recorder(client, keys.clock_key(FLEET), decoder_of(Clock))
    child = spawn(
        "plant",
        "--scenario",
        "paper-exp2",
        "--lockstep",
        "--wait-robots",
        "--lockstep-timeout",
        "30",
        "--endpoint",
        router.endpoint,
        ready="plant ready",
    )
    clocks.wait_for(lambda *_: True)  # running, blocked at tick 0 until answered
    k_wheels, k_dist, k_leader = (
        keys.wheels_key(FLEET, "r1"),
        keys.disturbance_key(FLEET),
        keys.leader_key(FLEET),
    )
    wheels = Wheels(t=0.0, seq=1, omega_r=1.0, omega_l=1.0, power_r=0.1, power_l=0.1, pose_t=None)
    drag = Disturbance(t=0.0, robot="r1", kind="drag", dx=0.1, dy=0.0, duration_s=1.0)
    leader = Leader(t=0.0, seq=1, x=0.0, y=0.0, theta=0.0, v_mps=0.0, omega_radps=0.0)

    def valid_once() -> None:
        pubs.put(k_wheels, encode(wheels), rt.QOS_CRITICAL)
        pubs.put(k_dist, encode(drag), rt.QOS_CRITICAL)
        pubs.put(k_leader, _ticked(leader, 10**6), rt.QOS_CRITICAL)

    warm_up(status, lambda s: s["rx"], ("wheels", "disturbance", "leader"), valid_once)
    status.clear()
    _, _, before = status.wait_for(lambda *_: True)
    assert before["rejected"] == 0

    far = forged(encode(drag), dx=1e300)
    no_target = pack({**to_map(drag), "kind": "teleport"})  # teleport needs x, y, theta
    must = {
        "wheels": hostile(
            wheels,
            "omega_r",
            {"power_r": 1e300},
            [("too fast", forged(encode(wheels), omega_r=1e300, omega_l=-1e300, pose_t=1e300))],
        ),
        "disturbance": hostile(
            drag, "kind", {"kind": "explode"}, [("far", far), ("no target", no_target)]
        ),
        "leader": hostile(leader, "x", {"theta": 1e300}, [("no tick", encode(leader))]),
    }
    absurd = {
        "wheels": [
            (
                "fast",
                encode(
                    Wheels(
                        t=0.0,
                        seq=2,
                        omega_r=WHEEL_RATE_MAX_RADPS,
                        omega_l=-WHEEL_RATE_MAX_RADPS,
                        power_r=1.0,
                        power_l=-1.0,
                        pose_t=TIME_MAX_S,
                    )
                ),
            )
        ],
        "disturbance": [
            (
                "unknown robot",
                encode(Disturbance(t=0.0, robot="zz", kind="drag", dx=0.0, dy=0.0, duration_s=0.0)),
            )
        ],
        "leader": [],
    }
    key_of = {"wheels": k_wheels, "disturbance": k_dist, "leader": k_leader}
    want = dict(before["rx"])
    for name, key in key_of.items():
        want[name] += publish_all(pubs, key, must[name] + absurd[name])
    n_clocks = len(clocks.snapshot())
    after = wait_counts(status, lambda s: s["rx"], want)
    assert after["rejected"] - before["rejected"] >= sum(len(v) for v in must.values())
    assert after["internal_errors"] == 0 and after["state"] == "running"
    assert_alive(child)

    # Still going: it re-announces clock 0 while waiting, and advances once tick 0 is answered.
    clocks.wait_for(lambda *_: len(clocks.snapshot()) > n_clocks, timeout_s=1.0)
    for rid in robots:
        answer = Wheels(
            t=0.0, seq=9, omega_r=0.0, omega_l=0.0, power_r=0.0, power_l=0.0, pose_t=None, tick=0
        )
        pubs.put(keys.wheels_key(FLEET, rid), encode(answer), rt.QOS_CRITICAL)
    pubs.put(k_leader, _ticked(leader, 0), rt.QOS_CRITICAL)
    clocks.wait_for(lambda _r, _k, c: c.tick == 1, timeout_s=2.0)
    assert_alive(child)
    elapsed = child.stop()  # while blocked waiting for tick 1's answers
    assert child.proc.returncode == 0 and elapsed < 1.5, child.describe()
    del tokens
