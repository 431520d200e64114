"""Zenoh transport shared by every process shell: settings, sessions, asyncio bridge, lifecycle.

This is the only module of ``bus_schemas`` that imports ``zenoh``; the message definitions and the
codec stay stdlib + msgpack. It knows nothing about message types: payloads are ``bytes``.

Theory of operation
-------------------
* **Settings -> config.** :class:`ZenohSettings` (or ``add_zenoh_arguments`` +
  ``settings_from_args`` on a CLI) describes where to connect. :func:`make_config` turns it into a
  ``zenoh.Config``: an optional JSON5 file first, our settings on top. Multicast scouting is
  always written as *off* unless ``multicast_scouting=True``, so parallel runs never find each
  other by accident.
* **Sessions.** :func:`open_session` / :func:`open_session_async` open a session. A client
  session fails at once when no router is up, so both retry until ``open_timeout_s`` and then
  raise :class:`TransportError` naming the endpoints.
* **Zenoh threads -> asyncio.** Zenoh runs subscriber callbacks on its own threads. The callbacks
  installed here only copy the sample (key, payload bytes, ``time.monotonic()`` receive time) and
  hand it to the event loop with ``loop.call_soon_threadsafe``; they never block and never call
  Zenoh. An :class:`Inbox` keeps either the latest value per key (poses, setpoints, wheels) or a
  bounded FIFO (events); it coalesces bursts so the loop is woken once per burst, not per sample.
* **Lifecycle.** :func:`run_node` owns the event loop: SIGINT/SIGTERM set a stop
  ``asyncio.Event``, ``main`` gets ``grace_s`` to return, is then cancelled, every session opened
  through this module and still open is closed, and a watchdog thread forces the process out
  ``hard_exit_s`` after the first signal if anything still hangs. Measured exit after SIGTERM:
  tens of milliseconds (``tests/test_transport.py``).

How to write a node
-------------------
::

    import argparse, asyncio
    from bus_schemas import transport as tp

    def main(argv: list[str]) -> int:
        parser = argparse.ArgumentParser(prog="formation agent")
        tp.add_zenoh_arguments(parser)
        settings = tp.settings_from_args(parser.parse_args(argv))
        return tp.run_node(lambda stop: node(stop, settings))

    async def node(stop: asyncio.Event, settings: tp.ZenohSettings) -> int:
        loop = asyncio.get_running_loop()
        session = await tp.open_session_async(settings)   # retries while the router starts
        try:
            token = tp.declare_token(session, "formation/demo/alive/robot/r1")  # keep a ref
            setpoints = tp.Inbox("latest")
            tp.subscribe(session, "formation/demo/robot/r1/setpoint", loop, setpoints)
            pubs = tp.Publishers(session)
            while not stop.is_set():
                await setpoints.wait(timeout_s=0.02)       # wake on new data or every 20 ms
                sp = setpoints.latest("formation/demo/robot/r1/setpoint")
                ...                                         # decode, step the firmware
                pubs.put("formation/demo/robot/r1/wheels", b"...", tp.QOS_CONTROL)
            return 0
        finally:
            session.close()    # undeclares token, subscribers, publishers; run_node re-checks

Rules: never block the loop (no ``time.sleep``, no blocking ``recv``); open the session inside
``main`` in ``try/finally``; start other processes with ``subprocess`` (fork+exec), never with a
``multiprocessing`` fork after Zenoh has started.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import os
import signal
import sys
import threading
import time
from collections import deque
from collections.abc import Awaitable, Callable, Sequence
from dataclasses import dataclass
from types import FrameType
from typing import Any, Final, Literal

import zenoh

__all__ = [
    "DEFAULT_ENDPOINT",
    "QOS_CONTROL",
    "QOS_CRITICAL",
    "QOS_TELEMETRY",
    "Inbox",
    "Publishers",
    "QoS",
    "Received",
    "TransportError",
    "ZenohSettings",
    "add_zenoh_arguments",
    "declare_token",
    "make_config",
    "open_session",
    "open_session_async",
    "run_node",
    "settings_from_args",
    "subscribe",
    "watch_liveliness",
]

DEFAULT_ENDPOINT: Final = "tcp/127.0.0.1:7447"
"""Where ``formation up`` / ``formation router`` listen by default (bus contract, Connection)."""

Mode = Literal["client", "peer", "router"]
_MODES: Final = ("client", "peer", "router")

# Transport keep-alive messages per lease period (Zenoh's own default ratio, written explicitly
# so a short lease always comes with a proportionally short keep-alive interval).
_KEEP_ALIVES_PER_LEASE: Final = 4
_MIN_LEASE_MS: Final = 100
_RETRY_PERIOD_S: Final = 0.1
_CONNECT_RETRY: Final = {"period_init_ms": 100, "period_max_ms": 500, "period_increase_factor": 2}
"""Client reconnection to its router after the link was lost (see :func:`make_config`)."""


class TransportError(ConnectionError):
    """A Zenoh session could not be opened (router absent, bad endpoint, port in use)."""


# --------------------------------------------------------------------------------------------
# Settings and configuration
# --------------------------------------------------------------------------------------------


def _as_endpoints(value: Sequence[str], what: str) -> tuple[str, ...]:
    if isinstance(value, str):  # a bare str would be split into characters
        raise TypeError(f"{what} must be a sequence of endpoints, not a str: use ({value!r},)")
    endpoints = tuple(value)
    for ep in endpoints:
        if not isinstance(ep, str) or "/" not in ep or ep.startswith("/") or ep.endswith("/"):
            raise ValueError(f"{what}: {ep!r} is not a Zenoh endpoint like 'tcp/127.0.0.1:7447'")
    return endpoints


@dataclass(frozen=True)
class ZenohSettings:
    """Where and how a process joins the Zenoh network.

    Attributes:
        connect: endpoints to connect to, e.g. ``("tcp/127.0.0.1:7447",)``. Empty: leave the
            config file's (or Zenoh's) value.
        listen: endpoints to listen on (routers, and peers others connect to). Empty: listen on
            nothing, or keep the config file's value when ``config_file`` is given.
        mode: ``"client"`` (default: everything goes through a router), ``"peer"`` or
            ``"router"``. ``None`` keeps the config file's mode.
        config_file: optional Zenoh JSON5 config loaded first; the other fields are applied on
            top (security, TLS, access control live there).
        lease_ms: lease this session announces, in milliseconds: the far end declares it dead
            (its liveliness tokens vanish) after ``lease_ms`` of silence, e.g. when the process is
            hung or SIGSTOPped. Zenoh's default is 10000; 1000 detects a hang in about 1 s.
            Keep-alives are sent every ``lease_ms / 4``. Set it on the process that may hang.
        multicast_scouting: multicast discovery; off unless explicitly enabled (a config file
            cannot switch it on by itself).
        namespace: optional prefix Zenoh adds to every key of this session (isolation of
            parallel runs); ``None`` keeps the config file's.
        open_timeout_s: how long a client keeps retrying to reach a router, in seconds.
    """

    connect: tuple[str, ...] = (DEFAULT_ENDPOINT,)
    listen: tuple[str, ...] = ()
    mode: Mode | None = "client"
    config_file: str | None = None
    lease_ms: int | None = None
    multicast_scouting: bool = False
    namespace: str | None = None
    open_timeout_s: float = 5.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "connect", _as_endpoints(self.connect, "connect"))
        object.__setattr__(self, "listen", _as_endpoints(self.listen, "listen"))
        if self.mode is not None and self.mode not in _MODES:
            raise ValueError(f"mode must be one of {_MODES}, got {self.mode!r}")
        if self.lease_ms is not None and (
            isinstance(self.lease_ms, bool) or int(self.lease_ms) < _MIN_LEASE_MS
        ):
            raise ValueError(f"lease_ms must be an int >= {_MIN_LEASE_MS}, got {self.lease_ms!r}")
        if self.namespace is not None and (
            not self.namespace or any(c in self.namespace for c in "*$?#")
        ):
            raise ValueError(
                f"namespace must be a non-empty key without wildcards: {self.namespace!r}"
            )
        if not self.open_timeout_s >= 0.0:
            raise ValueError(f"open_timeout_s must be >= 0, got {self.open_timeout_s!r}")


def add_zenoh_arguments(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Add the Zenoh options every process shares to ``parser`` and return it.

    Options: ``--endpoint`` (repeatable, connect), ``--listen`` (repeatable), ``--zenoh-config``,
    ``--mode``, ``--lease-ms``, ``--multicast-scouting``, ``--zenoh-namespace``. Their ``dest``
    names start with ``zenoh_`` so they never clash with a node's own options.
    """
    group = parser.add_argument_group("zenoh")
    group.add_argument(
        "--endpoint",
        dest="zenoh_connect",
        action="append",
        metavar="ENDPOINT",
        help=f"Zenoh endpoint to connect to, repeatable (default {DEFAULT_ENDPOINT})",
    )
    group.add_argument(
        "--listen",
        dest="zenoh_listen",
        action="append",
        metavar="ENDPOINT",
        help="Zenoh endpoint to listen on, repeatable (default: none)",
    )
    group.add_argument(
        "--zenoh-config",
        dest="zenoh_config",
        metavar="FILE",
        help="Zenoh JSON5 config file, loaded first; the options here override it",
    )
    group.add_argument(
        "--mode",
        dest="zenoh_mode",
        choices=_MODES,
        help="Zenoh mode (default client, or the config file's)",
    )
    group.add_argument(
        "--lease-ms",
        dest="zenoh_lease_ms",
        type=int,
        metavar="MS",
        help="transport lease in ms: a hung process is declared dead after this (Zenoh: 10000)",
    )
    group.add_argument(
        "--multicast-scouting",
        dest="zenoh_multicast_scouting",
        action="store_true",
        help="enable multicast discovery (off by default)",
    )
    group.add_argument(
        "--zenoh-namespace",
        dest="zenoh_namespace",
        metavar="PREFIX",
        help="prefix Zenoh adds to every key of this process",
    )
    return parser


