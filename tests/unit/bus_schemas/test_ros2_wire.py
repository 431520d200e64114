"""bus_schemas.ros2 against independent implementations: rosbags' CDR bytes and RIHS01 hashes,
the xxhash package's XXH3-128, and rmw_zenoh's design document examples, byte for byte."""

from __future__ import annotations

import ast
import math
import os
import struct
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import xxhash
from hypothesis import given, settings
from hypothesis import strategies as st

from bus_schemas.errors import DecodeError, Reason, SchemaError
from bus_schemas.ros2 import msgs, rmw
from bus_schemas.ros2.xxh3 import xxh3_128
from tests.support import ros2_reference as ref

ROOT = Path(__file__).resolve().parent.parent

# --- strategies --------------------------------------------------------------------------------

f64 = st.floats(allow_nan=False, allow_infinity=False)
f32 = st.floats(allow_nan=False, allow_infinity=False, width=32)
i32 = st.integers(-(2**31), 2**31 - 1)
name = st.text(st.characters(exclude_categories=["Cs"], exclude_characters="\x00"), max_size=12)
time_ = st.builds(msgs.Time, i32, st.integers(0, 999_999_999))
header = st.builds(msgs.Header, time_, name)
vector3 = st.builds(msgs.Vector3, f64, f64, f64)
point = st.builds(msgs.Point, f64, f64, f64)
quaternion = st.builds(msgs.Quaternion, f64, f64, f64, f64)
pose = st.builds(msgs.Pose, point, quaternion)
cov = st.lists(f64, min_size=36, max_size=36).map(tuple)
twist = st.builds(msgs.Twist, vector3, vector3)
odometry = st.builds(
    msgs.Odometry,
    header,
    name,
    st.builds(msgs.PoseWithCovariance, pose, cov),
    st.builds(msgs.TwistWithCovariance, twist, cov),
)
transform_stamped = st.builds(
    msgs.TransformStamped, header, name, st.builds(msgs.Transform, vector3, quaternion)
)
tf_message = st.builds(msgs.TFMessage, st.lists(transform_stamped, max_size=4).map(tuple))
pose_array = st.builds(msgs.PoseArray, header, st.lists(pose, max_size=5).map(tuple))
pose_stamped = st.builds(msgs.PoseStamped, header, pose)
color = st.builds(msgs.ColorRGBA, f32, f32, f32, f32)
marker = st.builds(
    msgs.Marker,
    header=header,
    ns=name,
    id=i32,
    type=st.integers(0, 11),
    action=st.integers(0, 3),
    pose=pose,
    scale=vector3,
    color=color,
    lifetime=st.builds(msgs.Duration, i32, st.integers(0, 999_999_999)),
    frame_locked=st.booleans(),
    points=st.lists(point, max_size=3).map(tuple),
    colors=st.lists(color, max_size=3).map(tuple),
    texture_resource=name,
    texture=st.builds(msgs.CompressedImage, header, name, st.binary(max_size=9)),
    uv_coordinates=st.lists(st.builds(msgs.UVCoordinate, f32, f32), max_size=3).map(tuple),
    text=name,
    mesh_resource=name,
    mesh_file=st.builds(msgs.MeshFile, name, st.binary(max_size=9)),
    mesh_use_embedded_materials=st.booleans(),
)
marker_array = st.builds(msgs.MarkerArray, st.lists(marker, max_size=3).map(tuple))
trigger_response = st.builds(msgs.TriggerResponse, st.booleans(), name)

CASES = {
    "geometry_msgs/msg/Twist": twist,
    "nav_msgs/msg/Odometry": odometry,
    "tf2_msgs/msg/TFMessage": tf_message,
    "geometry_msgs/msg/PoseArray": pose_array,
    "geometry_msgs/msg/PoseStamped": pose_stamped,
    "visualization_msgs/msg/MarkerArray": marker_array,
    "std_msgs/msg/Header": header,
    "builtin_interfaces/msg/Time": time_,
    "std_srvs/srv/Trigger_Response": trigger_response,
    "std_srvs/srv/Trigger_Request": st.just(msgs.TriggerRequest()),
}


# --- the robot's import floor ------------------------------------------------------------------


def test_ros2_core_imports_only_the_standard_library() -> None:
    allowed = set(sys.stdlib_module_names) | {"bus_schemas"}
    for path in sorted((ROOT / "bus_schemas" / "ros2").glob("*.py")):
        tree = ast.parse(path.read_text(encoding="utf-8"))
        names: set[str] = set()
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                names.update(a.name.split(".")[0] for a in node.names)
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names.add(node.module.split(".")[0])
        assert names <= allowed, f"{path.name} imports {sorted(names - allowed)}"


