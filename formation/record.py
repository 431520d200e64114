"""``formation record``: record every key of a fleet (and its liveliness changes) to MCAP.

Usage::

    formation record --out run.mcap [--fleet demo] [--duration S] [--raw] [--no-derived]
                     [--endpoint tcp/127.0.0.1:7447 ...]

Prints one line ``recording formation/<fleet>/** to <file>`` once subscribed, runs until
SIGINT/SIGTERM or ``--duration`` seconds, finalizes the file (summary, statistics, index) and
exits 0. ``formation up --record FILE`` calls :func:`start_recorder` for the same result.

What the file holds (docs/observability.md has the full channel list)
---------------------------------------------------------------------
* One channel per bus key, topic ``/<key>`` (``/formation/demo/robot/r1/pose``), message encoding
  ``json``, schema encoding ``jsonschema``, schema name ``formation.<Type>`` (``formation.Pose``).
  The JSON Schemas are generated from the declarative message tables of ``bus_schemas``
  (:func:`json_schema`), so the bus contract stays the single source. A message is written as
  the map that was on the wire (unknown extra fields kept) after the strict ``bus_schemas``
  validation passed; one that fails it goes to ``/recorder/rejected`` with the reason and the
  payload in base64.
* Liveliness: one channel per token key (``/formation/demo/alive/robot/r1``), schema
  ``formation.Liveliness``, one message ``{alive: true|false, ...}`` per appearance/disappearance
  (the tokens already alive when recording starts are written as ``alive: true`` at once).
* Derived channels Foxglove can plot without code: ``/derived/robot/<id>/tracking_error``
  (``norm_m`` = hypot(ex, ey) of the agent's status, eqs 17-18) and
  ``/derived/robot/<id>/latency`` (pose-to-wheels latency, see :class:`LatencyTracker`).
* ``/scene`` (``foxglove.SceneUpdate``) and ``/tf`` (``foxglove.FrameTransforms``), protobuf, at
  5 Hz of receive time: the 3D view of ``formation.live`` (robots, slots, leader-follower links),
  when foxglove-sdk is installed.
* With ``--raw``: the exact payload bytes as well, topic ``/raw/<key>``, encoding ``msgpack``
  (no schema; Foxglove cannot decode these, ``formation report`` prefers them when present).

Times: ``log_time`` is the receive time at the recorder, in ns of the wall clock (derived from
``time.monotonic_ns()`` plus one fixed offset taken at start, so differences between log times
are exact monotonic differences and the file shows real dates in Foxglove). ``publish_time`` is
the message's ``t`` in ns (sim time in lockstep, the publisher's monotonic clock in realtime);
``log_time`` for liveliness and derived records. The metadata record ``formation.recording``
holds the two clock anchors, so ``log_time`` can be mapped back to this host's monotonic clock.

Threading: Zenoh calls the subscriber callbacks on its own threads; they only copy the sample
into a bounded queue (:class:`BusTap`). One writer thread decodes and writes, so the MCAP writer
is only ever used by that thread. A full queue drops the sample and counts it.
"""

from __future__ import annotations

import argparse
import asyncio
import base64
import contextlib
import json
import math
import os
import queue
import socket
import sys
import threading
import time
from collections import OrderedDict
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any, Final, Literal, NamedTuple

import msgpack
import zenoh
from mcap.writer import CompressionType, Writer

from bus_schemas import (
    MAX_PAYLOAD_BYTES,
    VERSION,
    DecodeError,
    Message,
    Status,
    Wheels,
    from_map,
    keys,
    message_type_for_key,
    spec_of,
)
from bus_schemas import transport as tp
from bus_schemas.messages import Clock, Pose
from bus_schemas.spec import FLOAT64_MAX, UINT64_MAX, FieldSpec, Kind

READY_PREFIX: Final = "recording "
"""Start of the line ``formation record`` prints on stdout once it is subscribed."""

SCHEMA_PREFIX: Final = "formation."
RAW_PREFIX: Final = "/raw/"
DERIVED_PREFIX: Final = "/derived/robot/"
REJECTED_TOPIC: Final = "/recorder/rejected"
METADATA_NAME: Final = "formation.recording"
STATS_METADATA_NAME: Final = "formation.recording.stats"
RUN_METADATA_NAME: Final = "formation.run"
LIBRARY: Final = "formation-record"

