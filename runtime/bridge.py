"""The one bridge from Zenoh's threads to the code that consumes a sample, and liveliness.

Zenoh runs subscriber callbacks on its own threads. Every subscription of the project is
declared here (:func:`subscribe_on_thread`, :func:`watch_liveliness_on_thread`): the callback
runs on Zenoh's network thread (``indirect=False`` for samples), only copies the sample into a
:class:`Received` (key, payload bytes, receive time) and pushes it on, never blocks, never calls
Zenoh and never lets an exception escape. Running on the network thread keeps the order of
samples *across* keys of one session (zenoh-python's default runs each subscriber on a thread
of its own, so a plant's pose could be overtaken by its next clock); lockstep relies on that
order (docs/runtime.md).

Where the sample goes is the consumer's choice, one of four:

* a callable run on an asyncio loop with one :class:`Received` per sample, in arrival order
  (:func:`subscribe` with a callable: every process shell);
* an :class:`Inbox` read from the loop: the newest sample per key, or a bounded FIFO drained in
  batches, waking the loop once per burst (:func:`subscribe` with an Inbox: the launcher's
  collector, tools and benches that poll);
* one worker thread fed through a bounded queue (:class:`runtime.tap.BusTap`: the recorder, the
  live view and ``formation top``, whose handlers may be slow and must not hold up a loop); its
  samples first wait in a Zenoh-side FIFO (:func:`subscribe_buffered`), so a busy worker never
  stops the session from reading its link;
* a lockstep node's per-tick inputs, taken by one thread of its own from Zenoh-side rings
  (:class:`TickPump`): no Python runs on Zenoh's thread for them and no event loop wakes, so a
  tick costs the process one wake-up (see the class).
"""

from __future__ import annotations

import asyncio
import contextlib
import threading
import time
import weakref
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Final, Literal

import zenoh

__all__ = [
    "BufferedSubscription",
    "Inbox",
    "LivelinessHandler",
    "LoopFeed",
    "Push",
    "Received",
    "SampleHandler",
    "TickPump",
    "declare_token",
    "loop_feed",
    "subscribe",
    "subscribe_buffered",
    "subscribe_on_thread",
    "watch_liveliness",
    "watch_liveliness_on_thread",
]

# --------------------------------------------------------------------------------------------
# Receiving: Zenoh threads -> asyncio
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Received:
    """One sample as handed to the event loop.

    Attributes:
        key: the sample's key expression (without the session namespace).
        payload: the payload bytes (empty for a delete).
        rx_s: ``time.monotonic()`` on the Zenoh thread when the sample arrived, in seconds (a local
            receive time: compare it with this host's clock only).
        deleted: the sample is a DELETE.
    """

    key: str
    payload: bytes
    rx_s: float
    deleted: bool = False
    rx_ns: int = 0
    """``rx_s`` in integer nanoseconds (``time.monotonic_ns()``; 0 where a test built it)."""
    attachment: bytes | None = None
    """The sample's attachment bytes, None without one (ROS 2 samples carry rmw_zenoh's)."""


def _to_received(sample: zenoh.Sample) -> Received:
    ns = time.monotonic_ns()
    att = sample.attachment
    return Received(
        str(sample.key_expr),
        sample.payload.to_bytes(),
        ns / 1e9,  # == time.monotonic() at that instant
        sample.kind == zenoh.SampleKind.DELETE,
        ns,
        None if att is None else att.to_bytes(),
    )


def _post(loop: asyncio.AbstractEventLoop, fn: Callable[..., object], *args: Any) -> None:
    """``loop.call_soon_threadsafe`` that drops the call once the loop is closed (shutdown)."""
    # RuntimeError: the loop is closed, the node is exiting and the sample is moot.
    with contextlib.suppress(RuntimeError):
        loop.call_soon_threadsafe(fn, *args)


InboxMode = Literal["latest", "queue"]


