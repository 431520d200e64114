"""The operator in the loop (issue 28) with real processes on a real router: ``formation
teleop`` / ``goal`` drive a ``formation coordinator``'s virtual leader, the deadman stops it when
the stream stops, hostile commands are refused and counted, and a standby that takes over
continues the teleoperated leader without a jump.

The robots are bus inputs declared from the test session (as in test_node_coordinator.py): a
liveliness token per robot and poses that sit exactly on the setpoints the coordinator sends
(perfect followers, so the leader's wait for its team never holds it back here;
tests/fleet/test_operator_fleet.py runs the real agents and plant).
"""

from __future__ import annotations

import itertools
import math
import signal
import time
from collections.abc import Callable
from typing import Any

import msgpack
import pytest
import zenoh
from support.bus_watch import Recorder, decoder_of
from support.operator_bus import CFG, FLEET, START, Followers, leader_jumps
from support.routers import RouterHandle
from support.spawn import Spawner

import runtime as rt
from bus_schemas import Assignment, CmdVel, Leader, Path, Setpoint, Shape, encode, keys
from coordinator.core.leader import DEADMAN_S

# the deadman, then a braking from the teleop speed within the acceleration limit, plus the
# latency of a loaded machine (a tick, the bus, the recorder's thread)
V_TELEOP = 0.08
STOP_BOUND_S = DEADMAN_S + V_TELEOP / CFG.max_accel_mps2 + 0.5


@pytest.fixture
def client(session: Callable[..., zenoh.Session]) -> zenoh.Session:
    return session()


def _coordinator(spawn: Spawner, router: RouterHandle, *extra: str) -> Any:
    return spawn(
        "coordinator", "--scenario", "paper-exp2", "--endpoint", router.endpoint, *extra,
        ready="coordinator ready",
    )  # fmt: skip


def test_teleop_drives_the_leader_and_the_deadman_stops_it(
    spawn: Spawner, router: RouterHandle, client: zenoh.Session
) -> None:
    tokens = [rt.declare_token(client, keys.alive_robot_key(FLEET, r)) for r in START]
    leaders = Recorder(client, keys.leader_key(FLEET), decoder_of(Leader))
    assignments = Recorder(client, keys.assignment_key(FLEET), decoder_of(Assignment))
    _coordinator(spawn, router)
    with Followers(client):
        assignments.wait_for(lambda _r, _k, a: len(a.robots) == 3)
        teleop = spawn(
            "teleop", "--v", str(V_TELEOP), "--omega", "0.1", "--duration", "60", "--quiet",
            "--endpoint", router.endpoint,
        )  # fmt: skip
        leaders.wait_for(
            lambda _r, _k, m: m.mode == "teleop" and m.v_mps >= V_TELEOP - 1e-9, timeout_s=10.0
        )
        time.sleep(1.0)
        teleop.stop(signal.SIGKILL)  # the operator's tool dies: the stream stops
        t_kill = time.monotonic()
        r_stop, _, stopped = leaders.wait_for(
            lambda r, _k, m: r > t_kill and m.v_mps == 0.0 and m.omega_radps == 0.0,
            timeout_s=10.0,
        )
        time.sleep(0.5)
        _, _, still = leaders.wait_for(lambda r, *_: r > r_stop + 0.4)
        last_asg = assignments.snapshot()[-1][2]
    assert r_stop - t_kill <= STOP_BOUND_S, (r_stop - t_kill, STOP_BOUND_S)
    assert stopped.deadman is True and stopped.mode == "teleop"
    assert (still.x, still.y, still.v_mps) == (stopped.x, stopped.y, 0.0)  # it stays stopped
    msgs = leaders.snapshot()
    assert not leader_jumps(msgs), leader_jumps(msgs)[:5]
    # the followers kept their slots throughout (no re-assignment)
    assert dict(last_asg.robots) == {"r1": 0, "r2": 1, "r3": 2}
    assert not any(a.robots != last_asg.robots for _, _, a in assignments.snapshot()[1:])
    del tokens


