"""Memory of a long ``formation up`` run: is the RSS of every process flat? (issue 13, item 6)

Starts ``formation up --robots N --hosts H --duration S`` (realtime, batched bus) on a free port
and samples, every ``--every`` seconds, the resident set size (``VmRSS`` from /proc) of the
launcher and of each of its children. Prints one line per sample and, at the end, for each
process: RSS at the first sample after warm-up, at the end, and the slope of a least-squares
line through the samples after warm-up (MiB per minute). Asserts nothing.

Usage::

    python bench/bench_memory.py [--robots 300] [--hosts 4] [--duration 600] [--every 10]
                                 [--warmup 60] [--secure]
"""

from __future__ import annotations

import argparse
import os
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[1]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def rss_mib(pid: int) -> float | None:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    except OSError:
        return None
    return None


def children(pid: int) -> dict[int, str]:
    out = {}
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            raw = Path(f"/proc/{entry}/stat").read_text()
            args = Path(f"/proc/{entry}/cmdline").read_bytes().split(b"\0")
        except OSError:
            continue
        if int(raw[raw.rfind(")") + 2 :].split()[1]) != pid:
            continue
        words = [a.decode(errors="replace") for a in args if a]
        try:
            i = words.index("formation")
            name = words[i + 1]
            if name in ("agent-host", "coordinator") and "--name" in words:
                name += "-" + words[words.index("--name") + 1]
        except (ValueError, IndexError):
            name = " ".join(words[:3])
        out[int(entry)] = name
    return out


def slope_per_min(samples: list[tuple[float, float]]) -> float:
    if len(samples) < 2:
        return float("nan")
    n = len(samples)
    mt = sum(t for t, _ in samples) / n
    mr = sum(r for _, r in samples) / n
    var = sum((t - mt) ** 2 for t, _ in samples)
    cov = sum((t - mt) * (r - mr) for t, r in samples)
    return 60.0 * cov / var if var > 0 else float("nan")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--robots", type=int, default=300)
    ap.add_argument("--hosts", type=int, default=4)
    ap.add_argument("--duration", type=float, default=600.0)
    ap.add_argument("--every", type=float, default=10.0)
    ap.add_argument("--warmup", type=float, default=60.0)
    ap.add_argument("--secure", action="store_true")
    ns = ap.parse_args()
    out = Path(tempfile.mkdtemp(prefix="bench-memory-"))
    port = free_port()
    argv = [
        sys.executable, "-m", "formation", "up", "--robots", str(ns.robots),
        "--hosts", str(ns.hosts), "--duration", repr(ns.duration),
        "--endpoint", f"tcp/127.0.0.1:{port}", "--out", str(out), "--no-figures", "--quiet",
        "--ready-timeout", "120", *(["--secure"] if ns.secure else []),
    ]  # fmt: skip
    env = dict(os.environ, PYTHONPATH=str(REPO_ROOT))
    print(f"bench_memory: {' '.join(argv[1:])}", flush=True)
    up = subprocess.Popen(argv, env=env, cwd=REPO_ROOT)
    series: dict[str, list[tuple[float, float]]] = {}
    t0 = time.monotonic()
    try:
        while up.poll() is None:
            time.sleep(ns.every)
            t = time.monotonic() - t0
            procs = {up.pid: "launcher", **children(up.pid)}
            row = []
            for pid, name in sorted(procs.items(), key=lambda kv: kv[1]):
                r = rss_mib(pid)
                if r is None:
                    continue
                series.setdefault(name, []).append((t, r))
                row.append(f"{name} {r:.0f}")
            print(f"t {t:6.0f} s  RSS MiB: " + ", ".join(row), flush=True)
    except KeyboardInterrupt:
        up.terminate()
    up.wait()
    print(f"\nformation up exited with status {up.returncode}; {ns.robots} robots, "
          f"{ns.hosts} hosts, {ns.duration:g} s; warm-up {ns.warmup:g} s excluded")  # fmt: skip
    print(f"{'process':<22} {'RSS after warm-up':>18} {'RSS at end':>11} {'slope MiB/min':>14}")
    for name, samples in sorted(series.items()):
        steady = [(t, r) for t, r in samples if t >= ns.warmup]
        if not steady:
            continue
        print(
            f"{name:<22} {steady[0][1]:>15.0f} MiB {steady[-1][1]:>7.0f} MiB "
            f"{slope_per_min(steady):>14.2f}"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
