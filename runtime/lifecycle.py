"""Process lifecycle of every node: signals, bounded shutdown, and the one bootstrap ``serve``.

:func:`run_node` owns the event loop: SIGINT/SIGTERM set a stop ``asyncio.Event``, ``main`` gets
``grace_s`` to return, is then cancelled, every session opened through :mod:`runtime.transport`
and still open is closed (each waited for at most ``SESSION_CLOSE_S``:
:func:`runtime.transport.close_session`), and a watchdog thread forces the process out
``hard_exit_s`` after the first signal if anything still hangs (every process exits within a
second of a stop signal). Nothing in between waits without a bound: the loop's default executor
is not joined (:func:`_run_loop`), a blocked session close is given up and logged, and
:class:`StopTrace` says where a slow stop spent its time.

:func:`serve` is the bootstrap every process shell uses on top of it: open the session (retrying
while the router starts), hand the shell a :class:`NodeIO` (publishers, the subscription bridge,
liveliness, tokens kept alive), and close everything whatever happens.
"""

from __future__ import annotations

import asyncio
import atexit
import contextlib
import faulthandler
import gc
import os
import signal
import sys
import threading
import time
from collections.abc import Awaitable, Callable, Coroutine
from dataclasses import dataclass, field
from types import FrameType
from typing import Any, Final

import zenoh

from runtime import transport as _tp
from runtime.bridge import (
    LivelinessHandler,
    Received,
    TickPump,
    declare_token,
    subscribe,
    subscribe_on_thread,
    watch_liveliness,
)
from runtime.log import NodeLog

__all__ = [
    "FORCED_EXIT_CODE",
    "GC_FULL_EVERY",
    "GC_MIDDLE_EVERY",
    "GIL_SWITCH_INTERVAL_S",
    "PARENT_ENV",
    "NodeIO",
    "NodeMain",
    "bind_to_parent",
    "exit_fast",
    "fast_exit_requested",
    "gc_generation",
    "request_fast_exit",
    "run_node",
    "serve",
    "stop_signalled",
]

# --------------------------------------------------------------------------------------------
# Process lifecycle
# --------------------------------------------------------------------------------------------

NodeMain = Callable[[asyncio.Event], Awaitable[int]]

_STOP_SIGNALS: Final = (signal.SIGINT, signal.SIGTERM)
FORCED_EXIT_CODE: Final = 70
"""Exit status when the shutdown watchdog had to force the process out (EX_SOFTWARE)."""
OUTPUT_ERROR_EXIT: Final = 74
"""Exit status of a node that ran to its end but could not write an output file it was asked
for (EX_IOERR; a full or read-only disk: ``formation plant --stats-out``)."""
GIL_SWITCH_INTERVAL_S: Final = 0.0005
"""The interpreter's switch interval in every process shell (:func:`serve`; Python's default is
5 ms). Zenoh delivers a sample on its own thread, which needs the GIL for the bridge's callback
(receive time, hand-over to the loop): while the loop computes (an agent host stepping a
hundred robots), that thread waited up to 5 ms before it could even stamp the sample. 0.5 ms
bounds that wait; it costs nothing while no other thread wants the GIL (docs/scale.md)."""
GC_MIDDLE_EVERY: Final = 16
"""A process that collects its garbage by hand between rounds of work (the agent host in
realtime, ``HostNode.collect_garbage``): every round the youngest generation, every 16th the
middle one too, every :data:`GC_FULL_EVERY` th all of them (:func:`gc_generation`)."""
GC_FULL_EVERY: Final = 512


def gc_generation(round_k: int) -> int:
    """The oldest generation to collect after round ``round_k`` (1, 2, ...) of manual GC."""
    return 2 if round_k % GC_FULL_EVERY == 0 else 1 if round_k % GC_MIDDLE_EVERY == 0 else 0


STOP_TRACE_ENV: Final = "FORMATION_STOP_TRACE"
"""Set (to anything but empty or ``0``) in a node's environment: it writes one ``stop trace``
line to stderr when it leaves (:class:`StopTrace`); bench/bench_exit.py sets it."""
STOP_TRACE_SLOW_S: Final = 0.5
"""A stop slower than this (first signal to leaving) writes its trace line even without
:data:`STOP_TRACE_ENV`, so a slow stop in a real run says where its time went."""