DEFAULT_QUEUE_LEN: Final = 200_000
"""Samples the tap buffers between Zenoh threads and the worker (~1 min of a 3-robot fleet)."""
DEFAULT_CHUNK_BYTES: Final = 256 * 1024
"""MCAP chunk size: at most this much (uncompressed) is lost if the recorder is SIGKILLed."""


# --------------------------------------------------------------------------------------------
# JSON Schemas generated from the bus_schemas message tables
# --------------------------------------------------------------------------------------------


def _field_schema(fs: FieldSpec) -> dict[str, Any]:
    """JSON Schema of one field (without nil); bounds are the wire bounds of the spec."""
    out: dict[str, Any]
    if fs.kind in (Kind.FLOAT, Kind.INT):
        out = {"type": "number" if fs.kind is Kind.FLOAT else "integer"}
        if fs.lo is not None and abs(fs.lo) < FLOAT64_MAX and fs.lo > -(2**63):
            out["minimum"] = fs.lo
        if fs.hi is not None and abs(fs.hi) < FLOAT64_MAX and fs.hi < UINT64_MAX:
            out["maximum"] = fs.hi
    elif fs.kind is Kind.BOOL:
        out = {"type": "boolean"}
    elif fs.kind is Kind.STR:
        out = {"type": "string"}
        if fs.max_len is not None:
            out["maxLength"] = fs.max_len
        if fs.pattern is not None:
            out["pattern"] = f"^{fs.pattern}$"
    elif fs.kind is Kind.ENUM:
        out = {"type": "string", "enum": list(fs.choices)}
    elif fs.kind is Kind.FLOAT_LIST:
        item: dict[str, Any] = {"type": "number"}
        if fs.lo is not None and abs(fs.lo) < FLOAT64_MAX:
            item["minimum"] = fs.lo
        if fs.hi is not None and abs(fs.hi) < FLOAT64_MAX:
            item["maximum"] = fs.hi
        out = {"type": "array", "items": item, "maxItems": fs.max_len}
    elif fs.kind is Kind.INT_LIST:
        int_item: dict[str, Any] = {"type": "integer"}
        if fs.lo is not None and fs.lo > -(2**63):
            int_item["minimum"] = fs.lo
        if fs.hi is not None and fs.hi < UINT64_MAX:
            int_item["maximum"] = fs.hi
        out = {"type": "array", "items": int_item, "maxItems": fs.max_len}
    elif fs.kind is Kind.STR_LIST:
        out = {
            "type": "array",
            "items": {"type": "string", "pattern": f"^{fs.pattern}$"},
            "maxItems": fs.max_len,
        }
    elif fs.kind is Kind.STR_INT_MAP:
        value: dict[str, Any] = {"type": "integer"}
        if fs.value_lo is not None:
            value["minimum"] = fs.value_lo
        if fs.value_hi is not None and fs.value_hi < UINT64_MAX:
            value["maximum"] = fs.value_hi
        out = {
            "type": "object",
            "additionalProperties": value,
            "propertyNames": {"pattern": f"^{fs.pattern}$"},
            "maxProperties": fs.max_len,
        }
    else:  # pragma: no cover - every Kind is handled above
        raise TypeError(f"unhandled field kind {fs.kind}")
    text = fs.description + (f" [{fs.unit}]" if fs.unit and fs.unit != "1" else "")
    out["description"] = text
    return out


def json_schema(cls: type[Message]) -> dict[str, Any]:
    """The JSON Schema (draft 2020-12) of a bus message type, from its ``bus_schemas`` table.

    Required fields are the ones the codec requires; ``nil allowed`` fields accept ``null``;
    unknown extra properties are allowed (a newer publisher may add fields).
    """
    spec = spec_of(cls)
    props: dict[str, Any] = {}
    required: list[str] = []
    for f in spec.fields:
        prop = _field_schema(f.spec)
        if f.spec.nullable:
            prop["type"] = [prop["type"], "null"]
        props[f.name] = prop
        if not f.optional:
            required.append(f.name)
    return {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "title": schema_name(cls),
        "description": spec.summary + f"\n\nBus key: {spec.key} (bus contract v{VERSION}).",
        "type": "object",
        "properties": props,
        "required": required,
        "additionalProperties": True,
    }


