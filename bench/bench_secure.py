"""Benchmark: the cost of ``formation up --secure`` (mTLS + access control) against a plain run.

Runs, interleaved in the same invocation (plain, secure, plain, secure, ...), exactly::

    formation up --robots N --duration D --endpoint tcp/127.0.0.1:<port> --out <tmp> \
                 --no-figures [--secure]

and prints per run and as medians:

* **startup**: from starting ``formation up`` to its line saying the last node is ready (for
  ``--secure`` this includes the ephemeral CA, one ECDSA P-256 key and certificate per process,
  the router and client configs, and every TLS handshake);
* **pose->wheels latency** p50 / p99 / max, measured inside the plant (``plant_stats.json``: a
  frame's poses published -> the wheel command computed from that frame received back; two
  hops through the router, TLS-encrypted with ``--secure``), as in bench_up.py;
* **PKI**: the launcher's share of the startup measured alone,
``formation.launch.pki.write_run_configs``
  for the run's identities (CA, keys, certificates, router and client configs), wall and CPU
  time, a few repetitions (the startup figures above are dominated by the machine's load);
* **CPU**: CPU seconds of every process of the run (``/proc``, router, plant, coordinator,
  agents summed, launcher) over the whole run, and their sum per wall second of the run.

Usage: ``python bench/bench_secure.py [--robots 3] [--duration 15] [--repeat 3]``. Prints;
asserts nothing. Results and the command: docs/benchmarks.md; docs/security.md says what they
mean for the default.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

from bench_lockstep import watch_tree_cpu
from common import REPO_ROOT, free_port


def run_up(robots: int, duration_s: float, out: Path, secure: bool) -> dict[str, Any] | None:
    argv = [
        sys.executable, "-m", "formation", "up", "--robots", str(robots),
        "--duration", str(duration_s), "--endpoint", f"tcp/127.0.0.1:{free_port()}",
        "--out", str(out), "--no-figures", *(["--secure"] if secure else []),
    ]  # fmt: skip
    env = dict(os.environ, PYTHONPATH=str(REPO_ROOT))
    t0 = time.monotonic()
    proc = subprocess.Popen(argv, cwd=REPO_ROOT, env=env, stdout=subprocess.PIPE, text=True)
    lines: list[tuple[float, str]] = []

    def read() -> None:
        assert proc.stdout is not None
        for line in proc.stdout:
            lines.append((time.monotonic() - t0, line.rstrip()))

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    launcher_cpu, cpu = watch_tree_cpu(proc, 0.25)
    wall = time.monotonic() - t0
    reader.join(5.0)
    ready = [t for t, ln in lines if "ready in" in ln]
    if proc.returncode != 0 or not (out / "plant_stats.json").exists() or not ready:
        print(f"  formation up exited with status {proc.returncode}; see {out}/logs/")
        return None
    lat = json.loads((out / "plant_stats.json").read_text())["latency_ms"] or {}
    by_name: dict[str, float] = {}
    for name, seconds in cpu.values():
        key = "agents" if name.startswith("agent") else name.split()[0] if name else "?"
        by_name[key] = by_name.get(key, 0.0) + seconds
    by_name["launcher"] = launcher_cpu
    total = sum(by_name.values())
    return {
        "startup_s": max(ready),
        "p50": lat.get("p50", float("nan")),
        "p99": lat.get("p99", float("nan")),
        "max": lat.get("max", float("nan")),
        "cpu": by_name,
        "cpu_total_s": total,
        "cpu_per_wall": total / wall,
        "wall_s": wall,
    }


def time_pki(robots: int, repeat: int = 5) -> None:
    """``write_run_configs`` for a ``--secure`` fleet of ``robots`` agents, timed alone."""
    from bus_schemas import acl
    from formation.launch import pki

    idents = acl.fleet_identities(
        [f"r{k}" for k in range(1, robots + 1)], ("main",), plant=True, observers=("",)
    )
    walls, cpus = [], []
    for _ in range(repeat):
        with tempfile.TemporaryDirectory(prefix="bench-pki-") as tmp:
            w0, c0 = time.perf_counter(), time.process_time()
            pki.write_run_configs(tmp, idents, port=free_port())
            walls.append(time.perf_counter() - w0)
            cpus.append(time.process_time() - c0)
    print(
        f"  PKI of {len(idents)} identities (write_run_configs): wall median "
        f"{1e3 * statistics.median(walls):.0f} ms, CPU median {1e3 * statistics.median(cpus):.0f} "
        f"ms ({1e3 * statistics.median(cpus) / len(idents):.1f} ms per identity)",
        flush=True,
    )


def show(tag: str, r: dict[str, Any]) -> None:
    row = ", ".join(f"{k} {v:.1f}" for k, v in sorted(r["cpu"].items(), key=lambda kv: -kv[1]))
    print(
        f"  {tag:6s} startup {r['startup_s']:5.2f} s | pose->wheels p50 {r['p50']:.2f} ms "
        f"p99 {r['p99']:.2f} ms max {r['max']:.1f} ms | CPU {r['cpu_total_s']:.1f} s "
        f"({100 * r['cpu_per_wall']:.0f} % of a core over {r['wall_s']:.1f} s): {row}",
        flush=True,
    )


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--robots", type=int, default=3, help="robots (default 3)")
    p.add_argument("--duration", type=float, default=15.0, help="seconds per run (15)")
    p.add_argument("--repeat", type=int, default=3, help="pairs of runs (3)")
    args = p.parse_args()
    print(
        f"formation up --robots {args.robots} --duration {args.duration:g}, plain vs --secure, "
        f"{args.repeat} interleaved pairs, {os.cpu_count()} CPUs, "
        f"load {os.getloadavg()[0]:.1f}"
    )
    time_pki(args.robots)
    results: dict[str, list[dict[str, Any]]] = {"plain": [], "secure": []}
    with tempfile.TemporaryDirectory(prefix="bench-secure-") as tmp:
        for k in range(args.repeat):
            for tag in ("plain", "secure"):
                r = run_up(args.robots, args.duration, Path(tmp) / f"{tag}{k}", tag == "secure")
                if r is not None:
                    results[tag].append(r)
                    show(tag, r)
    print(f"medians (load after: {os.getloadavg()[0]:.1f}):")
    for tag, rs in results.items():
        if not rs:
            continue

        def med(key: str, rs: list[dict[str, Any]] = rs) -> float:
            return statistics.median(r[key] for r in rs)

        print(
            f"  {tag:6s} startup {med('startup_s'):5.2f} s | pose->wheels p50 {med('p50'):.2f} "
            f"ms p99 {med('p99'):.2f} ms | CPU {med('cpu_total_s'):.1f} s "
            f"({100 * med('cpu_per_wall'):.0f} % of a core)  [n={len(rs)}]"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
