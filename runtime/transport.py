"""Zenoh sessions for every process shell: settings, config, opening with retries, publishers.

Only the ``runtime`` package imports ``zenoh``; the contract (``bus_schemas``) stays stdlib +
msgpack and payloads here are plain ``bytes``.

* **Settings -> config.** :class:`ZenohSettings` (or ``add_zenoh_arguments`` +
  ``settings_from_args`` on a CLI) says where to connect. :func:`make_config` turns it into a
  ``zenoh.Config``: an optional JSON5 file first, our settings on top. Multicast scouting is
  always written as *off* unless asked for, so parallel runs never find each other by accident.
* **Sessions.** :func:`open_session` / :func:`open_session_async` open a session. A client
  session fails at once when no router is up, so both retry until ``open_timeout_s`` and then
  raise :class:`TransportError` naming the endpoints. Sessions opened while
  :func:`runtime.lifecycle.run_node` runs are tracked so it can close any a node forgot.
* **Publishing.** :class:`Publishers` declares one publisher per key with a fixed :class:`QoS`.

Receiving (the Zenoh thread -> event loop bridge) is :mod:`runtime.bridge`; the process
lifecycle and the one node bootstrap (:func:`runtime.lifecycle.serve`) are
:mod:`runtime.lifecycle`. docs/runtime.md has a worked example of a node.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import os
import re
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Final, Literal

import zenoh

from bus_schemas.session import DEFAULT_ENDPOINT, KEEP_ALIVES_PER_LEASE, MAX_MESSAGE_BYTES

__all__ = [
    "DEFAULT_ENDPOINT",
    "LOCKSTEP_ZENOH_RUNTIME",
    "MAX_MESSAGE_BYTES",
    "QOS_CONTROL",
    "QOS_CRITICAL",
    "QOS_TELEMETRY",
    "SESSION_CLOSE_S",
    "ZENOH_RUNTIME_ENV",
    "Publishers",
    "QoS",
    "TransportError",
    "ZenohSettings",
    "add_zenoh_arguments",
    "close_session",
    "make_config",
    "open_session",
    "open_session_async",
    "settings_from_args",
]


Mode = Literal["client", "peer", "router"]
_MODES: Final = ("client", "peer", "router")

_MIN_LEASE_MS: Final = 100
_RETRY_PERIOD_S: Final = 0.1
_CONNECT_RETRY: Final = {"period_init_ms": 100, "period_max_ms": 500, "period_increase_factor": 2}
"""Client reconnection to its router after the link was lost (see :func:`make_config`)."""


ZENOH_RUNTIME_ENV: Final = "ZENOH_RUNTIME"
LOCKSTEP_ZENOH_RUNTIME: Final = (
    "(app: (worker_threads: 1), acc: (handover: app), tx: (handover: app), "
    "rx: (handover: app), net: (handover: app))"
)
"""The value of Zenoh's ``ZENOH_RUNTIME`` environment variable (read once, when the process
opens its first session) that ``formation up --lockstep`` gives its children: every one of
Zenoh's runtimes (receive, transmit, accept, network, application) handed over to one worker
thread (a process shows two Zenoh threads, ``app-0`` and ``app-1``, instead of its default
nine). A lockstep tick is a chain of small bursts between seven processes on a few cores, and
each hand-over between Zenoh's threads (a sample read on one, its callback on another, a put
flushed by a third) is a wake-up the scheduler must find a core for (docs/benchmarks.md "One
Zenoh thread a lockstep process": 106 -> 51 context switches a tick). The price: a callback on
Zenoh's thread that blocks stops the process's whole Zenoh (its puts' flushing too), so no
handler may wait for a lock held across a put (the plant's tick thread puts after it lets go
of its guard); and keep-alives share that thread, which lockstep does not mind (a lost token is
a fault event only there). Realtime nodes keep Zenoh's default."""


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
    # Cap what a session reassembles, unless a config file already set a cap as small (every
    # session of every process: nodes, tools, the launcher).
    configured = json.loads(config.get_json("transport/link/rx/max_message_size"))
    if not isinstance(configured, int) or configured > MAX_MESSAGE_BYTES:
        put("transport/link/rx/max_message_size", MAX_MESSAGE_BYTES)
    # Zenoh's shared-memory transport (on by default between processes of one host) carries
    # messages over 3 KiB outside the link, past this cap, in segments mapped by every
    # receiver (measured here: a 4 MiB put reached a capped subscriber). The bus's payloads
    # are at most 64 KiB: keep everything on the link.
    put("transport/shared_memory/enabled", False)
    if settings.lease_ms is not None:
        put("transport/link/tx/lease", int(settings.lease_ms))
        put("transport/link/tx/keep_alive", KEEP_ALIVES_PER_LEASE)
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


def _close_node_sessions(timeout_s: float = 0.0) -> tuple[int, int]:
    """Close the sessions the running node opened and left open, each within ``timeout_s``
    (:func:`close_session`); return (how many were left open, how many are still not closed).
    A session whose owner already gave up waiting for its close is not waited for again."""
    with _node_sessions_lock:
        sessions = list(_node_sessions or [])
    forgotten = blocked = 0
    for s in sessions:
        if s.is_closed():
            continue
        with _closers_lock:
            given_up = id(s) in _closers  # its owner already waited for its close
        forgotten += not given_up
        blocked += not close_session(s, 0.0 if given_up else timeout_s)
    return forgotten, blocked


SESSION_CLOSE_S: Final = 0.3
"""How long a stopping process waits for ``session.close()`` (:func:`close_session`)."""
_closers: dict[int, threading.Thread] = {}  # id(session) -> the thread closing it
_closers_lock = threading.Lock()


def _close_quietly(session: zenoh.Session, first: Callable[[], object] | None) -> None:
    try:
        if first is not None:
            first()
    finally:
        # zenoh.ZError "close operation timed out" (its own bound, ~10 s): nobody waits any more
        with contextlib.suppress(zenoh.ZError):
            session.close()


def close_session(
    session: zenoh.Session,
    timeout_s: float = SESSION_CLOSE_S,
    *,
    first: Callable[[], object] | None = None,
) -> bool:
    """Close ``session`` (after calling ``first``, e.g. dropping its tokens), waiting at most
    ``timeout_s``; True if it is closed, False if the close is still blocked (then the caller
    should log it and leave anyway: the kernel closes the sockets when the process exits, the
    router drops the link and the process's tokens vanish).

    Why a bound: ``session.close()`` flushes what the session queued for its router. When the
    router does not read (stopped, or starved of CPU next to busy loops) and the queue is full,
    zenoh 1.10's close waits, measured 12-17 s (then it raises "close operation timed out");
    with an empty queue it takes ~5 ms even with the router stopped. The close runs on a daemon
    thread (the GIL is released while it waits), so the caller goes on after ``timeout_s``; a
    second call for a session whose close is still running joins that close again (it never
    starts another). Never raises for Zenoh's own close timeout.
    """
    if session.is_closed():
        return True
    key = id(session)  # the thread holds the session: the id is not reused while it runs
    with _closers_lock:
        thread = _closers.get(key)
        if thread is None:
            thread = threading.Thread(
                target=_close_quietly, args=(session, first), name="zenoh-close", daemon=True
            )
            _closers[key] = thread
            thread.start()
    thread.join(max(0.0, timeout_s))
    if thread.is_alive():
        return False
    with _closers_lock:
        _closers.pop(key, None)
    return True


_RUST_SOURCE = re.compile(r"\s*\bat /\S+\.rs:\d+\.?")


def zenoh_error_text(exc: BaseException) -> str:
    """A Zenoh error as one line for a user: no Rust source paths, no brackets, no newlines."""
    text = _RUST_SOURCE.sub("", str(exc)).replace("[", "").replace("]", "")
    return " ".join(text.split()).rstrip(".")


def _open_error(settings: ZenohSettings, waited_s: float, exc: BaseException) -> TransportError:
    text = zenoh_error_text(exc)
    if "Address already in use" in text:
        where = ", ".join(settings.listen) or "(config file endpoints)"
        return TransportError(
            f"cannot listen on {where}: address already in use (another `formation router` or "
            "`formation up` running? stop it or choose another endpoint)"
        )
    where = ", ".join(settings.connect) or "(config file endpoints)"
    return TransportError(
        f"could not open a Zenoh {settings.mode or 'session'} session to {where} "
        f"within {waited_s:.1f} s: {text}. Is `formation router` (or `formation up`) running?"
    )


def _runtime_error(value: str, why: str) -> TransportError:
    return TransportError(
        f"Zenoh cannot start its threads: the environment's {ZENOH_RUNTIME_ENV}={value[:200]!r} "
        f"{why} (unset it, or give Zenoh's RON, e.g. {LOCKSTEP_ZENOH_RUNTIME!r})"
    )


def _open_once(settings: ZenohSettings) -> zenoh.Session:
    """One ``zenoh.open``. A ``ZENOH_RUNTIME`` that Zenoh cannot parse makes it panic (a
    ``PanicException``, which is no ``Exception``): refused here before, when it is blank or no
    RON map at all, and otherwise turned into a :class:`TransportError` naming it."""
    value = os.environ.get(ZENOH_RUNTIME_ENV)
    if value is not None and not value.strip().startswith("("):
        raise _runtime_error(value, "is not a runtime configuration")
    config = make_config(settings)
    try:
        return _register(zenoh.open(config))
    except BaseException as exc:  # (a ZError, or anything else, goes up as it is)
        if type(exc).__name__ != "PanicException" or value is None:
            raise
        raise _runtime_error(value, f"made Zenoh fail: {zenoh_error_text(exc)[:200]}") from None


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
    coalesce what is queued. With eclipse-zenoh 1.10 it gave no latency gain here but cost many
    times the CPU per put and one more wake-up of every receiver per message, and lockstep ran
    faster without it (docs/zenoh-notes.md, docs/benchmarks.md). So no publisher here is express.
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
        self._matching: dict[str, list[bool]] = {}  # key -> [anyone subscribed] (matching)
        self._listeners: list[zenoh.MatchingListener] = []

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

    def matching(self, key: str, qos: QoS | None = None) -> bool:
        """Whether a subscriber anywhere matches ``key`` now: a form of a message that nobody
        reads need not be put. The first call declares the publisher and a Zenoh matching
        listener on it; from then on the answer is a lookup, kept current by the listener's
        callback on Zenoh's thread (so a thread that holds a lock an input handler waits for
        may ask: no call into Zenoh). True when Zenoh cannot say (put rather than lose a
        reader). Call it once per key before such a thread runs (the lockstep plant does)."""
        state = self._matching.get(key)
        if state is None:
            state = self._matching[key] = [True]
            pub = self.get(key, qos)

            def on_change(status: zenoh.MatchingStatus, state: list[bool] = state) -> None:
                state[0] = bool(status.matching)

            try:
                self._listeners.append(pub.declare_matching_listener(on_change))
                status = pub.matching_status  # (a MatchingStatus; the stubs say bool)
                state[0] = bool(getattr(status, "matching", status))
            except zenoh.ZError:
                state[0] = True
        return state[0]

    def undeclare_all(self) -> None:
        """Undeclare every cached publisher and matching listener (no-op for those of a closed
        session)."""
        for listener in self._listeners:
            listener.undeclare()
        self._listeners.clear()
        self._matching.clear()
        for pub, _ in self._pubs.values():
            pub.undeclare()
        self._pubs.clear()

    def __len__(self) -> int:
        return len(self._pubs)


# --------------------------------------------------------------------------------------------
