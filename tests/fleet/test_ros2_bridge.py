"""``formation ros2``: the pure translation (BridgeCore) and, over a real router, an independent
rmw_zenoh client (zenoh-ros2-sdk) that lists the topics with their types, receives
``/r1/odom``, publishes ``/formation/cmd_vel`` (reaching the bus as the operator's CmdVel) and
calls the
``/formation/estop`` Trigger service (reaching the fleet's e-stop key)."""

from __future__ import annotations

import json
import math
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
import zenoh
from support.spawn import free_port

from bus_schemas import (
    CmdVel,
    Estop,
    Goal,
    Leader,
    Pose,
    PoseBatch,
    Slot,
    Status,
    decode,
    encode,
    keys,
)
from bus_schemas.errors import DecodeError
from bus_schemas.ros2 import msgs, rmw
from formation.live.ros2_bridge import (
    READY,
    TWIST_COV_ESTIMATOR,
    TWIST_COV_FINITE_DIFFERENCE,
    BridgeCore,
)

pytestmark = pytest.mark.shares_cpu

ATT = rmw.encode_attachment(rmw.Attachment(1, 0, bytes(16)))


def twist(v: float, w: float) -> bytes:
    return msgs.encode(msgs.Twist(msgs.Vector3(x=v), msgs.Vector3(z=w)))


# --- the pure core -----------------------------------------------------------------------------


def test_odometry_twist_from_consecutive_poses() -> None:
    core = BridgeCore()
    core.on_pose("r1", 1.0, 0.0, 0.0, 0.0, stamp_ns=5_000_000_000)
    outs = core.on_pose("r1", 1.1, 0.02, 0.0, 0.05, stamp_ns=5_100_000_000)
    assert [o.topic for o in outs] == ["/r1/odom", "/tf"]
    odom = msgs.decode(outs[0].payload, msgs.Odometry)
    assert isinstance(odom, msgs.Odometry)
    assert (odom.header.frame_id, odom.child_frame_id) == ("map", "r1/base_link")
    assert odom.twist.twist.angular.z == pytest.approx(0.5)
    assert odom.twist.twist.linear.x == pytest.approx(0.02 * math.cos(0.025) / 0.1)
    yaw = msgs.yaw_from_quaternion(odom.pose.pose.orientation)
    assert yaw == pytest.approx(0.05)
    tf = msgs.decode(outs[1].payload, msgs.TFMessage)
    assert isinstance(tf, msgs.TFMessage)
    assert tf.transforms[0].child_frame_id == "r1/base_link"
    assert core.on_pose("r1", 1.1, 0.0, 0.0, 0.0, stamp_ns=5_200_000_000) == []  # same t: refused
    assert core.rejected.by_reason == {"pose_out_of_order": 1}


def test_a_poses_batch_gives_each_odometry_and_one_tf() -> None:
    core = BridgeCore()
    ids = ("r1", "r2", "r3")
    batch = PoseBatch(t=1.0, seq=1, robots=ids, x=(0.0, 1.0, 2.0), y=(0.0,) * 3,
                      theta=(0.0,) * 3, stamp=1.0)  # fmt: skip
    outs = core.on_poses(batch, stamp_ns=7)
    assert [o.topic for o in outs] == ["/r1/odom", "/r2/odom", "/r3/odom", "/tf"]
    tf = msgs.decode(outs[-1].payload, msgs.TFMessage)
    assert isinstance(tf, msgs.TFMessage)
    assert [t.child_frame_id for t in tf.transforms] == [f"{r}/base_link" for r in ids]
    assert [t.transform.translation.x for t in tf.transforms] == [0.0, 1.0, 2.0]
    assert core.on_poses(batch, stamp_ns=8) == []  # the same frame again: each one refused
    assert core.rejected.by_reason == {"pose_out_of_order": 3}


