"""The one neighbour rule (robot_agent.core.neighbours) in the shells, and clocks across hosts
(robot_agent.core.clocksync): a pose stamped on another host's clock, skewed by seconds, is aged
correctly within the link jitter and the robot keeps tracking."""

from __future__ import annotations

import math
import random
import threading
import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import pytest
import zenoh
from support.agent_io import setpoint_msg
from support.bus_watch import Recorder, decoder_of
from support.routers import RouterHandle
from support.spawn import REPO_ROOT, Spawner

import runtime as rt
from bus_schemas import (
    Clock,
    Pose,
    PoseBatch,
    Setpoint,
    Status,
    StatusBatch,
    Wheels,
    encode,
    keys,
)
from robot_agent.core.clocksync import ClockOffset, ClockOffsets
from robot_agent.core.firmware import Mode
from robot_agent.core.neighbours import COOPERATIVE_STATUS_S, NEIGHBOUR_STALE_S, neighbour
from robot_agent.core.params import AgentConfig, EstimatorParams
from robot_agent.core.safety_filter import Neighbour
from robot_agent.node.agent import AgentNode
from robot_agent.node.host import HostNode

FLEET = "demo"


def _sink(key: str, payload: bytes, qos: rt.QoS) -> None:
    pass


def _batch(t: float, stamp: float, rows: dict[str, tuple[float, float, float]]) -> bytes:
    return encode(
        PoseBatch(
            t=t,
            seq=1,
            robots=tuple(rows),
            x=tuple(r[0] for r in rows.values()),
            y=tuple(r[1] for r in rows.values()),
            theta=tuple(r[2] for r in rows.values()),
            stamp=stamp,
        )
    )


def test_neighbour_rule() -> None:
    n = neighbour(1.0, 2.0, 0.5, 9.96, 10.0, True)
    assert isinstance(n, Neighbour)
    assert (n.x, n.y, n.theta, n.cooperative) == (1.0, 2.0, 0.5, True)
    assert n.age_s == pytest.approx(0.04)
    assert (n.vx, n.vy, n.radius_m) == (0.0, 0.0, 0.0)
    assert neighbour(0, 0, 0, 10.5, 10.0, False).age_s == 0.0  # a capture "in the future"


def test_lockstep_agent_ages_neighbours_on_sim_time_and_takes_cooperative_from_the_clock() -> None:
    node = AgentNode("r1", FLEET, AgentConfig(), _sink, lockstep=True)
    poses = _batch(0.06, 0.02, {"r1": (0, 0, 0), "r2": (0.5, 0, 0.1), "r3": (0, 0.5, -0.2)})
    node.on_poses(rt.Received(keys.poses_key(FLEET), poses, 123.0))
    assert node.neighbour_table.neighbours(0.06) == []  # pending until the clock
    clock = Clock(t=0.06, seq=1, tick=3, tracking=("r1", "r3"))
    node.on_clock(rt.Received(keys.clock_key(FLEET), encode(clock), 124.0))
    got = {(n.x, n.y): n for n in node.neighbour_table.neighbours(0.06)}
    assert set(got) == {(0.5, 0.0), (0.0, 0.5)}
    r2, r3 = got[(0.5, 0.0)], got[(0.0, 0.5)]
    assert r2.theta == 0.1 and r3.theta == -0.2
    assert r2.age_s == 0.06 - 0.02 and r3.age_s == 0.06 - 0.02  # capture to now, sim time
    assert (r2.cooperative, r3.cooperative) == (False, True)
    # received more than NEIGHBOUR_STALE_S ago: dropped (the simulator's rule too)
    assert node.neighbour_table.neighbours(0.06 + NEIGHBOUR_STALE_S + 0.02) == []