def test_hostile_commands_are_refused_counted_and_never_move_the_leader(
    spawn: Spawner, router: RouterHandle, client: zenoh.Session
) -> None:
    tokens = [rt.declare_token(client, keys.alive_robot_key(FLEET, r)) for r in START]
    leaders = Recorder(client, keys.leader_key(FLEET), decoder_of(Leader))
    status = Recorder(client, keys.coordinator_status_key(FLEET, "main"), msgpack.unpackb)
    _coordinator(spawn, router)
    pubs = rt.Publishers(client)
    good = msgpack.unpackb(encode(CmdVel(t=1.0, seq=1, v_mps=0.05, omega_radps=0.0)))
    with Followers(client):
        leaders.wait_for(lambda *_: True)
        for bad in (math.nan, math.inf, 1e300, -1e300):
            for name in ("v_mps", "omega_radps"):
                pubs.put(keys.cmd_vel_key(FLEET), msgpack.packb({**good, name: bad}))
        pubs.put(keys.cmd_vel_key(FLEET), b"\xc1garbage")
        time.sleep(0.3)  # the rate limit's bucket refills (a burst is tested below)
        pubs.put(keys.path_key(FLEET), encode(Path(t=1.0, xs=(0.5,) * 300, ys=(0.5,) * 300)))
        # within the contract's range but absurd for this leader (> 10x its limits)
        time.sleep(0.3)
        pubs.put(keys.cmd_vel_key(FLEET), encode(CmdVel(t=1.0, seq=2, v_mps=15.0, omega_radps=0)))
        time.sleep(0.05)
        for i in range(200):  # a burst far beyond the rate
            pubs.put(keys.cmd_vel_key(FLEET), encode(CmdVel(t=1.0, seq=10 + i, v_mps=0.0,
                                                            omega_radps=0.0)))  # fmt: skip
        t_sent = time.monotonic()
        _, _, st = status.wait_for(
            lambda r, _k, s: r > t_sent + 0.3 and s["rejects"].get("cmd_vel-burst", 0) > 0,
            timeout_s=5.0,
        )
    rejects = st["rejects"]
    decode_refused = sum(n for k, n in rejects.items() if k.startswith("cmd_vel-")) - rejects.get(
        "cmd_vel-burst", 0
    )
    assert decode_refused >= 10, rejects  # 8 non-finite/out of range, garbage, 15 m/s
    assert rejects.get("cmd_vel-absurd", 0) == 1, rejects
    assert rejects.get("path-path_length", 0) == 1, rejects
    assert rejects["cmd_vel-burst"] >= 150, rejects
    msgs = leaders.snapshot()
    assert not leader_jumps(msgs), leader_jumps(msgs)[:5]
    assert all(abs(m.v_mps) <= CFG.max_speed_mps for _, _, m in msgs)
    del tokens


def test_a_goal_from_the_cli_is_taken_and_reached_with_a_continuous_join(
    spawn: Spawner, router: RouterHandle, client: zenoh.Session, tmp_path: Any
) -> None:
    tokens = [rt.declare_token(client, keys.alive_robot_key(FLEET, r)) for r in START]
    leaders = Recorder(client, keys.leader_key(FLEET), decoder_of(Leader))
    _coordinator(spawn, router)
    with Followers(client):
        _, _, first = leaders.wait_for(lambda *_: True)
        gx, gy = first.x + 0.3, first.y + 0.2
        goal = spawn("goal", f"{gx}", f"{gy}", "--endpoint", router.endpoint, "--timeout", "5")
        assert goal.proc.wait(timeout=30) == 0, goal.describe()
        assert "taken" in goal.stdout()
        _, _, done = leaders.wait_for(lambda _r, _k, m: m.mode == "stop", timeout_s=30.0)
    assert math.hypot(done.x - gx, done.y - gy) <= 4 * CFG.goal_tol_m
    msgs = leaders.snapshot()
    assert not leader_jumps(msgs), leader_jumps(msgs)[:5]
    join = [m for _, _, m in msgs if m.mode in ("script", "goal")]
    for a, b in itertools.pairwise(join):  # no velocity step at the join either
        assert abs(b.v_mps - a.v_mps) <= CFG.max_accel_mps2 * (b.t - a.t) + 0.021
    del tokens


