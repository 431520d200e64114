"""Test support: a simulated ROS 2 differential-drive base speaking rmw_zenoh's format.

What a TurtleBot3 running ``turtlebot3_node`` with rmw_zenoh looks like on the wire: a node in a
namespace announcing a ``cmd_vel`` subscription and an ``odom`` publisher with liveliness
tokens; it integrates the newest valid ``cmd_vel`` twist (a unicycle, 50 Hz) and publishes
``odom`` (nav_msgs/msg/Odometry with a 33-byte attachment). Written against
:mod:`bus_schemas.ros2` from the ROS side: it validates commands exactly like a base would
(CDR, finite values, attachment) and counts what it rejects.

Hooks for tests: :meth:`pause_odom` (the base's odometry goes silent), :meth:`put_odom_raw`
(hostile payloads on the odom key), :attr:`commands` (every accepted twist, in order).
"""

from __future__ import annotations

import math
import threading
import time
from typing import Any

import zenoh

from bus_schemas.errors import DecodeError, RejectCounts
from bus_schemas.ros2 import msgs, rmw


class SimRos2Base:
    """A ROS 2 base on ``session`` (an open Zenoh session); ``start()`` runs it, ``close()``."""

    def __init__(
        self,
        session: zenoh.Session,
        *,
        domain_id: int = 0,
        namespace: str = "",
        rate_hz: float = 50.0,
        node_name: str = "turtlebot3_node",
    ) -> None:
        self.session = session
        self.domain_id = domain_id
        self.namespace = namespace
        self.period_s = 1.0 / rate_hz
        ns = namespace.rstrip("/")
        self.cmd_key = rmw.topic_key(domain_id, f"{ns}/cmd_vel", msgs.ros_type(msgs.Twist))
        self.odom_key = rmw.topic_key(domain_id, f"{ns}/odom", msgs.ros_type(msgs.Odometry))
        zid = str(session.info.zid())
        self.node_token = rmw.node_token(domain_id, zid, 0, namespace, node_name)
        self.sub_token = rmw.endpoint_token(
            domain_id, zid, 0, 1, rmw.EntityKind.SUBSCRIPTION, namespace, node_name,
            f"{ns}/cmd_vel", msgs.ros_type(msgs.Twist), rmw.Qos(depth=10),
        )  # fmt: skip
        self.pub_token = rmw.endpoint_token(
            domain_id, zid, 0, 2, rmw.EntityKind.PUBLISHER, namespace, node_name,
            f"{ns}/odom", msgs.ros_type(msgs.Odometry), rmw.Qos(depth=10),
        )  # fmt: skip
        self.gid = rmw.entity_gid(self.pub_token)
        self.rejected = RejectCounts()
        self.commands: list[tuple[float, float]] = []
        self.x_m = self.y_m = self.theta_rad = 0.0
        self._cmd = (0.0, 0.0)
        self._lock = threading.Lock()
        self._odom_on = threading.Event()
        self._odom_on.set()
        self._stop = threading.Event()
        self._seq = 0
        self._thread = threading.Thread(target=self._run, name="sim-ros2-base", daemon=True)
        self._entities: list[Any] = []

    @property
    def last_command(self) -> tuple[float, float] | None:
        with self._lock:
            return self.commands[-1] if self.commands else None

    def start(self) -> SimRos2Base:
        lv = self.session.liveliness()
        self._pub = self.session.declare_publisher(self.odom_key)
        self._entities = [
            self.session.declare_subscriber(self.cmd_key, self._on_cmd),
            self._pub,
            *(lv.declare_token(k) for k in (self.node_token, self.sub_token, self.pub_token)),
        ]
        self._thread.start()
        return self

    def pause_odom(self, paused: bool = True) -> None:
        if paused:
            self._odom_on.clear()
        else:
            self._odom_on.set()

    def put_odom_raw(self, payload: bytes, attachment: bytes | None) -> None:
        self._pub.put(payload, attachment=attachment)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2.0)
        for e in self._entities:
            e.undeclare()
        self._entities = []

    def _on_cmd(self, sample: zenoh.Sample) -> None:
        att = rmw.decode_attachment(
            None if sample.attachment is None else sample.attachment.to_bytes()
        )
        if isinstance(att, DecodeError):
            self.rejected.add(att)
            return
        twist = msgs.decode(sample.payload.to_bytes(), msgs.Twist)
        if isinstance(twist, DecodeError):
            self.rejected.add(twist)
            return
        with self._lock:
            self._cmd = (twist.linear.x, twist.angular.z)
            self.commands.append(self._cmd)

    def _run(self) -> None:
        while not self._stop.wait(self.period_s):
            with self._lock:
                v, w = self._cmd
            dt = self.period_s
            self.x_m += v * math.cos(self.theta_rad) * dt
            self.y_m += v * math.sin(self.theta_rad) * dt
            self.theta_rad = math.remainder(self.theta_rad + w * dt, 2 * math.pi)
            if not self._odom_on.is_set():
                continue
            odom = msgs.Odometry(
                msgs.Header(msgs.time_from_s(time.time()), "odom"),
                "base_footprint",
                msgs.PoseWithCovariance(
                    msgs.Pose(
                        msgs.Point(self.x_m, self.y_m), msgs.quaternion_from_yaw(self.theta_rad)
                    )
                ),
                msgs.TwistWithCovariance(msgs.Twist(msgs.Vector3(x=v), msgs.Vector3(z=w))),
            )
            self._seq += 1
            att = rmw.encode_attachment(rmw.Attachment(self._seq, time.time_ns(), self.gid))
            try:
                self._pub.put(msgs.encode(odom), attachment=att)
            except zenoh.ZError:
                return  # session closed under us at teardown
