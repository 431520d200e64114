"""A recording read back: an MCAP file of ``formation record`` (or ``formation up --record``)
parsed into bus samples and liveliness events (:func:`read_recording`), and replayed in order
into the same :class:`formation.record.collector.RunCollector` a live run uses (:func:`replay`), so
a
report computes its metrics exactly as ``formation up`` does."""

from __future__ import annotations

import json
import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from mcap.records import Channel, Footer, Message, Metadata, Schema
from mcap.stream_reader import StreamReader

import scenario as scenario_mod
from bus_schemas import (
    Assignment,
    Clock,
    DecodeError,
    Pose,
    PoseBatch,
    Truth,
    TruthBatch,
    Wheels,
    decode,
    encode,
    from_map,
    keys,
    message_type_for_key,
)
from formation.record.collector import RunCollector
from formation.record.command import (
    METADATA_NAME,
    RAW_PREFIX,
    RUN_METADATA_NAME,
    STATS_METADATA_NAME,
)
from formation.record.latency import LatencySample, LatencyTracker
from robot_agent.core.params import RobotGeometry


class ReportError(ValueError):
    """The file is not a usable recording (not MCAP, no fleet traffic, no truth)."""


# --------------------------------------------------------------------------------------------
# Reading a recording
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Event:
    """One observation, in the recorder's arrival order: a sample or a liveliness change."""

    log_ns: int
    key: str
    payload: bytes | None = None  # msgpack bytes of a sample
    alive: bool | None = None  # liveliness change


@dataclass
class Recording:
    """The bus traffic of one MCAP recording."""

    path: Path
    info: dict[str, str]  # formation.recording metadata
    run: dict[str, str]  # formation.run metadata (empty if none)
    stats: dict[str, str]  # formation.recording.stats (empty if the recorder was killed)
    events: list[Event]
    topics: dict[str, int]  # messages per topic
    complete: bool  # the file has its footer
    source: str  # "raw" (msgpack payloads) or "json" (re-encoded from the JSON channels)
    bad_json: int = 0  # JSON messages that did not validate (should be 0)

    @property
    def fleet(self) -> str | None:
        """The fleet recorded (from the metadata, else from the keys)."""
        fleet = self.info.get("fleet")
        if fleet:
            return fleet
        for ev in self.events:
            info = keys.parse_key(ev.key)
            if info is not None:
                return info.fleet
        return None

    def mono_s(self, log_ns: int) -> float | None:
        """A log time as the recorder host's ``time.monotonic()`` (None without anchors)."""
        try:
            wall0 = int(self.info["wall_anchor_ns"])
            mono0 = int(self.info["monotonic_anchor_ns"])
        except (KeyError, ValueError):
            return None
        return (log_ns - wall0 + mono0) / 1e9


def read_recording(path: str | Path) -> Recording:  # noqa: PLR0915 (one pass over the MCAP, one branch per channel)
    """Read an MCAP recording sequentially (works on a file without footer).

    Samples come from the ``/raw/`` msgpack channels when the file has them, else from the JSON
    channels, re-encoded with ``bus_schemas.encode`` (lossless for every known field).
    Raises ``ReportError`` if the file is not MCAP, ``OSError`` if it cannot be read.
    """
    path = Path(path)
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    metadata: dict[str, dict[str, str]] = {}
    topics: dict[str, int] = {}
    raw_msgs: list[tuple[int, str, bytes]] = []
    json_msgs: list[tuple[int, str, bytes, str]] = []  # log_ns, topic, data, schema name
    complete = False
    with open(path, "rb") as f:
        try:
            for record in StreamReader(f, skip_magic=False).records:
                if isinstance(record, Message):
                    ch = channels.get(record.channel_id)
                    if ch is None:
                        continue
                    topics[ch.topic] = topics.get(ch.topic, 0) + 1
                    if ch.message_encoding == "msgpack" and ch.topic.startswith(RAW_PREFIX):
                        raw_msgs.append((record.log_time, ch.topic[len(RAW_PREFIX) :], record.data))
                    elif ch.message_encoding == "json":
                        sch = schemas.get(ch.schema_id)
                        name = sch.name if sch is not None else ""
                        json_msgs.append((record.log_time, ch.topic, record.data, name))
                elif isinstance(record, Channel):
                    channels.setdefault(record.id, record)
                elif isinstance(record, Schema):
                    schemas.setdefault(record.id, record)
                elif isinstance(record, Metadata):
                    metadata[record.name] = dict(record.metadata)
                elif isinstance(record, Footer):
                    complete = True
        except Exception as exc:  # McapError, EOFError, struct.error... on a torn or alien file
            if not channels and not metadata:
                raise ReportError(f"{path}: not an MCAP recording ({exc})") from exc
            # else: cut short (recorder killed): keep what was read

    events: list[Event] = []
    bad = 0
    use_raw = bool(raw_msgs)
    for log_ns, key, data in raw_msgs:
        events.append(Event(log_ns, key, payload=data))
    for log_ns, topic, data, schema_name in json_msgs:
        key = topic[1:]
        if schema_name == "formation.Liveliness":
            try:
                body = json.loads(data)
                events.append(Event(log_ns, key, alive=bool(body["alive"])))
            except (ValueError, KeyError, TypeError):
                bad += 1
            continue
        if use_raw:
            continue
        cls = message_type_for_key(key)
        if cls is None:
            continue  # derived, rejected, unknown keys: not bus messages the collector reads
        try:
            obj = json.loads(data)
        except ValueError:
            bad += 1
            continue
        msg = from_map(obj, cls) if isinstance(obj, dict) else None
        if msg is None or isinstance(msg, DecodeError):
            bad += 1
            continue
        events.append(Event(log_ns, key, payload=encode(msg)))
    # Arrival order: the recorder wrote in arrival order with non-decreasing log times; a stable
    # sort keeps file order among equal times and interleaves the raw and liveliness channels.
    events.sort(key=lambda e: e.log_ns)
    return Recording(
        path=path,
        info=metadata.get(METADATA_NAME, {}),
        run=metadata.get(RUN_METADATA_NAME, {}),
        stats=metadata.get(STATS_METADATA_NAME, {}),
        events=events,
        topics=topics,
        complete=complete,
        source="raw" if use_raw else "json",
        bad_json=bad,
    )


