"""The ``ros2`` motor backend: eq 8 both ways, odometry validation and staleness, and a real
Zenoh session on loopback driving a simulated ROS 2 base (tests/support/ros2_base.py)."""

from __future__ import annotations

import math
import struct
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
import zenoh
from hypothesis import given
from hypothesis import strategies as st
from support.spawn import free_port

import runtime as rt
from bus_schemas.ros2 import msgs, rmw
from robot_agent.core.kinematics import twist_from_wheels
from robot_agent.core.params import RobotGeometry
from robot_agent.motors import BackendContext, MotorBackend, create_backend
from robot_agent.motors.ros2 import Ros2Backend, Ros2MotorConfig
from scenario.robot_config import MotorConfig, robot_config_from_dict
from tests.support.ros2_base import SimRos2Base

GEOM = RobotGeometry(wheel_radius_m=0.033, half_track_m=0.08, max_wheel_radps=8.0)
GID = bytes(range(16))


def until(pred: Callable[[], Any], timeout_s: float = 5.0, what: str = "condition") -> Any:
    deadline = time.monotonic() + timeout_s
    while True:
        got = pred()
        if got:
            return got
        if time.monotonic() > deadline:
            raise AssertionError(f"{what} not met within {timeout_s} s")
        time.sleep(0.005)


def odom_bytes(v_mps: float, omega_radps: float) -> bytes:
    twist = msgs.Twist(msgs.Vector3(x=v_mps), msgs.Vector3(z=omega_radps))
    return msgs.encode(msgs.Odometry(twist=msgs.TwistWithCovariance(twist)))


def att(seq: int = 1) -> bytes:
    return rmw.encode_attachment(rmw.Attachment(seq, 0, GID))


class FakeClock:
    def __init__(self) -> None:
        self.t_s = 100.0

    def __call__(self) -> float:
        return self.t_s


# --- without Zenoh: the pure parts of the backend ----------------------------------------------


def test_is_a_motor_backend_and_configurable() -> None:
    backend = create_backend("ros2", Ros2MotorConfig(), BackendContext(GEOM))
    assert isinstance(backend, MotorBackend) and isinstance(backend, Ros2Backend)
    rc = robot_config_from_dict(
        {
            "robot_id": "r1",
            "zenoh": {"endpoints": ["tcp/10.0.0.2:7447"]},
            "motor": {"backend": "ros2", "namespace": "/tb3_1", "domain_id": 30},
        }
    )
    assert rc.motor.settings == Ros2MotorConfig(namespace="/tb3_1", domain_id=30)
    defaults = robot_config_from_dict(
        {
            "robot_id": "r1",
            "zenoh": {"endpoints": ["tcp/10.0.0.2:7447"]},
            "motor": {"backend": "ros2"},
        }
    )
    assert defaults.motor == MotorConfig(backend="ros2", settings=Ros2MotorConfig())
    with pytest.raises(ValueError):
        create_backend("ros2", None, BackendContext(GEOM))  # no settings
    for bad in ({"domain_id": 300}, {"cmd_vel_topic": "/abs"}, {"namespace": "a b"}):
        with pytest.raises(ValueError):
            Ros2MotorConfig(**bad)  # type: ignore[arg-type]


@given(
    v=st.floats(-0.2, 0.2),
    w=st.floats(-2.0, 2.0),
)
def test_odometry_becomes_wheel_speeds_eq8(v: float, w: float) -> None:
    clock = FakeClock()
    backend = Ros2Backend(Ros2MotorConfig(), GEOM, clock=clock)
    backend.on_odom(odom_bytes(v, w), att())
    got = backend.read_wheel_speeds()
    assert got is not None
    back_v, back_w = twist_from_wheels(got[0], got[1], GEOM)
    assert math.isclose(back_v, v, abs_tol=1e-12) and math.isclose(back_w, w, abs_tol=1e-12)


def test_stale_odometry_is_no_speeds() -> None:
    clock = FakeClock()
    backend = Ros2Backend(Ros2MotorConfig(odom_timeout_s=0.5), GEOM, clock=clock)
    assert backend.read_wheel_speeds() is None  # none yet
    backend.on_odom(odom_bytes(0.1, 0.0), att())
    clock.t_s += 0.4
    assert backend.read_wheel_speeds() is not None
    clock.t_s += 0.2
    assert backend.read_wheel_speeds() is None
    assert backend.stale_reads == 2