def test_ros2_core_runs_without_numpy_or_rosbags() -> None:
    code = (
        "import sys; sys.modules['numpy'] = None; sys.modules['rosbags'] = None; "
        "from bus_schemas.ros2 import msgs, rmw; "
        "b = msgs.encode(msgs.Twist(msgs.Vector3(0.5), msgs.Vector3(z=1.0))); "
        "assert len(b) == 52 and msgs.decode(b, msgs.Twist).angular.z == 1.0; print('ok')"
    )
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env)
    assert out.returncode == 0 and out.stdout.strip() == "ok", out.stderr


# --- type hashes -------------------------------------------------------------------------------


@pytest.mark.parametrize("rtype", list(dict.fromkeys(msgs.TYPES.values())), ids=lambda t: t.name)
def test_type_hash_equals_rosbags(rtype: msgs.RosType) -> None:
    if rtype.name in ref.SERVICES:
        assert rtype.type_hash == ref.service_hash(rtype.name)
    else:
        assert rtype.type_hash == ref.typestore().hash_rihs01(rtype.name)


def test_service_hash_method_reproduces_the_design_document() -> None:
    # the AddTwoInts key in rmw_zenoh's design.md: proves the service hash is computed right
    assert ref.service_hash("example_interfaces/srv/AddTwoInts") == (
        "RIHS01_e118de6bf5eeb66a2491b5bda11202e7b68f198d6f67922cf30364858239c81a"
    )


def test_dds_names() -> None:
    assert msgs.ros_type(msgs.Twist).dds_name == "geometry_msgs::msg::dds_::Twist_"
    assert msgs.ros_type(msgs.TriggerRequest).dds_name == "std_srvs::srv::dds_::Trigger_"


# --- CDR bytes ---------------------------------------------------------------------------------


@pytest.mark.parametrize("typename", list(CASES))
@settings(max_examples=60, deadline=None)
@given(data=st.data())
def test_bytes_equal_rosbags_and_round_trip(typename: str, data: st.DataObject) -> None:
    msg = data.draw(CASES[typename])
    ours = msgs.encode(msg)
    assert ours == ref.serialize(msg, typename)
    back = msgs.decode(ours, type(msg))
    assert back == msg


def test_twist_is_52_bytes_and_golden() -> None:
    b = msgs.encode(msgs.Twist(msgs.Vector3(0.25, 0.0, 0.0), msgs.Vector3(0.0, 0.0, -1.5)))
    assert len(b) == 52
    assert b[:4] == b"\x00\x01\x00\x00"
    assert struct.unpack("<6d", b[4:]) == (0.25, 0.0, 0.0, 0.0, 0.0, -1.5)