def schema_name(cls: type[Message]) -> str:
    """``formation.<Type>``, e.g. ``formation.Pose``: the MCAP / Foxglove schema name."""
    return SCHEMA_PREFIX + cls.__name__


def _object_schema(title: str, description: str, props: Mapping[str, Any]) -> dict[str, Any]:
    return {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "title": title,
        "description": description,
        "type": "object",
        "properties": dict(props),
        "required": list(props),
    }


LIVELINESS_SCHEMA: Final = _object_schema(
    "formation.Liveliness",
    "A liveliness token appeared (alive) or disappeared (process ended, crashed or its link "
    "lease expired).",
    {
        "alive": {"type": "boolean", "description": "true: token present; false: gone"},
        "kind": {"type": "string", "enum": ["robot", "coordinator", "plant", "other"]},
        "id": {"type": ["string", "null"], "description": "robot id or coordinator name"},
        "key": {"type": "string", "description": "the token's key expression"},
    },
)
TRACKING_ERROR_SCHEMA: Final = _object_schema(
    "formation.TrackingError",
    "Tracking error of one robot as its agent reports it (status ex, ey: eqs 17-18).",
    {
        "t": {"type": "number", "description": "status t [s]"},
        "ex": {"type": "number", "description": "setpoint x - reference point x [m]"},
        "ey": {"type": "number", "description": "setpoint y - reference point y [m]"},
        "norm_m": {"type": "number", "description": "hypot(ex, ey) [m]"},
        "slot": {"type": "integer", "description": "assigned slot, -1 if none"},
        "mode": {"type": "string", "description": "firmware mode"},
    },
)
LATENCY_SCHEMA: Final = _object_schema(
    "formation.Latency",
    "Latency of one wheel command: rx_latency_ms = recorder receive time of the wheels minus "
    "recorder receive time of the pose it was computed from (one clock); pose_age_ms = wheels "
    "receive time minus the pose's capture time pose_t (realtime, same host) or wheels t minus "
    "pose_t (lockstep, sim time).",
    {
        "t": {"type": "number", "description": "wheels t [s]"},
        "pose_t": {"type": "number", "description": "t of the pose used [s]"},
        "rx_latency_ms": {"type": ["number", "null"], "description": "[ms], null if unseen"},
        "pose_age_ms": {"type": ["number", "null"], "description": "[ms]"},
    },
)
REJECTED_SCHEMA: Final = _object_schema(
    "formation.Rejected",
    "A sample on a fleet key that failed the strict bus_schemas decode.",
    {
        "key": {"type": "string"},
        "reason": {"type": "string"},
        "detail": {"type": "string"},
        "field": {"type": ["string", "null"]},
        "payload_b64": {"type": "string", "description": "the payload bytes, base64"},
    },
)


# --------------------------------------------------------------------------------------------
# Decoding one sample
# --------------------------------------------------------------------------------------------


class Decoded(NamedTuple):
    """A sample that passed strict decoding: its type, the typed message and the wire map."""

    cls: type[Message]
    msg: Message
    obj: dict[str, Any]


def jsonable(value: Any) -> Any:
    """A msgpack-decoded value as JSON-ready data (bytes -> base64 str, tuples -> lists)."""
    if isinstance(value, dict):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [jsonable(v) for v in value]
    if isinstance(value, bytes | bytearray | memoryview):
        return base64.b64encode(bytes(value)).decode("ascii")
    if isinstance(value, float) and not math.isfinite(value):
        return None  # only in unknown extra fields: known fields reject non-finite values
    if isinstance(value, msgpack.ExtType):
        return {"ext": value.code, "data": base64.b64encode(value.data).decode("ascii")}
    return value


