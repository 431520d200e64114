"""The bus tap: every key and liveliness token of a fleet, handed to one worker thread.

Zenoh calls subscriber callbacks on its own threads; :class:`BusTap` only copies each sample
into a bounded queue (a full queue drops and counts), and one worker thread handles them in
arrival order. :class:`LatencyTracker` pairs each wheel command with the pose it was computed
from (pose-to-wheels latency). Used by the recorder, the live view and ``formation top``.
"""

from __future__ import annotations

import contextlib
import queue
import sys
import threading
import time
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Final, Literal, NamedTuple

import zenoh

from bus_schemas import (
    Wheels,
    keys,
)

DEFAULT_QUEUE_LEN: Final = 200_000
"""Samples the tap buffers between Zenoh threads and the worker (~1 min of a 3-robot fleet)."""


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