def settings_from_args(ns: argparse.Namespace) -> ZenohSettings:
    """Build :class:`ZenohSettings` from options added by :func:`add_zenoh_arguments`.

    Without ``--endpoint`` a client/peer connects to :data:`DEFAULT_ENDPOINT`, except when a
    config file is given (its ``connect`` is kept) or the mode is ``router``.
    """
    config_file: str | None = ns.zenoh_config
    mode: Mode | None = ns.zenoh_mode
    if mode is None and config_file is None:
        mode = "client"
    connect: tuple[str, ...]
    if ns.zenoh_connect:
        connect = tuple(ns.zenoh_connect)
    elif config_file is not None or mode == "router":
        connect = ()
    else:
        connect = (DEFAULT_ENDPOINT,)
    return ZenohSettings(
        connect=connect,
        listen=tuple(ns.zenoh_listen or ()),
        mode=mode,
        config_file=config_file,
        lease_ms=ns.zenoh_lease_ms,
        multicast_scouting=bool(ns.zenoh_multicast_scouting),
        namespace=ns.zenoh_namespace,
    )


def make_config(settings: ZenohSettings) -> zenoh.Config:
    """The ``zenoh.Config`` for ``settings``: the config file if any, then the settings on top.

    Without a config file the result is fully determined by ``settings`` (connect and listen are
    written even when empty, so a peer does not fall back to listening on every interface).
    """
    if settings.config_file is not None:
        try:
            config = zenoh.Config.from_file(settings.config_file)
        except zenoh.ZError as exc:
            raise ValueError(f"bad Zenoh config file {settings.config_file!r}: {exc}") from exc
    else:
        config = zenoh.Config()
    standalone = settings.config_file is None

    def put(key: str, value: object) -> None:
        config.insert_json5(key, json.dumps(value))

    if settings.mode is not None:
        put("mode", settings.mode)
    if settings.connect or standalone:
        put("connect/endpoints", list(settings.connect))
    if settings.listen or standalone:
        put("listen/endpoints", list(settings.listen))
    put("scouting/multicast/enabled", bool(settings.multicast_scouting))
    if (
        not settings.multicast_scouting
        and (settings.mode == "router" or not settings.connect)
        and json.loads(config.get_json("scouting/delay")) is None
    ):
        # Zenoh waits `scouting/delay` (500 ms) in open() for scouted peers to connect. With
        # multicast off a router (or a peer that connects nowhere) has nobody to wait for: skip
        # it, so `formation router` is ready in ~2 ms instead of ~500 ms.
        put("scouting/delay", 0)
    retries = settings.mode in (None, "client") or bool(settings.connect)
    if retries and json.loads(config.get_json("connect/retry")) is None:
        # A client whose router goes away keeps its session and reconnects by itself, then
        # re-declares its subscribers and liveliness tokens (measured with zenoh 1.10). Zenoh's
        # default retry period starts at 1 s and doubles up to 4 s: a router restart would
        # cost the loop 1-4 s. Retry every 100 ms, at most every 500 ms (measured here: the loop
        # is back ~40 ms after the router is), which on loopback costs nothing. The same for a
        # router or peer that connects to another router (a robot host's router across a link
        # that went down: Zenoh's default took up to 4.5 s to bring it back, tests/test_multihost).
        put("connect/retry", dict(_CONNECT_RETRY))
    if settings.lease_ms is not None:
        put("transport/link/tx/lease", int(settings.lease_ms))
        put("transport/link/tx/keep_alive", _KEEP_ALIVES_PER_LEASE)
    if settings.namespace is not None:
        put("namespace", settings.namespace)
    return config


