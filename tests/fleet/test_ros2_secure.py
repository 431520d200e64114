"""The ROS 2 bridge under ``--secure``: its own identity (CN ``ros2``) in the generated PKI and
access control. Only the bridge publishes its ROS topics; a ROS command (``/formation/cmd_vel``,
``/formation/goal``, the e-stop service) reaches the fleet only from the operator's identity and
only through the bridge, which forwards it to the operator's bus keys; ``formation up --ros2
--secure`` runs."""

from __future__ import annotations

import re
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
import zenoh
from support.spawn import free_port

from bus_schemas import CmdVel, Estop, Goal, Pose, acl, decode, encode, keys
from bus_schemas.acl import Access, Identity, Kind
from bus_schemas.errors import DecodeError
from bus_schemas.ros2 import graph, msgs, rmw
from formation.live.ros2_bridge import READY

pytestmark = pytest.mark.shares_cpu

FLEET = "demo"
ATT = rmw.encode_attachment(rmw.Attachment(1, 0, bytes(16)))
ODOM_KEY = rmw.topic_key(0, "/r1/odom", msgs.ros_type(msgs.Odometry))
CMD_KEY = rmw.topic_key(0, "/formation/cmd_vel", msgs.ros_type(msgs.Twist))
GOAL_KEY = rmw.topic_key(0, "/formation/goal", msgs.ros_type(msgs.PoseStamped))
ESTOP_KEY = rmw.topic_key(0, "/formation/estop", msgs.ros_type(msgs.TriggerRequest))
IDENTS = [
    Identity(Kind.ROS2),
    Identity(Kind.OPERATOR),
    Identity(Kind.OBSERVER),
    Identity(Kind.PLANT),
    acl.coordinator("main"),
    acl.robot("r1"),
]


def twist(v: float) -> bytes:
    return msgs.encode(msgs.Twist(msgs.Vector3(x=v), msgs.Vector3()))


def odom(y: float) -> bytes:
    pose = msgs.Pose(msgs.Point(0.0, y), msgs.quaternion_from_yaw(0.0))
    return msgs.encode(
        msgs.Odometry(msgs.Header(frame_id="map"), "r1/base_link", msgs.PoseWithCovariance(pose))
    )


def test_static_grants_of_the_bridge_identity() -> None:
    """The generated ACL, evaluated like the router does (bus_schemas.acl.may)."""
    section = acl.access_control(IDENTS, FLEET)
    ns_odom = rmw.topic_key(7, "/lab/r9/odom", msgs.ros_type(msgs.Odometry))
    for key in (ODOM_KEY, ns_odom, rmw.topic_key(0, "/tf", msgs.ros_type(msgs.TFMessage))):
        assert acl.may(section, "ros2", Access.PUBLISH, key)
        assert acl.may(section, "observer", Access.READ, key)
        for cn in ("operator", "observer", "plant", "coordinator.main", "robot.r1"):
            assert not acl.may(section, cn, Access.PUBLISH, key), (cn, key)
    # the same topic with another type is nobody's
    wrong = ODOM_KEY.rsplit("/", 1)[0] + "/RIHS01_" + "0" * 64
    assert not acl.may(section, "ros2", Access.PUBLISH, wrong)
    # ROS commands: the operator publishes them, the bridge reads them, nobody else
    for key in (CMD_KEY, GOAL_KEY):
        assert acl.may(section, "operator", Access.PUBLISH, key)
        assert acl.may(section, "ros2", Access.READ, key)
        for cn in ("ros2", "observer", "plant", "coordinator.main", "robot.r1"):
            assert not acl.may(section, cn, Access.PUBLISH, key), (cn, key)
    assert acl.may(section, "ros2", Access.ANSWER, ESTOP_KEY)
    assert acl.may(section, "operator", Access.ASK, ESTOP_KEY)
    assert not acl.may(section, "observer", Access.ASK, ESTOP_KEY)
    # on the bus the bridge writes only the operator's keys it forwards into
    bus_writes = {k for a, k in acl.grants(Identity(Kind.ROS2), FLEET) if a is Access.PUBLISH}
    assert {k for k in bus_writes if k.startswith("formation/")} == {
        keys.cmd_vel_key(FLEET),
        keys.goal_key(FLEET),
        keys.estop_key(FLEET),
    }
    # its tokens: only its own node's
    token = rmw.node_token(0, "ab12", 0, "", graph.NODE_NAME)
    assert acl.may(section, "ros2", Access.TOKEN, token)
    assert not acl.may(section, "ros2", Access.TOKEN, rmw.node_token(0, "ab12", 0, "", "rviz"))
    for cn in ("operator", "observer"):
        assert not acl.may(section, cn, Access.TOKEN, token)
        assert acl.may(section, cn, Access.WATCH, token)


class Inbox:
    def __init__(self) -> None:
        self.items: list[tuple[bytes, bytes | None]] = []
        self.lock = threading.Lock()

    def __call__(self, sample: zenoh.Sample) -> None:
        att = sample.attachment
        with self.lock:
            self.items.append((sample.payload.to_bytes(), None if att is None else att.to_bytes()))

    def decoded(self, cls: type[Any], decoder: Callable[..., Any] = decode) -> list[Any]:
        with self.lock:
            out = [decoder(p, cls) for p, _ in self.items]
        return [m for m in out if not isinstance(m, DecodeError)]


