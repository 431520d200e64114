"""The ``ros2`` motor backend: drive any ROS 2 base (TurtleBot3/4, Create 3, ...) over rmw_zenoh.

The agent becomes a ROS 2 node on the base's own Zenoh network (its ``rmw_zenohd``), without a
ROS install: it publishes ``<namespace>/cmd_vel`` (geometry_msgs/msg/Twist) and subscribes to
``<namespace>/odom`` (nav_msgs/msg/Odometry), with the CDR codecs and key/token conventions of
:mod:`bus_schemas.ros2`.

- ``apply(omega_r, omega_l)``: the wheel speeds become the base's twist, ``v = R (w_r + w_l) / 2``
  and ``omega = R (w_r - w_l) / (2 L)`` (the inverse of eq 8, ``kinematics.twist_from_wheels``);
  a wheel beyond ``max_wheel_radps`` is scaled down (both wheels, so the turn is kept).
- ``stop()`` (HOLD, ESTOP, shutdown) publishes a zero twist; ``close()`` publishes a zero twist,
  drops the liveliness tokens and closes the session.
- ``read_wheel_speeds()``: the newest odometry's twist as wheel speeds (eq 8), for the
  estimator exactly like encoder speeds; None when no odometry arrived within
  ``odom_timeout_s`` (a stale ``odom`` is treated like stale encoders: the firmware predicts).
- Every odometry sample is validated (CDR, finite values, attachment, plausible speeds);
  rejections are counted by reason (:attr:`Ros2Backend.rejected`) and in ``status().errors``.
- The node, its publisher and its subscription are announced with liveliness tokens, so
  ``ros2 node list`` / ``ros2 topic info -v /cmd_vel`` on the base shows the agent.

Like the RoboClaw driver (pyserial), Zenoh is imported when the backend opens, so importing
``robot_agent.motors`` stays standard-library only. This is a shell: it reads a monotonic clock
(injectable) for the odometry's age, and the wall clock for the rmw_zenoh attachment's
timestamp, which the format defines as ns since the UNIX epoch.
"""

from __future__ import annotations

import json
import math
import threading
import time
from collections.abc import Callable
from typing import Any

from bus_schemas.errors import DecodeError, RejectCounts
from bus_schemas.ros2 import msgs, rmw
from robot_agent.core.kinematics import twist_from_wheels, wheels_from_twist
from robot_agent.core.params import RobotGeometry

from .base import MotorStatus
from .ros2_config import Ros2MotorConfig

__all__ = ["Ros2Backend", "Ros2MotorConfig"]  # the config re-exported from ros2_config