# Sessions opened by this module while run_node is running (None: no node running), so run_node
# can close any its main forgot without touching sessions of anything else in the process.
# zenoh.Session does not support weak references; closed sessions are pruned on every open.
_node_sessions: list[zenoh.Session] | None = None
_node_sessions_lock = threading.Lock()


def _register(session: zenoh.Session) -> zenoh.Session:
    with _node_sessions_lock:
        if _node_sessions is not None:
            _node_sessions[:] = [s for s in _node_sessions if not s.is_closed()]
            _node_sessions.append(session)
    return session


def _track_node_sessions(enable: bool) -> list[zenoh.Session]:
    """Start (``True``) or stop tracking; return the sessions tracked so far."""
    global _node_sessions
    with _node_sessions_lock:
        tracked = _node_sessions or []
        _node_sessions = [] if enable else None
    return tracked


def _close_node_sessions() -> int:
    """Close the sessions the running node opened and left open; return how many."""
    with _node_sessions_lock:
        sessions = list(_node_sessions or [])
    closed = 0
    for s in sessions:
        if not s.is_closed():
            s.close()
            closed += 1
    return closed


def _open_error(settings: ZenohSettings, waited_s: float, exc: BaseException) -> TransportError:
    where = ", ".join(settings.connect) or "(config file endpoints)"
    return TransportError(
        f"could not open a Zenoh {settings.mode or 'session'} session to {where} "
        f"within {waited_s:.1f} s: {exc}. Is `formation router` (or `formation up`) running?"
    )