def decode_sample(key: str, payload: bytes) -> Decoded | DecodeError | None:
    """Strictly decode a sample of ``key``; None if the key carries no known message type.

    Unlike ``bus_schemas.decode`` this also returns the wire map (extra fields included), which
    is what the recorder writes as JSON.
    """
    cls = message_type_for_key(key)
    if cls is None:
        return None
    obj = unpack_map(payload)
    if isinstance(obj, DecodeError):
        return obj
    msg = from_map(obj, cls)
    if isinstance(msg, DecodeError):
        return msg
    return Decoded(cls, msg, obj)


def unpack_map(payload: bytes) -> dict[str, Any] | DecodeError:
    """Unpack one msgpack map (size-checked like ``bus_schemas.decode``) or say why not."""
    from bus_schemas import Reason

    if len(payload) > MAX_PAYLOAD_BYTES:
        return DecodeError(Reason.TOO_LARGE, f"{len(payload)} bytes", None)
    try:
        obj = msgpack.unpackb(payload, use_list=False, strict_map_key=False)
    except Exception as exc:  # any msgpack failure
        return DecodeError(Reason.MALFORMED, f"{type(exc).__name__}: {exc}"[:200], None)
    if type(obj) is not dict:
        return DecodeError(Reason.NOT_A_MAP, f"top-level object is {type(obj).__name__}", None)
    return obj


def tracking_error(msg: Status) -> dict[str, Any] | None:
    """The ``formation.TrackingError`` record of a status (None without ex, ey)."""
    if msg.ex is None or msg.ey is None:
        return None
    return {
        "t": msg.t,
        "ex": msg.ex,
        "ey": msg.ey,
        "norm_m": math.hypot(msg.ex, msg.ey),
        "slot": -1 if msg.slot is None else msg.slot,
        "mode": msg.mode,
    }


def alive_kind(key: str) -> tuple[str, str | None]:
    """``(kind, id)`` of a liveliness key: robot/coordinator/plant (or ``other``, None)."""
    parsed = keys.parse_alive_key(key)
    if parsed is None:
        return "other", None
    return parsed[1], parsed[2]


# --------------------------------------------------------------------------------------------
# Latency of wheel commands
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class LatencySample:
    """One wheel command's latency (see :data:`LATENCY_SCHEMA`); times in seconds."""

    robot: str
    t: float
    pose_t: float
    rx_latency_s: float | None
    pose_age_s: float


class LatencyTracker:
    """Matches each robot's wheel command to the pose it was computed from (``pose_t``).

    Feed every pose and wheels sample with its receive time (seconds, one monotonic clock);
    :meth:`on_wheels` returns the command's latency. Remembers the last ``window`` poses per
    robot (a command uses a pose of the last few frames). Lockstep is detected from the
    ``clock`` key: then ``pose_age_s`` is sim time (wheels ``t`` - ``pose_t``), otherwise the
    wheels receive time minus ``pose_t`` (meaningful when the publisher's monotonic clock is this
    host's, i.e. a local run).
    """

    def __init__(self, window: int = 64) -> None:
        self.window = window
        self.lockstep = False
        self._pose_rx: dict[str, OrderedDict[float, float]] = {}

    def on_clock(self) -> None:
        """A ``clock`` message was seen: the run is lockstep."""
        self.lockstep = True

    def on_pose(self, robot: str, t: float, rx_s: float) -> None:
        """A pose of ``robot`` with ``t`` arrived at ``rx_s``."""
        seen = self._pose_rx.get(robot)
        if seen is None:
            seen = self._pose_rx[robot] = OrderedDict()
        seen.setdefault(t, rx_s)  # the first arrival counts
        while len(seen) > self.window:
            seen.popitem(last=False)

    def on_wheels(self, robot: str, msg: Wheels, rx_s: float) -> LatencySample | None:
        """The latency of a wheel command, or None if it used no pose."""
        if msg.pose_t is None:
            return None
        seen = self._pose_rx.get(robot)
        pose_rx = None if seen is None else seen.get(msg.pose_t)
        age = (msg.t - msg.pose_t) if self.lockstep else (rx_s - msg.pose_t)
        return LatencySample(
            robot=robot,
            t=msg.t,
            pose_t=msg.pose_t,
            rx_latency_s=None if pose_rx is None else rx_s - pose_rx,
            pose_age_s=age,
        )