class StopTrace:
    """When each phase of a stop ended, from the first stop signal (``time.monotonic``).

    :func:`run_node`, :func:`serve` and :func:`exit_fast` mark their phases (:meth:`mark`); the
    process writes one line to stderr as it leaves (:meth:`report`), e.g. ``stop trace: signal
    at 1234.567890 s, loop 1 ms, main 15 ms, ... exit 40 ms`` (when the handler ran, on the
    system-wide ``time.monotonic`` clock, then each phase's end after it), when
    :data:`STOP_TRACE_ENV` is set or the stop took more than :data:`STOP_TRACE_SLOW_S`. Marking
    costs a clock read and a list append; nothing is recorded before the first signal.
    """

    def __init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        """Forget any earlier stop (:func:`run_node` starts with a fresh trace)."""
        self.t0: float | None = None
        self.marks: list[tuple[str, float]] = []
        self.reported = False

    def signalled(self) -> None:
        """The first stop signal (called from the Python signal handler)."""
        if self.t0 is None:
            self.t0 = time.monotonic()

    def mark(self, phase: str) -> None:
        if self.t0 is not None:
            self.marks.append((phase, time.monotonic()))

    def line(self) -> str:
        if self.t0 is None:
            return "stop trace: no stop signal"
        t0 = self.t0
        parts = [f"{phase} {(t - t0) * 1e3:.0f} ms" for phase, t in self.marks]
        return f"stop trace: signal at {t0:.6f} s, " + ", ".join(parts)

    def report(self) -> None:
        """Write :meth:`line` once, if asked for or slow (never raises)."""
        if self.t0 is None or self.reported:
            return
        self.reported = True
        end = self.marks[-1][1] if self.marks else time.monotonic()
        slow = end - self.t0 > STOP_TRACE_SLOW_S
        if slow or os.environ.get(STOP_TRACE_ENV, "") not in ("", "0"):
            with contextlib.suppress(OSError):
                os.write(2, (self.line() + "\n").encode())


stop_trace = StopTrace()
"""This process's :class:`StopTrace` (reported at exit: :func:`exit_fast`, the watchdog, or the
interpreter's own exit handlers for a process that leaves the usual way)."""
atexit.register(stop_trace.report)


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


def stop_signalled() -> bool:
    """True once a stop signal (SIGINT/SIGTERM) reached this process under :func:`run_node`:
    set by the Python signal handler itself, at once, while the stop ``Event`` is set by a loop
    callback that runs only after every callback already queued (a burst of samples, e.g. the
    tokens of a whole agent host vanishing). A handler that would do costly work for an event
    that is moot when the node stops checks this as well as the ``Event``."""
    return stop_trace.t0 is not None


def _forced_exit(message: str) -> None:
    """Leave the process now: no cleanup can run (the kernel closes the sockets, so peers see the
    links drop and the tokens vanish within milliseconds)."""
    stop_trace.mark("forced")
    stop_trace.report()
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
        stop_trace.mark("loop")
        stop.set()

    for sig in _STOP_SIGNALS:
        # The loop callback sets the stop Event (asyncio's own wake-up-fd mechanism) ...
        loop.add_signal_handler(sig, on_signal_in_loop, sig)
        # ... and a chained Python-level handler arms the watchdog at once. asyncio's Python
        # handler is a no-op placeholder (the wake-up fd does the work), so chaining is safe.
        inner = signal.getsignal(sig)

        def on_signal_now(signum: int, frame: FrameType | None, _inner: Any = inner) -> None:
            stop_trace.signalled()
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
        stop_trace.mark("main")
    finally:
        stopping.cancel()
        watchdog.arm()  # from here on, shutdown is on the clock
        for sig in _STOP_SIGNALS:
            loop.remove_signal_handler(sig)  # also detaches the loop's wake-up fd
            signal.signal(sig, previous[sig])
        # Close sessions while the loop is still open, so no callback posts to a closed loop.
        forgotten, blocked = _tp._close_node_sessions(_tp.SESSION_CLOSE_S)
        stop_trace.mark("sessions")
        if forgotten:
            print(f"run_node: closed {forgotten} session(s) main left open", file=sys.stderr)
        if blocked:
            print(
                f"run_node: {blocked} Zenoh session close(s) still blocked after "
                f"{_tp.SESSION_CLOSE_S:g} s (router not reading?): exiting without them",
                file=sys.stderr,
            )
    if task.cancelled():
        return 1
    return task.result()  # re-raises main's exception