def test_formation_outputs_in_a_namespace() -> None:
    core = BridgeCore(namespace="/lab")
    core.on_leader(Leader(t=1.0, seq=1, x=1.0, y=2.0, theta=0.5, v_mps=0.1, omega_radps=0.0))
    for k, role in ((0, "leader"), (1, "follower")):
        core.on_slot(
            Slot(t=1.0, seq=1, slot=k, role=role, stage=0, parent=None if k == 0 else 0,
                 x=float(k), y=0.0, theta=0.0, vx=0.0, vy=0.0)
        )  # fmt: skip
    outs = {o.topic: o for o in core.formation(stamp_ns=3_000_000_000)}
    assert set(outs) == {"/lab/formation/leader", "/lab/formation/slots", "/lab/formation/markers",
                         "/tf"}  # fmt: skip
    slots = msgs.decode(outs["/lab/formation/slots"].payload, msgs.PoseArray)
    assert isinstance(slots, msgs.PoseArray) and [p.position.x for p in slots.poses] == [0.0, 1.0]
    markers = msgs.decode(outs["/lab/formation/markers"].payload, msgs.MarkerArray)
    assert isinstance(markers, msgs.MarkerArray) and len(markers.markers) == 2
    tf = msgs.decode(outs["/tf"].payload, msgs.TFMessage)
    assert isinstance(tf, msgs.TFMessage)
    assert {t.child_frame_id for t in tf.transforms} == {
        "formation/leader",
        "formation/slot_0",
        "formation/slot_1",
    }


def test_cmd_vel_is_validated_rate_limited_and_counted() -> None:
    core = BridgeCore(max_cmd_hz=10.0)
    ok = core.on_cmd_vel(twist(0.2, -0.4), ATT, now_s=1.0)
    assert ok is not None and (ok.v_mps, ok.omega_radps) == (0.2, -0.4)
    assert isinstance(decode(encode(ok), CmdVel), CmdVel)  # a valid bus message
    nan = msgs.encode(msgs.Twist())[:4] + b"\x00" * 40 + b"\x00\x00\x00\x00\x00\x00\xf8\x7f"
    hostile = [
        (twist(0.2, 0.0), None, 2.0),  # no attachment
        (b"\x00\x01\x00\x00garbage", ATT, 2.0),
        (nan, ATT, 2.0),
        (twist(1e6, 0.0), ATT, 2.0),
        (twist(0.2, 0.0), ATT, 1.05),  # 20 Hz after the last: a flood at 10 Hz
    ]
    for payload, att, now in hostile:
        assert core.on_cmd_vel(payload, att, now_s=now) is None
    assert core.rejected.total == len(hostile)
    assert set(core.rejected.by_reason) == {
        "cmd_vel_missing_field",
        "cmd_vel_malformed",
        "cmd_vel_non_finite",
        "cmd_vel_out_of_range",
        "cmd_vel_flood",
    }
    assert core.forwarded == 1
    assert core.on_cmd_vel(twist(0.0, 0.0), ATT, now_s=1.2) is not None


def goal(x: float, y: float, yaw: float, frame: str = "map") -> bytes:
    header = msgs.Header(msgs.Time(1, 0), frame)
    pose = msgs.Pose(msgs.Point(x, y), msgs.quaternion_from_yaw(yaw))
    return msgs.encode(msgs.PoseStamped(header, pose))