# --------------------------------------------------------------------------------------------
# Replaying it into the collector
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class LivenessChange:
    """A liveliness change, placed on the run's bus clock."""

    key: str
    alive: bool
    bus_t: float | None  # sim time (lockstep) or publisher monotonic (realtime); None: before
    leader: str | None  # robot holding slot 0 (latest assignment) when it happened
    alive_after: frozenset[str]  # liveliness keys present right after it


@dataclass
class Replay:
    """What feeding a recording to a collector produced besides the collector's own state."""

    lockstep: bool
    changes: list[LivenessChange] = field(default_factory=list)
    latency: list[LatencySample] = field(default_factory=list)
    truth_t: dict[float, set[str]] = field(default_factory=dict)  # bus t -> robots with truth


def natural_order(rid: str) -> tuple[str, int, str]:
    head = rid.rstrip("0123456789")
    tail = rid[len(head) :]
    return (head, int(tail) if tail else -1, rid)


def _dt_from_clock(rec: Recording) -> float | None:
    """The lockstep tick from the clock messages (``t / tick``), or None without them."""
    ratios: list[float] = []
    for ev in rec.events:
        if ev.payload is None or not ev.key.endswith("/" + keys.CLOCK):
            continue
        clock = decode(ev.payload, Clock)
        if not isinstance(clock, DecodeError) and clock.tick > 0:
            ratios.append(clock.t / clock.tick)
            if len(ratios) >= 50:
                break
    return float(np.median(ratios)) if ratios else None


def has_clock(rec: Recording, fleet: str) -> bool:
    clock_key = keys.clock_key(fleet)
    return any(ev.key == clock_key for ev in rec.events)


def scenario_of(rec: Recording, override: str | None = None) -> scenario_mod.Scenario | None:
    """The run's scenario: ``override`` (name or file), else the one embedded by the recorder."""
    if override is not None:
        return scenario_mod.load(override)
    text = rec.run.get("scenario_toml")
    if text:
        try:
            data = tomllib.loads(text)
        except tomllib.TOMLDecodeError as exc:
            raise ReportError(f"embedded scenario is not valid TOML: {exc}") from exc
        return scenario_mod.parse(data, source=f"{rec.path} (embedded)")
    return None