def _open_once(settings: ZenohSettings) -> zenoh.Session:
    return _register(zenoh.open(make_config(settings)))


def _retries(settings: ZenohSettings) -> bool:
    # Peers and routers open immediately and keep dialling in the background; only a client
    # fails at once when no router answers.
    return settings.mode in (None, "client")


def open_session(settings: ZenohSettings, *, timeout_s: float | None = None) -> zenoh.Session:
    """Open a session, retrying a client for up to ``timeout_s`` (default ``open_timeout_s``).

    Blocks the calling thread: use :func:`open_session_async` inside an event loop. The caller
    owns the session and must ``close()`` it (``try/finally``).

    Raises:
        TransportError: the session could not be opened in time.
        ValueError: the config file is invalid.
    """
    timeout = settings.open_timeout_s if timeout_s is None else timeout_s
    start = time.monotonic()
    while True:
        try:
            return _open_once(settings)
        except zenoh.ZError as exc:
            waited = time.monotonic() - start
            if not _retries(settings) or waited >= timeout:
                raise _open_error(settings, waited, exc) from exc
        time.sleep(min(_RETRY_PERIOD_S, max(0.0, timeout - (time.monotonic() - start))))


async def open_session_async(
    settings: ZenohSettings, *, timeout_s: float | None = None
) -> zenoh.Session:
    """:func:`open_session` for a coroutine: retries with ``asyncio.sleep`` and can be cancelled.

    One attempt blocks the loop only for the few milliseconds ``zenoh.open`` takes.
    """
    timeout = settings.open_timeout_s if timeout_s is None else timeout_s
    start = time.monotonic()
    while True:
        try:
            return _open_once(settings)
        except zenoh.ZError as exc:
            waited = time.monotonic() - start
            if not _retries(settings) or waited >= timeout:
                raise _open_error(settings, waited, exc) from exc
        await asyncio.sleep(min(_RETRY_PERIOD_S, max(0.0, timeout - (time.monotonic() - start))))