class Inbox:
    """Receive buffer of one or more subscriptions, read from the event loop.

    ``Inbox("latest")`` keeps the newest sample per key (poses, setpoints, wheels): a reader
    never works on a backlog. ``Inbox("queue", maxlen=n)`` keeps every sample in order, up to
    ``maxlen`` (the oldest is dropped and counted beyond that), for events such as estop.

    :meth:`push` is the only method safe to call from another thread (Zenoh's); everything else
    must run on the loop. A burst of samples wakes the loop once: pushes accumulate under a lock
    and a single drain is scheduled with ``call_soon_threadsafe``. ``wake=False``: a push never
    wakes the loop; the reader takes what accumulated on its own schedule (:meth:`drain`,
    :meth:`get_nowait`, :meth:`latest`, :meth:`snapshot`, :meth:`take_updates`; :meth:`get` and
    :meth:`wait` refuse): a reader that polls anyway (the launcher's collector, every 20 ms)
    then costs no wake-up of its loop, and no switch of the interpreter lock between Zenoh's
    thread and the loop's, per burst of samples.

    Counters: ``received`` (samples pushed), ``dropped`` (queue overflow, more than ``maxlen``
    keys in latest mode, or arrival after the loop closed).
    """

    def __init__(
        self, mode: InboxMode = "latest", *, maxlen: int = 1024, wake: bool = True
    ) -> None:
        if mode not in ("latest", "queue"):
            raise ValueError(f"Inbox mode must be 'latest' or 'queue', got {mode!r}")
        if maxlen < 1:
            raise ValueError(f"maxlen must be >= 1, got {maxlen}")
        self.mode: Final[InboxMode] = mode
        self.maxlen: Final = maxlen
        self.wake: Final = wake
        self.received = 0
        self.dropped = 0
        self._loop: asyncio.AbstractEventLoop | None = None
        self._lock = threading.Lock()
        self._pending_latest: dict[str, Received] = {}
        self._pending_queue: deque[Received] = deque()
        self._drain_scheduled = False
        self._latest: dict[str, Received] = {}
        self._updated: dict[str, Received] = {}
        self._queue: deque[Received] = deque()
        self._event = asyncio.Event()

    # -- producer side (any thread) ------------------------------------------------------------

    def bind(self, loop: asyncio.AbstractEventLoop) -> None:
        """Attach the loop that reads this inbox (done by :func:`subscribe`)."""
        if self._loop is not None and self._loop is not loop:
            raise RuntimeError("an Inbox is read by one event loop only")
        self._loop = loop

    def push(self, item: Received) -> None:
        """Add a sample; thread-safe and non-blocking (a short uncontended lock)."""
        loop = self._loop
        if loop is None:
            raise RuntimeError("Inbox.push before bind(loop): use subscribe(...)")
        with self._lock:
            self.received += 1
            if self.mode == "latest":
                if (
                    item.key not in self._pending_latest
                    and len(self._pending_latest) >= self.maxlen
                ):
                    self.dropped += 1
                    return
                self._pending_latest[item.key] = item
            else:
                if len(self._pending_queue) >= self.maxlen:
                    self._pending_queue.popleft()
                    self.dropped += 1
                self._pending_queue.append(item)
            if self._drain_scheduled or not self.wake:
                return
            self._drain_scheduled = True
        try:
            loop.call_soon_threadsafe(self._drain)
        except RuntimeError:  # loop closed during shutdown
            with self._lock:
                self._drain_scheduled = False
                self.dropped += 1

    def _drain(self) -> None:  # on the loop
        with self._lock:
            latest, self._pending_latest = self._pending_latest, {}
            queued, self._pending_queue = self._pending_queue, deque()
            self._drain_scheduled = False
        for key, item in latest.items():
            if key not in self._latest and len(self._latest) >= self.maxlen and not item.deleted:
                self.dropped += 1  # more distinct keys than maxlen: refuse new ones
                continue
            if item.deleted:
                self._latest.pop(key, None)
            else:
                self._latest[key] = item
            self._updated[key] = item
        if queued:
            self._queue.extend(queued)
            overflow = len(self._queue) - self.maxlen
            for _ in range(max(0, overflow)):
                self._queue.popleft()
            if overflow > 0:
                self.dropped += overflow
        if latest or queued:
            self._event.set()

    # -- consumer side (the loop) --------------------------------------------------------------

    def _take(self) -> None:
        """``wake=False``: take what the pushes accumulated (nothing scheduled a drain)."""
        if not self.wake:
            self._drain()

    def latest(self, key: str) -> Received | None:
        """Newest sample of ``key`` (latest mode), or ``None`` if none yet / deleted."""
        self._take()
        return self._latest.get(key)

    def snapshot(self) -> dict[str, Received]:
        """Copy of the newest sample of every key (latest mode)."""
        self._take()
        return dict(self._latest)

    def take_updates(self) -> dict[str, Received]:
        """Keys updated since the previous call, with their newest sample (deletes included)."""
        self._take()
        updated, self._updated = self._updated, {}
        return updated

    def get_nowait(self) -> Received | None:
        """Oldest queued sample (queue mode), or ``None``."""
        self._take()
        return self._queue.popleft() if self._queue else None

    def drain(self) -> list[Received]:
        """All queued samples, oldest first (queue mode)."""
        self._take()
        items = list(self._queue)
        self._queue.clear()
        return items

    def _check_waitable(self) -> None:
        if not self.wake:
            raise RuntimeError(
                "Inbox(wake=False) is polled (drain, get_nowait): nothing wakes a wait"
            )

    async def get(self) -> Received:
        """Wait for and return the oldest queued sample (queue mode)."""
        self._check_waitable()
        while not self._queue:
            await self._event.wait()
            self._event.clear()
        return self._queue.popleft()

    async def wait(self, timeout_s: float | None = None) -> bool:
        """Wait until something arrived since the previous ``wait`` returned True.

        Returns False on timeout (``timeout_s`` in seconds; ``None`` waits forever).
        """
        self._check_waitable()
        if not self._event.is_set():
            try:
                async with asyncio.timeout(timeout_s):
                    await self._event.wait()
            except TimeoutError:
                return False
        self._event.clear()
        return True


