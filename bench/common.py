"""Helpers shared by the benchmarks: latency statistics, process spawning, the bare Zenoh floor.

Every latency a benchmark reports should be printed beside the bare Zenoh round trip measured in
the same run on the same machine, so a reader sees what the application adds::

    from common import measure_floor, print_latency_header, print_latency, LatencyStats

    floor = measure_floor()                          # router topology, callback receive
    stats = LatencyStats.from_samples(my_samples_s)  # seconds in, microseconds out
    print_latency_header()
    print_latency("zenoh floor (router, callback)", floor)
    print_latency("setpoint -> wheels", stats, floor=floor)

Processes are started with fork+exec (``subprocess``), never forked after Zenoh started, each in
its own session, and always stopped (SIGTERM, then SIGKILL) when the context exits.

This file is also the echo process of :func:`measure_floor`:
``python bench/common.py echo <client|peer> <connect|-> <listen|->``.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import os
import selectors
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Literal

REPO_ROOT = Path(__file__).resolve().parents[1]
if str(REPO_ROOT) not in sys.path:
    sys.path.insert(0, str(REPO_ROOT))

import zenoh  # noqa: E402

import runtime as rt  # noqa: E402

PING_KEY = "bench/floor/ping"
PONG_KEY = "bench/floor/pong"
ECHO_READY = "echo ready"
ROUTER_READY = "router listening on "

Topology = Literal["router", "peer"]
Receive = Literal["callback", "asyncio", "channel"]


# ---------------------------------------------------------------------------------------------
# Statistics
# ---------------------------------------------------------------------------------------------


def percentile(sorted_values: Sequence[float], q: float) -> float:
    """The ``q``-th percentile (0..100) of ascending ``sorted_values``, linear interpolation."""
    if not sorted_values:
        return math.nan
    pos = (len(sorted_values) - 1) * q / 100.0
    lo = math.floor(pos)
    hi = min(lo + 1, len(sorted_values) - 1)
    return sorted_values[lo] + (sorted_values[hi] - sorted_values[lo]) * (pos - lo)


@dataclass(frozen=True)
class LatencyStats:
    """Summary of latency samples, in microseconds; ``lost`` counts samples that timed out."""

    n: int
    lost: int
    min_us: float
    p50_us: float
    p90_us: float
    p99_us: float
    max_us: float
    mean_us: float
    cpu_us: float = math.nan
    """CPU time of the measuring process (every thread) per sample, where measured."""

    @classmethod
    def from_samples(
        cls, samples_s: Sequence[float], lost: int = 0, cpu_s: float | None = None
    ) -> LatencyStats:
        """Summarise latencies given in seconds (``cpu_s``: the process's CPU seconds over
        them, if measured)."""
        us = sorted(s * 1e6 for s in samples_s)
        if not us:
            return cls(0, lost, *(math.nan,) * 6)
        return cls(
            n=len(us),
            lost=lost,
            min_us=us[0],
            p50_us=percentile(us, 50),
            p90_us=percentile(us, 90),
            p99_us=percentile(us, 99),
            max_us=us[-1],
            mean_us=sum(us) / len(us),
            cpu_us=math.nan if cpu_s is None else cpu_s * 1e6 / (len(us) + lost),
        )


_HEADER = (
    f"{'path':<44} {'n':>6} {'lost':>4} {'p50 us':>8} {'p90 us':>8} {'p99 us':>8} "
    f"{'mean us':>8} {'max us':>8}"
)


def format_latency(label: str, stats: LatencyStats, floor: LatencyStats | None = None) -> str:
    """One table row; with ``floor``, the p50/p99 excess over the floor is appended."""
    row = (
        f"{label:<44} {stats.n:>6} {stats.lost:>4} {stats.p50_us:>8.1f} {stats.p90_us:>8.1f} "
        f"{stats.p99_us:>8.1f} {stats.mean_us:>8.1f} {stats.max_us:>8.1f}"
    )
    if floor is not None:
        row += (
            f"   (+{stats.p50_us - floor.p50_us:.1f} p50, +{stats.p99_us - floor.p99_us:.1f} p99"
            " over the floor)"
        )
    return row


def print_latency_header() -> None:
    """Print the column header of :func:`format_latency` rows."""
    print(_HEADER)
    print("-" * len(_HEADER))


def print_latency(label: str, stats: LatencyStats, floor: LatencyStats | None = None) -> None:
    """Print one row (see :func:`format_latency`)."""
    print(format_latency(label, stats, floor), flush=True)


# ---------------------------------------------------------------------------------------------
# Processes
# ---------------------------------------------------------------------------------------------


CLK_TCK = os.sysconf("SC_CLK_TCK")


def cpu_s(pid: int) -> float:
    """CPU seconds (user + system) process ``pid`` has used so far (``/proc/<pid>/stat``)."""
    raw = Path(f"/proc/{pid}/stat").read_text(errors="replace")
    f = raw[raw.rfind(")") + 2 :].split()
    return (int(f[11]) + int(f[12])) / CLK_TCK


def vm_hwm_kib(pid: int) -> int:
    """Peak resident set size (VmHWM, KiB) of process ``pid``; 0 if not reported."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1])
    return 0