def until(pred: Callable[[], Any], timeout_s: float, what: str) -> Any:
    deadline = time.monotonic() + timeout_s
    while not (got := pred()):
        if time.monotonic() > deadline:
            raise AssertionError(f"{what} not within {timeout_s} s")
        time.sleep(0.02)
    return got


@pytest.mark.zenoh
@pytest.mark.slow
def test_only_the_bridge_publishes_ros_keys_and_only_the_operator_commands(
    tmp_path: Path, spawn: Any
) -> None:
    from formation.launch.pki import write_run_configs
    from formation.launch.router import READY_PREFIX

    rc = write_run_configs(tmp_path / "run", IDENTS, port=free_port(), fleet=FLEET)
    spawn("router", "--zenoh-config", str(rc.router), ready=READY_PREFIX)
    bridge = spawn("ros2", "--zenoh-config", str(rc.clients["ros2"]), "--fleet", FLEET,
                   ready=READY)  # fmt: skip
    s = {cn: zenoh.open(zenoh.Config.from_file(str(rc.clients[cn]))) for cn in rc.clients}
    try:
        odoms, cmds, goals, estops = Inbox(), Inbox(), Inbox(), Inbox()
        subs = [
            s["observer"].declare_subscriber(ODOM_KEY, odoms),
            s["coordinator.main"].declare_subscriber(keys.cmd_vel_key(FLEET), cmds),
            s["coordinator.main"].declare_subscriber(keys.goal_key(FLEET), goals),
            s["coordinator.main"].declare_subscriber(keys.estop_key(FLEET), estops),
        ]
        time.sleep(0.5)
        pose_pub = s["plant"].declare_publisher(keys.pose_key(FLEET, "r1"))
        for k in range(1, 11):
            pose_pub.put(encode(Pose(t=0.1 * k, seq=k, x=0.01 * k, y=0.5, theta=0.0)))
            time.sleep(0.02)

        def ys() -> list[float]:
            return [o.pose.pose.position.y for o in odoms.decoded(msgs.Odometry, msgs.decode)]

        until(ys, 5.0, "the bridge's /r1/odom at the observer")
        # forged odometry from every other identity never arrives (the observer's own put
        # would reach its own subscriber inside its session, without the router)
        for cn in ("operator", "plant", "coordinator.main", "robot.r1"):
            s[cn].put(ODOM_KEY, odom(99.0), attachment=ATT)
        # ROS commands from identities other than the operator never reach the bridge
        for cn in ("observer", "plant", "robot.r1", "coordinator.main"):
            s[cn].put(CMD_KEY, twist(0.05), attachment=ATT)
        time.sleep(0.3)
        s["operator"].put(CMD_KEY, twist(0.15), attachment=ATT)
        header = msgs.Header(frame_id="map")
        goal = msgs.PoseStamped(header, msgs.Pose(msgs.Point(1.0, 2.0), msgs.Quaternion()))
        s["operator"].put(GOAL_KEY, msgs.encode(goal), attachment=ATT)
        got = until(lambda: cmds.decoded(CmdVel), 5.0, "the operator's cmd_vel on the bus")
        until(lambda: goals.decoded(Goal), 5.0, "the operator's goal on the bus")
        assert [c.v_mps for c in got] == [0.15]
        (g,) = goals.decoded(Goal)
        assert (g.x, g.y, g.heading) == (1.0, 2.0, 0.0)
        # the e-stop service: the operator's call reaches the fleet's e-stop, an observer's not
        request = msgs.encode(msgs.TriggerRequest())
        denied = list(s["observer"].get(ESTOP_KEY, payload=request, attachment=ATT, timeout=2.0))
        assert not [r for r in denied if r.ok is not None]
        replies = list(s["operator"].get(ESTOP_KEY, payload=request, attachment=ATT, timeout=5.0))
        (reply,) = [r.ok for r in replies if r.ok is not None]
        response = msgs.decode(reply.payload.to_bytes(), msgs.TriggerResponse)
        assert isinstance(response, msgs.TriggerResponse) and "estop" in response.message
        assert any(e.engage for e in estops.decoded(Estop))
        assert 99.0 not in ys() and set(ys()) == {0.5}
        for sub in subs:
            sub.undeclare()
        bridge.stop()
        assert "rejected 0" in bridge.stderr(), bridge.stderr()
    finally:
        for sess in s.values():
            sess.close()


@pytest.mark.zenoh
@pytest.mark.slow
def test_formation_up_ros2_secure_runs(spawn: Any, tmp_path: Path) -> None:
    out = tmp_path / "run"
    run = spawn(
        "up", "--endpoint", f"tcp/127.0.0.1:{free_port()}", "--fleet", FLEET, "--out", str(out),
        "--no-figures", "--scenario", "paper-exp1", "--duration", "2", "--ros2", "--secure",
        "--quiet",
    )  # fmt: skip
    assert run.proc.wait(120.0) == 0, run.describe()
    log = (out / "logs" / "ros2.log").read_text()
    published = re.search(r"published (\d+) ROS messages", log)
    assert published is not None and int(published.group(1)) > 0, log