def test_hostile_odometry_is_counted_and_ignored() -> None:
    clock = FakeClock()
    backend = Ros2Backend(Ros2MotorConfig(), GEOM, clock=clock)
    good = odom_bytes(0.1, 0.5)
    backend.on_odom(good, att())
    expected = backend.read_wheel_speeds()
    nan = bytearray(good)
    # twist.twist.linear.x sits 8*36 + 48 bytes before the end... find it by re-encoding
    marker = struct.pack("<d", 0.1)
    nan[nan.rindex(marker) : nan.rindex(marker) + 8] = struct.pack("<d", math.nan)
    hostile: list[tuple[bytes, bytes | None]] = [
        (good, None),  # no attachment
        (good, att()[:20]),  # a short attachment
        (good[:-3], att()),  # truncated CDR
        (bytes(nan), att()),  # NaN speed
        (odom_bytes(50.0, 0.0), att()),  # implausible speed
        (b"\x00\x01\x00\x00" + b"\xff" * 40, att()),  # garbage
        (good + b"\x00" * 70000, att()),  # oversized
    ]
    for payload, attachment in hostile:
        backend.on_odom(payload, attachment)
    assert backend.rejected.total == len(hostile)
    assert backend.read_wheel_speeds() == expected
    assert backend.status().errors == len(hostile)


def test_unopened_backend_counts_and_never_raises() -> None:
    backend = Ros2Backend(
        Ros2MotorConfig(endpoint="tcp/127.0.0.1:1", mode="client"),
        GEOM,
        session_factory=lambda cfg: (_ for _ in ()).throw(zenoh.ZError("no router")),
    )
    assert backend.open() is False
    assert backend.apply(1.0, 1.0, 0.0) is False
    assert backend.apply(math.nan, 1.0, 0.1) is False
    assert backend.stop() is False
    backend.close()
    s = backend.status()
    assert not s.healthy and not s.connected
    assert s.open_failures == 2 and s.rejected_inputs == 1 and s.consecutive_failures == 3


# --- over a real Zenoh session: the backend drives the simulated base --------------------------


@pytest.fixture
def base_and_backend(
    router: Any, session: Callable[..., zenoh.Session]
) -> Iterator[tuple[SimRos2Base, Ros2Backend]]:
    base = SimRos2Base(session(), namespace="/tb3_1", domain_id=7).start()
    opened: list[zenoh.Session] = []

    def factory(cfg: Ros2MotorConfig) -> zenoh.Session:
        s = rt.open_session(rt.ZenohSettings(connect=(router.endpoint,), open_timeout_s=5.0))
        opened.append(s)
        return s

    backend = Ros2Backend(
        Ros2MotorConfig(namespace="/tb3_1", domain_id=7, odom_timeout_s=0.3),
        GEOM,
        subscribe=rt.subscribe_on_thread,
        session_factory=factory,
    )
    try:
        yield base, backend
    finally:
        backend.close()
        base.close()
        for s in opened:
            rt.close_session(s)