def test_a_lockstep_agent_takes_its_own_pose_from_the_batch_as_from_its_pose_key() -> None:
    """A lockstep agent reads the plant's frames as ``poses`` batches: its own entry is its
    pose, exactly as ``robot/<id>/pose`` would have given it (same fields, same capture time,
    pending until the clock); a realtime agent keeps its own entry out (its pose key rules)."""
    rows = {"r1": (0.25, -0.5, 0.3), "r2": (0.5, 0, 0.1)}
    from_batch = AgentNode("r1", FLEET, AgentConfig(), _sink, lockstep=True)
    from_batch.on_poses(rt.Received(keys.poses_key(FLEET), _batch(0.06, 0.02, rows), 1.0))
    from_key = AgentNode("r1", FLEET, AgentConfig(), _sink, lockstep=True)
    pose = Pose(t=0.02, seq=1, x=0.25, y=-0.5, theta=0.3, robot="r1", pub_t=0.06)
    from_key.on_pose(rt.Received(keys.pose_key(FLEET, "r1"), encode(pose), 1.0))
    assert from_batch.pose == from_key.pose and from_batch.pose is not None
    assert (from_batch.pose.x, from_batch.pose.y, from_batch.pose.theta) == rows["r1"]
    assert from_batch.pose_capture_s == from_key.pose_capture_s == 0.02
    assert from_batch._pose_pending and from_key._pose_pending
    assert from_batch.faults.rejected == 0
    # without its own entry the batch leaves the pose alone
    other = AgentNode("r3", FLEET, AgentConfig(), _sink, lockstep=True)
    other.on_poses(rt.Received(keys.poses_key(FLEET), _batch(0.06, 0.02, rows), 1.0))
    assert other.pose is None and not other._pose_pending
    # realtime: the own entry of a batch is not the robot's pose
    rt_node = AgentNode("r1", FLEET, AgentConfig(), _sink, loop_mode="fixed")
    rt_node.on_poses(rt.Received(keys.poses_key(FLEET), _batch(0.06, 0.02, rows), 1.0))
    assert rt_node.pose is None


def test_realtime_cooperative_comes_from_fresh_status_of_agents_and_hosts() -> None:
    node = AgentNode("r1", FLEET, AgentConfig(), _sink, loop_mode="fixed")
    t0 = 1000.0
    poses = _batch(50.0, 49.99, {"r2": (0.5, 0, 0.0), "r3": (0, 0.5, 0.0), "r4": (1, 1, 0.0)})
    node.on_poses(rt.Received(keys.poses_key(FLEET), poses, t0))
    st = Status(t=7.0, seq=1, mode="tracking", slot=1, pid=1, host="h", rejected=0, robot="r2")
    node.peer_status.on_status(rt.Received(keys.status_key(FLEET, "r2"), encode(st), t0))
    batch = StatusBatch(
        t=3.0, seq=1, pid=2, host="h", robots=("r3", "r4"), mode=("tracking", "hold"),
        slot=(2, -1), rejected=(0, 0), ex=(0.0, 0.0), ey=(0.0, 0.0),
    )  # fmt: skip
    node.peer_status.on_host_status(
        rt.Received(keys.host_status_key(FLEET, "h"), encode(batch), t0)
    )
    coop = {(n.x, n.y): n.cooperative for n in node.neighbour_table.neighbours(t0 + 0.1)}
    assert coop == {(0.5, 0.0): True, (0.0, 0.5): True, (1.0, 1.0): False}
    later = t0 + COOPERATIVE_STATUS_S + 0.01  # the statuses went stale: obstacles again
    assert not any(n.cooperative for n in node.neighbour_table.neighbours(later))
    # a status whose robot field disagrees with its key is rejected and counted
    bad = replace(st, robot="r9")
    before = node.rejected
    node.peer_status.on_status(rt.Received(keys.status_key(FLEET, "r2"), encode(bad), t0))
    assert node.rejected == before + 1


def test_host_neighbours_carry_age_and_cooperative() -> None:
    host = HostNode("h1", ["r1", "r2"], FLEET, AgentConfig(), _sink, lockstep=True)
    poses = _batch(0.1, 0.04, {"r1": (0, 0, 0), "r2": (0.3, 0, 0.2), "r9": (0, 0.3, 0.1)})
    host.on_poses(rt.Received(keys.poses_key(FLEET), poses, 1.0))
    clock = Clock(t=0.1, seq=1, tick=5, tracking=("r9",))
    host.on_clock(rt.Received(keys.clock_key(FLEET), encode(clock), 1.0))
    nb = {(n.x, n.y): n for n in host._neighbours_of(host.nodes["r1"], 0.1)}
    assert set(nb) == {(0.3, 0.0), (0.0, 0.3)}
    assert nb[(0.0, 0.3)].cooperative and not nb[(0.3, 0.0)].cooperative
    assert nb[(0.3, 0.0)].age_s == pytest.approx(0.06) and nb[(0.3, 0.0)].theta == 0.2
    (batch,) = host.status_batches(0.1)  # the hosted robots' safety filter counters
    assert batch.filter_active is not None and len(batch.filter_active) == 2
    assert batch.filter_tiebreaks == (0, 0)
    encode(batch)


# -- clocks across hosts -------------------------------------------------------------------


