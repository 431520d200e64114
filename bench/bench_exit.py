"""Benchmark: how long every process kind takes to exit after SIGTERM, optionally next to CPU hogs
(the standard: every process exits within a second of SIGINT/SIGTERM and closes its session).

Each repeat starts two small fleets exactly as ``formation up`` does (the command lines come from
``formation.launch.nodes``: ``router_args`` and ``node_commands`` of a planned run, the environment
from ``formation.launch.children.child_env``, a free loopback port, multicast off):

* ``agents``: ``--camera rendered --hosts 0``: router, plant (``--no-poses``), camera (the real
  tracker on rendered frames), coordinator, one agent per robot;
* ``host``: ``--hosts 1``: router, plant, coordinator (``--batch``), one agent host.

Once every node printed its ready line, the fleet runs ``--settle`` seconds (traffic flows: the
plant's clock starts when the robots' tokens are up), then every node gets SIGTERM at once (what
the launcher does), and the router after they are gone. Per process: seconds from SIGTERM to the
exit this process saw (``os.wait4`` on a thread per child), its exit status, the CPU seconds it
used during the stop (``wait4``'s rusage minus ``/proc/<pid>/stat`` just before the signal),
and its ``stop trace`` line (``runtime.lifecycle.StopTrace``, asked for with
``FORMATION_STOP_TRACE=1``: when each phase of its stop ended, from its own signal handler).

``--hogs K`` starts K processes ``python3 -c 'while True: pass'`` (children of this bench, killed
at the end) before the first fleet and keeps them for the whole run; ``--hog-kind mem`` makes
them map, zero and free 64 MiB in a loop instead (the kernel's work), ``bursty`` busy for 4 ms
then asleep for 1 ms (keeping the scheduler's wake-up credit, like other fleets' processes).

Prints, per process kind: n, p50 / p90 / max seconds to exit, how many took over 1 s, the CPU
milliseconds of the stop (p50 / max), the resident memory before the signal (p50), the time from
the node's ``os._exit`` to the exit this bench saw (p50 / max: the kernel tearing the process
down, its threads and memory, plus this bench's own wake-up), the exit statuses seen; then p50 /
max of each traced phase's end, and the load average. Asserts nothing.

Usage: ``python bench/bench_exit.py [--repeat 10] [--hogs 4] [--robots 3] [--settle 2]
[--layouts agents,host] [--keep DIR]``. Results and the command: docs/benchmarks.md.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import re
import selectors
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

from common import REPO_ROOT, cpu_s, free_port, percentile

from formation.launch.children import child_env
from formation.launch.nodes import node_commands, router_args
from formation.launch.plan import UpConfig, plan_run

ROUTER_READY = "router listening on "
TRACE_RE = re.compile(r"^stop trace: (.*)$", re.M)
LAYOUTS = {
    "agents": {"hosts": 0, "camera": "rendered"},
    "host": {"hosts": 1, "camera": "emulated"},
}


@dataclass
class Proc:
    """One started process and what its stop measured."""

    kind: str
    argv: list[str]
    ready: str
    log: Path
    popen: subprocess.Popen[bytes] | None = None
    buf: bytes = b""
    is_ready: bool = False
    sent_s: float = 0.0
    exited_s: float | None = None
    status: int | None = None
    cpu_before_s: float = 0.0
    rss_mib: float | None = None
    cpu_stop_s: float | None = None
    trace: dict[str, float] = field(default_factory=dict)
    waiter: threading.Thread | None = None

    @property
    def exit_s(self) -> float | None:
        return None if self.exited_s is None else self.exited_s - self.sent_s

    def start(self, env: dict[str, str], cwd: Path) -> None:
        with open(self.log, "wb") as err:
            self.popen = subprocess.Popen(
                self.argv, cwd=cwd, env=env, stdin=subprocess.DEVNULL,
                stdout=subprocess.PIPE, stderr=err, start_new_session=True,
            )  # fmt: skip

    def sigterm(self) -> None:
        assert self.popen is not None
        pid = self.popen.pid
        with contextlib.suppress(OSError, ValueError, IndexError):
            self.cpu_before_s = cpu_s(pid)
            self.rss_mib = rss_kib(pid) / 1024
        self.waiter = threading.Thread(target=self._wait, daemon=True)
        self.sent_s = time.monotonic()
        os.kill(pid, signal.SIGTERM)
        self.waiter.start()

    def _wait(self) -> None:
        assert self.popen is not None
        _, raw, usage = os.wait4(self.popen.pid, 0)
        self.exited_s = time.monotonic()
        self.status = os.waitstatus_to_exitcode(raw)
        self.popen.returncode = self.status
        self.cpu_stop_s = usage.ru_utime + usage.ru_stime - self.cpu_before_s

    def join(self, timeout_s: float) -> None:
        """Wait for the exit; SIGKILL past ``timeout_s`` (the run's bound is long past)."""
        assert self.waiter is not None and self.popen is not None
        self.waiter.join(timeout_s)
        if self.waiter.is_alive():
            with contextlib.suppress(ProcessLookupError):
                os.kill(self.popen.pid, signal.SIGKILL)
            self.waiter.join()
        if self.popen.stdout is not None:
            self.popen.stdout.close()

    def kill(self) -> None:
        if self.popen is not None and self.popen.poll() is None and self.exited_s is None:
            with contextlib.suppress(ProcessLookupError):
                os.kill(self.popen.pid, signal.SIGKILL)
            with contextlib.suppress(ChildProcessError, subprocess.TimeoutExpired):
                self.popen.wait(5)


def rss_kib(pid: int) -> int:
    """Resident set size (VmRSS, KiB) of process ``pid``."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    return 0


def parse_trace(text: str, sent_s: float) -> dict[str, float]:
    """``signal at 100.5 s, loop 12 ms, main 15 ms`` -> {"handler": 0.5 - sent, "loop": 0.012 +
    handler, ...}: every phase's end in seconds after this bench sent SIGTERM (the trace's
    ``signal at`` is the child's ``time.monotonic``, the same clock system-wide)."""
    out: dict[str, float] = {}
    base = 0.0
    for part in text.split(", "):
        words = part.split()
        if words[:2] == ["signal", "at"] and len(words) == 4:
            with contextlib.suppress(ValueError):
                base = float(words[2]) - sent_s
                out["handler"] = base
        elif len(words) >= 2 and words[-1] == "ms":
            with contextlib.suppress(ValueError):
                out[" ".join(words[:-2])] = base + float(words[-2]) / 1e3
    return out


def wait_ready(procs: Sequence[Proc], timeout_s: float) -> None:
    """Read every process's stdout until its ready line; raise on an exit or the timeout."""
    deadline = time.monotonic() + timeout_s
    with selectors.DefaultSelector() as sel:
        for p in procs:
            assert p.popen is not None and p.popen.stdout is not None
            sel.register(p.popen.stdout, selectors.EVENT_READ, p)
        while not all(p.is_ready for p in procs):
            left = deadline - time.monotonic()
            if left <= 0:
                late = [p.kind for p in procs if not p.is_ready]
                raise TimeoutError(f"not ready within {timeout_s} s: {late}")
            for key, _ in sel.select(timeout=min(left, 1.0)):
                p = key.data
                chunk = os.read(key.fd, 65536)
                if not chunk:
                    sel.unregister(key.fileobj)
                    if not p.is_ready:
                        tail = p.log.read_text(errors="replace")[-1500:]
                        raise RuntimeError(f"{p.kind} exited before ready; stderr:\n{tail}")
                    continue
                p.buf += chunk
                if any(ln.startswith(p.ready) for ln in p.buf.decode(errors="replace").split("\n")):
                    p.is_ready = True
                    sel.unregister(key.fileobj)  # a ready node prints little: the pipe holds it


def kind_of(name: str) -> str:
    if name.startswith("agent-host"):
        return "agent-host"
    if name.startswith("agent-"):
        return "agent"
    return name


def run_fleet(layout: str, robots: int, settle_s: float, out: Path, ready_s: float) -> list[Proc]:
    """Start one fleet, let it run, SIGTERM its nodes at once, then the router; the processes."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    fleet = f"exit{os.getpid()}{layout}"
    cfg = UpConfig(
        scenario="paper-exp2", robots=robots, endpoint=endpoint, fleet=fleet, out=out,
        duration_s=3600.0, figures=False, quiet=True, **LAYOUTS[layout],  # type: ignore[arg-type]
    )  # fmt: skip
    plan = plan_run(cfg)
    out.mkdir(parents=True, exist_ok=True)
    if plan.scenario_toml is not None:
        (out / "scenario.toml").write_text(plan.scenario_toml)
    env = child_env()
    env["FORMATION_STOP_TRACE"] = "1"
    py = [sys.executable, "-m", "formation"]
    router = Proc("router", [*py, *router_args(endpoint, None)], ROUTER_READY, out / "router.log")
    nodes = [
        Proc(kind_of(name), [*py, *args], ready, out / f"{name}.log")
        for name, args, ready in node_commands(cfg, plan, lambda _id: ["--endpoint", endpoint])
    ]
    started: list[Proc] = []
    try:
        router.start(env, REPO_ROOT)
        started.append(router)
        wait_ready([router], ready_s)
        for p in nodes:
            p.start(env, REPO_ROOT)
            started.append(p)
        wait_ready(nodes, ready_s)
        time.sleep(settle_s)
        for p in nodes:
            p.sigterm()
        for p in nodes:
            p.join(10.0)
        router.sigterm()
        router.join(10.0)
    finally:
        for p in started:
            p.kill()
    for p in started:
        with contextlib.suppress(OSError):
            m = TRACE_RE.findall(p.log.read_text(errors="replace"))
            p.trace = parse_trace(m[-1], p.sent_s) if m else {}
        if p.trace and p.exit_s is not None:
            p.trace["reaped"] = p.exit_s
    return started


def report(procs: list[Proc]) -> None:
    kinds: dict[str, list[Proc]] = {}
    for p in procs:
        kinds.setdefault(p.kind, []).append(p)
    phases: list[str] = []
    for p in procs:
        for ph in p.trace:
            if ph not in phases:
                phases.append(ph)
    print(
        f"{'process':<12} {'n':>4} {'p50 s':>6} {'p90 s':>6} {'max s':>6} {'>1 s':>4} "
        f"{'cpu ms p50/max':>14} {'rss MiB':>7} {'after exit ms':>13}  exit statuses"
    )
    for kind, ps in kinds.items():
        times = sorted(p.exit_s for p in ps if p.exit_s is not None)
        cpus = sorted(p.cpu_stop_s * 1e3 for p in ps if p.cpu_stop_s is not None)
        rss = sorted(p.rss_mib for p in ps if p.rss_mib is not None)
        after = sorted(
            (p.trace["reaped"] - p.trace["exit"]) * 1e3
            for p in ps
            if "reaped" in p.trace and "exit" in p.trace
        )
        statuses: dict[int | None, int] = {}
        for p in ps:
            statuses[p.status] = statuses.get(p.status, 0) + 1
        over = sum(t > 1.0 for t in times)
        st = ", ".join(f"{s}: {n}" for s, n in sorted(statuses.items(), key=str))
        print(
            f"{kind:<12} {len(times):>4} {percentile(times, 50):>6.3f} "
            f"{percentile(times, 90):>6.3f} {times[-1] if times else float('nan'):>6.3f} {over:>4} "
            f"{_pair(cpus):>14} {percentile(rss, 50):>7.0f} {_pair(after):>13}  {st}"
        )
    print(
        "\nstop trace, p50 / max ms of each phase's end after SIGTERM was sent (handler: the "
        "node's Python signal handler ran; reaped: this bench saw the exit):"
    )
    for kind, ps in kinds.items():
        cells = []
        for ph in phases:
            vals = sorted(p.trace[ph] for p in ps if ph in p.trace)
            if vals:
                cells.append(f"{ph} {percentile(vals, 50) * 1e3:.0f}/{vals[-1] * 1e3:.0f}")
        print(f"  {kind:<12} " + ", ".join(cells))


def _pair(sorted_values: list[float]) -> str:
    """``p50/max`` of ascending values, whole numbers (``-`` if none)."""
    if not sorted_values:
        return "-"
    return f"{percentile(sorted_values, 50):.0f}/{sorted_values[-1]:.0f}"


HOGS = {
    "cpu": "while True: pass",
    # the kernel's work instead: map, zero and free 64 MiB at a time (page faults, page freeing)
    "mem": "while True: bytearray(64 << 20)",
    # a busy loop that sleeps 1 ms every 4 ms: it keeps the scheduler's wake-up credit, as the
    # Python processes of other fleets and test runs do (a pure busy loop loses it)
    "bursty": (
        "import time\nwhile True:\n    t = time.monotonic()\n"
        "    while time.monotonic() - t < 0.004: pass\n    time.sleep(0.001)"
    ),
}


def start_hogs(k: int, kind: str = "cpu") -> list[subprocess.Popen[bytes]]:
    return [
        subprocess.Popen(["python3", "-c", HOGS[kind]], stdin=subprocess.DEVNULL) for _ in range(k)
    ]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=10)
    ap.add_argument("--hogs", type=int, default=0, help="CPU busy loops for the whole run")
    ap.add_argument("--hog-kind", choices=sorted(HOGS), default="cpu", help="what a hog does")
    ap.add_argument("--robots", type=int, default=3)
    ap.add_argument("--settle", type=float, default=2.0, help="seconds a ready fleet runs")
    ap.add_argument("--layouts", default="agents,host", help=f"of {','.join(LAYOUTS)}")
    ap.add_argument("--ready-timeout", type=float, default=120.0)
    ap.add_argument("--keep", type=Path, help="keep every fleet's logs under this directory")
    ns = ap.parse_args()
    layouts = [x for x in ns.layouts.split(",") if x]
    for x in layouts:
        if x not in LAYOUTS:
            ap.error(f"unknown layout {x!r}")
    root = ns.keep or Path(tempfile.mkdtemp(prefix="bench-exit-"))
    load0 = os.getloadavg()
    print(
        f"bench_exit: {ns.repeat} repeats of {layouts}, {ns.robots} robots, "
        f"{ns.hogs} {ns.hog_kind} hogs, "
        f"settle {ns.settle:g} s; load average {load0[0]:.1f} {load0[1]:.1f} {load0[2]:.1f}",
        flush=True,
    )
    hogs = start_hogs(ns.hogs, ns.hog_kind)
    procs: list[Proc] = []
    try:
        for r in range(ns.repeat):
            for layout in layouts:
                try:
                    got = run_fleet(
                        layout, ns.robots, ns.settle, root / f"{r}-{layout}", ns.ready_timeout
                    )
                except (TimeoutError, RuntimeError) as exc:
                    print(f"  repeat {r} {layout}: {exc}", flush=True)
                    continue
                procs += got
                worst = max(got, key=lambda p: p.exit_s or 0.0)
                print(
                    f"  repeat {r} {layout}: slowest {worst.kind} {worst.exit_s or 0.0:.3f} s "
                    f"(status {worst.status}); load {os.getloadavg()[0]:.1f}",
                    flush=True,
                )
    finally:
        for h in hogs:
            h.kill()
        for h in hogs:
            h.wait()
        if ns.keep is None:
            shutil.rmtree(root, ignore_errors=True)
    load1 = os.getloadavg()
    print()
    report(procs)
    print(f"\nload average at the end {load1[0]:.1f} {load1[1]:.1f} {load1[2]:.1f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