@pytest.mark.zenoh
def test_backend_drives_a_simulated_ros2_base(
    base_and_backend: tuple[SimRos2Base, Ros2Backend], session: Callable[..., zenoh.Session]
) -> None:
    base, backend = base_and_backend
    assert backend.open()
    until(lambda: base.last_command == (0.0, 0.0), what="the zero twist of open()")

    # the agent is a node of the base's ROS graph, with the right topics and types
    observer = session()
    replies = until(
        lambda: [
            rmw.parse_token(str(r.ok.key_expr))
            for r in observer.liveliness().get(rmw.graph_pattern(7), timeout=1.0)
            if r.ok is not None
        ],
        what="liveliness tokens",
    )
    tokens = {(t.node_name, t.kind, t.topic, t.ros_type) for t in replies}
    assert ("formation_agent", rmw.EntityKind.NODE, None, None) in tokens
    assert (
        "formation_agent",
        rmw.EntityKind.PUBLISHER,
        "/tb3_1/cmd_vel",
        "geometry_msgs/msg/Twist",
    ) in tokens
    assert (
        "formation_agent",
        rmw.EntityKind.SUBSCRIPTION,
        "/tb3_1/odom",
        "nav_msgs/msg/Odometry",
    ) in tokens

    # wheels -> twist (inverse of eq 8) on the base; the base's odom -> wheels for the estimator
    omega_r, omega_l = 3.0, 2.0
    v, w = twist_from_wheels(omega_r, omega_l, GEOM)
    assert backend.apply(omega_r, omega_l, 1.0)
    got = until(lambda: base.last_command if base.last_command != (0.0, 0.0) else None)
    assert got == pytest.approx((v, w), abs=1e-12)
    speeds = until(lambda: backend.read_wheel_speeds(), what="odometry back")
    until(
        lambda: (
            (s := backend.read_wheel_speeds()) is not None
            and s == pytest.approx((omega_r, omega_l))
        ),
        what="odometry of the commanded twist",
    )
    assert speeds is not None
    until(lambda: backend.status().healthy, what="healthy")
    assert base.x_m > 0.0  # it moved

    # a saturated command keeps the turn: both wheels scaled by the same factor
    assert backend.apply(16.0, 8.0, 1.1)
    v2, w2 = twist_from_wheels(8.0, 4.0, GEOM)
    until(lambda: base.last_command == pytest.approx((v2, w2)), what="scaled twist")

    # HOLD/ESTOP: stop() is a zero twist at once
    assert backend.stop()
    until(lambda: base.last_command == (0.0, 0.0), what="zero twist on stop")

    # a silent base: stale odometry is no encoder speeds, and the backend reports it
    base.pause_odom()
    until(lambda: backend.read_wheel_speeds() is None, what="stale odometry")
    assert not backend.status().healthy
    base.pause_odom(False)
    until(lambda: backend.read_wheel_speeds() is not None, what="odometry again")

    # hostile samples on the odom key are dropped and counted, the backend keeps going
    before = backend.rejected.total
    base.put_odom_raw(b"\x00\x01\x00\x00junk", att())
    base.put_odom_raw(odom_bytes(0.1, 0.0), None)
    until(lambda: backend.rejected.total >= before + 2, what="hostile odometry counted")
    assert base.rejected.total == 0  # every command the backend sent was valid

    # close(): a last zero twist, then the agent leaves the ROS graph
    assert backend.apply(2.0, 2.0, 1.2)
    until(lambda: base.last_command != (0.0, 0.0), what="moving again")
    backend.close()
    until(lambda: base.last_command == (0.0, 0.0), what="zero twist on close")

    def agent_tokens() -> list[str]:
        return [
            str(r.ok.key_expr)
            for r in observer.liveliness().get(rmw.graph_pattern(7), timeout=1.0)
            if r.ok is not None and "formation_agent" in str(r.ok.key_expr)
        ]

    until(lambda: not agent_tokens(), what="tokens gone")


@pytest.mark.zenoh
@pytest.mark.slow
def test_agent_process_holds_a_ros2_base_at_zero(
    router: Any, spawn: Any, session: Callable[..., zenoh.Session], tmp_path: Path
) -> None:
    """`formation agent --config` with backend "ros2": the shell wires the backend (its odom
    subscription through runtime.bridge); with the fleet's router unreachable the agent holds
    the base at zero (a stream of zero twists), shows up in the base's ROS graph, and leaves
    it on SIGTERM."""
    base = SimRos2Base(session(), namespace="/tb3_1").start()
    try:
        config = tmp_path / "r1.toml"
        config.write_text(
            'robot_id = "r1"\n'
            f'[zenoh]\nendpoints = ["tcp/127.0.0.1:{free_port()}"]\n'  # the fleet: unreachable
            f'[motor]\nbackend = "ros2"\nendpoint = "{router.endpoint}"\nmode = "client"\n'
            'namespace = "/tb3_1"\n'
        )
        agent = spawn("agent", "--config", str(config))
        until(lambda: len(base.commands) >= 5, 15.0, "a stream of commands")
        assert set(base.commands) == {(0.0, 0.0)}
        assert base.rejected.total == 0
        observer = session()

        def agent_tokens() -> list[rmw.LivelinessToken]:
            out = []
            for r in observer.liveliness().get(rmw.graph_pattern(0), timeout=1.0):
                if r.ok is not None:
                    tok = rmw.parse_token(str(r.ok.key_expr))
                    if isinstance(tok, rmw.LivelinessToken) and tok.node_name == "formation_agent":
                        out.append(tok)
            return out

        kinds = {t.kind for t in until(agent_tokens, 10.0, "the agent in the ROS graph")}
        assert kinds == {
            rmw.EntityKind.NODE, rmw.EntityKind.PUBLISHER, rmw.EntityKind.SUBSCRIPTION,
        }  # fmt: skip
        agent.stop()
        assert agent.proc.returncode == 0, agent.describe()
        until(lambda: not agent_tokens(), 10.0, "the agent gone from the ROS graph")
    finally:
        base.close()