def test_a_standby_continues_the_teleoperated_leader_without_a_jump(
    spawn: Spawner, router: RouterHandle, client: zenoh.Session
) -> None:
    tokens = [rt.declare_token(client, keys.alive_robot_key(FLEET, r)) for r in START]
    leaders = Recorder(client, keys.leader_key(FLEET), decoder_of(Leader))
    status = Recorder(client, keys.all_coordinator_status_pattern(FLEET), msgpack.unpackb)
    main = _coordinator(spawn, router)
    _coordinator(spawn, router, "--name", "b", "--standby")
    with Followers(client):
        spawn(
            "teleop", "--v", str(V_TELEOP), "--omega", "0.15", "--duration", "60", "--quiet",
            "--endpoint", router.endpoint,
        )  # fmt: skip
        leaders.wait_for(
            lambda _r, _k, m: m.mode == "teleop" and m.v_mps >= V_TELEOP - 1e-9, timeout_s=10.0
        )
        time.sleep(1.0)
        main.stop(signal.SIGKILL)
        t_kill = time.monotonic()
        _, _, b_active = status.wait_for(
            lambda r, _k, s: r > t_kill and s["name"] == "b" and s["role"] == "active",
            timeout_s=10.0,
        )
        time.sleep(1.0)
    msgs = leaders.snapshot()
    before = [m for r, _, m in msgs if r <= t_kill]
    after = [(r, k, m) for r, k, m in msgs if r > t_kill + 0.05]
    assert before and after
    last, first = before[-1], after[0][2]
    # b went on from main's last state: no farther than the speed limit allows over the gap
    # between the two messages (stamps of one machine's monotonic clock; the gap is a tick on a
    # quiet machine, 0.65 s was seen next to a CPU hog, and the teleop stream went on meanwhile),
    # same mode, velocity within one tick's acceleration
    assert first.mode == "teleop"
    gap_s = max(first.t - last.t, 0.1)
    assert math.hypot(first.x - last.x, first.y - last.y) <= CFG.max_speed_mps * gap_s + 1e-6
    assert abs(first.v_mps - last.v_mps) <= CFG.max_accel_mps2 * 0.1 + 1e-9
    assert not leader_jumps(after), leader_jumps(after)[:5]
    # the teleoperated leader is no function of t - leader_t0: b did not check main's origin
    # against it (no heartbeat refused as a spoof while main ran)
    assert b_active["rejects"].get("heartbeat-leader_t0", 0) == 0, b_active["rejects"]
    del tokens


def _slot_offsets(
    leaders: list[tuple[float, str, Leader]], setpoints: list[tuple[float, str, Setpoint]]
) -> dict[str, list[tuple[float, float, float]]]:
    """Each robot's setpoint in the leader's body frame, ``(t, dx, dy)``, at the ticks where
    both were received (the same ``t``: one tick's outputs)."""
    by_t = {m.t: m for _, _, m in leaders}
    out: dict[str, list[tuple[float, float, float]]] = {}
    for _, _, sp in setpoints:
        ld = by_t.get(sp.t)
        if ld is None:
            continue
        c, s = math.cos(ld.theta), math.sin(ld.theta)
        dx, dy = sp.x - ld.x, sp.y - ld.y
        out.setdefault(sp.robot, []).append((sp.t, c * dx + s * dy, -s * dx + c * dy))
    return out


