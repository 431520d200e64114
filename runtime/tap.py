"""The bridge's worker-thread delivery: every key and liveliness token of a fleet, handed to one
worker thread in arrival order.

For consumers whose handler may be slow (the recorder writes MCAP, the live view encodes
scenes) and must not hold up an event loop. The Zenoh side is the one bridge of
:mod:`runtime.bridge` (:func:`~runtime.bridge.subscribe_buffered`,
:func:`~runtime.bridge.watch_liveliness_on_thread`): samples wait in a Zenoh-side FIFO, so the
session keeps reading its link however busy the worker is (a backlog is in this process, not
in the router's queue, when a run's router exits); a pump thread copies each into a bounded
queue (a full queue drops and counts); one worker thread handles them.
Used by ``formation record``, ``formation top`` and the Foxglove live view.
"""

from __future__ import annotations

import contextlib
import queue
import sys
import threading
import time
from collections.abc import Callable
from typing import Any, Final, Literal, NamedTuple

import zenoh

from bus_schemas import keys
from runtime.bridge import (
    BufferedSubscription,
    Received,
    subscribe_buffered,
    watch_liveliness_on_thread,
)

__all__ = ["DEFAULT_QUEUE_LEN", "BusItem", "BusTap", "ItemKind"]

DEFAULT_QUEUE_LEN: Final = 200_000
"""Samples the tap buffers between Zenoh threads and the worker (~1 min of a 3-robot fleet)."""

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
        self._samples: BufferedSubscription | None = None
        try:
            self._samples = subscribe_buffered(
                session,
                keys.fleet_pattern(fleet),
                self._on_sample,
                capacity=maxlen,
                name=f"{name}-rx",
            )
            self._subs.append(
                watch_liveliness_on_thread(
                    session, keys.alive_pattern(fleet), self._on_liveliness, history=True
                )
            )
        except BaseException:
            self.close()
            raise

    # Zenoh threads (through runtime.bridge) -------------------------------------------------

    def _push(self, item: BusItem) -> None:
        if self._closed:  # a sample the FIFO still held when close() ran out of time
            with self._lock:
                self.dropped += 1
            return
        try:
            self._queue.put_nowait(item)
        except queue.Full:
            with self._lock:
                self.dropped += 1
            return
        with self._lock:
            self.received += 1

    def _on_sample(self, rx: Received) -> None:
        self._push(BusItem("delete" if rx.deleted else "put", rx.key, rx.payload, rx.rx_ns))

    def _on_liveliness(self, rx: Received) -> None:
        self._push(BusItem("dead" if rx.deleted else "alive", rx.key, b"", rx.rx_ns))

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
        deadline = time.monotonic() + timeout_s
        for sub in self._subs:
            # ZError: the session was closed first, the subscriber is gone already.
            with contextlib.suppress(zenoh.ZError):
                sub.undeclare()
        self._subs.clear()
        samples, self._samples = self._samples, None
        if samples is not None:  # what the Zenoh FIFO still holds goes into the queue first
            samples.undeclare()
            samples.join(max(0.0, deadline - time.monotonic()))
        if self._closed:
            return
        self._closed = True
        self._queue.put(_STOP)  # blocks only if full; the worker is draining it
        self._thread.join(timeout=max(0.0, deadline - time.monotonic()))
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
