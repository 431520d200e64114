"""The MCAP writer of a recording (:class:`Recorder`): one JSON channel per bus key with its
JSON Schema, liveliness, rejected samples, the derived channels (tracking error, eqs 17-18, and
latency), the 3D scene and, with ``raw``, the msgpack payloads; its counters
(:class:`RecorderStats`).

Split out of ``formation/record/command.py`` (the ``formation record`` command,
:func:`start_recorder`
and :func:`run_info`; its docstring describes the file), which re-exports every public name.
"""

from __future__ import annotations

import base64
import json
import os
import socket
import threading
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any, Final

import zenoh
from mcap.writer import CompressionType, Writer

from bus_schemas import (
    VERSION,
    DecodeError,
    Message,
    PoseBatch,
    Status,
    Wheels,
    keys,
)
from bus_schemas.messages import Clock, Pose
from formation.outputs.bus_json import (
    DERIVED_PREFIX,
    LATENCY_SCHEMA,
    LIVELINESS_SCHEMA,
    REJECTED_SCHEMA,
    TRACKING_ERROR_SCHEMA,
    alive_kind,
    decode_sample,
    json_schema,
    jsonable,
    schema_name,
    tracking_error,
    unpack_map,
)
from formation.record.latency import LatencyTracker
from runtime.files import os_error_text
from runtime.tap import DEFAULT_QUEUE_LEN, BusItem, BusTap

RAW_PREFIX: Final = "/raw/"
REJECTED_TOPIC: Final = "/recorder/rejected"
METADATA_NAME: Final = "formation.recording"
STATS_METADATA_NAME: Final = "formation.recording.stats"
RUN_METADATA_NAME: Final = "formation.run"
LIBRARY: Final = "formation-record"

DEFAULT_CHUNK_BYTES: Final = 256 * 1024
"""MCAP chunk size: at most this much (uncompressed) is lost if the recorder is SIGKILLed."""


def _scenario_of(run: Mapping[str, str] | None) -> Any:
    """The scenario embedded in the run metadata (``scenario_toml``), for the 3D scene; None
    without one or if it does not load."""
    text = (run or {}).get("scenario_toml")
    if not text:
        return None
    try:
        import tomllib

        import scenario as scenario_mod

        return scenario_mod.parse(tomllib.loads(text))
    except (ValueError, TypeError):  # ScenarioError and TOMLDecodeError are ValueErrors
        return None


def _plan_mesh_of(scn: Any) -> Any:
    """The plan of the scenario's trajectory as a 3D mesh (issue 27), or None (no plan, or one
    that does not plan: the run could not have started with it)."""
    if scn is None:
        return None
    from formation.outputs.plan_view import plan_mesh, plan_view

    try:
        view = plan_view(scn.trajectory, timed=False)
    except ValueError:
        return None
    return None if view is None else plan_mesh(view)


@dataclass
class RecorderStats:
    """Counters of one recording."""

    messages: int = 0  # MCAP messages written, all channels
    samples: int = 0  # bus samples decoded and written as JSON
    rejected: int = 0  # samples that failed strict decoding
    unknown: int = 0  # samples on keys with no known message type
    deletes: int = 0  # DELETE samples on fleet keys (not written)
    liveliness: int = 0  # liveliness changes written
    dropped: int = 0  # samples lost because the tap's queue was full
    handler_errors: int = 0  # exceptions while writing (should stay 0)
    unwritten: int = 0  # observations not written because the file could not be (error)
    error: str | None = None
    """Why the file could not be written or finalized (a full or read-only disk), or None: the
    file then ends at its last complete write (no summary, no footer)."""
    per_key: dict[str, int] = field(default_factory=dict)


