"""The few ROS 2 message types the fleet speaks, as frozen dataclasses with CDR codecs.

Field names are ROS's own (``linear``, ``angular``, ``nanosec``, ...): they *are* the wire schema
and ROS users read them in ``ros2 topic echo``; units follow REP 103 (metres, radians, seconds,
m/s, rad/s). Nested messages are dataclasses, sequences are tuples, ``uint8[]`` is ``bytes``.

Use::

    from bus_schemas.ros2 import msgs
    payload = msgs.encode(msgs.Twist(msgs.Vector3(0.2, 0.0, 0.0), msgs.Vector3(0.0, 0.0, 0.5)))
    odom = msgs.decode(payload_bytes, msgs.Odometry)
    if isinstance(odom, DecodeError): rejected.add(odom)

``encode`` raises :class:`~bus_schemas.errors.SchemaError` for an invalid message (NaN, wrong
covariance length, an int out of range); ``decode`` never raises on data and returns a
:class:`~bus_schemas.errors.DecodeError` for malformed CDR, wrong lengths, trailing bytes, NaN or
inf, oversized payloads. The bytes equal rosbags' ``serialize_cdr``
(tests/unit/bus_schemas/test_ros2_wire.py).
Type names, DDS names and RIHS01 hashes (REP 2016) are in :data:`TYPES`; the hashes are
constants here and recomputed with rosbags in the tests.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, TypeVar

from bus_schemas.errors import DecodeError, Invalid, Reason, SchemaError
from bus_schemas.ros2.cdr import Reader, Writer

__all__ = [
    "MAX_PAYLOAD_BYTES",
    "TYPES",
    "ColorRGBA",
    "CompressedImage",
    "Duration",
    "Header",
    "Marker",
    "MarkerArray",
    "MeshFile",
    "Odometry",
    "Point",
    "Pose",
    "PoseArray",
    "PoseStamped",
    "PoseWithCovariance",
    "Quaternion",
    "RosType",
    "TFMessage",
    "Time",
    "Transform",
    "TransformStamped",
    "TriggerRequest",
    "TriggerResponse",
    "Twist",
    "TwistWithCovariance",
    "UVCoordinate",
    "Vector3",
    "decode",
    "encode",
    "quaternion_from_yaw",
    "ros_type",
    "time_from_ns",
    "time_from_s",
    "time_to_s",
    "yaw_from_quaternion",
]

MAX_PAYLOAD_BYTES = 1 << 20
"""Largest payload any decoder here accepts (1 MiB); a type may set a smaller bound."""

ZERO36: tuple[float, ...] = (0.0,) * 36

M = TypeVar("M")


# --- builtin_interfaces, std_msgs -------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Time:
    """builtin_interfaces/msg/Time: ``sec`` (int32) + ``nanosec`` (uint32, < 1e9)."""

    sec: int = 0
    nanosec: int = 0


@dataclass(frozen=True, slots=True)
class Duration:
    """builtin_interfaces/msg/Duration: ``sec`` (int32) + ``nanosec`` (uint32, < 1e9)."""

    sec: int = 0
    nanosec: int = 0


@dataclass(frozen=True, slots=True)
class Header:
    """std_msgs/msg/Header: ``stamp`` and the coordinate ``frame_id`` (REP 105 names)."""

    stamp: Time = field(default_factory=Time)
    frame_id: str = ""


@dataclass(frozen=True, slots=True)
class ColorRGBA:
    """std_msgs/msg/ColorRGBA: float32 channels, 0..1."""

    r: float = 0.0
    g: float = 0.0
    b: float = 0.0
    a: float = 0.0


def time_from_s(t_s: float) -> Time:
    """A Time from seconds (``t_s`` >= 0, finite; rounded to the nanosecond)."""
    if not math.isfinite(t_s) or t_s < 0.0:
        raise ValueError(f"time {t_s!r} s is not a finite non-negative number")
    ns = round(t_s * 1e9)
    return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


def time_from_ns(t_ns: int) -> Time:
    """A Time from integer nanoseconds (``t_ns`` >= 0: exact, no float rounding)."""
    if t_ns < 0:
        raise ValueError(f"time {t_ns!r} ns is negative")
    return Time(sec=t_ns // 1_000_000_000, nanosec=t_ns % 1_000_000_000)


def time_to_s(stamp: Time | Duration) -> float:
    """Seconds of a Time or Duration."""
    return stamp.sec + stamp.nanosec * 1e-9


# --- geometry_msgs -----------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Vector3:
    """geometry_msgs/msg/Vector3 (float64 x, y, z)."""

    x: float = 0.0
    y: float = 0.0
    z: float = 0.0


@dataclass(frozen=True, slots=True)
class Point:
    """geometry_msgs/msg/Point (float64 x, y, z; metres)."""

    x: float = 0.0
    y: float = 0.0
    z: float = 0.0


@dataclass(frozen=True, slots=True)
class Quaternion:
    """geometry_msgs/msg/Quaternion (x, y, z, w); identity by default."""

    x: float = 0.0
    y: float = 0.0
    z: float = 0.0
    w: float = 1.0


@dataclass(frozen=True, slots=True)
class Pose:
    """geometry_msgs/msg/Pose."""

    position: Point = field(default_factory=Point)
    orientation: Quaternion = field(default_factory=Quaternion)


@dataclass(frozen=True, slots=True)
class PoseWithCovariance:
    """geometry_msgs/msg/PoseWithCovariance: 6x6 row-major covariance (x, y, z, rx, ry, rz)."""

    pose: Pose = field(default_factory=Pose)
    covariance: tuple[float, ...] = ZERO36


@dataclass(frozen=True, slots=True)
class Twist:
    """geometry_msgs/msg/Twist: ``linear`` (m/s) and ``angular`` (rad/s) in the child frame."""

    linear: Vector3 = field(default_factory=Vector3)
    angular: Vector3 = field(default_factory=Vector3)


@dataclass(frozen=True, slots=True)
class TwistWithCovariance:
    """geometry_msgs/msg/TwistWithCovariance."""

    twist: Twist = field(default_factory=Twist)
    covariance: tuple[float, ...] = ZERO36


@dataclass(frozen=True, slots=True)
class Transform:
    """geometry_msgs/msg/Transform."""

    translation: Vector3 = field(default_factory=Vector3)
    rotation: Quaternion = field(default_factory=Quaternion)


@dataclass(frozen=True, slots=True)
class TransformStamped:
    """geometry_msgs/msg/TransformStamped: ``header.frame_id`` -> ``child_frame_id``."""

    header: Header = field(default_factory=Header)
    child_frame_id: str = ""
    transform: Transform = field(default_factory=Transform)


@dataclass(frozen=True, slots=True)
class PoseArray:
    """geometry_msgs/msg/PoseArray."""

    header: Header = field(default_factory=Header)
    poses: tuple[Pose, ...] = ()


@dataclass(frozen=True, slots=True)
class PoseStamped:
    """geometry_msgs/msg/PoseStamped."""

    header: Header = field(default_factory=Header)
    pose: Pose = field(default_factory=Pose)


def quaternion_from_yaw(yaw_rad: float) -> Quaternion:
    """The rotation by ``yaw_rad`` about +z (REP 103: counter-clockwise seen from above)."""
    half = 0.5 * yaw_rad
    return Quaternion(0.0, 0.0, math.sin(half), math.cos(half))


def yaw_from_quaternion(q: Quaternion) -> float | None:
    """The heading (rad, in (-pi, pi]) of ``q`` about +z, or None for a degenerate quaternion
    (norm below 0.5: no rotation can be read from it). Roll and pitch are ignored (a ground
    robot); the formula is the z-y-x Euler yaw, valid for non-unit quaternions too."""
    norm2 = q.x * q.x + q.y * q.y + q.z * q.z + q.w * q.w
    if not math.isfinite(norm2) or norm2 < 0.25:
        return None
    # atan2(2(wz + xy), 1 - 2(y^2 + z^2)) of the normalised quaternion, both terms scaled by
    # the squared norm (atan2 does not care about a common positive factor).
    yaw = math.atan2(2.0 * (q.w * q.z + q.x * q.y), norm2 - 2.0 * (q.y * q.y + q.z * q.z))
    return math.pi if yaw == -math.pi else yaw


# --- nav_msgs, tf2_msgs ------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Odometry:
    """nav_msgs/msg/Odometry: pose in ``header.frame_id`` (``odom``/``map``), twist in
    ``child_frame_id`` (``base_link``): ``twist.twist.linear.x`` (m/s) and
    ``twist.twist.angular.z`` (rad/s) for a differential-drive base."""

    header: Header = field(default_factory=Header)
    child_frame_id: str = ""
    pose: PoseWithCovariance = field(default_factory=PoseWithCovariance)
    twist: TwistWithCovariance = field(default_factory=TwistWithCovariance)


@dataclass(frozen=True, slots=True)
class TFMessage:
    """tf2_msgs/msg/TFMessage (what ``/tf`` carries)."""

    transforms: tuple[TransformStamped, ...] = ()


# --- visualization_msgs ------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class CompressedImage:
    """sensor_msgs/msg/CompressedImage (only a Marker's texture here)."""

    header: Header = field(default_factory=Header)
    format: str = ""
    data: bytes = b""


@dataclass(frozen=True, slots=True)
class UVCoordinate:
    """visualization_msgs/msg/UVCoordinate (float32 u, v)."""

    u: float = 0.0
    v: float = 0.0


@dataclass(frozen=True, slots=True)
class MeshFile:
    """visualization_msgs/msg/MeshFile."""

    filename: str = ""
    data: bytes = b""


@dataclass(frozen=True, slots=True)
class Marker:
    """visualization_msgs/msg/Marker (Jazzy layout). ``type``: 0 arrow, 1 cube, 2 sphere,
    3 cylinder, 4 line strip, 5 line list, 9 text; ``action``: 0 add/modify, 2 delete,
    3 delete all."""

    header: Header = field(default_factory=Header)
    ns: str = ""
    id: int = 0
    type: int = 0
    action: int = 0
    pose: Pose = field(default_factory=Pose)
    scale: Vector3 = field(default_factory=Vector3)
    color: ColorRGBA = field(default_factory=ColorRGBA)
    lifetime: Duration = field(default_factory=Duration)
    frame_locked: bool = False
    points: tuple[Point, ...] = ()
    colors: tuple[ColorRGBA, ...] = ()
    texture_resource: str = ""
    texture: CompressedImage = field(default_factory=CompressedImage)
    uv_coordinates: tuple[UVCoordinate, ...] = ()
    text: str = ""
    mesh_resource: str = ""
    mesh_file: MeshFile = field(default_factory=MeshFile)
    mesh_use_embedded_materials: bool = False


@dataclass(frozen=True, slots=True)
class MarkerArray:
    """visualization_msgs/msg/MarkerArray."""

    markers: tuple[Marker, ...] = ()


# --- std_srvs ----------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class TriggerRequest:
    """std_srvs/srv/Trigger request: no fields (one padding byte on the wire, as rosidl adds
    ``structure_needs_at_least_one_member``)."""


@dataclass(frozen=True, slots=True)
class TriggerResponse:
    """std_srvs/srv/Trigger response."""

    success: bool = False
    message: str = ""


# --- writers and readers -----------------------------------------------------------------------
# One function pair per type; the field name passed down is the path shown in a DecodeError.


def _w_time(w: Writer, m: Time | Duration, f: str) -> None:
    w.i32(m.sec, f + ".sec")
    if type(m.nanosec) is int and m.nanosec >= 1_000_000_000:
        raise Invalid(Reason.OUT_OF_RANGE, f"nanosec {m.nanosec} >= 1e9", f + ".nanosec")
    w.u32(m.nanosec, f + ".nanosec")


def _r_sec_ns(r: Reader, f: str) -> tuple[int, int]:
    sec = r.i32(f + ".sec")
    nanosec = r.u32(f + ".nanosec")
    if nanosec >= 1_000_000_000:
        raise Invalid(Reason.OUT_OF_RANGE, f"nanosec {nanosec} >= 1e9", f + ".nanosec")
    return sec, nanosec


def _r_time(r: Reader, f: str) -> Time:
    return Time(*_r_sec_ns(r, f))


def _r_duration(r: Reader, f: str) -> Duration:
    return Duration(*_r_sec_ns(r, f))


def _w_header(w: Writer, m: Header, f: str) -> None:
    _w_time(w, m.stamp, f + ".stamp")
    w.string(m.frame_id, f + ".frame_id")


def _r_header(r: Reader, f: str) -> Header:
    return Header(_r_time(r, f + ".stamp"), r.string(f + ".frame_id"))


def _w_xyz(w: Writer, m: Vector3 | Point, f: str) -> None:
    w.f64(m.x, f + ".x")
    w.f64(m.y, f + ".y")
    w.f64(m.z, f + ".z")


def _r_vector3(r: Reader, f: str) -> Vector3:
    return Vector3(r.f64(f + ".x"), r.f64(f + ".y"), r.f64(f + ".z"))


def _r_point(r: Reader, f: str) -> Point:
    return Point(r.f64(f + ".x"), r.f64(f + ".y"), r.f64(f + ".z"))


def _w_quaternion(w: Writer, m: Quaternion, f: str) -> None:
    w.f64(m.x, f + ".x")
    w.f64(m.y, f + ".y")
    w.f64(m.z, f + ".z")
    w.f64(m.w, f + ".w")


def _r_quaternion(r: Reader, f: str) -> Quaternion:
    return Quaternion(r.f64(f + ".x"), r.f64(f + ".y"), r.f64(f + ".z"), r.f64(f + ".w"))


def _w_pose(w: Writer, m: Pose, f: str) -> None:
    _w_xyz(w, m.position, f + ".position")
    _w_quaternion(w, m.orientation, f + ".orientation")


def _r_pose(r: Reader, f: str) -> Pose:
    return Pose(_r_point(r, f + ".position"), _r_quaternion(r, f + ".orientation"))


def _w_twist(w: Writer, m: Twist, f: str) -> None:
    _w_xyz(w, m.linear, f + ".linear")
    _w_xyz(w, m.angular, f + ".angular")


def _r_twist(r: Reader, f: str) -> Twist:
    return Twist(_r_vector3(r, f + ".linear"), _r_vector3(r, f + ".angular"))


def _w_odometry(w: Writer, m: Odometry, f: str) -> None:
    _w_header(w, m.header, "header")
    w.string(m.child_frame_id, "child_frame_id")
    _w_pose(w, m.pose.pose, "pose.pose")
    w.f64s(m.pose.covariance, 36, "pose.covariance")
    _w_twist(w, m.twist.twist, "twist.twist")
    w.f64s(m.twist.covariance, 36, "twist.covariance")


def _r_odometry(r: Reader, f: str) -> Odometry:
    header = _r_header(r, "header")
    child = r.string("child_frame_id")
    pose = PoseWithCovariance(_r_pose(r, "pose.pose"), r.f64s(36, "pose.covariance"))
    twist = TwistWithCovariance(_r_twist(r, "twist.twist"), r.f64s(36, "twist.covariance"))
    return Odometry(header, child, pose, twist)


def _w_transform_stamped(w: Writer, m: TransformStamped, f: str) -> None:
    _w_header(w, m.header, f + ".header")
    w.string(m.child_frame_id, f + ".child_frame_id")
    _w_xyz(w, m.transform.translation, f + ".transform.translation")
    _w_quaternion(w, m.transform.rotation, f + ".transform.rotation")


def _r_transform_stamped(r: Reader, f: str) -> TransformStamped:
    header = _r_header(r, f + ".header")
    child = r.string(f + ".child_frame_id")
    translation = _r_vector3(r, f + ".transform.translation")
    return TransformStamped(
        header, child, Transform(translation, _r_quaternion(r, f + ".transform.rotation"))
    )


def _w_seq(w: Writer, items: tuple[Any, ...], f: str, write: Callable[..., None]) -> None:
    if not isinstance(items, tuple | list):
        raise Invalid(Reason.WRONG_TYPE, f"expected a tuple, got {type(items).__name__}", f)
    w.count(len(items), f)
    for i, item in enumerate(items):
        write(w, item, f"{f}[{i}]")


def _r_seq(r: Reader, f: str, min_bytes: int, read: Callable[[Reader, str], M]) -> tuple[M, ...]:
    n = r.count(min_bytes, f)
    return tuple(read(r, f"{f}[{i}]") for i in range(n))


def _w_tf(w: Writer, m: TFMessage, f: str) -> None:
    _w_seq(w, m.transforms, "transforms", _w_transform_stamped)


def _r_tf(r: Reader, f: str) -> TFMessage:
    # a TransformStamped is at least 8 (stamp) + 4 + 4 (two empty strings) + 56 bytes
    return TFMessage(_r_seq(r, "transforms", 72, _r_transform_stamped))


def _w_pose_array(w: Writer, m: PoseArray, f: str) -> None:
    _w_header(w, m.header, "header")
    _w_seq(w, m.poses, "poses", _w_pose)


def _r_pose_array(r: Reader, f: str) -> PoseArray:
    return PoseArray(_r_header(r, "header"), _r_seq(r, "poses", 56, _r_pose))


def _w_pose_stamped(w: Writer, m: PoseStamped, f: str) -> None:
    _w_header(w, m.header, "header")
    _w_pose(w, m.pose, "pose")


def _r_pose_stamped(r: Reader, f: str) -> PoseStamped:
    return PoseStamped(_r_header(r, "header"), _r_pose(r, "pose"))


def _w_color(w: Writer, m: ColorRGBA, f: str) -> None:
    w.f32(m.r, f + ".r")
    w.f32(m.g, f + ".g")
    w.f32(m.b, f + ".b")
    w.f32(m.a, f + ".a")


def _r_color(r: Reader, f: str) -> ColorRGBA:
    return ColorRGBA(r.f32(f + ".r"), r.f32(f + ".g"), r.f32(f + ".b"), r.f32(f + ".a"))


def _w_uv(w: Writer, m: UVCoordinate, f: str) -> None:
    w.f32(m.u, f + ".u")
    w.f32(m.v, f + ".v")


def _r_uv(r: Reader, f: str) -> UVCoordinate:
    return UVCoordinate(r.f32(f + ".u"), r.f32(f + ".v"))


def _w_marker(w: Writer, m: Marker, f: str) -> None:
    _w_header(w, m.header, f + ".header")
    w.string(m.ns, f + ".ns")
    w.i32(m.id, f + ".id")
    w.i32(m.type, f + ".type")
    w.i32(m.action, f + ".action")
    _w_pose(w, m.pose, f + ".pose")
    _w_xyz(w, m.scale, f + ".scale")
    _w_color(w, m.color, f + ".color")
    _w_time(w, m.lifetime, f + ".lifetime")
    w.boolean(m.frame_locked, f + ".frame_locked")
    _w_seq(w, m.points, f + ".points", _w_xyz)
    _w_seq(w, m.colors, f + ".colors", _w_color)
    w.string(m.texture_resource, f + ".texture_resource")
    _w_header(w, m.texture.header, f + ".texture.header")
    w.string(m.texture.format, f + ".texture.format")
    w.octets(m.texture.data, f + ".texture.data")
    _w_seq(w, m.uv_coordinates, f + ".uv_coordinates", _w_uv)
    w.string(m.text, f + ".text")
    w.string(m.mesh_resource, f + ".mesh_resource")
    w.string(m.mesh_file.filename, f + ".mesh_file.filename")
    w.octets(m.mesh_file.data, f + ".mesh_file.data")
    w.boolean(m.mesh_use_embedded_materials, f + ".mesh_use_embedded_materials")


def _r_marker(r: Reader, f: str) -> Marker:
    header = _r_header(r, f + ".header")
    ns = r.string(f + ".ns")
    id_ = r.i32(f + ".id")
    type_ = r.i32(f + ".type")
    action = r.i32(f + ".action")
    pose = _r_pose(r, f + ".pose")
    scale = _r_vector3(r, f + ".scale")
    color = _r_color(r, f + ".color")
    lifetime = _r_duration(r, f + ".lifetime")
    frame_locked = r.boolean(f + ".frame_locked")
    points = _r_seq(r, f + ".points", 24, _r_point)
    colors = _r_seq(r, f + ".colors", 16, _r_color)
    texture_resource = r.string(f + ".texture_resource")
    texture = CompressedImage(
        _r_header(r, f + ".texture.header"),
        r.string(f + ".texture.format"),
        r.octets(f + ".texture.data"),
    )
    uv = _r_seq(r, f + ".uv_coordinates", 8, _r_uv)
    text = r.string(f + ".text")
    mesh_resource = r.string(f + ".mesh_resource")
    mesh_file = MeshFile(r.string(f + ".mesh_file.filename"), r.octets(f + ".mesh_file.data"))
    embedded = r.boolean(f + ".mesh_use_embedded_materials")
    return Marker(
        header, ns, id_, type_, action, pose, scale, color, lifetime, frame_locked, points,
        colors, texture_resource, texture, uv, text, mesh_resource, mesh_file, embedded,
    )  # fmt: skip


def _w_marker_array(w: Writer, m: MarkerArray, f: str) -> None:
    _w_seq(w, m.markers, "markers", _w_marker)


def _r_marker_array(r: Reader, f: str) -> MarkerArray:
    return MarkerArray(_r_seq(r, "markers", 100, _r_marker))


def _w_trigger_request(w: Writer, m: TriggerRequest, f: str) -> None:
    w.u8(0, "structure_needs_at_least_one_member")


def _r_trigger_request(r: Reader, f: str) -> TriggerRequest:
    r.u8("structure_needs_at_least_one_member")
    return TriggerRequest()


def _w_trigger_response(w: Writer, m: TriggerResponse, f: str) -> None:
    w.boolean(m.success, "success")
    w.string(m.message, "message")


def _r_trigger_response(r: Reader, f: str) -> TriggerResponse:
    return TriggerResponse(r.boolean("success"), r.string("message"))


# --- the registry ------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class RosType:
    """A ROS 2 interface as rmw_zenoh names it on the wire.

    Attributes:
        name: the ROS name (``geometry_msgs/msg/Twist``; a service: ``std_srvs/srv/Trigger``).
        type_hash: the RIHS01 hash (REP 2016) of the type description; for a service, of the
            service (request, response and event together), which is what its keys carry.
        max_bytes: the largest payload the decoder accepts.
    """

    name: str
    type_hash: str
    max_bytes: int = MAX_PAYLOAD_BYTES

    @property
    def dds_name(self) -> str:
        """The DDS type name in keys and tokens: ``geometry_msgs::msg::dds_::Twist_``."""
        package, kind, short = self.name.split("/")
        return f"{package}::{kind}::dds_::{short}_"


TWIST = RosType(
    "geometry_msgs/msg/Twist",
    "RIHS01_9c45bf16fe0983d80e3cfe750d6835843d265a9a6c46bd2e609fcddde6fb8d2a",
    max_bytes=52,
)
ODOMETRY = RosType(
    "nav_msgs/msg/Odometry",
    "RIHS01_3cc97dc7fb7502f8714462c526d369e35b603cfc34d946e3f2eda2766dfec6e0",
    max_bytes=64 * 1024,
)
TF_MESSAGE = RosType(
    "tf2_msgs/msg/TFMessage",
    "RIHS01_e369d0f05a23ae52508854b66f6aa0437f3449d652e8cbf22d5abe85d020f087",
)
POSE_ARRAY = RosType(
    "geometry_msgs/msg/PoseArray",
    "RIHS01_af0cc36d190e104d546d168d6b39df04fa4b4ccecf59cb4c9ed328d3d5004aa0",
)
POSE_STAMPED = RosType(
    "geometry_msgs/msg/PoseStamped",
    "RIHS01_10f3786d7d40fd2b54367835614bff85d4ad3b5dab62bf8bca0cc232d73b4cd8",
    max_bytes=64 * 1024,
)
MARKER_ARRAY = RosType(
    "visualization_msgs/msg/MarkerArray",
    "RIHS01_86cb8800b6fb05b5eff1abd7a56f62a5641d3ae9a1c29e78e67e704f1d067dcf",
)
HEADER = RosType(
    "std_msgs/msg/Header",
    "RIHS01_f49fb3ae2cf070f793645ff749683ac6b06203e41c891e17701b1cb597ce6a01",
)
TIME = RosType(
    "builtin_interfaces/msg/Time",
    "RIHS01_b106235e25a4c5ed35098aa0a61a3ee9c9b18d197f398b0e4206cea9acf9c197",
)
TRIGGER = RosType(
    "std_srvs/srv/Trigger",
    "RIHS01_eeff2cd6fa5ad9d27cdf4dec64818317839b62f212a91e6b5304b634b2062c5f",
    max_bytes=64 * 1024,
)
"""The service: request and response travel on the same key, so they share this name/hash."""

_CODECS: dict[type, tuple[RosType, Callable[..., None], Callable[[Reader, str], Any]]] = {
    Twist: (TWIST, _w_twist, _r_twist),
    Odometry: (ODOMETRY, _w_odometry, _r_odometry),
    TFMessage: (TF_MESSAGE, _w_tf, _r_tf),
    PoseArray: (POSE_ARRAY, _w_pose_array, _r_pose_array),
    PoseStamped: (POSE_STAMPED, _w_pose_stamped, _r_pose_stamped),
    MarkerArray: (MARKER_ARRAY, _w_marker_array, _r_marker_array),
    Header: (HEADER, _w_header, _r_header),
    Time: (TIME, _w_time, _r_time),
    TriggerRequest: (TRIGGER, _w_trigger_request, _r_trigger_request),
    TriggerResponse: (TRIGGER, _w_trigger_response, _r_trigger_response),
}

TYPES: dict[type, RosType] = {cls: entry[0] for cls, entry in _CODECS.items()}
"""Every top-level type this module encodes -> its ROS name and hash."""


def ros_type(cls: type) -> RosType:
    """The RosType of a message class (KeyError for a class without a codec here)."""
    return _CODECS[cls][0]


def encode(msg: object) -> bytes:
    """``msg`` as a CDR payload (little endian, encapsulation header included).

    Raises SchemaError for an invalid message (non-finite float, wrong covariance length, an
    integer out of its range, a too-long string) and TypeError for a type without a codec.
    """
    entry = _CODECS.get(type(msg))
    if entry is None:
        raise TypeError(f"{type(msg).__name__} has no ROS 2 codec here")
    w = Writer()
    try:
        entry[1](w, msg, "")
    except Invalid as exc:
        raise SchemaError(exc.error) from None
    except AttributeError as exc:  # a wrong nested type (e.g. a Point where a Pose goes)
        raise SchemaError(DecodeError(Reason.WRONG_TYPE, str(exc)[:200], None)) from None
    return w.done()


def decode(data: bytes | bytearray | memoryview, cls: type[M]) -> M | DecodeError:
    """The message of type ``cls`` in ``data``, or a DecodeError; never raises on data.

    Raises TypeError only for a ``cls`` without a codec (a bug in the caller).
    """
    entry = _CODECS.get(cls)
    if entry is None:
        raise TypeError(f"{cls!r} has no ROS 2 codec here")
    rtype, _, read = entry
    try:
        r = Reader(data, rtype.max_bytes)
        msg: M = read(r, "")
        r.finish()
    except Invalid as exc:
        return exc.error
    except Exception as exc:  # defensive: no input may knock a control loop over
        return DecodeError(Reason.MALFORMED, f"{type(exc).__name__}: {exc}"[:200], None)
    return msg