def free_port() -> int:
    """A TCP port on 127.0.0.1 that the kernel considered free a moment ago."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.bind(("127.0.0.1", 0))
        port: int = sock.getsockname()[1]
        return port


def _child_env() -> dict[str, str]:
    env = dict(os.environ)
    env.pop("ZENOH_CONFIG", None)
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(REPO_ROOT), env.get("PYTHONPATH")) if p)
    env["PYTHONUNBUFFERED"] = "1"
    return env


def _wait_ready(proc: subprocess.Popen[bytes], prefix: str, timeout_s: float) -> str:
    assert proc.stdout is not None
    deadline = time.monotonic() + timeout_s
    buf = b""
    with selectors.DefaultSelector() as sel:
        sel.register(proc.stdout, selectors.EVENT_READ)
        while True:
            for line in buf.decode(errors="replace").splitlines():
                if line.startswith(prefix):
                    return line
            left = deadline - time.monotonic()
            if left <= 0:
                raise TimeoutError(f"{proc.args!r}: no {prefix!r} line within {timeout_s} s")
            if sel.select(timeout=left):
                chunk = os.read(proc.stdout.fileno(), 4096)
                if not chunk:
                    raise RuntimeError(f"{proc.args!r} exited (status {proc.wait()}) before ready")
                buf += chunk


def stop_process(proc: subprocess.Popen[bytes], timeout_s: float = 2.0) -> int:
    """SIGTERM ``proc``, SIGKILL it after ``timeout_s``; return its exit status."""
    if proc.poll() is None:
        with contextlib.suppress(ProcessLookupError):
            proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
    for stream in (proc.stdin, proc.stdout):
        if stream is not None:
            stream.close()
    return proc.returncode


@contextlib.contextmanager
def running(
    argv: Sequence[str],
    *,
    ready: str | None = None,
    timeout_s: float = 15.0,
    stderr: IO[bytes] | None = None,
) -> Iterator[subprocess.Popen[bytes]]:
    """Run ``argv`` (cwd = repository) for the duration of the ``with`` block.

    stdin is a pipe the child may watch to exit with its parent; stdout is a pipe read until the
    line starting with ``ready`` (the child should print nothing much after it); stderr is
    inherited so errors show, or goes to ``stderr`` (an open file).
    """
    proc = subprocess.Popen(
        list(argv),
        cwd=REPO_ROOT,
        env=_child_env(),
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=stderr,
        start_new_session=True,
    )
    try:
        if ready is not None:
            _wait_ready(proc, ready, timeout_s)
        yield proc
    finally:
        stop_process(proc)


@contextlib.contextmanager
def router(endpoint: str | None = None) -> Iterator[str]:
    """A ``formation router`` subprocess on ``endpoint`` (default: a free loopback port)."""
    endpoint = endpoint or f"tcp/127.0.0.1:{free_port()}"
    argv = [sys.executable, "-m", "formation", "router", "--listen", endpoint]
    with running(argv, ready=ROUTER_READY):
        yield endpoint


# ---------------------------------------------------------------------------------------------
# The floor: bare Zenoh round trip between two processes
# ---------------------------------------------------------------------------------------------


def _declare_fast_publisher(session: zenoh.Session, key: str) -> zenoh.Publisher:
    # Same QoS as the control path (QOS_CONTROL) but BLOCK: a ping-pong never queues, and a
    # dropped ping would only cost a timeout.
    return session.declare_publisher(
        key,
        express=False,
        priority=zenoh.Priority.REAL_TIME,
        congestion_control=zenoh.CongestionControl.BLOCK,
    )


def _wait_matched(pub: zenoh.Publisher, timeout_s: float = 10.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not pub.matching_status:
        if time.monotonic() > deadline:
            raise TimeoutError(f"no subscriber matched {pub.key_expr} within {timeout_s} s")
        time.sleep(0.005)


def _seq(payload: bytes) -> int:
    return int.from_bytes(payload[:8], "little")


def _ping_payload(seq: int, size: int) -> bytes:
    return seq.to_bytes(8, "little") + bytes(max(0, size - 8))


def _timed_round_trips(
    n: int, warmup: int, round_trip: Callable[[int], bool]
) -> tuple[list[float], int, float]:
    """Time ``round_trip(i)`` (True: the pong came back) ``n`` times after ``warmup``; returns the
    samples (s), how many were lost and this process's CPU seconds over the timed ones."""
    samples: list[float] = []
    lost = 0
    cpu0 = time.process_time()
    for i in range(warmup + n):
        if i == warmup:
            cpu0 = time.process_time()
        t0 = time.perf_counter()
        if not round_trip(i):
            lost += i >= warmup
            continue
        if i >= warmup:
            samples.append(time.perf_counter() - t0)
    return samples, lost, time.process_time() - cpu0