@pytest.mark.parametrize("skew_s", [-3600.0, -2.5, 0.0, 2.5, 1e6])
def test_offset_lower_envelope_ages_a_skewed_source_within_the_jitter(skew_s: float) -> None:
    rng = random.Random(1)
    c = ClockOffset()
    d_min, jitter = 0.0004, 0.004
    worst = 0.0
    for k in range(2000):
        local_pub = 100.0 + 0.02 * k  # local time the remote host published
        delay = d_min + rng.random() * jitter
        rx = local_pub + delay
        capture_remote = local_pub - 0.03 + skew_s  # a 30 ms pipeline before publication
        c.observe(local_pub + skew_s, rx)
        cap_local = c.to_local(capture_remote, rx)
        assert cap_local is not None
        if k >= 50:  # once the envelope has seen a fast message
            err = (rx - cap_local) - (rx - (local_pub - 0.03))  # estimated age - true age
            worst = max(worst, abs(err))
    assert worst <= d_min + jitter
    assert c.rejected == 0 and c.resets == 0


def test_offset_follows_drift_and_restarts_on_a_step_of_the_remote_clock() -> None:
    c = ClockOffset(window_s=5.0)
    for k in range(3000):  # 60 s at 50 Hz, 50 ppm drift
        local = 10.0 + 0.02 * k
        c.observe(local * (1 + 50e-6) + 7.0, local + 0.001)
    true_off = -(60.0 * 50e-6 + 10.0 * 50e-6) - 7.0  # local - remote at the end, about
    assert c.offset_s is not None and abs(c.offset_s - (true_off + 0.001)) < 1e-3
    # the publisher restarted: its clock now reads 1000 s more (a sample far below)
    c.observe(1000.0 + 70.0, 70.001)
    assert c.resets == 1 and c.offset_s == pytest.approx(70.001 - 1070.0)
    assert not c.observe(math.nan, 1.0) and c.rejected == 1
    table = ClockOffsets()
    assert table.capture_to_local("k", 5.0, 4.9, 50.0) == pytest.approx(49.9)
    assert table.capture_to_local("k", 5.0, 6.0, 50.0) == 50.0  # never after the receipt


@pytest.mark.parametrize("skew_s", [-5.0, 4.0, 86400.0])
def test_realtime_agent_on_a_skewed_camera_clock_keeps_tracking(skew_s: float) -> None:
    """A camera host whose clock is ``skew_s`` off publishes poses (capture ``t``, ``pub_t``);
    the agent's estimator gets capture times on the local clock within the link jitter, and the
    robot tracks (no HOLD, no rejected pose). Without the conversion a skew of seconds would put
    every capture outside the estimator's bounds."""
    cfg = AgentConfig(estimator=replace(EstimatorParams(), enabled=True))
    node = AgentNode("r1", FLEET, cfg, _sink, loop_mode="fixed")
    rng = random.Random(2)
    t0, latency, d_min, jitter = 500.0, 0.03, 0.0003, 0.003
    sp_key, pose_key = keys.setpoint_key(FLEET, "r1"), keys.pose_key(FLEET, "r1")
    errs = []
    modes = []
    for k in range(150):  # 3 s at 50 Hz, camera at 50 Hz
        now = t0 + 0.02 * k
        sp = Setpoint(
            t=now, seq=k + 1, robot="r1", slot=1, role="follower", stage=1, parent=0,
            x=0.05 + 0.001 * k, y=0.0,
            vx=0.05, vy=0.0, theta=0.0,
        )  # fmt: skip
        node.on_setpoint(rt.Received(sp_key, encode(sp), now - 0.005))
        capture = now - latency - d_min - rng.random() * jitter  # local time of the capture
        pub = capture + latency
        rx = pub + (now - latency - capture)  # arrives just before this tick
        msg = Pose(
            t=capture + skew_s, seq=k + 1, x=0.001 * k, y=0.0, theta=0.0, robot="r1",
            pub_t=pub + skew_s,
        )  # fmt: skip
        node.on_pose(rt.Received(pose_key, encode(msg), rx))
        assert node.pose_capture_s is not None
        if k >= 10:
            errs.append(node.pose_capture_s - capture)
        cmd = node.step(now)
        assert cmd is not None
        modes.append(cmd.mode)
    assert max(abs(e) for e in errs) <= d_min + jitter
    assert all(m is Mode.TRACKING for m in modes[2:]), modes
    st = node.firmware.status()
    assert st.rejected_count == 0, st.last_reject_reason


def test_status_carries_the_safety_filter_counters() -> None:
    node = AgentNode("r1", FLEET, AgentConfig(), _sink, loop_mode="fixed")
    node.step(1.0)
    msg = node.status_message(1.0)
    assert msg.filter is not None and set(msg.filter) >= {"ticks", "active", "violations"}
    assert msg.min_clearance_m is None  # nothing in range yet
    encode(msg)  # within the schema's bounds