class Recorder:
    """Writes bus observations to an MCAP file (see the module docstring for the layout).

    ``write(item)`` must be called from one thread at a time (the :class:`BusTap` worker, or the
    caller's thread when fed directly); :meth:`attach` creates such a tap on a session.
    :meth:`close` finalizes the file; it is idempotent.
    """

    def __init__(
        self,
        path: str | Path,
        fleet: str = keys.DEFAULT_FLEET,
        *,
        raw: bool = False,
        derived: bool = True,
        chunk_bytes: int = DEFAULT_CHUNK_BYTES,
        compression: CompressionType = CompressionType.ZSTD,
        run: Mapping[str, str] | None = None,
        scene_hz: float | None = 5.0,
    ) -> None:
        self.path = Path(path)
        self.fleet = keys.check_fleet(fleet)
        self.raw = raw
        self.derived = derived
        self.stats = RecorderStats()
        self.latency = LatencyTracker()
        self._mono_anchor_ns = time.monotonic_ns()
        self._wall_anchor_ns = time.time_ns()
        self._tap: BusTap | None = None
        self._closed = False
        self._close_lock = threading.Lock()
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._file: IO[bytes] = open(self.path, "wb")  # noqa: SIM115 - closed in close()
        self._writer = Writer(self._file, chunk_size=chunk_bytes, compression=compression)
        self._writer.start(profile="", library=LIBRARY)
        self._schema_ids: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self._seq: dict[int, int] = {}
        self._scene: Any = None  # formation.live.scene.SceneModel when foxglove-sdk is installed
        self._scene_period_ns = 0
        self._next_scene_ns = 0
        if scene_hz is not None and scene_hz > 0:
            try:
                from formation.live.scene import SceneModel
            except ImportError:  # foxglove-sdk not installed: no 3D scene in the file
                pass
            else:
                scn = _scenario_of(run)
                self._scene = SceneModel(self.fleet, world=None if scn is None else scn.agent.world)
                self._scene.set_plan(_plan_mesh_of(scn))  # the planned path and corridor
                self._scene_period_ns = int(1e9 / scene_hz)
        self._writer.add_metadata(
            METADATA_NAME,
            {
                "fleet": self.fleet,
                "key_expr": keys.fleet_pattern(self.fleet),
                "bus_version": str(VERSION),
                "host": socket.gethostname(),
                "pid": str(os.getpid()),
                "wall_anchor_ns": str(self._wall_anchor_ns),
                "monotonic_anchor_ns": str(self._mono_anchor_ns),
                "log_time": "wall clock ns = wall_anchor_ns + (rx monotonic_ns - "
                "monotonic_anchor_ns)",
                "publish_time": "message t in ns (sim time in lockstep, publisher monotonic in "
                "realtime); log_time for liveliness and derived channels",
            },
        )
        if run:
            self._writer.add_metadata(RUN_METADATA_NAME, {str(k): str(v) for k, v in run.items()})

    # Time ---------------------------------------------------------------------------------

    def log_time_ns(self, rx_mono_ns: int) -> int:
        """Wall-clock ns of a monotonic receive time (one fixed offset, taken at start)."""
        return self._wall_anchor_ns + (rx_mono_ns - self._mono_anchor_ns)

    # Channels -----------------------------------------------------------------------------

    def _schema(self, name: str, schema: Mapping[str, Any]) -> int:
        sid = self._schema_ids.get(name)
        if sid is None:
            data = json.dumps(schema, separators=(",", ":")).encode()
            sid = self._schema_ids[name] = self._writer.register_schema(name, "jsonschema", data)
        return sid

    def _channel(
        self,
        topic: str,
        schema: tuple[str, Mapping[str, Any]] | None,
        encoding: str = "json",
        metadata: dict[str, str] | None = None,
    ) -> int:
        cid = self._channels.get(topic)
        if cid is None:
            sid = 0 if schema is None else self._schema(*schema)
            cid = self._writer.register_channel(topic, encoding, sid, metadata or {})
            self._channels[topic] = cid
        return cid

    def _write(
        self, cid: int, log_ns: int, data: bytes, publish_ns: int, seq: int | None = None
    ) -> None:
        if seq is None:
            seq = self._seq.get(cid, 0)
            self._seq[cid] = seq + 1
        self._writer.add_message(cid, log_ns, data, publish_ns, seq & 0xFFFFFFFF)
        self.stats.messages += 1

    def _write_json(self, cid: int, log_ns: int, obj: Any, publish_ns: int) -> None:
        data = json.dumps(obj, separators=(",", ":"), allow_nan=False).encode()
        self._write(cid, log_ns, data, publish_ns)

    # Items --------------------------------------------------------------------------------

    def write(self, item: BusItem) -> None:
        """Write one bus observation (a sample or a liveliness change). Once the file cannot
        be written (``OSError``: a full or read-only disk) nothing more is written: the
        observations are counted in ``stats.unwritten`` and ``stats.error`` says why."""
        if self._closed:
            return
        if self.stats.error is not None:
            self.stats.unwritten += 1
            return
        log_ns = self.log_time_ns(item.rx_ns)
        try:
            if item.kind in ("alive", "dead"):
                self._write_liveliness(item, log_ns)
            elif item.kind == "delete":
                self.stats.deletes += 1
            else:
                self._write_sample(item, log_ns)
        except OSError as exc:
            self.stats.error = os_error_text(exc)
            self.stats.unwritten += 1

    def _write_liveliness(self, item: BusItem, log_ns: int) -> None:
        kind, ident = alive_kind(item.key)
        cid = self._channel(
            "/" + item.key,
            (LIVELINESS_SCHEMA["title"], LIVELINESS_SCHEMA),
            metadata={"key": item.key},
        )
        body = {"alive": item.kind == "alive", "kind": kind, "id": ident, "key": item.key}
        self._write_json(cid, log_ns, body, log_ns)
        self.stats.liveliness += 1
        if self._scene is not None:
            self._scene.set_alive(item.key, item.kind == "alive")

    def _write_sample(self, item: BusItem, log_ns: int) -> None:
        key = item.key
        self.stats.per_key[key] = self.stats.per_key.get(key, 0) + 1
        if self.raw:
            raw_cid = self._channel(RAW_PREFIX + key, None, "msgpack", {"key": key})
            self._write(raw_cid, log_ns, item.payload, log_ns)
        decoded = decode_sample(key, item.payload)
        if decoded is None:
            self._write_unknown(item, log_ns)
            return
        if isinstance(decoded, DecodeError):
            self._write_rejected(item, log_ns, decoded)
            return
        cls, msg, obj = decoded
        cid = self._channel(
            "/" + key,
            (schema_name(cls), json_schema(cls)),
            metadata={"key": key, "bus_version": str(VERSION)},
        )
        publish_ns = round(msg.t * 1e9)
        seq = getattr(msg, "seq", None)
        data = json.dumps(jsonable(obj), separators=(",", ":"), allow_nan=False).encode()
        self._write(cid, log_ns, data, publish_ns, seq)
        self.stats.samples += 1
        self._derive(key, msg, item.rx_ns, log_ns)
        if self._scene is not None:
            self._scene.update(key, msg)
            if log_ns >= self._next_scene_ns:
                self._write_scene(log_ns)

    def _write_scene(self, log_ns: int) -> None:
        """The 3D scene (``/scene``, ``/tf``) as protobuf, like the live Foxglove server's."""
        from foxglove.messages import FrameTransforms, SceneUpdate

        from formation.live.scene import SCENE_TOPIC, TF_TOPIC

        self._next_scene_ns = log_ns + self._scene_period_ns
        for topic, cls, msg in (
            (SCENE_TOPIC, SceneUpdate, self._scene.scene(log_ns)),
            (TF_TOPIC, FrameTransforms, self._scene.transforms(log_ns)),
        ):
            cid = self._channels.get(topic)
            if cid is None:
                schema = cls.get_schema()
                sid = self._writer.register_schema(schema.name, schema.encoding, schema.data)
                self._schema_ids[schema.name] = sid
                cid = self._writer.register_channel(topic, "protobuf", sid, {})
                self._channels[topic] = cid
            self._write(cid, log_ns, msg.encode(), log_ns)

    def _write_unknown(self, item: BusItem, log_ns: int) -> None:
        self.stats.unknown += 1
        obj = unpack_map(item.payload)
        if isinstance(obj, DecodeError):
            self._write_rejected(item, log_ns, obj)
            return
        cid = self._channel("/" + item.key, None, metadata={"key": item.key})
        t = obj.get("t")
        publish_ns = log_ns
        if isinstance(t, float | int) and not isinstance(t, bool) and 0 <= t < 1e10:
            publish_ns = round(t * 1e9)
        self._write_json(cid, log_ns, jsonable(obj), publish_ns)

    def _write_rejected(self, item: BusItem, log_ns: int, err: DecodeError) -> None:
        self.stats.rejected += 1
        cid = self._channel(REJECTED_TOPIC, (REJECTED_SCHEMA["title"], REJECTED_SCHEMA))
        body = {
            "key": item.key,
            "reason": str(err.reason),
            "detail": err.detail,
            "field": err.field,
            "payload_b64": base64.b64encode(item.payload).decode("ascii"),
        }
        self._write_json(cid, log_ns, body, log_ns)

    def _derive(self, key: str, msg: Message, rx_ns: int, log_ns: int) -> None:
        if isinstance(msg, Clock):
            self.latency.on_clock()
            return
        if isinstance(msg, PoseBatch):
            self.latency.on_frame(msg.robots, msg.stamp, rx_ns / 1e9)
            return
        robot = keys.parse_robot_key(key)
        if robot is None:
            return
        rid = robot[1]
        rx_s = rx_ns / 1e9
        if isinstance(msg, Pose):
            self.latency.on_pose(rid, msg.t, rx_s)
        elif isinstance(msg, Wheels):
            lat = self.latency.on_wheels(rid, msg, rx_s)
            if lat is not None and self.derived:
                cid = self._channel(
                    f"{DERIVED_PREFIX}{rid}/latency", (LATENCY_SCHEMA["title"], LATENCY_SCHEMA)
                )
                self._write_json(
                    cid,
                    log_ns,
                    {
                        "t": lat.t,
                        "pose_t": lat.pose_t,
                        "rx_latency_ms": None
                        if lat.rx_latency_s is None
                        else lat.rx_latency_s * 1e3,
                        "pose_age_ms": lat.pose_age_s * 1e3,
                    },
                    log_ns,
                )
        elif isinstance(msg, Status) and self.derived:
            body = tracking_error(msg)
            if body is not None:
                cid = self._channel(
                    f"{DERIVED_PREFIX}{rid}/tracking_error",
                    (TRACKING_ERROR_SCHEMA["title"], TRACKING_ERROR_SCHEMA),
                )
                self._write_json(cid, log_ns, body, log_ns)

    # Session ------------------------------------------------------------------------------

    def attach(self, session: zenoh.Session, *, maxlen: int = DEFAULT_QUEUE_LEN) -> BusTap:
        """Subscribe to the fleet on ``session``; samples are written by a worker thread."""
        if self._tap is not None:
            raise RuntimeError("Recorder.attach: already attached")
        self._tap = BusTap(session, self.fleet, self.write, maxlen=maxlen, name="recorder")
        return self._tap

    def close(self) -> RecorderStats:
        """Stop the tap (if attached), write the statistics and finalize the file (idempotent)."""
        with self._close_lock:
            tap, self._tap = self._tap, None
            if tap is not None:
                tap.close()
                self.stats.dropped += tap.dropped
                self.stats.handler_errors += tap.errors
            if self._closed:
                return self.stats
            self._closed = True
            try:
                if self.stats.error is None:  # a writer that failed once cannot finish
                    self._finish()
            except OSError as exc:
                self.stats.error = os_error_text(exc)
            finally:
                try:
                    self._file.close()
                except OSError as exc:  # the last buffered bytes did not fit
                    self.stats.error = self.stats.error or os_error_text(exc)
            return self.stats

    def _finish(self) -> None:
        self._writer.add_metadata(
            STATS_METADATA_NAME,
            {
                "messages": str(self.stats.messages),
                "samples": str(self.stats.samples),
                "rejected": str(self.stats.rejected),
                "unknown": str(self.stats.unknown),
                "liveliness": str(self.stats.liveliness),
                "dropped": str(self.stats.dropped),
                "handler_errors": str(self.stats.handler_errors),
                "stopped_wall_ns": str(time.time_ns()),
            },
        )
        self._writer.finish()
        self._file.flush()
        os.fsync(self._file.fileno())  # a full disk shows here, not after the report
