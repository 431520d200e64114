"""``formation report run.mcap --rosbag DIR`` (formation.record.rosbag): a recording as a ROS 2 bag
with MCAP storage, read back with rosbags' reader and deserializer (an independent rosbag2
implementation): topics, types, message counts, and decoded values equal to the recording's."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
from mcap.reader import make_reader
from rosbags.rosbag2 import Reader
from rosbags.typesys import Stores, get_typestore
from support.record_stream import DT, FLEET, record_items, synthetic_stream

from bus_schemas import Pose, decode, keys
from bus_schemas.ros2 import msgs
from formation.record import report as report_mod
from formation.record.replay import read_recording
from formation.record.rosbag import RosbagError, export_rosbag

TICKS = 50


@pytest.fixture
def recording(tmp_path: Path) -> Path:
    path = tmp_path / "run.mcap"
    record_items(path, synthetic_stream(TICKS))
    return path


def test_report_writes_a_rosbag2_that_rosbags_reads(recording: Path, tmp_path: Path) -> None:
    bag = tmp_path / "bag"
    code = report_mod.main(
        [str(recording), "--rosbag", str(bag), "--no-figures", "--quiet",
         "--out", str(tmp_path / "report")]
    )  # fmt: skip
    assert code == 0
    assert (bag / "metadata.yaml").is_file() and len(list(bag.glob("*.mcap"))) == 1

    expected = {
        "/r1/odom": ("nav_msgs/msg/Odometry", TICKS),
        "/r2/odom": ("nav_msgs/msg/Odometry", TICKS),
        # a tf per pose, and one per leader message for the leader and the slots
        "/tf": ("tf2_msgs/msg/TFMessage", 2 * TICKS + TICKS),
        "/formation/leader": ("geometry_msgs/msg/PoseStamped", TICKS),
        "/formation/slots": ("geometry_msgs/msg/PoseArray", TICKS),
        "/formation/markers": ("visualization_msgs/msg/MarkerArray", TICKS),
    }
    store = get_typestore(Stores.ROS2_JAZZY)
    rec = read_recording(recording)
    r1_poses = [
        (ev.log_ns, decode(ev.payload, Pose))
        for ev in rec.events
        if ev.key == keys.pose_key(FLEET, "r1") and ev.payload is not None
    ]
    with Reader(bag) as reader:
        got = {c.topic: (c.msgtype, c.msgcount) for c in reader.connections}
        assert got == expected
        odoms: list[tuple[int, Any]] = [
            (ts, store.deserialize_cdr(raw, conn.msgtype))
            for conn, ts, raw in reader.messages()
            if conn.topic == "/r1/odom"
        ]
        slots: list[Any] = [
            store.deserialize_cdr(raw, conn.msgtype)
            for conn, _, raw in reader.messages()
            if conn.topic == "/formation/slots"
        ]
    # each odometry is the recorded pose, stamped with the recorder's log time
    assert len(odoms) == len(r1_poses) == TICKS
    for (ts, odom), (log_ns, pose) in zip(odoms, r1_poses, strict=True):
        assert isinstance(pose, Pose)
        assert ts == log_ns
        assert odom.header.stamp.sec * 1_000_000_000 + odom.header.stamp.nanosec == log_ns
        assert (odom.header.frame_id, odom.child_frame_id) == ("map", "r1/base_link")
        assert odom.pose.pose.position.x == pose.x and odom.pose.pose.position.y == pose.y
    # r1 moves at 0.02 m/s along x (synthetic_stream): the body twist of consecutive poses
    assert odoms[-1][1].twist.twist.linear.x == pytest.approx(0.02)
    last_t = (TICKS - 1) * DT
    assert [p.position.x for p in slots[-1].poses] == pytest.approx(
        [0.15 + 0.02 * last_t, 0.15 + 0.02 * last_t - 0.3]
    )

    # the MCAP inside is rosbag2's: ros2msg schemas with the wire's names, CDR messages
    with open(next(bag.glob("*.mcap")), "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    schemas = {s.name: s.encoding for s in summary.schemas.values()}
    assert schemas["nav_msgs/msg/Odometry"] == "ros2msg"
    assert {c.message_encoding for c in summary.channels.values()} == {"cdr"}
    # the bag's RIHS01 hashes are the ones bus_schemas.ros2 puts on rmw_zenoh's keys
    text = (bag / "metadata.yaml").read_text()
    assert "storage_identifier: mcap" in text
    for cls in (msgs.Odometry, msgs.TFMessage, msgs.PoseArray, msgs.PoseStamped):
        assert msgs.ros_type(cls).type_hash in text


def test_export_refuses_an_existing_folder_and_a_recording_without_poses(
    recording: Path, tmp_path: Path
) -> None:
    rec = read_recording(recording)
    taken = tmp_path / "taken"
    taken.mkdir()
    with pytest.raises(RosbagError, match="exists"):
        export_rosbag(rec, taken)
    assert report_mod.main([str(recording), "--rosbag", str(taken), "--quiet"]) == 2
    rec.events = [e for e in rec.events if "/pose" not in e.key and "/leader" not in e.key]
    with pytest.raises(RosbagError, match="no pose"):
        export_rosbag(rec, tmp_path / "empty")
    assert not (tmp_path / "empty").exists()


def test_a_poses_batch_recording_gives_one_tf_per_frame(tmp_path: Path) -> None:
    """A fleet whose localization sends ``poses`` batches (the plant, an agent-host run): each
    robot's odometry per frame, and one ``/tf`` per frame with every robot in it."""
    from bus_schemas import PoseBatch, encode
    from runtime.tap import BusItem

    ids = ("r1", "r2", "r3")
    items = [
        BusItem(
            "put",
            keys.poses_key(FLEET),
            encode(
                PoseBatch(
                    t=k * DT,
                    seq=k,
                    robots=ids,
                    x=(0.1 * k,) * 3,
                    y=(0.0, 1.0, 2.0),
                    theta=(0.0,) * 3,
                    stamp=k * DT,
                )
            ),
            1_000_000_000 + k * 20_000_000,
        )
        for k in range(1, 21)
    ]
    path = tmp_path / "batch.mcap"
    record_items(path, items)
    summary = export_rosbag(read_recording(path), tmp_path / "bag")
    assert dict(summary.counts) == {"/r1/odom": 20, "/r2/odom": 20, "/r3/odom": 20, "/tf": 20}
    store = get_typestore(Stores.ROS2_JAZZY)
    with Reader(tmp_path / "bag") as reader:
        tfs: list[Any] = [
            store.deserialize_cdr(raw, c.msgtype) for c, _, raw in reader.messages()
            if c.topic == "/tf"
        ]  # fmt: skip
    assert [t.child_frame_id for t in tfs[0].transforms] == [f"{r}/base_link" for r in ids]
    assert [t.transform.translation.y for t in tfs[-1].transforms] == [0.0, 1.0, 2.0]