LEFTOVER_TASKS_S: Final = 0.1
""":func:`_run_loop`: how long tasks still pending when the node's main ended get to finish
after their cancellation."""


def _run_loop(coro: Coroutine[Any, Any, int]) -> int:
    """``asyncio.run(coro)`` without its unbounded waits at the end: the tasks left pending get
    :data:`LEFTOVER_TASKS_S` after their cancellation, and the loop's default executor is shut
    down without waiting for its threads (``loop.close()``; ``asyncio.run`` joins them, so a
    ``run_in_executor`` call blocked in Zenoh, e.g. a query waiting for its timeout, held the
    process until it returned). A thread left behind is a daemon-like worker the process does
    not wait for: the entry point leaves with :func:`exit_fast`."""
    loop = asyncio.new_event_loop()
    asyncio.set_event_loop(loop)
    try:
        return loop.run_until_complete(coro)
    finally:
        try:
            pending = [t for t in asyncio.all_tasks(loop) if not t.done()]
            for t in pending:
                t.cancel()
            if pending:
                loop.run_until_complete(asyncio.wait(pending, timeout=LEFTOVER_TASKS_S))
            for t in pending:
                if t.done() and not t.cancelled() and t.exception() is not None:
                    loop.call_exception_handler(
                        {"message": "unhandled exception in a task left at shutdown",
                         "exception": t.exception(), "task": t}
                    )  # fmt: skip
            loop.run_until_complete(loop.shutdown_asyncgens())
        finally:
            asyncio.set_event_loop(None)
            loop.close()  # its default executor: shutdown(wait=False)


def run_node(main: NodeMain, *, grace_s: float = 0.4, hard_exit_s: float = 0.9) -> int:
    """Run a node's ``main(stop)`` on a fresh event loop and return its exit status.

    * SIGINT and SIGTERM set ``stop``; ``main`` should then return promptly (``0`` on a clean
      stop). A second signal forces the exit.
    * ``main`` gets ``grace_s`` seconds after ``stop`` to return, then it is cancelled (status 1).
    * Every session opened with :func:`open_session`/:func:`open_session_async` and still open
      is closed before the loop is, whatever happened (return, exception, cancellation); each
      close is waited for at most ``SESSION_CLOSE_S`` (a close still blocked is left to its
      thread and said on stderr). Tasks still pending then get ``LEFTOVER_TASKS_S`` after their
      cancellation; the loop's executor threads are not waited for.
    * If the process is still shutting down ``hard_exit_s`` seconds after the first signal (or
      after ``main`` ended), a watchdog writes to stderr and calls ``os._exit(70)``.

    Call it from the main thread; use ``raise SystemExit(run_node(main))`` or return its value
    from a ``formation`` subcommand. ``main``'s exceptions propagate after the cleanup.
    """
    if threading.current_thread() is not threading.main_thread():
        raise RuntimeError("run_node must be called from the main thread (signal handlers)")
    if _tp._node_sessions is not None:
        raise RuntimeError("run_node is already running")
    watchdog = _ShutdownWatchdog(hard_exit_s)
    stop_trace.reset()
    _tp._track_node_sessions(True)
    try:
        return _run_loop(_supervise(main, grace_s, watchdog))
    finally:
        stop_trace.mark("loop closed")
        _tp._close_node_sessions()  # again (no wait): one opened during the loop's teardown
        _tp._track_node_sessions(False)
        watchdog.disarm()
        stop_trace.mark("run_node")
        request_fast_exit()


# --------------------------------------------------------------------------------------------
# Leaving the process
# --------------------------------------------------------------------------------------------

EXIT_HANDLERS_DEADLINE_S: Final = 1.0
""":func:`exit_fast`: the exit handlers' time before the process is forced out (status 1)."""
_fast_exit = False


def request_fast_exit() -> None:
    """Say this process's work is done and its sessions closed: the entry point may leave with
    :func:`exit_fast` (run_node calls it; so does the ``formation up`` launcher)."""
    global _fast_exit
    _fast_exit = True


def fast_exit_requested() -> bool:
    return _fast_exit


