"""A recording as a ROS 2 bag: ``formation report run.mcap --rosbag DIR``.

The bag is what ``formation ros2`` would have shown a ROS 2 graph during the run (docs/ros2.md):
the recording's bus samples go through the bridge's own pure translation
(:class:`formation.live.ros2_bridge.BridgeCore`), so the bag holds exactly the bridge's topics,
types and CDR bytes:

- ``/<id>/odom`` (nav_msgs/msg/Odometry) and ``/tf`` (tf2_msgs/msg/TFMessage) for every
  recorded pose (``pose``, or the ``poses`` batch: then one ``/tf`` for the whole batch), the
  twist the estimator's of the recorded ``status`` / host ``status`` when fresh by ``log_time``
  (as the bridge judges it by its clock), else the finite difference;
- ``/formation/leader`` (geometry_msgs/msg/PoseStamped), ``/formation/slots``
  (geometry_msgs/msg/PoseArray), ``/formation/markers`` (visualization_msgs/msg/MarkerArray) and
  their ``/tf``, one snapshot per recorded ``leader`` message.

Times: a message's bag timestamp and its header stamp are the recorder's ``log_time`` of the
bus sample it comes from (wall clock, ns; formation.record.command), like ``ros2 bag record``
on the recording host. The storage is rosbag2's MCAP (``metadata.yaml`` + one ``.mcap`` with
``ros2msg`` schemas and CDR payloads), written with rosbags' ``Writer`` (bag version 9, RIHS01
hashes in the metadata); the message definitions come from rosbags' ROS 2 Jazzy typestore,
whose hashes must equal the ones ``bus_schemas.ros2.msgs`` puts on the wire (checked here at
export, and in tests/unit/formation/test_rosbag_export.py with rosbags' reader).
"""

from __future__ import annotations

import shutil
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

from bus_schemas import (
    DecodeError,
    Leader,
    Pose,
    PoseBatch,
    Slot,
    Status,
    StatusBatch,
    decode,
    keys,
)
from bus_schemas.ros2 import msgs
from formation.live.ros2_bridge import BridgeCore, Outgoing
from formation.record.replay import Recording

__all__ = ["RosbagError", "RosbagSummary", "export_rosbag"]


class RosbagError(ValueError):
    """The bag cannot be written (the folder exists, the typestore disagrees, no messages)."""


@dataclass
class RosbagSummary:
    """What :func:`export_rosbag` wrote: messages per topic, the types, what it skipped."""

    path: Path
    counts: Counter[str] = field(default_factory=Counter)
    types: dict[str, str] = field(default_factory=dict)
    skipped: Counter[str] = field(default_factory=Counter)

    def line(self) -> str:
        total = sum(self.counts.values())
        skipped = f", skipped {dict(self.skipped)}" if self.skipped else ""
        return f"rosbag2 (MCAP) {self.path}: {total} messages on {len(self.counts)} topics{skipped}"


def _outgoing(core: BridgeCore, key: str, payload: bytes, stamp_ns: int) -> list[Outgoing]:
    """One recorded bus sample -> the bridge's ROS messages for it (may be none); the bridge's
    clock is the recorder's (``stamp_ns``)."""
    info = keys.parse_key(key)
    if info is None:
        return []
    now_s = stamp_ns * 1e-9
    if info.leaf == keys.STATUS and info.robot is not None:
        status = decode(payload, Status)
        if isinstance(status, DecodeError):
            core.rejected.add(status)
        else:
            core.on_status(info.robot, status, now_s)
        return []
    if info.leaf == keys.HOST_STATUS:
        hb = decode(payload, StatusBatch)
        if isinstance(hb, DecodeError):
            core.rejected.add(hb)
        else:
            core.on_status_batch(hb, now_s)
        return []
    if info.leaf == keys.POSE and info.robot is not None:
        pose = decode(payload, Pose)
        if isinstance(pose, DecodeError):
            core.rejected.add(pose)
            return []
        return core.on_pose(info.robot, pose.t, pose.x, pose.y, pose.theta, stamp_ns, now_s)
    if info.leaf == keys.POSES:
        batch = decode(payload, PoseBatch)
        if isinstance(batch, DecodeError):
            core.rejected.add(batch)
            return []
        return core.on_poses(batch, stamp_ns, now_s)
    if info.leaf == keys.LEADER:
        leader = decode(payload, Leader)
        if isinstance(leader, DecodeError):
            core.rejected.add(leader)
            return []
        core.on_leader(leader)
        return core.formation(stamp_ns)
    if info.leaf == keys.SLOT:
        slot = decode(payload, Slot)
        if isinstance(slot, DecodeError):
            core.rejected.add(slot)
        else:
            core.on_slot(slot)
    return []


def export_rosbag(rec: Recording, out_dir: Path, *, namespace: str = "") -> RosbagSummary:
    """Write the ROS 2 bag of ``rec`` into the new folder ``out_dir`` (it must not exist).

    Raises RosbagError if ``out_dir`` exists, the recording yields no ROS message, or rosbags'
    typestore hashes a type differently from ``bus_schemas.ros2.msgs``."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    if out_dir.exists():
        raise RosbagError(f"{out_dir} exists (rosbag2 writes a new folder)")
    store = get_typestore(Stores.ROS2_JAZZY)
    for rtype in msgs.TYPES.values():
        if rtype.name.split("/")[1] == "msg" and store.hash_rihs01(rtype.name) != rtype.type_hash:
            raise RosbagError(f"rosbags' {rtype.name} hash differs from the wire's")
    core = BridgeCore(namespace=namespace)
    summary = RosbagSummary(out_dir)
    writer = Writer(out_dir, version=9, storage_plugin=StoragePlugin.MCAP)
    connections: dict[str, object] = {}
    writer.open()
    try:
        for ev in rec.events:
            if ev.payload is None:
                continue
            for out in _outgoing(core, ev.key, ev.payload, ev.log_ns):
                conn = connections.get(out.topic)
                if conn is None:
                    conn = writer.add_connection(out.topic, out.rtype.name, typestore=store)
                    connections[out.topic] = conn
                    summary.types[out.topic] = out.rtype.name
                writer.write(conn, ev.log_ns, out.payload)  # type: ignore[arg-type]
                summary.counts[out.topic] += 1
    finally:
        writer.close()
    summary.skipped.update(core.rejected.by_reason)
    if not summary.counts:
        shutil.rmtree(out_dir, ignore_errors=True)
        raise RosbagError(f"{rec.path}: no pose, leader or slot to export")
    return summary