class Ros2Backend:
    """A :class:`~robot_agent.motors.base.MotorBackend` publishing cmd_vel and reading odom.

    ``subscribe(session, key_expr, push)`` declares the odometry subscription and calls
    ``push(received)`` on Zenoh's thread with an object carrying ``payload`` and ``attachment``
    bytes: the agent's shell passes ``runtime.bridge.subscribe_on_thread`` (every subscription
    of the project goes through that bridge; this core module may not import the runtime).
    ``session_factory`` returns an open Zenoh session for this config; by default one is opened
    with ``zenoh.open``. ``clock`` is the monotonic clock of the odometry's age.
    """

    name = "ros2"

    def __init__(
        self,
        config: Ros2MotorConfig,
        geometry: RobotGeometry,
        *,
        subscribe: Callable[[Any, str, Callable[[Any], None]], Any] | None = None,
        session_factory: Callable[[Ros2MotorConfig], Any] | None = None,
        clock: Callable[[], float] = time.monotonic,
        wall_ns: Callable[[], int] = time.time_ns,
    ) -> None:
        self.config = config
        self.geometry = geometry
        self._subscribe = subscribe
        self._factory = session_factory or _open_session
        self._clock = clock
        self._wall_ns = wall_ns
        self._lock = threading.Lock()
        self._session: Any = None
        self._publisher: Any = None
        self._subscriber: Any = None
        self._tokens: list[Any] = []
        self._gid = b"\x00" * rmw.GID_BYTES
        self._seq = 0
        self._cmd_key = rmw.topic_key(
            config.domain_id, config.fqn(config.cmd_vel_topic), msgs.ros_type(msgs.Twist)
        )
        self._odom_key = rmw.topic_key(
            config.domain_id, config.fqn(config.odom_topic), msgs.ros_type(msgs.Odometry)
        )
        # odometry: (v_mps, omega_radps, arrival on self._clock), newest only
        self._odom: tuple[float, float, float] | None = None
        self.rejected = RejectCounts()
        self.odom_received = 0
        self.stale_reads = 0
        self._omega_r = self._omega_l = 0.0
        self._commands = self._acks = self._io_errors = self._clamped = 0
        self._rejected_inputs = self._open_failures = self._reconnects = 0
        self._consecutive = 0
        self._last_error: str | None = None
        self._last_ok_s: float | None = None
        self._retry_at_s = -math.inf
        self._backoff_s = 0.5
        self._ever_open = False

    # --- MotorBackend ------------------------------------------------------------------------

    def open(self) -> bool:
        """Open the Zenoh session, declare the node, publisher and subscription, send zero."""
        if self._session is not None:
            return True
        try:
            self._declare()
        except Exception as exc:  # zenoh.ZError, OSError: counted, retried from apply()
            self._open_failures += 1
            self._last_error = f"open: {type(exc).__name__}: {exc}"[:200]
            self._undeclare()
            return False
        if self._ever_open:
            self._reconnects += 1
        self._ever_open = True
        self._backoff_s = 0.5
        return self._publish(0.0, 0.0)

    def apply(self, omega_r_radps: float, omega_l_radps: float, now_s: float) -> bool:
        """Publish the twist of these wheel speeds (zero for a non-finite input)."""
        if not (math.isfinite(omega_r_radps) and math.isfinite(omega_l_radps)):
            self._rejected_inputs += 1
            omega_r_radps = omega_l_radps = 0.0
        limit = self.geometry.max_wheel_radps
        peak = max(abs(omega_r_radps), abs(omega_l_radps))
        if peak > limit:
            # scale both wheels: the turn radius is kept (PX4's inverse kinematics does this)
            self._clamped += 1
            omega_r_radps *= limit / peak
            omega_l_radps *= limit / peak
        retry = self._session is None and math.isfinite(now_s) and now_s >= self._retry_at_s
        if retry and not self.open():
            self._retry_at_s = now_s + self._backoff_s
            self._backoff_s = min(2.0 * self._backoff_s, 5.0)
        self._omega_r, self._omega_l = omega_r_radps, omega_l_radps
        v_mps, omega_radps = twist_from_wheels(omega_r_radps, omega_l_radps, self.geometry)
        ok = self._publish(v_mps, omega_radps)
        if ok and math.isfinite(now_s):
            self._last_ok_s = now_s
        return ok

    def stop(self) -> bool:
        """Publish a zero twist now."""
        self._omega_r = self._omega_l = 0.0
        return self._publish(0.0, 0.0)

    def close(self) -> None:
        """Zero twist (best effort), drop the tokens, close the session. Idempotent."""
        if self._session is not None:
            self._publish(0.0, 0.0)
        self._undeclare()

    def status(self) -> MotorStatus:
        """Healthy when the session is up, the last command went out and odometry is fresh."""
        fresh = self._odom_age_s() is not None
        connected = self._session is not None
        return MotorStatus(
            backend=self.name,
            healthy=connected and self._consecutive == 0 and fresh,
            connected=connected,
            omega_r_radps=self._omega_r,
            omega_l_radps=self._omega_l,
            commands=self._commands,
            acks=self._acks,
            errors=self._io_errors + self._rejected_inputs + self.rejected.total,
            no_ack=self.stale_reads,
            io_errors=self._io_errors,
            rejected_inputs=self._rejected_inputs,
            clamped=self._clamped,
            reconnects=self._reconnects,
            open_failures=self._open_failures,
            consecutive_failures=self._consecutive,
            last_error=self._last_error,
            last_ok_s=self._last_ok_s,
            firmware=None,
        )

    def read_wheel_speeds(self) -> tuple[float, float] | None:
        """The newest odometry's ``(omega_r, omega_l)`` (rad/s, eq 8), or None when stale."""
        with self._lock:
            odom = self._odom
        if odom is None or self._clock() - odom[2] > self.config.odom_timeout_s:
            self.stale_reads += 1
            return None
        return wheels_from_twist(odom[0], odom[1], self.geometry)

    # --- odometry ----------------------------------------------------------------------------

    def on_odom(self, payload: bytes, attachment: bytes | None) -> None:
        """One odometry sample (called on Zenoh's thread): validated, counted, kept if good."""
        att = rmw.decode_attachment(attachment)
        if isinstance(att, DecodeError):
            self.rejected.add(att)
            return
        odom = msgs.decode(payload, msgs.Odometry)
        if isinstance(odom, DecodeError):
            self.rejected.add(odom)
            return
        twist = odom.twist.twist
        v_mps, omega_radps = twist.linear.x, twist.angular.z
        if abs(v_mps) > self.config.max_speed_mps or abs(omega_radps) > self.config.max_turn_radps:
            self.rejected.add("implausible")
            return
        with self._lock:
            self._odom = (v_mps, omega_radps, self._clock())
            self.odom_received += 1

    def _odom_age_s(self) -> float | None:
        with self._lock:
            odom = self._odom
        if odom is None:
            return None
        age = self._clock() - odom[2]
        return age if age <= self.config.odom_timeout_s else None

    # --- Zenoh -------------------------------------------------------------------------------

    def _declare(self) -> None:
        cfg = self.config
        if self._subscribe is None:
            raise RuntimeError("no subscription bridge (subscribe=) was given")
        session = self._factory(cfg)
        self._session = session
        zid = str(session.info.zid())
        twist_t, odom_t = msgs.ros_type(msgs.Twist), msgs.ros_type(msgs.Odometry)
        node = rmw.node_token(cfg.domain_id, zid, 0, cfg.namespace, cfg.node_name)
        pub = rmw.endpoint_token(
            cfg.domain_id, zid, 0, 1, rmw.EntityKind.PUBLISHER, cfg.namespace, cfg.node_name,
            cfg.fqn(cfg.cmd_vel_topic), twist_t, rmw.Qos(depth=10),
        )  # fmt: skip
        sub = rmw.endpoint_token(
            cfg.domain_id, zid, 0, 2, rmw.EntityKind.SUBSCRIPTION, cfg.namespace, cfg.node_name,
            cfg.fqn(cfg.odom_topic), odom_t, rmw.Qos(depth=10),
        )  # fmt: skip
        self._gid = rmw.entity_gid(pub)
        self._publisher = session.declare_publisher(self._cmd_key)

        def push(received: Any) -> None:  # Zenoh's thread: validate, keep, return
            try:
                self.on_odom(received.payload, received.attachment)
            except Exception as exc:  # defensive: on_odom counts, it does not raise
                self.rejected.add(f"callback:{type(exc).__name__}")

        self._subscriber = self._subscribe(session, self._odom_key, push)
        liveliness = session.liveliness()
        self._tokens = [liveliness.declare_token(k) for k in (node, pub, sub)]

    def _publish(self, v_mps: float, omega_radps: float) -> bool:
        publisher = self._publisher
        self._commands += 1
        if publisher is None:
            self._consecutive += 1
            return False
        payload = msgs.encode(msgs.Twist(msgs.Vector3(x=v_mps), msgs.Vector3(z=omega_radps)))
        self._seq += 1
        att = rmw.encode_attachment(rmw.Attachment(self._seq, self._wall_ns(), self._gid))
        try:
            publisher.put(payload, attachment=att)
        except Exception as exc:
            self._io_errors += 1
            self._consecutive += 1
            self._last_error = f"put: {type(exc).__name__}: {exc}"[:200]
            return False
        self._acks += 1
        self._consecutive = 0
        return True

    def _undeclare(self) -> None:
        for entity in (*self._tokens, self._subscriber, self._publisher):
            if entity is not None:
                try:
                    entity.undeclare()
                except Exception:
                    self._io_errors += 1
        self._tokens, self._subscriber, self._publisher = [], None, None
        session, self._session = self._session, None
        if session is not None:
            try:
                session.close()
            except Exception:
                self._io_errors += 1


def _open_session(config: Ros2MotorConfig) -> Any:
    """A Zenoh session like an rmw_zenoh node's: ``mode`` to ``endpoint``, no multicast."""
    import zenoh  # imported here: `robot_agent.motors` stays importable without Zenoh

    conf = zenoh.Config()
    conf.insert_json5("mode", json.dumps(config.mode))
    conf.insert_json5("connect/endpoints", json.dumps([config.endpoint]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    if config.mode == "peer":
        conf.insert_json5("listen/endpoints", json.dumps(["tcp/127.0.0.1:0"]))
    return zenoh.open(conf)