SampleHandler = Callable[[Received], object]
Push = Callable[[Received], object]
"""Called on Zenoh's network thread with each sample: must be quick, must not block."""


def subscribe_on_thread(
    session: zenoh.Session, key_expr: str, push: Push
) -> zenoh.Subscriber[None]:
    """The Zenoh-thread half of the bridge: call ``push(Received)`` on Zenoh's network thread
    for every sample on ``key_expr``, in the order the session received them (across keys too).
    Exceptions of ``push`` are dropped (nothing may escape into Zenoh's thread). The subscriber
    stays declared until ``undeclare()`` or the session closes, even if the returned object is
    dropped (zenoh 1.x)."""

    def on_sample(sample: zenoh.Sample) -> None:  # Zenoh network thread
        with contextlib.suppress(Exception):  # e.g. the loop closed at shutdown: drop it
            push(_to_received(sample))

    return session.declare_subscriber(key_expr, zenoh.handlers.Callback(on_sample, indirect=False))


class BufferedSubscription:
    """A subscriber whose samples wait in a bounded Zenoh-side FIFO and are handed to ``push``
    by one Python thread of its own, in the order the session received them (one subscriber:
    across keys too). See :func:`subscribe_buffered`."""

    def __init__(
        self, session: zenoh.Session, key_expr: str, push: Push, *, capacity: int, name: str
    ) -> None:
        self._sub = session.declare_subscriber(key_expr, zenoh.handlers.FifoChannel(capacity))
        self._rx = self._sub.handler  # still drains what it holds after undeclare()
        self._push = push
        self._thread = threading.Thread(target=self._pump, name=name, daemon=True)
        self._thread.start()

    def _pump(self) -> None:
        rx, push = self._rx, self._push
        while True:
            try:
                sample = rx.recv()  # blocks without the GIL
            except zenoh.ZError:  # undeclared (or session closed) and drained
                return
            with contextlib.suppress(Exception):
                push(_to_received(sample))

    def undeclare(self) -> None:
        """Stop receiving; what the FIFO holds is still handed over (see :meth:`join`)."""
        with contextlib.suppress(zenoh.ZError):  # the session was closed first: gone already
            self._sub.undeclare()

    def join(self, timeout_s: float | None = None) -> bool:
        """After :meth:`undeclare`: wait until the FIFO is drained; False on timeout."""
        self._thread.join(timeout_s)
        return not self._thread.is_alive()