def test_decodes_rosbags_odometry() -> None:
    ts = ref.typestore()
    t = ts.types
    odom = t["nav_msgs/msg/Odometry"](
        header=t["std_msgs/msg/Header"](
            stamp=t["builtin_interfaces/msg/Time"](sec=3, nanosec=5), frame_id="odom"
        ),
        child_frame_id="base_footprint",
        pose=t["geometry_msgs/msg/PoseWithCovariance"](
            pose=t["geometry_msgs/msg/Pose"](
                position=t["geometry_msgs/msg/Point"](x=1.0, y=2.0, z=0.0),
                orientation=t["geometry_msgs/msg/Quaternion"](
                    x=0.0, y=0.0, z=math.sin(0.4), w=math.cos(0.4)
                ),
            ),
            covariance=np.zeros(36),
        ),
        twist=t["geometry_msgs/msg/TwistWithCovariance"](
            twist=t["geometry_msgs/msg/Twist"](
                linear=t["geometry_msgs/msg/Vector3"](x=0.2, y=0.0, z=0.0),
                angular=t["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.3),
            ),
            covariance=np.zeros(36),
        ),
    )
    raw = bytes(ts.serialize_cdr(odom, "nav_msgs/msg/Odometry"))
    got = msgs.decode(raw, msgs.Odometry)
    assert isinstance(got, msgs.Odometry)
    assert got.header.frame_id == "odom" and got.child_frame_id == "base_footprint"
    assert got.twist.twist.linear.x == 0.2 and got.twist.twist.angular.z == 0.3
    yaw = msgs.yaw_from_quaternion(got.pose.pose.orientation)
    assert yaw is not None and math.isclose(yaw, 0.8)


def test_big_endian_payload_is_read() -> None:
    body = struct.pack(">6d", 1.0, 2.0, 3.0, 4.0, 5.0, 6.0)
    got = msgs.decode(b"\x00\x00\x00\x00" + body, msgs.Twist)
    assert got == msgs.Twist(msgs.Vector3(1.0, 2.0, 3.0), msgs.Vector3(4.0, 5.0, 6.0))


@given(yaw=st.floats(-math.pi, math.pi), scale=st.floats(0.6, 5.0))
def test_yaw_quaternion_round_trip(yaw: float, scale: float) -> None:
    q = msgs.quaternion_from_yaw(yaw)
    q = msgs.Quaternion(q.x * scale, q.y * scale, q.z * scale, q.w * scale)
    got = msgs.yaw_from_quaternion(q)
    assert got is not None
    assert abs(math.remainder(got - yaw, 2 * math.pi)) < 1e-9


def test_degenerate_quaternion_has_no_yaw() -> None:
    assert msgs.yaw_from_quaternion(msgs.Quaternion(0.0, 0.0, 0.0, 0.0)) is None


# --- rejections --------------------------------------------------------------------------------

ODOM = msgs.Odometry(msgs.Header(msgs.Time(1, 2), "odom"), "base_link")


def test_every_truncation_is_a_decode_error() -> None:
    full = msgs.encode(ODOM)
    for n in range(len(full)):
        got = msgs.decode(full[:n], msgs.Odometry)
        assert isinstance(got, DecodeError), n
        assert got.reason is Reason.MALFORMED


def test_nan_and_inf_are_rejected() -> None:
    good = msgs.encode(msgs.Twist())
    for bad in (math.nan, math.inf, -math.inf):
        raw = good[:4] + struct.pack("<d", bad) + good[12:]
        got = msgs.decode(raw, msgs.Twist)
        assert isinstance(got, DecodeError) and got.reason is Reason.NON_FINITE
        assert got.field == ".linear.x"
        with pytest.raises(SchemaError):
            msgs.encode(msgs.Twist(msgs.Vector3(bad)))


def test_oversized_wrong_header_trailing_and_bad_string() -> None:
    twist = msgs.encode(msgs.Twist())
    cases = {
        Reason.TOO_LARGE: twist + b"\x00" * 8,  # a Twist is exactly 52 bytes
        Reason.MALFORMED: b"\x00\x02\x00\x00" + twist[4:],  # XCDR2 is not plain CDR
    }
    for reason, raw in cases.items():
        got = msgs.decode(raw, msgs.Twist)
        assert isinstance(got, DecodeError) and got.reason is reason, (reason, got)
    pose = msgs.encode(msgs.PoseStamped())
    trailing = msgs.decode(pose + b"\x01", msgs.PoseStamped)
    assert isinstance(trailing, DecodeError) and trailing.reason is Reason.MALFORMED
    # frame_id: length 2 but no NUL terminator
    raw = pose[:12] + struct.pack("<I", 2) + b"ab" + pose[17:]
    assert isinstance(msgs.decode(raw, msgs.PoseStamped), DecodeError)


def test_huge_sequence_count_is_refused_without_allocating() -> None:
    raw = msgs.encode(msgs.TFMessage())[:4] + struct.pack("<I", 2**32 - 1)
    got = msgs.decode(raw, msgs.TFMessage)
    assert isinstance(got, DecodeError) and got.reason is Reason.TOO_LARGE


def test_encode_rejects_bad_messages() -> None:
    bad = [
        msgs.Odometry(pose=msgs.PoseWithCovariance(covariance=(0.0,) * 35)),
        msgs.PoseStamped(msgs.Header(msgs.Time(2**31, 0))),
        msgs.PoseStamped(msgs.Header(msgs.Time(0, 1_000_000_000))),
        msgs.PoseStamped(msgs.Header(frame_id="a\x00b")),
        msgs.TriggerResponse(success=1),  # type: ignore[arg-type]
    ]
    for msg in bad:
        with pytest.raises(SchemaError):
            msgs.encode(msg)


@settings(max_examples=300, deadline=None)
@given(data=st.binary(max_size=300), cls=st.sampled_from(sorted(msgs.TYPES, key=str)))
def test_random_bytes_never_raise(data: bytes, cls: type) -> None:
    got = msgs.decode(b"\x00\x01\x00\x00" + data, cls)
    assert isinstance(got, DecodeError | cls)


# --- rmw_zenoh: keys, attachments, tokens, GIDs ------------------------------------------------

STRING = msgs.RosType(
    "std_msgs/msg/String",
    "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18",
)
ADD_TWO_INTS = msgs.RosType(
    "example_interfaces/srv/AddTwoInts",
    "RIHS01_e118de6bf5eeb66a2491b5bda11202e7b68f198d6f67922cf30364858239c81a",
)


def test_string_hash_is_rosbags() -> None:
    assert ref.typestore().hash_rihs01("std_msgs/msg/String") == STRING.type_hash


def test_keys_equal_the_design_document() -> None:
    h = STRING.type_hash
    assert rmw.topic_key(0, "/chatter", STRING) == f"0/chatter/std_msgs::msg::dds_::String_/{h}"
    assert rmw.topic_key(0, "/robot1/chatter", STRING) == (
        f"0/robot1/chatter/std_msgs::msg::dds_::String_/{h}"
    )
    assert rmw.topic_key(2, "add_two_ints", ADD_TWO_INTS) == (
        "2/add_two_ints/example_interfaces::srv::dds_::AddTwoInts_/"
        "RIHS01_e118de6bf5eeb66a2491b5bda11202e7b68f198d6f67922cf30364858239c81a"
    )


def test_tokens_equal_the_design_document() -> None:
    h = STRING.type_hash
    a = ADD_TWO_INTS.type_hash
    assert rmw.node_token(2, "aac3178e146ba6f1fc6e6a4085e77f21", 0, "", "listener") == (
        "@ros2_lv/2/aac3178e146ba6f1fc6e6a4085e77f21/0/0/NN/%/%/listener"
    )
    sub = rmw.endpoint_token(
        2, "aac3178e146ba6f1fc6e6a4085e77f21", 0, 10, rmw.EntityKind.SUBSCRIPTION, "/",
        "listener", "/chatter", STRING, rmw.Qos(depth=10),
    )  # fmt: skip
    assert sub == (
        "@ros2_lv/2/aac3178e146ba6f1fc6e6a4085e77f21/0/10/MS/%/%/listener/%chatter/"
        f"std_msgs::msg::dds_::String_/{h}/::,10:,:,:,,"
    )
    pub = rmw.endpoint_token(
        2, "8b20917502ee955ac4476e0266340d5c", 0, 10, rmw.EntityKind.PUBLISHER, "",
        "talker", "/chatter", STRING, rmw.Qos(depth=7),
    )  # fmt: skip
    assert pub == (
        "@ros2_lv/2/8b20917502ee955ac4476e0266340d5c/0/10/MP/%/%/talker/%chatter/"
        f"std_msgs::msg::dds_::String_/{h}/::,7:,:,:,,"
    )
    srv = rmw.endpoint_token(
        2, "f9980ee0495eaafb3e38f0d19e2eae12", 0, 10, rmw.EntityKind.SERVICE, "",
        "add_two_ints_server", "/add_two_ints", ADD_TWO_INTS, rmw.Qos(depth=10),
    )  # fmt: skip
    assert srv == (
        "@ros2_lv/2/f9980ee0495eaafb3e38f0d19e2eae12/0/10/SS/%/%/add_two_ints_server/"
        f"%add_two_ints/example_interfaces::srv::dds_::AddTwoInts_/{a}/::,10:,:,:,,"
    )
    cli = rmw.endpoint_token(
        2, "e1dc8d1b45ae8717fce78689cc655685", 0, 10, rmw.EntityKind.CLIENT, "",
        "add_two_ints_client", "/add_two_ints", ADD_TWO_INTS, rmw.Qos(depth=10),
    )  # fmt: skip
    assert cli == (
        "@ros2_lv/2/e1dc8d1b45ae8717fce78689cc655685/0/10/SC/%/%/add_two_ints_client/"
        f"%add_two_ints/example_interfaces::srv::dds_::AddTwoInts_/{a}/::,10:,:,:,,"
    )
    parsed = rmw.parse_token(srv)
    assert isinstance(parsed, rmw.LivelinessToken)
    assert parsed.kind is rmw.EntityKind.SERVICE and parsed.topic == "/add_two_ints"
    assert parsed.ros_type == "example_interfaces/srv/AddTwoInts"
    assert parsed.qos == rmw.Qos(depth=10)


def test_namespaced_tokens_mangle() -> None:
    tok = rmw.endpoint_token(
        0, "ab12", 3, 4, rmw.EntityKind.PUBLISHER, "/fleet", "bridge", "/r1/odom",
        msgs.ros_type(msgs.Odometry),
    )  # fmt: skip
    assert "/3/4/MP/%/%fleet/bridge/%r1%odom/nav_msgs::msg::dds_::Odometry_/" in tok
    assert tok.endswith("/::,:,:,:,,")
    got = rmw.parse_token(tok)
    assert isinstance(got, rmw.LivelinessToken)
    assert (got.namespace, got.node_name, got.topic) == ("/fleet", "bridge", "/r1/odom")


def test_bad_names_are_refused() -> None:
    for bad in ("", "/", "a//b", "a/", "1abc", "a b", "a/*"):
        with pytest.raises(ValueError):
            rmw.topic_key(0, bad, STRING)
    with pytest.raises(ValueError):
        rmw.topic_key(233, "chatter", STRING)
    with pytest.raises(ValueError):
        rmw.node_token(0, "NOT-HEX", 0, "", "n")


qos_st = st.builds(
    rmw.Qos,
    reliability=st.sampled_from([1, 2]),
    durability=st.sampled_from([1, 2]),
    history=st.sampled_from([1, 2]),
    depth=st.integers(0, 10_000),
    deadline_ns=st.one_of(st.just(rmw.DURATION_INFINITE_NS), st.integers(0, 10**12)),
    lifespan_ns=st.one_of(st.just(rmw.DURATION_INFINITE_NS), st.integers(0, 10**12)),
    liveliness=st.sampled_from([1, 3]),
    lease_ns=st.one_of(st.just(rmw.DURATION_INFINITE_NS), st.integers(0, 10**12)),
)


@given(qos=qos_st)
def test_qos_string_round_trip(qos: rmw.Qos) -> None:
    assert rmw.parse_qos(rmw.qos_string(qos)) == qos


def test_qos_strings() -> None:
    assert rmw.qos_string(rmw.DEFAULT_QOS) == "::,:,:,:,,"
    assert rmw.qos_string(rmw.Qos(reliability=2, depth=1)) == "2::,1:,:,:,,"
    assert rmw.parse_qos("1:2:1,10") == rmw.Qos(1, 2, 1, 10)  # the older short form
    for bad in ("", "x:y", "a::,:,:,:,,", "::,:,:,:"):
        assert isinstance(rmw.parse_qos(bad), DecodeError)


@given(
    seq=st.integers(-(2**63), 2**63 - 1),
    stamp=st.integers(0, 2**63 - 1),
    gid=st.binary(min_size=16, max_size=16),
)
def test_attachment_round_trip(seq: int, stamp: int, gid: bytes) -> None:
    att = rmw.Attachment(seq, stamp, gid)
    raw = rmw.encode_attachment(att)
    assert len(raw) == 33 and raw[16] == 16
    assert raw[:8] == seq.to_bytes(8, "little", signed=True)
    assert raw[8:16] == stamp.to_bytes(8, "little", signed=True)
    assert rmw.decode_attachment(raw) == att


def test_attachment_golden_and_rejections() -> None:
    # 1.7e18 ns = 0x17979cfe362a0000, little endian
    raw = rmw.encode_attachment(rmw.Attachment(1, 1_700_000_000_000_000_000, bytes(range(16))))
    assert raw.hex() == (
        "0100000000000000" "00002a36fe9c9717" "10" "000102030405060708090a0b0c0d0e0f"
    )  # fmt: skip
    for bad in (None, b"", raw[:-1], raw + b"\x00", raw[:16] + b"\x08" + raw[17:]):
        assert isinstance(rmw.decode_attachment(bad), DecodeError)
    with pytest.raises(ValueError):
        rmw.encode_attachment(rmw.Attachment(0, 0, b"short"))


def test_xxh3_equals_xxhash_for_every_length_path() -> None:
    for n in [*range(0, 300), 1023, 1024, 1025, 2048, 5000]:
        data = bytes((i * 131 + n) & 0xFF for i in range(n))
        low, high = xxh3_128(data)
        assert (high << 64) | low == xxhash.xxh3_128_intdigest(data), n


def test_gid_is_xxh3_of_the_token() -> None:
    tok = "@ros2_lv/2/aac3178e146ba6f1fc6e6a4085e77f21/0/0/NN/%/%/listener"
    digest = xxhash.xxh3_128_intdigest(tok.encode())
    assert rmw.entity_gid(tok) == digest.to_bytes(16, "little")