def test_a_recorded_estimator_twist_is_the_odometrys_when_fresh(tmp_path: Path) -> None:
    """Issue 29: the bag's odometry takes a robot's estimator twist from the recorded host
    status while it is fresh by the recorder's log time (as the bridge by its clock), else the
    finite difference; the twist covariance says which."""
    from bus_schemas import PoseBatch, StatusBatch, encode
    from formation.live.ros2_bridge import TWIST_COV_ESTIMATOR, TWIST_COV_FINITE_DIFFERENCE
    from runtime.tap import BusItem

    ms = 1_000_000
    status = StatusBatch(
        t=0.0, seq=1, pid=1, host="h", robots=("r1", "r2"), mode=("tracking",) * 2,
        slot=(0, 1), rejected=(0, 0), ex=(0.0, 0.0), ey=(0.0, 0.0),
        twist_robots=("r1",), v_mps=(0.125,), omega_radps=(-0.5,),
    )  # fmt: skip
    items = [BusItem("put", keys.host_status_key(FLEET, "h"), encode(status), 1000 * ms)]
    for k in range(1, 41):  # frames every 20 ms: fresh for 0.4 s after the status, then stale
        frame = PoseBatch(t=k * DT, seq=k, robots=("r1", "r2"), x=(0.002 * k, 0.0),
                          y=(0.0, 1.0), theta=(0.0, 0.0), stamp=k * DT)  # fmt: skip
        items.append(BusItem("put", keys.poses_key(FLEET), encode(frame), 1000 * ms + k * 20 * ms))
    path = tmp_path / "twist.mcap"
    record_items(path, items)
    rec = read_recording(path)
    (t0,) = [ev.log_ns for ev in rec.events if ev.key == keys.host_status_key(FLEET, "h")]
    export_rosbag(rec, tmp_path / "bag")
    store = get_typestore(Stores.ROS2_JAZZY)
    with Reader(tmp_path / "bag") as reader:
        odom: dict[str, list[tuple[int, Any]]] = {"/r1/odom": [], "/r2/odom": []}
        for c, ts, raw in reader.messages():
            if c.topic in odom:
                msg: Any = store.deserialize_cdr(raw, c.msgtype)
                odom[c.topic].append((ts, msg.twist))
    for ts, tw in odom["/r1/odom"]:
        if ts - t0 < 400 * ms:
            assert (tw.twist.linear.x, tw.twist.angular.z) == (0.125, -0.5)
            assert tuple(tw.covariance) == TWIST_COV_ESTIMATOR
        elif ts - t0 > 400 * ms:  # stale: the finite difference (0.002 m per 20 ms frame)
            assert tw.twist.linear.x == pytest.approx(0.002 / DT)
            assert tuple(tw.covariance) == TWIST_COV_FINITE_DIFFERENCE
    assert {tuple(tw.covariance) for _, tw in odom["/r2/odom"]} == {TWIST_COV_FINITE_DIFFERENCE}
    assert sum(ts - t0 < 400 * ms for ts, _ in odom["/r1/odom"]) == 19
    assert sum(ts - t0 > 400 * ms for ts, _ in odom["/r1/odom"]) == 20