def subscribe_buffered(
    session: zenoh.Session, key_expr: str, push: Push, *, capacity: int, name: str = "bus-rx"
) -> BufferedSubscription:
    """Like :func:`subscribe_on_thread`, but Zenoh's network thread never waits for Python: each
    sample goes into a Zenoh FIFO of ``capacity`` samples (it holds Zenoh up only when full)
    and one thread of its own calls ``push(Received)`` (``rx_s``: when that thread took it).

    For a consumer whose Python work competes with its receive path, the recorder's tap: a
    callback on the network thread must take the GIL for every sample, and while the tap's
    worker holds it (writing MCAP on a starved machine) the session stopped reading its link,
    the router queued the backlog and lost it when it exited (a recording of a finished
    ``formation up`` run ended ticks early; its router was even forced to exit, trying to flush
    it). Buffered here, a backlog is in this process when the router goes away."""
    return BufferedSubscription(session, key_expr, push, capacity=capacity, name=name)


class TickPump:
    """A lockstep node's per-tick inputs, handled on one thread of its own, tick by tick.

    A lockstep node is woken by one *trigger* per tick (an agent's ``clock``); every other input
    of the tick (a *side*: an agent's setpoint, poses, own pose, movers, fault notices) is read
    only when that trigger comes. Each key gets a Zenoh-side ring (``zenoh.handlers.RingChannel``:
    Zenoh's thread stores the sample without the interpreter lock and never waits); the pump's
    thread blocks on the trigger's ring (without the lock) and, for each trigger sample, under
    ``guard``, first hands every side sample waiting to its handler (side by side in the order
    :meth:`side` declared them; each key's samples in their order), then the trigger's.

    Against a callback on Zenoh's thread and a wake of the event loop (:class:`LoopFeed`), a
    sample costs no switch of the interpreter lock and the tick no wake of the loop: measured in
    docs/benchmarks.md ("Lockstep agents on a tick thread of their own"). The order *across* keys is
    the price: a side sample that arrived just after the trigger (but before the pump looked) is
    handled before it. So a side input must be tick-tagged (a setpoint, movers, a fault notice:
    kept for the tick they name) or causally before the trigger (the plant's poses, sent before
    its clock on the same link; the next ones only after this node answered).

    ``guard`` is held while handlers run: whatever else touches the node's state (the event
    loop's e-stop and status) takes it too, so the state has one owner at a time. The rings hold
    ``capacity`` samples each (a flood drops the oldest; the trigger's are the plant's clocks,
    one a tick). Handlers must not raise (they count their own errors); one that does is counted
    in :attr:`errors` and the rest still run. The thread ends when the session closes (or
    :meth:`undeclare`); samples still waiting then are dropped.
    """

    def __init__(
        self,
        session: zenoh.Session,
        guard: contextlib.AbstractContextManager[Any],
        *,
        capacity: int = 256,
        name: str = "tick-pump",
    ) -> None:
        if capacity < 1:
            raise ValueError(f"capacity must be >= 1, got {capacity}")
        self._session = session
        self._guard = guard
        self._capacity = capacity
        self._name = name
        self._sides: list[tuple[Any, SampleHandler]] = []
        self._subs: list[zenoh.Subscriber[Any]] = []
        self._thread: threading.Thread | None = None
        self.ticks = 0
        """Trigger samples handled so far."""
        self.handled = 0
        """Samples handed to their handlers so far (triggers and sides)."""
        self.errors = 0
        """Handlers that raised (each sample's handler is still called)."""

    def _ring(self, key_expr: str) -> Any:
        sub = self._session.declare_subscriber(key_expr, zenoh.handlers.RingChannel(self._capacity))
        self._subs.append(sub)
        return sub.handler

    def side(self, key_expr: str, fn: SampleHandler) -> None:
        """Declare a side input: its samples are handled just before the next trigger's."""
        if self._thread is not None:
            raise RuntimeError("TickPump.side after start: declare every side first")
        self._sides.append((self._ring(key_expr), fn))

    def start(self, key_expr: str, fn: SampleHandler) -> None:
        """Declare the trigger and start the thread (once)."""
        if self._thread is not None:
            raise RuntimeError("TickPump.start twice")
        trigger = self._ring(key_expr)
        self._thread = threading.Thread(
            target=self._pump, args=(trigger, fn), name=self._name, daemon=True
        )
        self._thread.start()

    def _call(self, fn: SampleHandler, sample: zenoh.Sample) -> None:
        self.handled += 1
        try:
            fn(_to_received(sample))
        except Exception:
            self.errors += 1

    def _pump(self, trigger: Any, fn: SampleHandler) -> None:
        sides = self._sides
        call = self._call
        while True:
            try:
                sample = trigger.recv()  # blocks without the interpreter lock
            except zenoh.ZError:  # undeclared or the session closed
                return
            with self._guard:
                try:
                    for ring, side_fn in sides:
                        while (waiting := ring.try_recv()) is not None:
                            call(side_fn, waiting)
                except zenoh.ZError:  # closed while draining
                    return
                self.ticks += 1
                call(fn, sample)

    def undeclare(self) -> None:
        """Stop receiving; the thread ends (what waits is dropped)."""
        for sub in self._subs:
            with contextlib.suppress(zenoh.ZError):
                sub.undeclare()

    def join(self, timeout_s: float | None = None) -> bool:
        """After :meth:`undeclare` (or the session's close): wait for the thread; False on
        timeout."""
        if self._thread is not None:
            self._thread.join(timeout_s)
            return not self._thread.is_alive()
        return True