# --------------------------------------------------------------------------------------------
# Publishing
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=True)
class QoS:
    """Quality of service of one publisher (fixed when it is declared).

    ``express`` puts the message in a batch of its own instead of letting the transmit task
    coalesce what is queued. Measured here with eclipse-zenoh 1.10 (two clients through a
    router, 100-byte ping-pong): no latency gain (round trip p50 519 us express vs 482 us not,
    p99 1363 vs 706 us, on a loaded machine) but ~20x the CPU per put in the caller (30-45 us vs
    ~2 us), and every express message is one more wake-up of every receiving process. Lockstep
    went from 4.8x to 6.2x real time when the control and critical QoS stopped using it
    (``formation up --lockstep --duration 30``, back to back). So no publisher here is express.
    ``CongestionControl.DROP``: when the transmit queue stays full for ~1 ms the message being
    sent is dropped (fine at control rates, but a tight loop of thousands of puts does lose
    some, measured); ``BLOCK`` waits instead (the message must arrive).
    """

    priority: zenoh.Priority
    congestion_control: zenoh.CongestionControl
    express: bool


QOS_CONTROL: Final = QoS(zenoh.Priority.REAL_TIME, zenoh.CongestionControl.DROP, express=False)
"""Control loop data where only the newest counts: setpoint, wheels, pose."""

QOS_CRITICAL: Final = QoS(zenoh.Priority.REAL_TIME, zenoh.CongestionControl.BLOCK, express=False)
"""Must arrive, at once: estop, and every message a lockstep run waits for (clock)."""

QOS_TELEMETRY: Final = QoS(zenoh.Priority.DATA, zenoh.CongestionControl.DROP, express=False)
"""Observation data, batched: status, truth, leader, slot, assignment."""


class Publishers:
    """Cache of ``zenoh.Publisher`` objects, one declared per key on first use.

    The QoS of a key is fixed by its first use; using the same key with another QoS raises
    ``ValueError`` (a silent mismatch would hide a latency bug). Closing the session undeclares
    them all; :meth:`undeclare_all` does it earlier.
    """

    def __init__(self, session: zenoh.Session, default_qos: QoS = QOS_TELEMETRY) -> None:
        self._session = session
        self._default = default_qos
        self._pubs: dict[str, tuple[zenoh.Publisher, QoS]] = {}

    def get(self, key: str, qos: QoS | None = None) -> zenoh.Publisher:
        """The publisher of ``key``, declared with ``qos`` (or the default) on first use."""
        want = self._default if qos is None else qos
        entry = self._pubs.get(key)
        if entry is not None:
            if qos is not None and entry[1] != want:
                raise ValueError(f"publisher {key!r} already declared with {entry[1]}, not {want}")
            return entry[0]
        pub = self._session.declare_publisher(
            key,
            priority=want.priority,
            congestion_control=want.congestion_control,
            express=want.express,
        )
        self._pubs[key] = (pub, want)
        return pub

    def put(self, key: str, payload: bytes, qos: QoS | None = None) -> None:
        """Publish ``payload`` on ``key`` (raises ``zenoh.ZError`` once the session is closed)."""
        self.get(key, qos).put(payload)

    def undeclare_all(self) -> None:
        """Undeclare every cached publisher (no-op for those of a closed session)."""
        for pub, _ in self._pubs.values():
            pub.undeclare()
        self._pubs.clear()

    def __len__(self) -> int:
        return len(self._pubs)


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