# --------------------------------------------------------------------------------------------
# The tap: Zenoh threads -> one worker thread
# --------------------------------------------------------------------------------------------

ItemKind = Literal["put", "delete", "alive", "dead"]


class BusItem(NamedTuple):
    """One observation of the bus: a sample (put/delete) or a liveliness change (alive/dead)."""

    kind: ItemKind
    key: str
    payload: bytes
    rx_ns: int  # time.monotonic_ns() on the Zenoh thread


_STOP: Final = BusItem("delete", "", b"", -1)


class BusTap:
    """Subscribes to every key and liveliness token of a fleet; hands them to one worker thread.

    ``handler(item)`` runs on the worker thread for every :class:`BusItem` in arrival order;
    ``tick(now_ns)`` (optional) runs on it at least every ``tick_s`` seconds. The Zenoh callbacks
    only copy the sample and enqueue it (never block: a full queue drops and counts). Handler
    exceptions are counted in ``errors`` (the first one is printed to stderr) and never stop the
    worker. :meth:`close` undeclares the subscribers, lets the worker finish the queue and joins
    it; it is idempotent.
    """

    def __init__(
        self,
        session: zenoh.Session,
        fleet: str,
        handler: Callable[[BusItem], None],
        *,
        tick: Callable[[int], None] | None = None,
        tick_s: float = 0.1,
        maxlen: int = DEFAULT_QUEUE_LEN,
        name: str = "bus-tap",
    ) -> None:
        self.fleet = keys.check_fleet(fleet)
        self.received = 0
        self.dropped = 0
        self.errors = 0
        self._handler = handler
        self._tick = tick
        self._tick_s = tick_s
        self._queue: queue.Queue[BusItem] = queue.Queue(maxsize=maxlen)
        self._closed = False
        self._abandon = False
        self._lock = threading.Lock()
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()
        self._subs: list[Any] = []
        try:
            self._subs.append(
                session.declare_subscriber(keys.fleet_pattern(fleet), self._on_sample)
            )
            self._subs.append(
                session.liveliness().declare_subscriber(
                    keys.alive_pattern(fleet), self._on_liveliness, history=True
                )
            )
        except BaseException:
            self.close()
            raise

    # Zenoh threads ------------------------------------------------------------------------

    def _push(self, item: BusItem) -> None:
        if self._closed:
            return
        try:
            self._queue.put_nowait(item)
        except queue.Full:
            with self._lock:
                self.dropped += 1
            return
        with self._lock:
            self.received += 1

    def _on_sample(self, sample: zenoh.Sample) -> None:
        kind: ItemKind = "delete" if sample.kind == zenoh.SampleKind.DELETE else "put"
        self._push(
            BusItem(kind, str(sample.key_expr), sample.payload.to_bytes(), time.monotonic_ns())
        )

    def _on_liveliness(self, sample: zenoh.Sample) -> None:
        kind: ItemKind = "alive" if sample.kind == zenoh.SampleKind.PUT else "dead"
        self._push(BusItem(kind, str(sample.key_expr), b"", time.monotonic_ns()))

    # Local feeding (tests, replays) -------------------------------------------------------

    def feed(self, item: BusItem) -> None:
        """Enqueue an item as if it came from Zenoh (thread-safe)."""
        self._push(item)

    # Worker -------------------------------------------------------------------------------

    def _run(self) -> None:
        next_tick = time.monotonic_ns() + int(self._tick_s * 1e9)
        while True:
            timeout = max(0.0, (next_tick - time.monotonic_ns()) / 1e9)
            try:
                item: BusItem | None = self._queue.get(timeout=timeout)
            except queue.Empty:
                item = None
            if item is _STOP:
                break
            if self._abandon:
                if item is not None:
                    with self._lock:
                        self.dropped += 1
                break
            if item is not None:
                self._call(self._handler, item)
            now = time.monotonic_ns()
            if now >= next_tick:
                if self._tick is not None:
                    self._call(self._tick, now)
                next_tick = now + int(self._tick_s * 1e9)

    def _call(self, fn: Callable[[Any], None], arg: Any) -> None:
        try:
            fn(arg)
        except Exception as exc:  # a bad sample or a bug must not kill the recorder
            self.errors += 1
            if self.errors == 1:
                print(f"{self._thread.name}: {type(exc).__name__}: {exc}", file=sys.stderr)

    def close(self, timeout_s: float = 5.0) -> None:
        """Undeclare the subscribers, process what is queued, stop the worker (idempotent).

        If the backlog takes longer than ``timeout_s`` seconds, the rest is dropped (counted in
        ``dropped``); when this returns, the worker has stopped and the handler is not running.
        """
        for sub in self._subs:
            # ZError: the session was closed first, the subscriber is gone already.
            with contextlib.suppress(zenoh.ZError):
                sub.undeclare()
        self._subs.clear()
        if self._closed:
            return
        self._closed = True
        self._queue.put(_STOP)  # blocks only if full; the worker is draining it
        self._thread.join(timeout=timeout_s)
        if self._thread.is_alive():  # a huge backlog: give up on it, keep what was handled
            self._abandon = True
            self._thread.join()
            while True:
                try:
                    left = self._queue.get_nowait()
                except queue.Empty:
                    break
                if left is not _STOP:
                    with self._lock:
                        self.dropped += 1