class LoopFeed:
    """The hand-over of samples to one event loop's handlers: one FIFO of ``(handler,
    Received)`` shared by every callable subscription of the loop, so the handlers run in the
    order the session received the samples, across keys too.

    A burst of samples wakes the loop once: :meth:`push` (Zenoh's thread) appends under a short
    lock and schedules one :meth:`_drain` with ``call_soon_threadsafe`` only when none is
    pending; the drain runs the handlers of everything queued, in order. Before, each sample
    was a ``call_soon_threadsafe`` of its own (a ``Handle``, a write to the loop's self-pipe
    and, when the loop slept, a wake-up of its thread): a lockstep clock and the poses before
    it now cost the agent one. ``wake=False`` (:func:`subscribe`): the sample waits in the
    FIFO, in its place, without scheduling a drain; the next sample that wakes the loop (or
    :meth:`flush`) runs it, before itself.

    A handler that raises does not keep the others from running: the exception goes to the
    loop's exception handler, as an exception of a ``call_soon`` callback did.
    """

    def __init__(self, loop: asyncio.AbstractEventLoop) -> None:
        self._loop = loop
        self._lock = threading.Lock()
        self._pending: deque[tuple[SampleHandler, Received]] = deque()
        self._scheduled = False
        self.drains = 0
        """How many drains ran (each: one wake-up of the loop for a burst)."""
        self.handled = 0
        """How many samples the drains handed to their handlers."""

    def push(self, fn: SampleHandler, rx: Received, wake: bool = True) -> None:
        """Queue ``fn(rx)`` (any thread; never blocks but for the short lock)."""
        with self._lock:
            self._pending.append((fn, rx))
            if self._scheduled or not wake:
                return
            self._scheduled = True
        try:
            self._loop.call_soon_threadsafe(self._drain)
        except RuntimeError:  # the loop is closed: the node is exiting and the sample is moot
            with self._lock:
                self._scheduled = False

    def flush(self) -> None:
        """On the loop: run the handlers of what is queued now (``wake=False`` samples)."""
        self._drain()

    def _drain(self) -> None:  # on the loop
        with self._lock:
            items, self._pending = self._pending, deque()
            self._scheduled = False
        if not items:
            return
        self.drains += 1
        self.handled += len(items)
        for fn, rx in items:
            try:
                fn(rx)
            except Exception as exc:
                self._loop.call_exception_handler(
                    {"message": f"handler of {rx.key!r} raised", "exception": exc}
                )