def _wait_on_slots(leaders: Recorder, setpoints: Recorder, timeout_s: float = 15.0) -> float:
    """Until every robot's setpoint has stood still in the leader's frame for 10 ticks: its slot,
    not an approach point (a robot whose first pose came a tick after the coordinator started
    is newly assigned and closes in on its slot at ``APPROACH_SPEED_MPS``, 2 mm a tick). The
    coordinator's time of the last of those ticks."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        offsets = _slot_offsets(leaders.snapshot(), setpoints.snapshot())
        if set(offsets) == set(START) and all(
            len(track) > 10
            and all(
                math.hypot(x1 - x0, y1 - y0) < 1e-5
                for (_, x0, y0), (_, x1, y1) in itertools.pairwise(track[-11:])
            )
            for track in offsets.values()
        ):
            return min(track[-1][0] for track in offsets.values())
        time.sleep(0.05)
    raise AssertionError(f"the robots were not on their slots within {timeout_s} s")


def test_a_standby_continues_a_reshape_mid_way_without_a_jump(
    spawn: Spawner, router: RouterHandle, client: zenoh.Session
) -> None:
    """``formation shape column``, then the active coordinator dies mid-reshape: the standby
    starts the same plan at the active's start time (the ``leader`` message's ``reshape_t0``,
    ...), so every slot goes on from where it was, at the reshape's speed, to the column."""
    from coordinator.core.reshape import RESHAPE_SPEED_MPS

    tokens = [rt.declare_token(client, keys.alive_robot_key(FLEET, r)) for r in START]
    leaders = Recorder(client, keys.leader_key(FLEET), decoder_of(Leader))
    setpoints = Recorder(client, keys.all_setpoints_pattern(FLEET), decoder_of(Setpoint))
    status = Recorder(client, keys.all_coordinator_status_pattern(FLEET), msgpack.unpackb)
    main = _coordinator(spawn, router)
    _coordinator(spawn, router, "--name", "b", "--standby")
    pubs = rt.Publishers(client)
    with Followers(client):
        status.wait_for(lambda _r, _k, s: s["name"] == "b" and s["role"] == "standby")
        leaders.wait_for(lambda *_: True)
        formed = _wait_on_slots(leaders, setpoints)  # from here the reshape is the only motion
        pubs.put(keys.shape_key(FLEET), encode(Shape(t=1.0, kind="column")), rt.QOS_CRITICAL)
        leaders.wait_for(
            lambda _r, _k, m: m.shape == "column" and (m.reshape or 0.0) >= 0.1, timeout_s=10.0
        )
        t_kill = time.monotonic()
        main.stop(signal.SIGKILL)
        _, _, b_active = status.wait_for(
            lambda r, _k, s: r > t_kill and s["name"] == "b" and s["role"] == "active",
            timeout_s=10.0,
        )
        leaders.wait_for(lambda r, *_: r > t_kill + 1.0, timeout_s=10.0)
        _, _, b_later = status.wait_for(lambda r, _k, s: r > t_kill + 1.0 and s["name"] == "b")
    msgs = leaders.snapshot()
    # b's first leader message: where the sequence starts again (b's own publisher)
    k = next(i for i in range(1, len(msgs)) if msgs[i][2].seq < msgs[i - 1][2].seq)
    last, first = msgs[k - 1][2], msgs[k][2]
    assert msgs[k - 1][0] <= msgs[k][0] and msgs[k][0] > t_kill
    assert last.reshape is not None and 0.0 < last.reshape < 1.0, last
    # b runs the very reshape main was running: same start, duration and target
    assert first.shape == "column" and first.reshape is not None, first
    assert (first.reshape_t0, first.reshape_s, first.slots) == (
        last.reshape_t0,
        last.reshape_s,
        last.slots,
    )
    assert last.reshape <= first.reshape < 1.0
    assert b_later["rejects"].get("shape-takeover", 0) == 0, b_later["rejects"]
    # every slot goes on from where it was in the leader's frame: no faster than the reshape
    offsets = _slot_offsets(msgs, setpoints.snapshot())
    assert set(offsets) == set(START)
    for rid, track in offsets.items():
        on_slots = [p for p in track if p[0] >= formed]
        assert len(on_slots) > 100, (rid, len(on_slots))
        for (t0, x0, y0), (t1, x1, y1) in itertools.pairwise(on_slots):
            allowed = 1.5 * RESHAPE_SPEED_MPS * (t1 - t0) + 1e-6  # the smoothstep's peak
            assert math.hypot(x1 - x0, y1 - y0) <= allowed, (rid, t0, t1)
    assert not leader_jumps(msgs[k:]), leader_jumps(msgs[k:])[:5]
    del tokens, b_active