# --------------------------------------------------------------------------------------------
# The recorder
# --------------------------------------------------------------------------------------------


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
    per_key: dict[str, int] = field(default_factory=dict)


def run_info(
    scenario: str | None = None,
    *,
    lockstep: bool | None = None,
    settle_s: float | None = None,
    **extra: object,
) -> dict[str, str]:
    """What a recording should know about its run, for ``formation report``.

    ``scenario`` is a built-in name or a TOML file: its text is embedded (``scenario_toml``), so
    the report rebuilds the run's robots, slots, geometry and settling band without the file.
    ``lockstep`` and ``settle_s`` are what the live run used; ``extra`` (seed, duration_s, ...)
    is stored as text. Raises ``ScenarioError`` if the scenario cannot be read.
    """
    out: dict[str, str] = {}
    if scenario is not None:
        from formation import scenario as scenario_mod

        path = scenario_mod.resolve(scenario)
        out["scenario"] = scenario
        out["scenario_toml"] = path.read_text()
    if lockstep is not None:
        out["lockstep"] = "true" if lockstep else "false"
    if settle_s is not None:
        out["settle_s"] = repr(float(settle_s))
    for name, value in extra.items():
        out[name] = str(value)
    return out


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
        self._scene: Any = None  # formation.live.SceneModel when foxglove-sdk is installed
        self._scene_period_ns = 0
        self._next_scene_ns = 0
        if scene_hz is not None and scene_hz > 0:
            try:
                from formation.live import SceneModel
            except ImportError:  # foxglove-sdk not installed: no 3D scene in the file
                pass
            else:
                self._scene = SceneModel(self.fleet)
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
        """Write one bus observation (a sample or a liveliness change)."""
        if self._closed:
            return
        log_ns = self.log_time_ns(item.rx_ns)
        if item.kind in ("alive", "dead"):
            self._write_liveliness(item, log_ns)
        elif item.kind == "delete":
            self.stats.deletes += 1
        else:
            self._write_sample(item, log_ns)

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

        from formation.live import SCENE_TOPIC, TF_TOPIC

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
            self._closed = True
            self._writer.finish()
            self._file.close()
            return self.stats


class RecorderHandle:
    """What :func:`start_recorder` returns: ``.close()`` stops and finalizes (idempotent)."""

    def __init__(
        self, recorder: Recorder, tap: BusTap, own_session: zenoh.Session | None = None
    ) -> None:
        self.recorder = recorder
        self.tap = tap
        self._own_session = own_session

    @property
    def path(self) -> Path:
        """The MCAP file being written."""
        return self.recorder.path

    def close(self) -> RecorderStats:
        """Stop recording and finalize the file; closes the session if the handle opened it."""
        stats = self.recorder.close()
        if self._own_session is not None and not self._own_session.is_closed():
            self._own_session.close()
        return stats