def exit_fast(code: int) -> None:
    """Leave the process with ``code`` without the interpreter's teardown: the ``atexit``
    handlers run and stdout/stderr are flushed, then ``os._exit``.

    Why: on a loaded machine (a CPU hog of 2x the cores) the teardown of a process that held a
    Zenoh session (the final garbage collection of every module's objects) was seen to take
    more than a second after run_node had returned, so a node exceeded its stop bound although
    its sessions were closed in time (issue 13 item 7; the stack of such a process: "Garbage-
    collecting, <no Python frame>"). Call it only from the process's entry point. The exit
    handlers get :data:`EXIT_HANDLERS_DEADLINE_S`; past that, faulthandler (a C thread, no GIL
    needed) writes every thread's stack to stderr and exits with status 1."""
    faulthandler.dump_traceback_later(EXIT_HANDLERS_DEADLINE_S, exit=True)
    stop_trace.mark("exit")
    try:
        atexit._run_exitfuncs()  # the stop trace's report among them
    finally:
        stop_trace.report()  # if the handlers failed before it (a no-op otherwise)
        for stream in (sys.stdout, sys.stderr):
            with contextlib.suppress(Exception):
                stream.flush()
        os._exit(code)


# --------------------------------------------------------------------------------------------
# The node bootstrap
# --------------------------------------------------------------------------------------------


@dataclass
class NodeIO:
    """What :func:`serve` hands a process shell: its open session and the ways to use it.

    Attributes:
        session: the open Zenoh session (closed by :func:`serve`).
        loop: the running event loop.
        pubs: the publishers of this node (:class:`runtime.transport.Publishers`).
        log: the node's :class:`~runtime.log.NodeLog`.
        settings: the settings the session was opened with (``lease_ms`` sizes the hang gap).
    """

    session: zenoh.Session
    loop: asyncio.AbstractEventLoop
    pubs: _tp.Publishers
    log: NodeLog
    settings: _tp.ZenohSettings
    _keep: list[Any] = field(default_factory=list)

    def subscribe(
        self, key_expr: str, handler: Callable[[Received], object], *, wake: bool = True
    ) -> None:
        """Deliver every sample of ``key_expr`` to ``handler`` on the loop, in arrival order
        (:func:`runtime.bridge.subscribe`, the one bridge). ``wake=False``: a sample of this
        key is handled, in its place, when the next one that wakes the loop arrives (a
        lockstep node's inputs that only its next clock reads)."""
        self._keep.append(subscribe(self.session, key_expr, self.loop, handler, wake=wake))

    def subscribe_on_thread(self, key_expr: str, handler: Callable[[Received], object]) -> None:
        """Call ``handler`` on Zenoh's network thread for every sample of ``key_expr``, in the
        order the session received them (:func:`runtime.bridge.subscribe_on_thread`): no wake
        of the loop (a lockstep plant's inputs, each a few microseconds). The handler takes
        the node's guard itself and must never wait for a lock another thread holds across a
        put: with one Zenoh thread (``runtime.transport.LOCKSTEP_ZENOH_RUNTIME``) that put
        may be waiting for this very thread."""
        self._keep.append(subscribe_on_thread(self.session, key_expr, handler))

    def tick_pump(
        self, guard: contextlib.AbstractContextManager[Any], *, name: str = "tick-pump"
    ) -> TickPump:
        """A lockstep node's :class:`runtime.bridge.TickPump` on this session, kept (and
        undeclared) with the node's subscriptions; declare its sides, then ``start`` it."""
        pump = TickPump(self.session, guard, name=name)
        self._keep.append(pump)
        return pump

    def watch_liveliness(self, pattern: str, on_change: LivelinessHandler) -> None:
        """Call ``on_change(key, alive)`` on the loop when a token matching ``pattern`` appears
        or vanishes (those already alive are reported once)."""
        self._keep.append(watch_liveliness(self.session, pattern, self.loop, on_change))

    def declare_token(self, key: str) -> None:
        """Declare a liveliness token at ``key``, kept alive until the node ends."""
        self._keep.append(declare_token(self.session, key))

    def close(self) -> None:
        """Drop the tokens and subscriptions (the session close undeclares them too); a tick
        pump's thread ends."""
        for kept in self._keep:
            if isinstance(kept, TickPump):
                kept.undeclare()
        self._keep.clear()


NodeBody = Callable[[NodeIO, asyncio.Event], Awaitable[int]]