def test_goal_becomes_the_operators_goal_and_hostile_goals_are_counted() -> None:
    core = BridgeCore()
    ok = core.on_goal(goal(1.5, -0.5, 0.3), ATT, now_s=1.0)
    assert ok is not None and (ok.x, ok.y) == (1.5, -0.5)
    assert ok.heading == pytest.approx(0.3)
    assert isinstance(decode(encode(ok), Goal), Goal)  # a valid bus message
    zero_q = msgs.encode(
        msgs.PoseStamped(msgs.Header(frame_id="map"), msgs.Pose(orientation=msgs.Quaternion(w=0.0)))
    )
    hostile = [
        (goal(1.0, 0.0, 0.0), None, 2.0),  # no attachment
        (goal(1.0, 0.0, 0.0, frame="odom"), ATT, 2.0),
        (goal(1e6, 0.0, 0.0), ATT, 2.0),
        (zero_q, ATT, 2.0),
        (goal(1.0, 0.0, 0.0)[:-3], ATT, 2.0),  # truncated CDR
        (goal(1.0, 0.0, 0.0) + bytes(70_000), ATT, 2.0),  # oversized
        (goal(1.0, 0.0, 0.0), ATT, 1.1),  # 10 Hz after the last: a flood at 5 Hz
    ]
    for payload, att, now in hostile:
        assert core.on_goal(payload, att, now_s=now) is None
    assert core.rejected.total == len(hostile)
    assert {"goal_missing_field", "goal_frame", "goal_out_of_range", "goal_quaternion",
            "goal_flood"} <= set(core.rejected.by_reason)  # fmt: skip
    assert core.forwarded == 1


def test_oversized_and_wrong_length_cmd_vel_is_counted() -> None:
    core = BridgeCore()
    for payload in (twist(0.1, 0.0) + bytes(8), twist(0.1, 0.0) + bytes(1 << 16), b""):
        assert core.on_cmd_vel(payload, ATT, now_s=1.0) is None
    assert core.rejected.by_reason == {"cmd_vel_too_large": 2, "cmd_vel_malformed": 1}
    assert core.forwarded == 0


# --- the bridge process and an independent ROS 2 client ----------------------------------------


class BusSide:
    """A tiny fleet stand-in on the bus: publishes poses, leader and slots; records what the
    bridge forwards (teleop) and what its e-stop service sends (estop)."""

    def __init__(self, session: zenoh.Session, fleet: str = "demo") -> None:
        self.session, self.fleet = session, fleet
        self.teleops: list[CmdVel] = []
        self.estops: list[Estop] = []
        self._stop = threading.Event()
        self._subs = [
            session.declare_subscriber(keys.cmd_vel_key(fleet), self._on_teleop),
            session.declare_subscriber(keys.estop_key(fleet), self._on_estop),
        ]
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _on_teleop(self, sample: zenoh.Sample) -> None:
        msg = decode(sample.payload.to_bytes(), CmdVel)
        if not isinstance(msg, DecodeError):
            self.teleops.append(msg)

    def _on_estop(self, sample: zenoh.Sample) -> None:
        msg = decode(sample.payload.to_bytes(), Estop)
        if not isinstance(msg, DecodeError):
            self.estops.append(msg)

    def _run(self) -> None:
        k = 0
        while not self._stop.wait(0.05):
            k += 1
            t = 0.05 * k
            f = self.fleet
            put = self.session.put
            put(keys.pose_key(f, "r1"), encode(Pose(t=t, seq=k, x=0.01 * k, y=0.5, theta=0.1)))
            put(keys.status_key(f, "r1"), encode(Status(t=t, seq=k, mode="tracking", slot=0,
                pid=1, host="h", rejected=0, v_mps=0.2, omega_radps=-0.05)))  # fmt: skip
            put(keys.leader_key(f), encode(Leader(t=t, seq=k, x=0.01 * k, y=0.0, theta=0.0,
                                                  v_mps=0.2, omega_radps=0.0)))  # fmt: skip
            put(keys.slot_key(f, 0), encode(Slot(t=t, seq=k, slot=0, role="leader", stage=0,
                parent=None, x=0.01 * k, y=0.0, theta=0.0, vx=0.2, vy=0.0)))  # fmt: skip

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2.0)
        for s in self._subs:
            s.undeclare()


def until(pred: Callable[[], Any], timeout_s: float, what: str) -> Any:
    deadline = time.monotonic() + timeout_s
    while not (got := pred()):
        if time.monotonic() > deadline:
            raise AssertionError(f"{what} not within {timeout_s} s")
        time.sleep(0.02)
    return got