def _ping_pong_callback(
    session: zenoh.Session, n: int, warmup: int, size: int
) -> tuple[list[float], int, float]:
    """Receive pongs in a Zenoh callback that sets a ``threading.Event``."""
    expected = [-1]
    got = threading.Event()

    def on_pong(sample: zenoh.Sample) -> None:  # Zenoh thread: no blocking, no Zenoh calls
        if _seq(sample.payload.to_bytes()) == expected[0]:
            got.set()

    sub = session.declare_subscriber(PONG_KEY, on_pong)
    pub = _declare_fast_publisher(session, PING_KEY)
    _wait_matched(pub)

    def round_trip(i: int) -> bool:
        payload = _ping_payload(i, size)
        expected[0] = i
        got.clear()
        pub.put(payload)
        return got.wait(timeout=0.1 if i < warmup else 1.0)

    try:
        return _timed_round_trips(n, warmup, round_trip)
    finally:
        sub.undeclare()
        pub.undeclare()


def _ping_pong_channel(
    session: zenoh.Session, n: int, warmup: int, size: int
) -> tuple[list[float], int, float]:
    """Receive pongs from a Zenoh ring (``RingChannel``) with a blocking ``recv()`` on this
    thread: no Python on Zenoh's thread (what ``runtime.bridge.TickPump``'s thread does)."""
    sub = session.declare_subscriber(PONG_KEY, zenoh.handlers.RingChannel(64))
    pub = _declare_fast_publisher(session, PING_KEY)
    _wait_matched(pub)

    def round_trip(i: int) -> bool:
        pub.put(_ping_payload(i, size))
        while _seq(sub.recv().payload.to_bytes()) != i:
            pass
        return True

    try:
        return _timed_round_trips(n, warmup, round_trip)
    finally:
        sub.undeclare()
        pub.undeclare()


def _ping_pong_asyncio(
    session: zenoh.Session, n: int, warmup: int, size: int
) -> tuple[list[float], int, float]:
    """Receive pongs through the asyncio bridge (``transport.subscribe`` + ``Inbox``)."""

    async def run() -> tuple[list[float], int, float]:
        inbox = rt.Inbox("queue")
        sub = rt.subscribe(session, PONG_KEY, asyncio.get_running_loop(), inbox)
        pub = _declare_fast_publisher(session, PING_KEY)
        _wait_matched(pub)
        samples: list[float] = []
        lost = 0
        cpu0 = 0.0
        try:
            for i in range(warmup + n):
                if i == warmup:
                    cpu0 = time.process_time()
                payload = _ping_payload(i, size)
                t0 = time.perf_counter()
                pub.put(payload)
                try:
                    async with asyncio.timeout(0.1 if i < warmup else 1.0):
                        while _seq((await inbox.get()).payload) != i:
                            pass
                except TimeoutError:
                    lost += i >= warmup
                    continue
                if i >= warmup:
                    samples.append(time.perf_counter() - t0)
        finally:
            cpu = time.process_time() - cpu0
            sub.undeclare()
            pub.undeclare()
        return samples, lost, cpu

    return asyncio.run(run())


