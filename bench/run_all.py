"""Run every benchmark in ``bench/`` one after the other and keep what each printed.

Usage::

    python bench/run_all.py [--quick] [--only NAME ...] [--out runs/bench]

Each benchmark prints its own figures and asserts nothing; this runner only sequences them (they
must not run at the same time on a 2-core machine: they would measure each other), prints their
output as it comes, and writes it to ``<out>/<name>.txt`` plus ``<out>/summary.txt`` (the
command, exit status and wall time of each). ``docs/benchmarks.md`` quotes these files and names
the command behind every number. ``--quick`` runs shorter variants (a smoke run, not figures to
quote). A benchmark that fails is reported and the others still run; the exit status is 1 if
any failed.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent

# name -> (full arguments, quick arguments). Order: cheapest first, soaks last.
BENCHES: dict[str, tuple[list[str], list[str]]] = {
    "bench_firmware": ([], ["--ticks", "20000"]),
    "bench_firmware_fleet": ([], ["--seconds", "2", "--repeats", "1"]),
    "bench_assignment": ([], ["--runs", "1"]),
    "bench_plan": ([], ["--runs", "1", "--maps", "2"]),
    "bench_replan": ([], ["--seconds", "3"]),
    "bench_assignment_scale": ([], ["--runs", "1"]),
    "bench_sim": ([], ["--runs", "1", "--only", "paper-exp2"]),
    "bench_zenoh_rtt": ([], ["--n", "300"]),
    "bench_latency": ([], ["--robots", "3", "--window", "5"]),
    "bench_lockstep": ([], ["--duration", "20", "--robots", "3"]),
    "bench_lockstep_floor": ([], ["--ticks", "300"]),
    "bench_lockstep_handlers": ([], ["--duration", "6"]),
    "bench_startup": ([], ["--repeat", "1"]),
    "bench_scale": ([], ["--quick"]),
    "bench_up": ([], ["--repeat", "1", "--duration", "8"]),
    "bench_camera": ([], ["--frames", "10", "--seconds", "4"]),
    "bench_soak": ([], ["--kills", "5"]),
    "bench_decode": ([], ["--fuzz", "20000"]),
    "bench_exit": (["--repeat", "5", "--hogs", "4"], ["--repeat", "1"]),
    "bench_token_burst": ([], ["--repeat", "1", "--robots", "100", "--lost", "50"]),
    "bench_flood": ([], ["--keys", "pose", "--seconds", "2"]),
}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--quick", action="store_true", help="short smoke variants")
    p.add_argument("--only", nargs="+", default=None, metavar="NAME", help="run only these")
    p.add_argument("--out", type=Path, default=Path("runs/bench"), help="output folder")
    ns = p.parse_args(argv)
    unknown = set(ns.only or []) - set(BENCHES)
    if unknown:
        p.error(f"unknown benchmark(s) {sorted(unknown)}; known: {', '.join(BENCHES)}")
    ns.out.mkdir(parents=True, exist_ok=True)
    summary: list[str] = []
    failed = 0
    for name, (full, quick) in BENCHES.items():
        if ns.only and name not in ns.only:
            continue
        script = HERE / f"{name}.py"
        if not script.exists():
            summary.append(f"{name}: missing ({script.name} not in bench/)")
            continue
        cmd = [sys.executable, str(script), *(quick if ns.quick else full)]
        shown = " ".join(["python", f"bench/{script.name}", *cmd[2:]])
        print(f"\n===== {shown}", flush=True)
        start = time.monotonic()
        lines: list[str] = []
        with subprocess.Popen(
            cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, cwd=HERE.parent
        ) as proc:
            assert proc.stdout is not None
            for line in proc.stdout:
                print(line, end="", flush=True)
                lines.append(line)
            rc = proc.wait()
        wall = time.monotonic() - start
        (ns.out / f"{name}.txt").write_text(f"$ {shown}\n" + "".join(lines))
        summary.append(f"{name}: exit {rc}, {wall:.0f} s: {shown}")
        failed += rc != 0
    text = "\n".join(summary) + "\n"
    (ns.out / "summary.txt").write_text(text)
    print("\n===== summary\n" + text, end="")
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