@pytest.mark.zenoh
@pytest.mark.slow
def test_independent_ros2_client_sees_and_drives_the_bridge(
    router: Any, spawn: Any, session: Callable[..., zenoh.Session]
) -> None:
    bridge = spawn("ros2", "--endpoint", router.endpoint, "--domain-id", "3", ready=READY)
    raw = session()
    bus = BusSide(raw)
    try:
        client = spawn.command(
            [sys.executable, "-m", "tests.support.ros2_sdk_client", str(router.port), "3"]
        )
        assert client.proc.wait(60.0) == 0, client.describe()
        lines = [json.loads(x) for x in client.stdout().splitlines() if x.startswith("{")]
        results = {line["what"]: line for line in lines}
        assert "error" not in results, results.get("error")

        topics = results["topics"]["topics"]
        assert topics["/r1/odom"] == ["nav_msgs/msg/Odometry"]
        assert topics["/tf"] == ["tf2_msgs/msg/TFMessage"]
        assert topics["/formation/slots"] == ["geometry_msgs/msg/PoseArray"]
        assert topics["/formation/leader"] == ["geometry_msgs/msg/PoseStamped"]
        assert topics["/formation/markers"] == ["visualization_msgs/msg/MarkerArray"]
        assert "geometry_msgs/msg/Twist" in topics["/formation/cmd_vel"]

        services = results["services"]["services"]
        assert services["/formation/estop"] == ["std_srvs/srv/Trigger"]
        assert services["/formation/release"] == ["std_srvs/srv/Trigger"]

        (odom,) = results["odom"]["samples"]
        assert (odom["frame_id"], odom["child_frame_id"]) == ("map", "r1/base_link")
        assert odom["y"] == pytest.approx(0.5)
        # the robot's status (20 Hz here) carries its estimator twist: the odometry's (issue 29)
        assert (odom["v"], odom["omega"]) == (0.2, -0.05)
        assert odom["cov_vx"] == TWIST_COV_ESTIMATOR[0]

        teleops = until(lambda: bus.teleops, 5.0, "CmdVel on the bus")
        assert (teleops[0].v_mps, teleops[0].omega_radps) == (0.15, -0.25)

        # the e-stop service reached the fleet's e-stop key (no robots here: nobody acked)
        response = results["trigger"]["response"]
        assert response is not None and "estop engaged for the fleet" in response["message"]
        assert response["success"] is False
        assert any(e.engage and e.robot is None for e in bus.estops)

        # hostile ROS input: malformed, NaN, no attachment, a wrong type hash, then a flood of
        # 300 valid commands at once; dropped and counted, at most --max-cmd-hz pass
        cmd_key = rmw.topic_key(3, "/formation/cmd_vel", msgs.ros_type(msgs.Twist))
        nan = msgs.encode(msgs.Twist())[:4] + bytes(40) + bytes.fromhex("000000000000f87f")
        raw.put(cmd_key, b"\x00\x01\x00\x00garbage", attachment=ATT)
        raw.put(cmd_key, nan, attachment=ATT)
        raw.put(cmd_key, twist(0.1, 0.0))
        wrong = cmd_key.rsplit("/", 1)[0] + "/RIHS01_" + "0" * 64
        raw.put(wrong, twist(0.3, 0.0), attachment=ATT)  # another type: never matched
        before = len(bus.teleops)
        t0 = time.monotonic()
        for _ in range(300):
            raw.put(cmd_key, twist(0.05, 0.0), attachment=ATT)
        flood_s = time.monotonic() - t0
        time.sleep(0.5)
        passed = len(bus.teleops) - before
        assert 1 <= passed <= 50 * (flood_s + 0.5) + 2, (passed, flood_s)
        assert all(t.v_mps == 0.05 for t in bus.teleops[before:])
        # a malformed service request gets no reply and changes nothing; a goal in another
        # frame or an oversized one is dropped
        estops = len(bus.estops)
        trigger_key = rmw.topic_key(3, "/formation/estop", msgs.ros_type(msgs.TriggerRequest))
        replies = list(raw.get(trigger_key, payload=b"\x00\x01", attachment=ATT, timeout=1.0))
        assert [r for r in replies if r.ok is not None] == [] and len(bus.estops) == estops
        goal_key = rmw.topic_key(3, "/formation/goal", msgs.ros_type(msgs.PoseStamped))
        raw.put(goal_key, goal(1.0, 0.0, 0.0, frame="odom"), attachment=ATT)
        raw.put(goal_key, goal(1.0, 0.0, 0.0) + bytes(70_000), attachment=ATT)
        time.sleep(0.3)
        bridge.stop()
        counts = bridge.stderr()
        for reason in ("cmd_vel_malformed", "cmd_vel_non_finite", "cmd_vel_missing_field",
                       "cmd_vel_flood", "trigger_malformed", "goal_frame",
                       "goal_too_large"):  # fmt: skip
            assert f"'{reason}'" in counts, counts
    finally:
        bus.close()