def measure_floor(
    *,
    n: int = 2000,
    warmup: int = 200,
    payload_bytes: int = 100,
    topology: Topology = "router",
    receive: Receive = "callback",
) -> LatencyStats:
    """Bare Zenoh round trip between this process and an echo subprocess, in microseconds.

    ``topology="router"``: both are clients of a ``formation router`` subprocess on a free port
    (how the fleet runs); ``"peer"``: the echo is a listening peer and this process a peer
    connected to it, no router. ``receive="callback"``: the pong is caught in a Zenoh callback
    (threading.Event); ``"asyncio"``: through ``transport.subscribe`` into an ``Inbox`` awaited
    on an event loop (what the process shells do); ``"channel"``: a blocking ``recv()`` on a
    Zenoh ring (a lockstep agent's tick thread). ``n`` round trips are timed after ``warmup``;
    the result's ``cpu_us`` is this process's CPU per round trip (every thread).
    """
    if n < 1 or warmup < 0 or payload_bytes < 8:
        raise ValueError("need n >= 1, warmup >= 0, payload_bytes >= 8")
    with contextlib.ExitStack() as stack:
        endpoint: str
        if topology == "router":
            endpoint = stack.enter_context(router())
            echo = ["client", endpoint, "-"]
            mine = rt.ZenohSettings(connect=(endpoint,))
        elif topology == "peer":
            endpoint = f"tcp/127.0.0.1:{free_port()}"
            echo = ["peer", "-", endpoint]
            mine = rt.ZenohSettings(mode="peer", connect=(endpoint,))
        else:
            raise ValueError(f"unknown topology {topology!r}")
        stack.enter_context(
            running(
                [sys.executable, str(Path(__file__).resolve()), "echo", *echo], ready=ECHO_READY
            )
        )
        session = rt.open_session(mine)
        stack.callback(session.close)
        if receive == "callback":
            samples, lost, cpu = _ping_pong_callback(session, n, warmup, payload_bytes)
        elif receive == "asyncio":
            samples, lost, cpu = _ping_pong_asyncio(session, n, warmup, payload_bytes)
        elif receive == "channel":
            samples, lost, cpu = _ping_pong_channel(session, n, warmup, payload_bytes)
        else:
            raise ValueError(f"unknown receive {receive!r}")
    return LatencyStats.from_samples(samples, lost, cpu)


def _exit_with_parent() -> None:
    """Daemon thread body: our stdin is the parent's pipe; EOF means the parent is gone."""
    with contextlib.suppress(OSError):
        while sys.stdin.buffer.read(4096):
            pass
    os._exit(0)


def _echo(argv: list[str]) -> int:
    """Echo every ping back as a pong until SIGTERM (default action) or the parent exits."""
    mode, connect, listen = argv
    if mode not in ("client", "peer"):
        raise SystemExit(f"echo: mode must be client or peer, not {mode!r}")
    settings = rt.ZenohSettings(
        mode=mode,  # type: ignore[arg-type]  # checked just above
        connect=() if connect == "-" else (connect,),
        listen=() if listen == "-" else (listen,),
    )
    threading.Thread(target=_exit_with_parent, daemon=True).start()
    session = rt.open_session(settings)
    pub = _declare_fast_publisher(session, PONG_KEY)
    sub = session.declare_subscriber(PING_KEY, zenoh.handlers.FifoChannel(1024))
    print(ECHO_READY, flush=True)
    # A blocking receive loop on the main thread: the put is not made from a Zenoh callback.
    for sample in sub:
        pub.put(sample.payload)
    session.close()
    return 0


if __name__ == "__main__":
    if len(sys.argv) == 5 and sys.argv[1] == "echo":
        raise SystemExit(_echo(sys.argv[2:]))
    raise SystemExit(f"usage: {sys.argv[0]} echo <client|peer> <connect|-> <listen|->")