def test_the_number_of_slots_changes_live_and_too_many_is_refused_and_counted(
    spawn: Spawner, router: RouterHandle, client: zenoh.Session
) -> None:
    """``formation shape KIND --slots N``: more slots than robots alive is one line and exit 2
    at the CLI, and refused and counted at the coordinator (a Shape sent anyway); fewer is taken
    and the leader message says how many slots the running reshape ends with."""
    tokens = [rt.declare_token(client, keys.alive_robot_key(FLEET, r)) for r in START]
    leaders = Recorder(client, keys.leader_key(FLEET), decoder_of(Leader))
    status = Recorder(client, keys.coordinator_status_key(FLEET, "main"), msgpack.unpackb)
    _coordinator(spawn, router)
    with Followers(client):
        leaders.wait_for(lambda *_: True)
        many = spawn("shape", "column", "--slots", "5", "--endpoint", router.endpoint)
        assert many.proc.wait(timeout=30) == 2, many.describe()
        lines = many.stderr().splitlines()
        assert len(lines) == 1 and "--slots 5" in lines[0] and "3 robots alive" in lines[0]
        rt.Publishers(client).put(
            keys.shape_key(FLEET), encode(Shape(t=1.0, kind="column", slots=5)), rt.QOS_CRITICAL
        )
        status.wait_for(lambda _r, _k, s: s["rejects"].get("shape-too_many_slots", 0) == 1)
        fewer = spawn("shape", "column", "--slots", "2", "--endpoint", router.endpoint)
        assert fewer.proc.wait(timeout=30) == 0, fewer.describe()
        assert "reshaping into a column of 2 slots" in fewer.stdout()
        _, _, m = leaders.wait_for(lambda _r, _k, m: m.slots == 2, timeout_s=5.0)
    assert m.shape == "column" and m.reshape is not None and m.reshape_from == "scenario"
    del tokens


def test_a_gamepad_drives_the_leader(
    spawn: Spawner, router: RouterHandle, client: zenoh.Session, tmp_path: Any
) -> None:
    """``formation teleop --gamepad DEV`` reads the Linux joystick API's events; a FIFO stands in
    for ``/dev/input/js0`` (the same 8-byte events a kernel driver writes)."""
    import os

    from formation.operate.drive import JS_AXIS, JS_EVENT, JS_INIT

    fifo = tmp_path / "js0"
    os.mkfifo(fifo)
    tokens = [rt.declare_token(client, keys.alive_robot_key(FLEET, r)) for r in START]
    leaders = Recorder(client, keys.leader_key(FLEET), decoder_of(Leader))
    status = Recorder(client, keys.coordinator_status_key(FLEET, "main"), msgpack.unpackb)
    _coordinator(spawn, router)
    writer = os.open(fifo, os.O_RDWR | os.O_NONBLOCK)  # held open: the tool never sees an EOF
    try:
        with Followers(client):
            spawn(
                "teleop", "--gamepad", str(fifo), "--duration", "30", "--quiet",
                "--endpoint", router.endpoint,
            )  # fmt: skip
            init = JS_EVENT.pack(0, 0, JS_AXIS | JS_INIT, 0) + JS_EVENT.pack(0, 0, JS_AXIS, 1)
            os.write(writer, init)
            time.sleep(0.5)
            t_stick = time.monotonic()
            os.write(writer, JS_EVENT.pack(10, -32767, JS_AXIS, 1))  # stick fully up: forward
            _, _, driven = leaders.wait_for(
                lambda r, _k, m: (
                    r > t_stick and m.mode == "teleop" and m.v_mps == CFG.max_speed_mps
                ),
                timeout_s=10.0,
            )
            # the stick asks 0.2 m/s, the leader's limit is 0.1: clamped and counted
            status.wait_for(
                lambda r, _k, s: r > t_stick and s["rejects"].get("cmd_vel-clamped", 0) > 0
            )
    finally:
        os.close(writer)
    assert driven.omega_radps == 0.0
    assert not leader_jumps(leaders.snapshot())
    del tokens
