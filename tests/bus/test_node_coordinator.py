"""``formation coordinator`` as a real process on a real router.

The robots are bus inputs declared from the test session: a liveliness token
``alive/robot/<id>`` and poses on ``robot/<id>/pose`` per robot (no fake processes).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import msgpack
import pytest
import zenoh
from support.bus_watch import Recorder, decoder_of
from support.coordinator_io import FLEET, START, PoseFeeder
from support.routers import RouterHandle
from support.spawn import Spawner

import runtime as rt
from bus_schemas import Assignment, Clock, Leader, PoseBatch, Setpoint, Slot, encode, keys


@pytest.fixture
def client(session: Callable[..., zenoh.Session]) -> zenoh.Session:
    return session()


def test_setpoints_for_alive_robots_and_reassignment_when_the_leader_dies(
    spawn: Spawner, router: RouterHandle, client: zenoh.Session
) -> None:
    pubs = rt.Publishers(client)
    tokens = {r: rt.declare_token(client, keys.alive_robot_key(FLEET, r)) for r in START}
    setpoints = Recorder(client, keys.all_setpoints_pattern(FLEET), decoder_of(Setpoint))
    assignments = Recorder(client, keys.assignment_key(FLEET), decoder_of(Assignment))
    leaders = Recorder(client, keys.leader_key(FLEET), decoder_of(Leader))
    slots = Recorder(client, keys.all_slots_pattern(FLEET), decoder_of(Slot))
    status = Recorder(client, f"formation/{FLEET}/coordinator/main/status", msgpack.unpackb)
    child = spawn(
        "coordinator", "--scenario", "paper-exp2", "--endpoint", router.endpoint, ready="coord"
    )
    assert child.stdout().splitlines()[0] == "coordinator ready"
    with PoseFeeder(pubs, set(START)) as feeder:
        _, _, first = assignments.wait_for(lambda _r, _k, a: len(a.robots) == 3)
        # r1 is nearest the leader slot, r2 on the left (slot 1), r3 on the right (slot 2).
        assert dict(first.robots) == {"r1": 0, "r2": 1, "r3": 2} and first.leader == "r1"
        t_all = time.monotonic()
        time.sleep(0.3)
        recent = [sp for r, _, sp in setpoints.snapshot() if r > t_all]
        by_robot = {sp.robot: sp for sp in recent}
        assert set(by_robot) == {"r1", "r2", "r3"}
        assert by_robot["r1"].slot == 0 and by_robot["r1"].role == "leader"
        assert by_robot["r2"].slot == 1 and by_robot["r2"].parent == 0
        n_leader = len([1 for r, _, _ in leaders.snapshot() if r > t_all])
        assert 8 <= n_leader <= 20, f"{n_leader} leader messages in 0.3 s at 50 Hz"
        assert {s.slot for r, _, s in slots.snapshot() if r > t_all} == {0, 1, 2}

        tokens.pop("r1").undeclare()  # the leader's agent dies (its poses keep coming)
        t_dead = time.monotonic()
        _, _, after = assignments.wait_for(lambda r, _k, a: r > t_dead and "r1" not in a.robots)
        assert after.leader in ("r2", "r3") and sorted(after.robots.values()) == [0, 1]
        assert after.robots[after.leader] == 0  # the leader slot is refilled first
        time.sleep(0.2)
        late = [sp for r, _, sp in setpoints.snapshot() if r > t_dead + 0.1]
        assert late and "r1" not in {sp.robot for sp in late}

        # r3 still alive but its poses stop: it keeps its slot while its last pose is younger
        # than the hold bound (one late pose on a loaded machine re-assigns nobody), then goes
        feeder.robots.discard("r3")
        t_blind = time.monotonic()
        r_gone, _, blind = assignments.wait_for(
            lambda r, _k, a: r > t_blind and "r3" not in a.robots
        )
        kept = [a for r, _, a in assignments.snapshot() if t_blind < r < t_blind + 1.0]
        assert all("r3" in a.robots for a in kept), kept
        assert r_gone - t_blind > 1.0  # the hold bound (1.5 s), not stale_pose_s (0.2 s)
        assert dict(blind.robots) == {"r2": 0}
        _, _, st = status.wait_for(lambda r, _k, _s: r > t_blind)
    assert st["rejected"] == 0 and st["alive"] == ["r2", "r3"] and st["leader"] == "r2"
    elapsed = child.stop()
    assert child.proc.returncode == 0 and elapsed < 1.5, child.describe()
    assert "assignment r1->0 r2->1 r3->2; leader r1" in child.stderr()  # role changes logged


def test_lockstep_answers_each_clock_with_the_leader_last(
    spawn: Spawner, router: RouterHandle, client: zenoh.Session
) -> None:
    pubs = rt.Publishers(client)
    tokens = [rt.declare_token(client, keys.alive_robot_key(FLEET, r)) for r in START]
    # One subscriber for the whole fleet, on Zenoh's thread: the true arrival order.
    every = Recorder(client, f"formation/{FLEET}/**", msgpack.unpackb)
    spawn(
        "coordinator",
        "--scenario",
        "paper-exp2",
        "--lockstep",
        "--endpoint",
        router.endpoint,
        ready="coordinator ready",
    )
    dt = 0.02
    clock_key = keys.clock_key(FLEET)

    def answer(k: int) -> list[tuple[str, dict[str, Any]]]:
        """The messages carrying tick k, in arrival order, once the leader(k) arrived."""
        every.wait_for(
            lambda _r, key, m: key.endswith("/leader") and m.get("tick") == k, timeout_s=2.0
        )
        return [
            (key, m) for _, key, m in every.snapshot() if m.get("tick") == k and key != clock_key
        ]

    k = 0
    deadline = time.monotonic() + 5.0
    while True:  # the frame then clock k, until the answer covers every robot
        rows = list(START.items())  # (a lockstep coordinator reads the plant's frames)
        frame = PoseBatch(
            t=k * dt, seq=k + 1, robots=tuple(r for r, _ in rows),
            x=tuple(p[0] for _, p in rows), y=tuple(p[1] for _, p in rows),
            theta=tuple(p[2] for _, p in rows), stamp=k * dt,
        )  # fmt: skip
        pubs.put(keys.poses_key(FLEET), encode(frame), rt.QOS_CRITICAL)
        pubs.put(clock_key, encode(Clock(t=k * dt, seq=k + 1, tick=k)), rt.QOS_CRITICAL)
        time.sleep(0.03)
        got = [key for key, m in answer(k) if key.endswith("/setpoint")] if k > 0 else []
        if len(got) == 3:
            break
        assert time.monotonic() < deadline, "the coordinator never assigned the three robots"
        k += 1
    msgs = answer(k)
    names = [key.rsplit("/", 2)[-2] + "/" + key.rsplit("/", 1)[-1] for key, _ in msgs]
    assert names[-1].endswith("leader"), f"leader must come last: {names}"
    assert sum(key.endswith("/setpoint") for key, _ in msgs) == 3
    assert {m["slot"] for key, m in msgs if "/slot/" in key} == {0, 1, 2}
    assert all(m["t"] == k * dt for _, m in msgs)  # sim time: the clock's t
    n_before = len(every.snapshot())
    pubs.put(clock_key, encode(Clock(t=k * dt, seq=99, tick=k)), rt.QOS_CRITICAL)  # repeated
    time.sleep(0.2)
    repeat = [
        (key, m)
        for _, key, m in every.snapshot()[n_before:]
        if m.get("tick") == k and key != clock_key
    ]
    assert repeat == msgs  # the same messages (same seq), in the same order
    del tokens