def test_realtime_neighbour_ages_from_a_skewed_frame_clock_are_right_within_the_jitter() -> None:
    node = AgentNode("r1", FLEET, AgentConfig(), _sink, loop_mode="fixed")
    rng = random.Random(3)
    skew, latency, d_min, jitter = -1234.5, 0.03, 0.0002, 0.002
    worst = 0.0
    for k in range(200):
        capture = 5000.0 + 1 / 30 * k  # local time of the frame's exposure
        pub = capture + latency
        rx = pub + d_min + rng.random() * jitter
        frame = _batch(pub + skew, capture + skew, {"r2": (0.5, 0.0, 0.0)})
        node.on_poses(rt.Received(keys.poses_key(FLEET), frame, rx))
        now = rx + 0.005
        (nb,) = node.neighbour_table.neighbours(now)
        if k >= 10:
            worst = max(worst, abs(nb.age_s - (now - capture)))
    assert worst <= d_min + jitter


def test_coordinator_keeps_robots_for_the_estimators_dropout_bound_like_the_simulator() -> None:
    from coordinator.core.coordinator import pose_stale_s
    from coordinator.node.coordinator import CoordinatorNode
    from scenario import load

    sc = load("paper-exp1")
    est = replace(sc.agent.estimator, enabled=True, max_dropout_cmd_s=0.35)
    on = sc.with_overrides(agent=replace(sc.agent, estimator=est))
    off = replace(sc.agent, estimator=replace(est, enabled=False))
    assert pose_stale_s(off, odometry=False) == sc.agent.safety.stale_pose_s
    assert pose_stale_s(on.agent, odometry=False) == 0.35
    assert pose_stale_s(on.agent, odometry=True) == max(
        est.max_dropout_odom_s, sc.agent.safety.stale_pose_s
    )
    node = CoordinatorNode(on, "main", FLEET, _sink, lockstep=True)
    assert node.stale_pose_s == 0.35  # the scenario's plant has no encoders


# -- over a real router ----------------------------------------------------------------------


@pytest.mark.parametrize("skew_s", [-30.0, 20.0])
def test_agent_process_tracks_on_a_camera_whose_clock_is_off_by_seconds(
    skew_s: float,
    spawn: Spawner,
    router: RouterHandle,
    session: Callable[..., zenoh.Session],
    tmp_path: Path,
) -> None:
    """``formation agent`` with the estimator on, fed by a "camera host" (this test) whose
    monotonic clock reads ``skew_s`` off: poses carry ``t`` (capture, 30 ms before
    publication) and ``pub_t`` on that clock. The agent tracks (status ``tracking``, wheels
    forward) and rejects nothing: the capture times reach the estimator on the agent's clock.
    Without the conversion every capture would lie seconds outside the estimator's bounds."""
    base = (REPO_ROOT / "scenario" / "builtin" / "paper-exp1.toml").read_text()
    path = tmp_path / "est.toml"
    path.write_text(base + "\n[estimator]\nenabled = true\n")
    client = session()
    pubs = rt.Publishers(client)
    spawn("agent", "--id", "r1", "--scenario", str(path), "--endpoint", router.endpoint,
          ready="agent")  # fmt: skip
    status = Recorder(client, keys.status_key(FLEET, "r1"), decoder_of(Status))
    wheels = Recorder(client, keys.wheels_key(FLEET, "r1"), decoder_of(Wheels))
    stop = threading.Event()

    def camera() -> None:
        seq = 0
        while not stop.is_set():
            seq += 1
            capture = time.monotonic() - 0.03  # the frame was exposed 30 ms ago
            sp = setpoint_msg("r1", 0.45, 0.0, t=time.monotonic(), seq=seq)
            pubs.put(keys.setpoint_key(FLEET, "r1"), encode(sp), rt.QOS_CRITICAL)
            pose = Pose(
                t=capture + skew_s, seq=seq, x=0.0, y=0.0, theta=0.0, robot="r1",
                pub_t=time.monotonic() + skew_s,
            )  # fmt: skip
            pubs.put(keys.pose_key(FLEET, "r1"), encode(pose), rt.QOS_CRITICAL)
            stop.wait(0.02)

    feeder = threading.Thread(target=camera, daemon=True)
    feeder.start()
    try:
        wheels.wait_for(lambda _r, _k, w: w.mode == "tracking" and w.omega_r > 0.5, 10.0)
        t_ok = time.monotonic()
        time.sleep(1.0)
        _, _, st = status.wait_for(lambda r, _k, _s: r > t_ok + 0.8, 5.0)
    finally:
        stop.set()
        feeder.join(2.0)
    late = [w for r, _, w in wheels.snapshot() if r > t_ok]
    assert late and all(w.mode == "tracking" for w in late)  # never HOLD after starting
    assert st.mode == "tracking" and st.rejected == 0, st
    assert st.filter is not None and st.filter["ticks"] > 0