def make_collector(
    rec: Recording, fleet: str, scn: scenario_mod.Scenario | None, lockstep: bool
) -> RunCollector:
    """The collector ``formation up`` would have built for this run."""
    if scn is not None:
        return RunCollector.for_scenario(scn, fleet=fleet, lockstep=lockstep)
    robots: set[str] = set()
    truths_key = keys.truths_key(fleet)
    for ev in rec.events:
        parsed = keys.parse_robot_key(ev.key)
        if parsed is not None and parsed[2] == keys.TRUTH and parsed[0] == fleet:
            robots.add(parsed[1])
        elif ev.key == truths_key and ev.payload is not None:  # batched (lockstep, --batch)
            batch = decode(ev.payload, TruthBatch)
            if not isinstance(batch, DecodeError):
                robots.update(batch.robots)
    if not robots:
        raise ReportError(f"{rec.path}: no truth of fleet {fleet!r} in the recording")
    dt = _dt_from_clock(rec) if lockstep else None
    if lockstep and dt is None:
        raise ReportError(f"{rec.path}: lockstep run but no clock tick > 0 to get dt from")
    geom = RobotGeometry()
    return RunCollector(
        sorted(robots, key=natural_order),
        slot_ids=None,
        fleet=fleet,
        dt_s=dt,
        ref_offset_m=geom.ref_offset_m,
        body_radius_m=geom.body_radius_m,
    )


def replay(rec: Recording, collector: RunCollector, lockstep: bool) -> Replay:  # noqa: PLR0915 (one branch per event kind, in arrival order)
    """Feed every event to ``collector`` in arrival order; track liveliness, leader, latency."""
    out = Replay(lockstep=lockstep)
    fleet = collector.fleet
    clock_key = keys.clock_key(fleet)
    assignment_key = keys.assignment_key(fleet)
    truths_key = keys.truths_key(fleet)
    poses_key = keys.poses_key(fleet)
    tracker = LatencyTracker()
    if lockstep:
        tracker.on_clock()
    alive: set[str] = set()
    leader: str | None = None
    last_clock_t: float | None = None
    last_truth: tuple[float, int] | None = None  # (bus t, log_ns)
    for ev in rec.events:
        if ev.alive is not None:
            collector.feed_alive(ev.key, ev.alive)
            if ev.alive:
                alive.add(ev.key)
            else:
                alive.discard(ev.key)
            bus_t: float | None
            if lockstep:
                bus_t = last_clock_t
            elif last_truth is not None:
                bus_t = last_truth[0] + (ev.log_ns - last_truth[1]) / 1e9
            else:
                bus_t = None
            out.changes.append(LivenessChange(ev.key, ev.alive, bus_t, leader, frozenset(alive)))
            continue
        if ev.payload is None:
            continue
        collector.feed(ev.key, ev.payload)
        parsed = keys.parse_robot_key(ev.key)
        if parsed is not None:
            if parsed[0] != fleet:
                continue
            rid, leaf = parsed[1], parsed[2]
            rx_s = rec.mono_s(ev.log_ns)
            rx = ev.log_ns / 1e9 if rx_s is None else rx_s
            if leaf == keys.TRUTH:
                truth = decode(ev.payload, Truth)
                if not isinstance(truth, DecodeError):
                    out.truth_t.setdefault(truth.t, set()).add(rid)
                    if last_truth is None or truth.t >= last_truth[0]:
                        last_truth = (truth.t, ev.log_ns)
            elif leaf == keys.POSE:
                pose = decode(ev.payload, Pose)
                if not isinstance(pose, DecodeError):
                    tracker.on_pose(rid, pose.t, rx)
            elif leaf == keys.WHEELS:
                wheels = decode(ev.payload, Wheels)
                if not isinstance(wheels, DecodeError):
                    sample = tracker.on_wheels(rid, wheels, rx)
                    if sample is not None:
                        if rx_s is None and not lockstep:  # no anchors: the age is meaningless
                            sample = LatencySample(
                                sample.robot, sample.t, sample.pose_t, sample.rx_latency_s, math.nan
                            )
                        out.latency.append(sample)
        elif ev.key == clock_key:
            clock = decode(ev.payload, Clock)
            if not isinstance(clock, DecodeError):
                last_clock_t = clock.t
        elif ev.key == assignment_key:
            assignment = decode(ev.payload, Assignment)
            if not isinstance(assignment, DecodeError):
                leader = assignment.leader
        elif ev.key == truths_key:  # the batched truth (lockstep, --batch): as each robot's
            tb = decode(ev.payload, TruthBatch)
            if not isinstance(tb, DecodeError):
                out.truth_t.setdefault(tb.stamp, set()).update(tb.robots)
                if last_truth is None or tb.stamp >= last_truth[0]:
                    last_truth = (tb.stamp, ev.log_ns)
        elif lockstep and ev.key == poses_key:  # (the tracker's poses in lockstep)
            pb = decode(ev.payload, PoseBatch)
            if not isinstance(pb, DecodeError):
                rx_s = rec.mono_s(ev.log_ns)
                tracker.on_frame(pb.robots, pb.stamp, ev.log_ns / 1e9 if rx_s is None else rx_s)
    return out
