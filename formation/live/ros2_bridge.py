"""``formation ros2``: the fleet as a ROS 2 node graph over rmw_zenoh's wire format, no ROS install.

Any ROS 2 Jazzy (or later) machine whose rmw_zenoh nodes reach the fleet's Zenoh router sees
(docs/ros2.md), with ``<ns>`` the ``--namespace`` (empty by default) and frames after REP 105:

- ``<ns>/<id>/odom`` (nav_msgs/msg/Odometry): each robot's measured pose (``pose`` or the
  ``poses`` batch) in ``map``, child frame ``<id>/base_link``, and its twist in the body frame:
  its estimator's (``v_mps``, ``omega_radps`` of its ``status`` or its host's batch) when a
  status received within :data:`TWIST_FRESH_S` has it, else from consecutive poses (finite
  difference over the poses' own ``t``); the twist's covariance says which
  (:data:`TWIST_COV_ESTIMATOR`, :data:`TWIST_COV_FINITE_DIFFERENCE`);
- ``/tf`` (tf2_msgs/msg/TFMessage): ``map`` -> ``<id>/base_link`` per pose (one message with
  every robot per ``poses`` batch), and at
  ``--rate`` Hz ``map`` -> ``formation/leader`` and ``map`` -> ``formation/slot_<k>``;
- ``<ns>/formation/leader`` (geometry_msgs/msg/PoseStamped), ``<ns>/formation/slots``
  (geometry_msgs/msg/PoseArray, slot order) and ``<ns>/formation/markers``
  (visualization_msgs/msg/MarkerArray: a coloured arrow per slot by role, for RViz2);
- ``<ns>/formation/cmd_vel`` (geometry_msgs/msg/Twist) in: validated (CDR, attachment, finite,
  within the contract's speed and turn bounds, at most ``--max-cmd-hz``) and forwarded as the
  operator's ``CmdVel``
  (``formation/<fleet>/operator/cmd_vel``: the virtual leader's teleop input, deadman
  included); every rejection is counted by reason;
- ``<ns>/formation/goal`` (geometry_msgs/msg/PoseStamped, frame ``map``) in: validated the same
  way (position within the contract's, a quaternion with a yaw, at most 5 a second) and
  forwarded as the operator's ``Goal`` (position and heading; ``formation/<fleet>/operator/goal``);
- ``<ns>/formation/estop`` and ``<ns>/formation/release`` (std_srvs/srv/Trigger services): the
  fleet's existing e-stop path (``formation.operate.estop_tool.send_estop``: latched by the
  coordinators, acknowledged by the robots); the reply says who acknowledged.

Under ``--secure`` the bridge is its own identity (CN ``ros2``): the router lets only it publish
these topics and declare its tokens, and lets it publish on the bus only the operator's
``cmd_vel``, ``goal`` and ``estop`` (bus_schemas.ros2.graph, bus_schemas.acl_rules).

Every entity has its rmw_zenoh liveliness token, so ``ros2 topic list -t`` and
``ros2 service list -t`` show them with their types. The pure translation is
:class:`BridgeCore` (bus messages in, ROS payloads out, no Zenoh, no clock); the shell below
subscribes only through ``runtime.bridge`` (``io.subscribe``) and stamps ROS headers with the
wall clock (ROS time).
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Final

import runtime as rt
from bus_schemas import (
    CmdVel,
    DecodeError,
    Goal,
    Leader,
    Pose,
    PoseBatch,
    RejectCounts,
    Slot,
    Status,
    StatusBatch,
    decode,
    encode,
    keys,
)
from bus_schemas.fields import SPEED_MAX_MPS, TURN_RATE_MAX_RADPS
from bus_schemas.ros2 import graph, msgs, rmw
from bus_schemas.spec import POSITION_MAX_M
from runtime.sdnotify import Notifier, pet_watchdog
from runtime.timers import STATUS_PERIOD_S

__all__ = [
    "TWIST_COV_ESTIMATOR",
    "TWIST_COV_FINITE_DIFFERENCE",
    "TWIST_FRESH_S",
    "BridgeCore",
    "Outgoing",
    "main",
]

NODE_NAME: Final = graph.NODE_NAME
GOAL_FRAMES: Final = ("map", "")
"""Frames a goal may be given in: the fixed frame (REP 105), or none (taken as ``map``)."""
READY: Final = "ros2 bridge ready"
TWIST_FRESH_S: Final = 2 * STATUS_PERIOD_S
"""A robot's estimator twist (its newest status's) is used while received at most this long ago
(s, the bridge's clock): two status periods."""


def _twist_cov(var_v: float, var_omega: float) -> tuple[float, ...]:
    """A planar twist's 6x6 row-major covariance (vx, vy, vz, wx, wy, wz): ``var_v`` on vx and
    vy (a unicycle's lateral speed is zero but for slip), ``var_omega`` on wz, 0 elsewhere."""
    cov = [0.0] * 36
    cov[0] = cov[7] = var_v
    cov[35] = var_omega
    return tuple(cov)


TWIST_COV_ESTIMATOR: Final = _twist_cov(0.02**2, 0.1**2)
"""Twist covariance of the estimator's twist (the encoders' mean over the last tick, or the
commanded one without encoders): (0.02 m/s)^2 and (0.1 rad/s)^2."""
TWIST_COV_FINITE_DIFFERENCE: Final = _twist_cov(0.1**2, 0.5**2)
"""Twist covariance of the finite difference of two camera poses (larger: a few mm of pose
noise over one camera period of tens of ms is ~0.1 m/s): (0.1 m/s)^2 and (0.5 rad/s)^2."""
ROLE_COLOURS: Final[dict[str, msgs.ColorRGBA]] = {
    "leader": msgs.ColorRGBA(0.9, 0.2, 0.2, 1.0),
    "subleader": msgs.ColorRGBA(0.95, 0.6, 0.1, 1.0),
    "follower": msgs.ColorRGBA(0.2, 0.5, 0.9, 1.0),
}


@dataclass(frozen=True, slots=True)
class Outgoing:
    """One ROS message to publish: topic (fully qualified), its type, the CDR payload."""

    topic: str
    rtype: msgs.RosType
    payload: bytes


@dataclass
class _Track:
    """The last pose of one robot (for the finite-difference twist)."""

    t_s: float
    x_m: float
    y_m: float
    theta_rad: float
    v_mps: float = 0.0
    omega_radps: float = 0.0


@dataclass(frozen=True, slots=True)
class _EstTwist:
    """A robot's estimator twist as its newest status gave it, and when it was received."""

    rx_s: float
    v_mps: float
    omega_radps: float


@dataclass
class BridgeCore:
    """Bus messages in, ROS 2 payloads out. Pure: stamps and times are arguments.

    Attributes:
        namespace: ROS namespace of every topic but ``/tf`` ("" or ``/fleet_a``).
        max_cmd_hz: the most ``cmd_vel`` messages accepted per second (a flood is dropped).
        rejected: every refused input by reason (bus payloads and ROS commands alike).
    """

    namespace: str = ""
    max_cmd_hz: float = 50.0
    max_goal_hz: float = 5.0
    rejected: RejectCounts = field(default_factory=RejectCounts)
    forwarded: int = 0
    _tracks: dict[str, _Track] = field(default_factory=dict)
    _twists: dict[str, _EstTwist] = field(default_factory=dict)
    _slots: dict[int, Slot] = field(default_factory=dict)
    _leader: Leader | None = None
    _last_cmd_s: float = -math.inf
    _last_goal_s: float = -math.inf
    _teleop_seq: int = 0

    def topic(self, relative: str) -> str:
        """``relative`` (``r1/odom``) in the namespace: ``/ns/r1/odom``."""
        return f"{self.namespace.rstrip('/')}/{relative}"

    # --- fleet -> ROS -------------------------------------------------------------------------

    def on_status(self, robot: str, status: Status, rx_s: float) -> None:
        """A robot's ``status`` received at ``rx_s`` (s, the bridge's monotonic clock): its
        estimator twist, if it has one, for its odometry (a status without: unknown)."""
        if status.v_mps is None or status.omega_radps is None:
            self._twists.pop(robot, None)
        else:
            self._twists[robot] = _EstTwist(rx_s, status.v_mps, status.omega_radps)

    def on_status_batch(self, batch: StatusBatch, rx_s: float) -> None:
        """An agent host's status batch received at ``rx_s``: the estimator twist of each
        robot it lists in ``twist_robots``; its other robots' twists are unknown."""
        for rid in batch.robots:
            self._twists.pop(rid, None)
        if batch.twist_robots is None or batch.v_mps is None or batch.omega_radps is None:
            return
        for rid, v, w in zip(batch.twist_robots, batch.v_mps, batch.omega_radps, strict=True):
            self._twists[rid] = _EstTwist(rx_s, v, w)

    def on_pose(self, robot: str, t_s: float, x_m: float, y_m: float, theta_rad: float,
                stamp_ns: int, now_s: float | None = None) -> list[Outgoing]:  # fmt: skip
        """A robot's measured pose (bus ``t`` = ``t_s``) -> its odometry and its tf, the
        headers stamped ``stamp_ns`` (ns since the UNIX epoch: ROS time); ``now_s`` is the
        bridge's monotonic clock (None: no estimator twist is used, the finite difference)."""
        header = msgs.Header(msgs.time_from_ns(stamp_ns), "map")
        odom = self._odometry(header, robot, t_s, x_m, y_m, theta_rad, now_s)
        if odom is None:
            return []
        tf = msgs.TFMessage((self._transform(header, f"{robot}/base_link", odom.pose.pose),))
        return [self._odom_out(robot, odom), self._tf_out(tf)]

    def on_poses(self, batch: PoseBatch, stamp_ns: int, now_s: float | None = None
                  ) -> list[Outgoing]:  # fmt: skip
        """A ``poses`` batch (one camera frame, bus ``t`` = its ``stamp``) -> each robot's
        odometry, then one ``/tf`` with every robot's transform (one message per frame, not one
        per robot: tf2 takes many transforms a message); ``now_s`` as in :meth:`on_pose`."""
        header = msgs.Header(msgs.time_from_ns(stamp_ns), "map")
        out: list[Outgoing] = []
        transforms: list[msgs.TransformStamped] = []
        for rid, x, y, th in zip(batch.robots, batch.x, batch.y, batch.theta, strict=True):
            odom = self._odometry(header, rid, batch.stamp, x, y, th, now_s)
            if odom is not None:
                out.append(self._odom_out(rid, odom))
                transforms.append(self._transform(header, f"{rid}/base_link", odom.pose.pose))
        if transforms:
            out.append(self._tf_out(msgs.TFMessage(tuple(transforms))))
        return out

    def _odometry(self, header: msgs.Header, robot: str, t_s: float, x_m: float, y_m: float,
                  theta_rad: float, now_s: float | None) -> msgs.Odometry | None:  # fmt: skip
        """The odometry of a pose (None: out of order), its twist the estimator's when fresh
        at ``now_s``, else from the previous pose."""
        prev = self._tracks.get(robot)
        track = _Track(t_s, x_m, y_m, theta_rad)
        if prev is not None:
            dt_s = t_s - prev.t_s
            if dt_s <= 0.0:
                self.rejected.add("pose_out_of_order")
                return None
            # body-frame twist of a unicycle between two poses: forward displacement along the
            # mean heading, heading change wrapped (eqs 1-3 discretised)
            mean = prev.theta_rad + 0.5 * math.remainder(theta_rad - prev.theta_rad, math.tau)
            dx, dy = x_m - prev.x_m, y_m - prev.y_m
            track.v_mps = (dx * math.cos(mean) + dy * math.sin(mean)) / dt_s
            track.omega_radps = math.remainder(theta_rad - prev.theta_rad, math.tau) / dt_s
        self._tracks[robot] = track
        pose = msgs.Pose(msgs.Point(x_m, y_m), msgs.quaternion_from_yaw(theta_rad))
        est = self._twists.get(robot)
        if now_s is not None and est is not None and 0.0 <= now_s - est.rx_s <= TWIST_FRESH_S:
            v_mps, omega_radps, cov = est.v_mps, est.omega_radps, TWIST_COV_ESTIMATOR
        else:
            v_mps, omega_radps = track.v_mps, track.omega_radps
            cov = TWIST_COV_FINITE_DIFFERENCE
        twist = msgs.Twist(msgs.Vector3(x=v_mps), msgs.Vector3(z=omega_radps))
        return msgs.Odometry(
            header,
            f"{robot}/base_link",
            msgs.PoseWithCovariance(pose),
            msgs.TwistWithCovariance(twist, cov),
        )

    def _odom_out(self, robot: str, odom: msgs.Odometry) -> Outgoing:
        topic = self.topic(f"{robot}/{graph.ODOM}")
        return Outgoing(topic, msgs.ros_type(msgs.Odometry), msgs.encode(odom))

    @staticmethod
    def _tf_out(tf: msgs.TFMessage) -> Outgoing:
        return Outgoing(graph.TF, msgs.ros_type(msgs.TFMessage), msgs.encode(tf))

    def on_leader(self, leader: Leader) -> None:
        self._leader = leader

    def on_slot(self, slot: Slot) -> None:
        self._slots[slot.slot] = slot

    def formation(self, stamp_ns: int) -> list[Outgoing]:
        """The leader, the slots (PoseArray, markers) and their tf, stamped ``stamp_ns``."""
        header = msgs.Header(msgs.time_from_ns(stamp_ns), "map")
        out: list[Outgoing] = []
        transforms: list[msgs.TransformStamped] = []
        if self._leader is not None:
            lp = _pose(self._leader.x, self._leader.y, self._leader.theta)
            out.append(
                Outgoing(
                    self.topic(graph.LEADER),
                    msgs.ros_type(msgs.PoseStamped),
                    msgs.encode(msgs.PoseStamped(header, lp)),
                )
            )
            transforms.append(self._transform(header, "formation/leader", lp))
        slots = [self._slots[k] for k in sorted(self._slots)]
        poses = tuple(_pose(s.x, s.y, s.theta) for s in slots)
        if slots:
            out.append(
                Outgoing(
                    self.topic(graph.SLOTS),
                    msgs.ros_type(msgs.PoseArray),
                    msgs.encode(msgs.PoseArray(header, poses)),
                )
            )
            markers = tuple(
                msgs.Marker(
                    header=header,
                    ns="formation/slots",
                    id=s.slot,
                    type=0,
                    action=0,
                    pose=p,
                    scale=msgs.Vector3(0.12, 0.03, 0.03),
                    color=ROLE_COLOURS.get(s.role, msgs.ColorRGBA(0.6, 0.6, 0.6, 1.0)),
                    lifetime=msgs.Duration(1, 0),
                )
                for s, p in zip(slots, poses, strict=True)
            )
            out.append(
                Outgoing(
                    self.topic(graph.MARKERS),
                    msgs.ros_type(msgs.MarkerArray),
                    msgs.encode(msgs.MarkerArray(markers)),
                )
            )
            transforms += [
                self._transform(header, f"formation/slot_{s.slot}", p)
                for s, p in zip(slots, poses, strict=True)
            ]
        if transforms:
            tf = msgs.TFMessage(tuple(transforms))
            out.append(self._tf_out(tf))
        return out

    @staticmethod
    def _transform(header: msgs.Header, child: str, pose: msgs.Pose) -> msgs.TransformStamped:
        p = pose.position
        return msgs.TransformStamped(
            header, child, msgs.Transform(msgs.Vector3(p.x, p.y, p.z), pose.orientation)
        )

    # --- ROS -> fleet -------------------------------------------------------------------------

    def on_cmd_vel(self, payload: bytes, attachment: bytes | None, now_s: float) -> CmdVel | None:
        """A ``cmd_vel`` sample -> the operator's CmdVel to publish, or None (refused, counted)."""
        att = rmw.decode_attachment(attachment)
        if isinstance(att, DecodeError):
            self.rejected.add(f"cmd_vel_{att.reason}")
            return None
        twist = msgs.decode(payload, msgs.Twist)
        if isinstance(twist, DecodeError):
            self.rejected.add(f"cmd_vel_{twist.reason}")
            return None
        v_mps, omega_radps = twist.linear.x, twist.angular.z
        if abs(v_mps) > SPEED_MAX_MPS or abs(omega_radps) > TURN_RATE_MAX_RADPS:
            self.rejected.add("cmd_vel_out_of_range")
            return None
        if now_s - self._last_cmd_s < 1.0 / self.max_cmd_hz:
            self.rejected.add("cmd_vel_flood")
            return None
        self._last_cmd_s = now_s
        self._teleop_seq += 1
        self.forwarded += 1
        return CmdVel(t=now_s, seq=self._teleop_seq, v_mps=v_mps, omega_radps=omega_radps)

    def on_goal(self, payload: bytes, attachment: bytes | None, now_s: float) -> Goal | None:
        """A ``/formation/goal`` PoseStamped (``map`` frame) -> the operator's Goal (position and
        heading), or None (refused, counted: malformed, another frame, a position beyond the
        contract's, a quaternion with no yaw, more than ``max_goal_hz``)."""
        att = rmw.decode_attachment(attachment)
        if isinstance(att, DecodeError):
            self.rejected.add(f"goal_{att.reason}")
            return None
        msg = msgs.decode(payload, msgs.PoseStamped)
        if isinstance(msg, DecodeError):
            self.rejected.add(f"goal_{msg.reason}")
            return None
        if msg.header.frame_id not in GOAL_FRAMES:
            self.rejected.add("goal_frame")
            return None
        x_m, y_m = msg.pose.position.x, msg.pose.position.y
        heading = msgs.yaw_from_quaternion(msg.pose.orientation)
        if abs(x_m) > POSITION_MAX_M or abs(y_m) > POSITION_MAX_M:
            self.rejected.add("goal_out_of_range")
            return None
        if heading is None:
            self.rejected.add("goal_quaternion")
            return None
        if now_s - self._last_goal_s < 1.0 / self.max_goal_hz:
            self.rejected.add("goal_flood")
            return None
        self._last_goal_s = now_s
        self.forwarded += 1
        return Goal(t=now_s, x=x_m, y=y_m, heading=heading)


def _pose(x_m: float, y_m: float, theta_rad: float) -> msgs.Pose:
    return msgs.Pose(msgs.Point(x_m, y_m), msgs.quaternion_from_yaw(theta_rad))


# --- the shell ---------------------------------------------------------------------------------


@dataclass
class _Graph:
    """The bridge's ROS graph on one session: publishers, tokens, entity ids."""

    session: Any
    domain_id: int
    namespace: str
    zid: str
    tokens: dict[str, Any] = field(default_factory=dict)
    publishers: dict[str, tuple[Any, bytes]] = field(default_factory=dict)
    seq: dict[str, int] = field(default_factory=dict)
    next_id: int = 1
    published: int = 0

    def _token(self, kind: rmw.EntityKind, topic: str, rtype: msgs.RosType) -> str:
        key = rmw.endpoint_token(
            self.domain_id, self.zid, 0, self.next_id, kind, self.namespace, NODE_NAME, topic,
            rtype, rmw.Qos(depth=10),
        )  # fmt: skip
        self.next_id += 1
        self.tokens[key] = self.session.liveliness().declare_token(key)
        return key

    def announce(self) -> None:
        node = rmw.node_token(self.domain_id, self.zid, 0, self.namespace, NODE_NAME)
        self.tokens[node] = self.session.liveliness().declare_token(node)

    def endpoint(self, kind: rmw.EntityKind, topic: str, rtype: msgs.RosType) -> str:
        """Announce a subscription or service (its key is the return value)."""
        self._token(kind, topic, rtype)
        return rmw.topic_key(self.domain_id, topic, rtype)

    def publish(self, out: Outgoing, wall_ns: int) -> None:
        entry = self.publishers.get(out.topic)
        if entry is None:
            token = self._token(rmw.EntityKind.PUBLISHER, out.topic, out.rtype)
            pub = self.session.declare_publisher(
                rmw.topic_key(self.domain_id, out.topic, out.rtype)
            )
            entry = self.publishers[out.topic] = (pub, rmw.entity_gid(token))
        seq = self.seq[out.topic] = self.seq.get(out.topic, 0) + 1
        att = rmw.encode_attachment(rmw.Attachment(seq, wall_ns, entry[1]))
        entry[0].put(out.payload, attachment=att)
        self.published += 1

    def close(self) -> None:
        for pub, _ in self.publishers.values():
            pub.undeclare()
        for token in self.tokens.values():
            token.undeclare()
        self.publishers.clear()
        self.tokens.clear()


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(
        prog="formation ros2",
        description="Show the fleet to ROS 2 (rmw_zenoh) and take /formation/cmd_vel, e-stop "
        "and release from it (docs/ros2.md).",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    parser.add_argument("--fleet", default=keys.DEFAULT_FLEET)
    parser.add_argument("--domain-id", type=int, default=0, help="ROS_DOMAIN_ID (0..232)")
    parser.add_argument("--namespace", default="", help="ROS namespace of the topics, e.g. /lab")
    parser.add_argument("--rate", type=float, default=10.0, help="leader/slots publish rate (Hz)")
    parser.add_argument("--max-cmd-hz", type=float, default=50.0, help="cmd_vel flood limit")
    rt.add_zenoh_arguments(parser)
    ns = parser.parse_args(argv)
    try:
        rt.check_names(("--fleet", ns.fleet))
        if not (0 <= ns.domain_id <= 232):
            raise rt.UsageError(f"--domain-id {ns.domain_id} outside 0..232")
        if ns.namespace:
            rmw.node_token(ns.domain_id, "0", 0, ns.namespace, NODE_NAME)
        for name in ("rate", "max_cmd_hz"):
            if not (math.isfinite(getattr(ns, name)) and 0.0 < getattr(ns, name) <= 1000.0):
                raise rt.UsageError(f"--{name.replace('_', '-')} must be in (0, 1000]")
        settings = rt.zenoh_settings(ns)
    except (rt.UsageError, ValueError) as exc:
        rt.NodeLog("ros2").info(str(exc))
        return rt.USAGE_EXIT

    async def body(io: rt.NodeIO, stop: asyncio.Event) -> int:
        return await run_bridge(io, stop, ns.fleet, ns.domain_id, ns.namespace, ns.rate,
                                ns.max_cmd_hz)  # fmt: skip

    return rt.serve("ros2", settings, body)


async def run_bridge(  # noqa: PLR0915 (the bridge's wiring: one handler per ROS name)
    io: rt.NodeIO,
    stop: asyncio.Event,
    fleet: str,
    domain_id: int,
    namespace: str,
    rate_hz: float,
    max_cmd_hz: float,
    *,
    wall_ns: Callable[[], int] = time.time_ns,
) -> int:
    """The bridge on an open session until ``stop``; returns the exit status."""
    from formation.operate.estop_tool import send_estop

    core = BridgeCore(namespace=namespace, max_cmd_hz=max_cmd_hz)
    ros = _Graph(io.session, domain_id, namespace, str(io.session.info.zid()))
    ros.announce()

    def publish_all(outs: list[Outgoing]) -> None:
        now_ns = time.time_ns()
        for out in outs:
            ros.publish(out, now_ns)

    def on_pose(rx: rt.Received) -> None:
        parsed = keys.parse_robot_key(rx.key)
        msg = decode(rx.payload, Pose)
        if parsed is None or isinstance(msg, DecodeError):
            core.rejected.add(msg if isinstance(msg, DecodeError) else "pose_key")
            return
        publish_all(
            core.on_pose(parsed[1], msg.t, msg.x, msg.y, msg.theta, wall_ns(), time.monotonic())
        )

    def on_poses(rx: rt.Received) -> None:
        batch = decode(rx.payload, PoseBatch)
        if isinstance(batch, DecodeError):
            core.rejected.add(batch)
            return
        publish_all(core.on_poses(batch, wall_ns(), time.monotonic()))

    def on_status(rx: rt.Received) -> None:
        parsed = keys.parse_robot_key(rx.key)
        msg = decode(rx.payload, Status)
        if parsed is None or isinstance(msg, DecodeError):
            core.rejected.add(msg if isinstance(msg, DecodeError) else "status_key")
            return
        core.on_status(parsed[1], msg, time.monotonic())

    def on_status_batch(rx: rt.Received) -> None:
        batch = decode(rx.payload, StatusBatch)
        if isinstance(batch, DecodeError):
            core.rejected.add(batch)
            return
        core.on_status_batch(batch, time.monotonic())

    def on_leader(rx: rt.Received) -> None:
        msg = decode(rx.payload, Leader)
        if isinstance(msg, DecodeError):
            core.rejected.add(msg)
        else:
            core.on_leader(msg)

    def on_slot(rx: rt.Received) -> None:
        msg = decode(rx.payload, Slot)
        if isinstance(msg, DecodeError):
            core.rejected.add(msg)
        else:
            core.on_slot(msg)

    def on_cmd_vel(rx: rt.Received) -> None:
        teleop = core.on_cmd_vel(rx.payload, rx.attachment, time.monotonic())
        if teleop is not None:
            io.pubs.put(keys.cmd_vel_key(fleet), encode(teleop))

    def on_goal(rx: rt.Received) -> None:
        goal = core.on_goal(rx.payload, rx.attachment, time.monotonic())
        if goal is not None:
            io.pubs.put(keys.goal_key(fleet), encode(goal))

    io.subscribe(keys.all_poses_pattern(fleet), on_pose)
    io.subscribe(keys.poses_key(fleet), on_poses)
    io.subscribe(keys.all_status_pattern(fleet), on_status)
    io.subscribe(keys.all_host_status_pattern(fleet), on_status_batch)
    io.subscribe(keys.leader_key(fleet), on_leader)
    io.subscribe(keys.all_slots_pattern(fleet), on_slot)
    twist_t = msgs.ros_type(msgs.Twist)
    cmd_key = ros.endpoint(rmw.EntityKind.SUBSCRIPTION, core.topic(graph.CMD_VEL), twist_t)
    io.subscribe(cmd_key, on_cmd_vel)
    pose_t = msgs.ros_type(msgs.PoseStamped)
    goal_key = ros.endpoint(rmw.EntityKind.SUBSCRIPTION, core.topic(graph.GOAL), pose_t)
    io.subscribe(goal_key, on_goal)

    # e-stop and release: std_srvs/srv/Trigger services on the fleet's existing e-stop path
    loop = asyncio.get_running_loop()
    busy: set[str] = set()
    trigger_t = msgs.ros_type(msgs.TriggerRequest)

    async def serve_trigger(query: Any, engage: bool) -> None:
        att = rmw.decode_attachment(_attachment_bytes(query))
        payload = query.payload.to_bytes() if query.payload is not None else b""
        req = msgs.decode(payload, msgs.TriggerRequest)
        try:
            if isinstance(att, DecodeError) or isinstance(req, DecodeError):
                core.rejected.add("trigger_malformed")
                return  # no reply: a malformed request has no client to answer
            name = "estop" if engage else "release"  # one in progress of each at a time
            if name in busy:
                core.rejected.add("trigger_busy")
                response = msgs.TriggerResponse(False, f"an {name} is already in progress")
            else:
                busy.add(name)
                try:
                    report = await send_estop(io.session, fleet, engage, None)
                finally:
                    busy.discard(name)
                response = msgs.TriggerResponse(report.ok, report.line())
            reply_att = rmw.encode_attachment(rmw.Attachment(att.seq, time.time_ns(), att.gid))
            query.reply(query.key_expr, msgs.encode(response), attachment=reply_att)
        finally:
            query.drop()

    queryables = []
    pending: set[asyncio.Task[None]] = set()
    for name, engage in ((graph.ESTOP, True), (graph.RELEASE, False)):
        key = ros.endpoint(rmw.EntityKind.SERVICE, core.topic(name), trigger_t)

        def on_query(query: Any, engage: bool = engage) -> None:  # Zenoh's thread
            def start() -> None:
                task = loop.create_task(serve_trigger(query, engage))
                pending.add(task)
                task.add_done_callback(pending.discard)

            loop.call_soon_threadsafe(start)

        queryables.append(io.session.declare_queryable(key, on_query, complete=True))

    print(f"{READY}: domain {domain_id}, fleet {fleet}", flush=True)
    # systemd (deploy/systemd/formation-ros2.service): READY=1 now, WATCHDOG=1 from this loop
    notifier = Notifier()
    notifier.ready(f"ros2 bridge: domain {domain_id}, fleet {fleet}")
    pet = asyncio.ensure_future(pet_watchdog(notifier, stop))
    period_s = 1.0 / rate_hz
    try:
        while not stop.is_set():
            publish_all(core.formation(wall_ns()))
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(stop.wait(), period_s)
    finally:
        pet.cancel()
        notifier.stopping()
        notifier.close()
        for task in pending:
            task.cancel()
        for q in queryables:
            q.undeclare()
        ros.close()
        io.log.info(
            f"published {ros.published} ROS messages, forwarded {core.forwarded} "
            f"cmd_vel/goal, rejected {core.rejected.total} "
            f"{core.rejected.as_dict()}"
        )
    return 0


def _attachment_bytes(query: Any) -> bytes | None:
    att = query.attachment
    return None if att is None else bytes(att.to_bytes())