_FEEDS: weakref.WeakKeyDictionary[asyncio.AbstractEventLoop, LoopFeed] = weakref.WeakKeyDictionary()


def loop_feed(loop: asyncio.AbstractEventLoop) -> LoopFeed:
    """The one :class:`LoopFeed` of ``loop`` (made on first use; call it from the loop's
    thread, as :func:`subscribe` does)."""
    feed = _FEEDS.get(loop)
    if feed is None:
        feed = _FEEDS[loop] = LoopFeed(loop)
    return feed


def subscribe(
    session: zenoh.Session,
    key_expr: str,
    loop: asyncio.AbstractEventLoop,
    handler: Inbox | SampleHandler,
    *,
    wake: bool = True,
) -> zenoh.Subscriber[None]:
    """Subscribe to ``key_expr`` and deliver each sample to the event loop ``loop``, in the
    order the session received them (across keys too: see the module docstring).

    ``handler`` is a callable run on the loop thread with one :class:`Received` per sample
    (through the loop's :class:`LoopFeed`), or an :class:`Inbox`. ``wake=False`` (callables
    only): a sample of this key does not wake the loop; it is handled, in its place, when the
    next sample that does wakes it (a lockstep node's inputs that only its next clock reads).
    """
    if isinstance(handler, Inbox):
        if not wake:
            raise ValueError("wake=False is for callables: an Inbox has its own (Inbox(wake=))")
        handler.bind(loop)
        return subscribe_on_thread(session, key_expr, handler.push)
    fn = handler
    push = loop_feed(loop).push
    return subscribe_on_thread(session, key_expr, lambda rx: push(fn, rx, wake))


# --------------------------------------------------------------------------------------------
# Liveliness
# --------------------------------------------------------------------------------------------


def declare_token(session: zenoh.Session, key: str) -> zenoh.LivelinessToken:
    """Declare a liveliness token at ``key``. KEEP THE RETURNED TOKEN REFERENCED: it is
    undeclared when garbage-collected. It also vanishes when the session closes, the process
    dies (~3 ms after SIGKILL) or the link lease expires (a hang: ``lease_ms``)."""
    return session.liveliness().declare_token(key)


LivelinessHandler = Callable[[str, bool], object]


def watch_liveliness_on_thread(
    session: zenoh.Session, pattern: str, push: Push, *, history: bool = True
) -> zenoh.Subscriber[None]:
    """The Zenoh-thread half for liveliness: ``push(Received)`` on a Zenoh thread when a token
    matching ``pattern`` appears (``deleted`` False) or disappears (``deleted`` True); the
    payload is empty. With ``history`` the tokens already alive are reported once."""

    def on_sample(sample: zenoh.Sample) -> None:  # Zenoh thread
        with contextlib.suppress(Exception):
            push(_to_received(sample))

    return session.liveliness().declare_subscriber(pattern, on_sample, history=history)


def watch_liveliness(
    session: zenoh.Session,
    pattern: str,
    loop: asyncio.AbstractEventLoop,
    on_change: LivelinessHandler,
    *,
    history: bool = True,
) -> zenoh.Subscriber[None]:
    """Call ``on_change(key, alive)`` on the loop thread when a token matching ``pattern``
    appears (``True``) or disappears (``False``). With ``history`` the tokens already alive are
    reported once at declaration."""

    def push(rx: Received) -> None:
        _post(loop, on_change, rx.key, not rx.deleted)

    return watch_liveliness_on_thread(session, pattern, push, history=history)


# --------------------------------------------------------------------------------------------