def serve(
    name: str,
    settings: _tp.ZenohSettings,
    body: NodeBody,
    *,
    grace_s: float = 0.4,
    hard_exit_s: float = 0.9,
) -> int:
    """Run a process shell: the one bootstrap of every node; returns the exit status.

    Opens the session (retrying while the router starts; on failure logs one line and returns
    1), then awaits ``body(io, stop)`` under :func:`run_node` (signals, bounded shutdown), and
    closes the tokens, subscriptions and session whatever happens, waiting for that at most
    ``SESSION_CLOSE_S`` (then ``io.log`` says the close is still blocked and the node leaves).
    ``name`` prefixes the log lines (``io.log``). ``body`` declares its publishers and
    subscriptions on ``io``, prints its ready line, runs until ``stop`` is set and returns the
    exit status (0 on a clean stop).
    """

    sys.setswitchinterval(GIL_SWITCH_INTERVAL_S)
    # Everything imported so far lives as long as the process: out of the collector's sight, a
    # full collection walks only what the node creates (measured in an agent host: 15 ms with
    # the imports' ~60k objects, which held the loop and Zenoh's thread that long).
    gc.collect()
    gc.freeze()

    async def main(stop: asyncio.Event) -> int:
        log = NodeLog(name)
        try:
            session = await _tp.open_session_async(settings)
        except (_tp.TransportError, ValueError) as exc:
            log.info(str(exc))
            return 1
        io = NodeIO(session, asyncio.get_running_loop(), _tp.Publishers(session), log, settings)
        try:
            return await body(io, stop)
        finally:
            stop_trace.mark("body")
            if not _tp.close_session(session, first=io.close):
                log.info(
                    f"Zenoh session close still blocked after {_tp.SESSION_CLOSE_S:g} s (router "
                    "not reading?): exiting without it"
                )
            stop_trace.mark("session")

    return run_node(main, grace_s=grace_s, hard_exit_s=hard_exit_s)


# --------------------------------------------------------------------------------------------
# Children of a launcher die with it
# --------------------------------------------------------------------------------------------

PARENT_ENV: Final = "FORMATION_PARENT_PID"
"""Set by a launcher (``formation up``) in its children's environment: the launcher's pid. A
process started with it calls :func:`bind_to_parent` first thing, so it never outlives the
launcher (issue 13: 101 orphans of a SIGKILLed launcher held the port and two cores)."""
_PR_SET_PDEATHSIG: Final = 1
PARENT_WATCH_PERIOD_S: Final = 0.2


def _set_pdeathsig(sig: int) -> bool:
    """``prctl(PR_SET_PDEATHSIG, sig)`` through libc (Linux); False where unavailable."""
    import ctypes
    import ctypes.util

    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
        return int(libc.prctl(_PR_SET_PDEATHSIG, sig, 0, 0, 0)) == 0
    except (OSError, AttributeError):
        return False


def bind_to_parent(env: dict[str, str] | None = None) -> bool:
    """Die with the launcher that started this process (a no-op unless :data:`PARENT_ENV`
    names this process's parent). Returns True when bound.

    Two layers: the kernel's parent-death signal (``PR_SET_PDEATHSIG`` = SIGKILL: when the
    launcher dies, whatever way, the kernel kills this process; a stopped (SIGSTOPped) process
    dies too, and its sockets close, so the port is free), and a daemon thread that polls
    ``getppid()`` every :data:`PARENT_WATCH_PERIOD_S` and exits the process (status 70) if the
    parent changed (systems without prctl; the signal covers the race of a launcher dying
    before the prctl: the ppid check right after it). The variable is removed from this
    process's environment so its own children (none today) are not bound to the wrong pid."""
    environ = os.environ if env is None else env
    raw = environ.pop(PARENT_ENV, None)
    if raw is None:
        return False
    try:
        parent = int(raw)
    except ValueError:
        return False
    if os.getppid() != parent:
        if parent > 1 and not _pid_alive(parent):
            _forced_exit(f"bind_to_parent: launcher {parent} is gone before this process started")
        return False  # started by something else with the variable inherited: not ours
    _set_pdeathsig(signal.SIGKILL)
    if os.getppid() != parent:  # the launcher died between the check and the prctl
        _forced_exit(f"bind_to_parent: launcher {parent} died while this process started")

    def watch() -> None:
        import time

        while os.getppid() == parent:
            time.sleep(PARENT_WATCH_PERIOD_S)
        _forced_exit(f"bind_to_parent: launcher {parent} is gone: exiting")

    threading.Thread(target=watch, name="parent-watch", daemon=True).start()
    return True


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True