def _to_received(sample: zenoh.Sample) -> Received:
    return Received(
        key=str(sample.key_expr),
        payload=sample.payload.to_bytes(),
        rx_s=time.monotonic(),
        deleted=sample.kind == zenoh.SampleKind.DELETE,
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
    and a single drain is scheduled with ``call_soon_threadsafe``.

    Counters: ``received`` (samples pushed), ``dropped`` (queue overflow, more than ``maxlen``
    keys in latest mode, or arrival after the loop closed).
    """

    def __init__(self, mode: InboxMode = "latest", *, maxlen: int = 1024) -> None:
        if mode not in ("latest", "queue"):
            raise ValueError(f"Inbox mode must be 'latest' or 'queue', got {mode!r}")
        if maxlen < 1:
            raise ValueError(f"maxlen must be >= 1, got {maxlen}")
        self.mode: Final[InboxMode] = mode
        self.maxlen: Final = maxlen
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
            if self._drain_scheduled:
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

    def latest(self, key: str) -> Received | None:
        """Newest sample of ``key`` (latest mode), or ``None`` if none yet / deleted."""
        return self._latest.get(key)

    def snapshot(self) -> dict[str, Received]:
        """Copy of the newest sample of every key (latest mode)."""
        return dict(self._latest)

    def take_updates(self) -> dict[str, Received]:
        """Keys updated since the previous call, with their newest sample (deletes included)."""
        updated, self._updated = self._updated, {}
        return updated

    def get_nowait(self) -> Received | None:
        """Oldest queued sample (queue mode), or ``None``."""
        return self._queue.popleft() if self._queue else None

    def drain(self) -> list[Received]:
        """All queued samples, oldest first (queue mode)."""
        items = list(self._queue)
        self._queue.clear()
        return items

    async def get(self) -> Received:
        """Wait for and return the oldest queued sample (queue mode)."""
        while not self._queue:
            await self._event.wait()
            self._event.clear()
        return self._queue.popleft()

    async def wait(self, timeout_s: float | None = None) -> bool:
        """Wait until something arrived since the previous ``wait`` returned True.

        Returns False on timeout (``timeout_s`` in seconds; ``None`` waits forever).
        """
        if not self._event.is_set():
            try:
                async with asyncio.timeout(timeout_s):
                    await self._event.wait()
            except TimeoutError:
                return False
        self._event.clear()
        return True


SampleHandler = Callable[[Received], object]


def subscribe(
    session: zenoh.Session,
    key_expr: str,
    loop: asyncio.AbstractEventLoop,
    handler: Inbox | SampleHandler,
) -> zenoh.Subscriber[None]:
    """Subscribe to ``key_expr`` and deliver each sample to the event loop ``loop``.

    ``handler`` is an :class:`Inbox`, or a callable run on the loop thread with one
    :class:`Received` per sample, in arrival order. A callback subscriber stays declared until
    ``undeclare()`` or the session closes, even if the returned object is dropped (zenoh 1.x).
    """
    if isinstance(handler, Inbox):
        inbox = handler
        inbox.bind(loop)

        def on_sample_inbox(sample: zenoh.Sample) -> None:  # Zenoh thread
            inbox.push(_to_received(sample))

        return session.declare_subscriber(key_expr, on_sample_inbox)

    fn = handler

    def on_sample(sample: zenoh.Sample) -> None:  # Zenoh thread
        _post(loop, fn, _to_received(sample))

    return session.declare_subscriber(key_expr, on_sample)


# --------------------------------------------------------------------------------------------
# Liveliness
# --------------------------------------------------------------------------------------------


def declare_token(session: zenoh.Session, key: str) -> zenoh.LivelinessToken:
    """Declare a liveliness token at ``key``. KEEP THE RETURNED TOKEN REFERENCED: it is
    undeclared when garbage-collected. It also vanishes when the session closes, the process
    dies (~3 ms after SIGKILL) or the link lease expires (a hang: ``lease_ms``)."""
    return session.liveliness().declare_token(key)


LivelinessHandler = Callable[[str, bool], object]


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

    def on_sample(sample: zenoh.Sample) -> None:  # Zenoh thread
        _post(loop, on_change, str(sample.key_expr), sample.kind == zenoh.SampleKind.PUT)

    return session.liveliness().declare_subscriber(pattern, on_sample, history=history)


# --------------------------------------------------------------------------------------------
# Process lifecycle
# --------------------------------------------------------------------------------------------

NodeMain = Callable[[asyncio.Event], Awaitable[int]]

_STOP_SIGNALS: Final = (signal.SIGINT, signal.SIGTERM)
FORCED_EXIT_CODE: Final = 70
"""Exit status when the shutdown watchdog had to force the process out (EX_SOFTWARE)."""


class _ShutdownWatchdog:
    """Forces ``os._exit`` if the process has not finished shutting down in time.

    Armed from a plain Python signal handler, so it starts counting even if the event loop is
    stuck in blocking code and never runs its own signal callback.
    """

    def __init__(self, deadline_s: float) -> None:
        self._deadline_s = deadline_s
        self._armed = threading.Event()
        self._done = threading.Event()
        self._thread = threading.Thread(target=self._run, name="shutdown-watchdog", daemon=True)
        self._thread.start()

    def arm(self) -> None:  # safe in a signal handler: only sets an Event nobody else locks
        self._armed.set()

    @staticmethod
    def fire_now() -> None:
        """Exit at once (the operator sent a second signal)."""
        _forced_exit("run_node: second stop signal, exiting now")

    def disarm(self) -> None:
        self._done.set()
        self._armed.set()
        self._thread.join(timeout=1.0)

    def _run(self) -> None:
        self._armed.wait()
        if self._done.wait(self._deadline_s):
            return
        _forced_exit("run_node: shutdown did not finish in time, forcing exit")


def _forced_exit(message: str) -> None:
    """Leave the process now: no cleanup can run (the kernel closes the sockets, so peers see the
    links drop and the tokens vanish within milliseconds)."""
    with contextlib.suppress(OSError):
        os.write(2, message.encode() + b"\n")
    os._exit(FORCED_EXIT_CODE)


def _install_stop_signals(
    loop: asyncio.AbstractEventLoop, stop: asyncio.Event, watchdog: _ShutdownWatchdog
) -> dict[int, Any]:
    """Install the stop handlers; return the previous Python handlers to restore."""
    previous: dict[int, Any] = {sig: signal.getsignal(sig) for sig in _STOP_SIGNALS}

    def on_signal_in_loop(signum: int) -> None:
        if stop.is_set():  # second signal: the operator insists
            watchdog.fire_now()
        stop.set()

    for sig in _STOP_SIGNALS:
        # The loop callback sets the stop Event (asyncio's own wake-up-fd mechanism) ...
        loop.add_signal_handler(sig, on_signal_in_loop, sig)
        # ... and a chained Python-level handler arms the watchdog at once. asyncio's Python
        # handler is a no-op placeholder (the wake-up fd does the work), so chaining is safe.
        inner = signal.getsignal(sig)

        def on_signal_now(signum: int, frame: FrameType | None, _inner: Any = inner) -> None:
            watchdog.arm()
            if callable(_inner):
                _inner(signum, frame)

        signal.signal(sig, on_signal_now)
    return previous


async def _supervise(main: NodeMain, grace_s: float, watchdog: _ShutdownWatchdog) -> int:
    loop = asyncio.get_running_loop()
    stop = asyncio.Event()
    previous = _install_stop_signals(loop, stop, watchdog)
    task: asyncio.Task[int] = asyncio.ensure_future(main(stop))
    stopping = asyncio.ensure_future(stop.wait())
    try:
        await asyncio.wait({task, stopping}, return_when=asyncio.FIRST_COMPLETED)
        if not task.done():
            await asyncio.wait({task}, timeout=grace_s)
        if not task.done():
            print(
                f"run_node: main did not return {grace_s:.2f} s after stop; cancelling",
                file=sys.stderr,
            )
            task.cancel()
            await asyncio.wait({task})
    finally:
        stopping.cancel()
        watchdog.arm()  # from here on, shutdown is on the clock
        for sig in _STOP_SIGNALS:
            loop.remove_signal_handler(sig)  # also detaches the loop's wake-up fd
            signal.signal(sig, previous[sig])
        # Close sessions while the loop is still open, so no callback posts to a closed loop.
        forgotten = _close_node_sessions()
        if forgotten:
            print(f"run_node: closed {forgotten} session(s) main left open", file=sys.stderr)
    if task.cancelled():
        return 1
    return task.result()  # re-raises main's exception


def run_node(main: NodeMain, *, grace_s: float = 0.4, hard_exit_s: float = 0.9) -> int:
    """Run a node's ``main(stop)`` on a fresh event loop and return its exit status.

    * SIGINT and SIGTERM set ``stop``; ``main`` should then return promptly (``0`` on a clean
      stop). A second signal forces the exit.
    * ``main`` gets ``grace_s`` seconds after ``stop`` to return, then it is cancelled (status 1).
    * Every session opened with :func:`open_session`/:func:`open_session_async` and still open
      is closed before the loop is, whatever happened (return, exception, cancellation).
    * If the process is still shutting down ``hard_exit_s`` seconds after the first signal (or
      after ``main`` ended), a watchdog writes to stderr and calls ``os._exit(70)``.

    Call it from the main thread; use ``raise SystemExit(run_node(main))`` or return its value
    from a ``formation`` subcommand. ``main``'s exceptions propagate after the cleanup.
    """
    if threading.current_thread() is not threading.main_thread():
        raise RuntimeError("run_node must be called from the main thread (signal handlers)")
    if _node_sessions is not None:
        raise RuntimeError("run_node is already running")
    watchdog = _ShutdownWatchdog(hard_exit_s)
    _track_node_sessions(True)
    try:
        return asyncio.run(_supervise(main, grace_s, watchdog))
    finally:
        _close_node_sessions()  # again: a session opened during asyncio.run's own teardown
        _track_node_sessions(False)
        watchdog.disarm()