@pytest.mark.zenoh
@pytest.mark.slow
def test_formation_up_ros2_shows_the_fleet_to_a_ros2_client(spawn: Any, tmp_path: Path) -> None:
    port = free_port()
    run = spawn(
        "up", "--endpoint", f"tcp/127.0.0.1:{port}", "--fleet", "demo", "--out",
        str(tmp_path / "run"), "--no-figures", "--scenario", "paper-exp1", "--duration", "25",
        "--ros2", "--quiet",
    )  # fmt: skip
    client = spawn.command(
        [sys.executable, "-m", "tests.support.ros2_sdk_client", str(port), "0", "watch"]
    )
    assert client.proc.wait(90.0) == 0, client.describe()
    results = {
        line["what"]: line
        for line in (json.loads(x) for x in client.stdout().splitlines() if x.startswith("{"))
    }
    assert "error" not in results, results.get("error")
    topics = results["topics"]["topics"]
    robots = {t.split("/")[1] for t in topics if t.endswith("/odom")}
    assert {"r1", "r2", "r3"} <= robots, topics
    assert topics["/tf"] == ["tf2_msgs/msg/TFMessage"]
    assert topics["/formation/slots"] == ["geometry_msgs/msg/PoseArray"]
    (odom,) = results["odom"]["samples"]
    assert odom["child_frame_id"] == "r1/base_link"
    # the twist: the robot's estimator's (its host's status batch) or, were it stale on this
    # loaded machine, the finite difference; the covariance says which
    assert odom["cov_vx"] in (TWIST_COV_ESTIMATOR[0], TWIST_COV_FINITE_DIFFERENCE[0])
    source = "estimator" if odom["cov_vx"] == TWIST_COV_ESTIMATOR[0] else "finite difference"
    print(f"odometry twist from the {source}")
    # how long after `formation up` started the client saw every topic (the report quotes it)
    print(f"topics seen {results['topics']['after_s']} s after the client started")
    run.stop()


@pytest.mark.zenoh
@pytest.mark.slow
def test_bridge_speaks_sd_notify(router: Any, spawn: Any, tmp_path: Path) -> None:
    """deploy/systemd/formation-ros2.service is Type=notify with a watchdog: READY=1 once its
    ROS entities are declared, WATCHDOG=1 from its loop, STOPPING=1 on SIGTERM."""
    from support.notify_socket import FakeSystemd

    systemd = FakeSystemd(tmp_path / "notify.sock")
    try:
        bridge = spawn("ros2", "--endpoint", router.endpoint, ready=READY, env=systemd.env())
        ready = systemd.wait("READY=1")
        until(lambda: len([t for t in systemd.times("WATCHDOG=1") if t > ready]) >= 3, 5.0,
              "three WATCHDOG=1 after READY=1")  # fmt: skip
        bridge.stop()
        systemd.wait("STOPPING=1", 5.0)
    finally:
        systemd.close()