def start_recorder(
    session_or_settings: zenoh.Session | tp.ZenohSettings,
    fleet: str,
    path: str | Path,
    *,
    raw: bool = False,
    derived: bool = True,
    run: Mapping[str, str] | None = None,
) -> RecorderHandle:
    """Start recording ``formation/<fleet>/**`` and its liveliness to the MCAP file ``path``.

    Given a session, the recorder subscribes on it (the caller keeps owning the session and
    must call ``handle.close()`` before closing it). Given :class:`ZenohSettings`, it opens its
    own session and closes it in ``handle.close()``. ``run`` (see :func:`run_info`) is stored as
    the ``formation.run`` metadata record. Returns once subscribed; raises ``OSError`` if the file
    cannot be created, ``TransportError`` if the session cannot open.

    ``formation up --record FILE`` calls it on its own session right after subscribing its
    collector::

        handle = start_recorder(session, fleet, path, run=run_info(
            plan.scenario_arg, lockstep=cfg.lockstep, settle_s=plan.settle_s, seed=plan.seed))
        ...
        handle.close()   # before session.close()
    """
    own: zenoh.Session | None = None
    if isinstance(session_or_settings, tp.ZenohSettings):
        own = tp.open_session(session_or_settings)
        session = own
    else:
        session = session_or_settings
    try:
        recorder = Recorder(path, fleet, raw=raw, derived=derived, run=run)
        tap = recorder.attach(session)
    except BaseException:
        if own is not None:
            own.close()
        raise
    return RecorderHandle(recorder, tap, own)


# --------------------------------------------------------------------------------------------
# CLI
# --------------------------------------------------------------------------------------------


def build_parser() -> argparse.ArgumentParser:
    """The ``formation record`` argument parser."""
    p = argparse.ArgumentParser(
        prog="formation record",
        description="Record every key of a fleet and its liveliness changes to an MCAP file "
        "(JSON channels with JSON Schemas; open it in Foxglove or run `formation report`).",
    )
    p.add_argument("--out", type=Path, required=True, help="MCAP file to write")
    p.add_argument("--fleet", default=keys.DEFAULT_FLEET, help="fleet name (default demo)")
    p.add_argument("--duration", type=float, default=None, help="stop after S seconds")
    p.add_argument("--raw", action="store_true", help="also keep the msgpack payloads")
    p.add_argument("--no-derived", action="store_true", help="skip the /derived/ channels")
    p.add_argument(
        "--scenario",
        default=None,
        help="scenario of the run (name or TOML file), embedded for `formation report`",
    )
    tp.add_zenoh_arguments(p)
    return p


def main(argv: list[str]) -> int:
    """``formation record``: exit 0 after a clean stop, 1 if the session cannot open."""
    args = build_parser().parse_args(argv)
    try:
        keys.check_fleet(args.fleet)
    except ValueError as exc:
        print(f"formation record: {exc}", file=sys.stderr)
        return 2
    if args.duration is not None and not args.duration > 0:
        print("formation record: --duration must be > 0", file=sys.stderr)
        return 2
    try:
        run = run_info(args.scenario) if args.scenario is not None else None
    except ValueError as exc:  # ScenarioError
        print(f"formation record: {exc}", file=sys.stderr)
        return 2
    settings = tp.settings_from_args(args)

    async def node(stop: asyncio.Event) -> int:
        try:
            session = await tp.open_session_async(settings)
        except tp.TransportError as exc:
            print(f"formation record: {exc}", file=sys.stderr)
            return 1
        recorder: Recorder | None = None
        try:
            recorder = Recorder(
                args.out, args.fleet, raw=args.raw, derived=not args.no_derived, run=run
            )
            recorder.attach(session)
            print(f"{READY_PREFIX}{keys.fleet_pattern(args.fleet)} to {args.out}", flush=True)
            with contextlib.suppress(TimeoutError):  # --duration elapsed
                await asyncio.wait_for(stop.wait(), timeout=args.duration)
        finally:
            if recorder is not None:
                # Finalizing takes milliseconds; run it off the loop so a signal still lands.
                stats = await asyncio.to_thread(recorder.close)
                print(
                    f"recorded {stats.samples} samples ({stats.rejected} rejected, "
                    f"{stats.liveliness} liveliness changes) to {args.out}",
                    flush=True,
                )
            session.close()
        return 0

    return tp.run_node(node, grace_s=0.8, hard_exit_s=3.0)
