"""Instructions per firmware tick, counted by valgrind: a speed figure a busy machine cannot blur.

``bench_firmware.py`` times ``Firmware.step``; next to other processes on a shared 2-core
machine its p50 moves by 10 % from run to run. This counts the CPU instructions of the same
ticks instead (valgrind's callgrind, ``Ir``), which repeat to a few in 50,000 whatever else
runs: the difference between two versions of the code shows at the 1 % level.

Each count is the difference of two runs (``--ticks`` more ticks in the second) divided by the
extra ticks, so the interpreter's start and the imports cancel out. The ticks are
``bench_firmware.py --estimator``'s (3 neighbours, a fused camera pose and encoder speeds every
tick); ``PYTHONHASHSEED=0`` keeps the interpreter's own work the same from run to run.

``--against DIR`` counts a second source tree (e.g. ``git worktree add /tmp/before <commit>``,
with its own ``make accel`` for the compiled core) in the same run: the baseline beside the
figure. Instructions are not time (a C call and a cache miss differ), so read them beside
``bench_firmware.py``'s p50; this is the tie-breaker when the p50s overlap.

Run: ``.venv/bin/python bench/bench_firmware_instructions.py [--against DIR] [--ticks N]``.
A measurement, not a test: the exit code is 0 unless it crashes; without valgrind it says so.
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
BASE_TICKS = 2000

# The child: bench_firmware.py's CPU-time loop over its --estimator inputs, from one tree.
_CHILD = """
import importlib.util, sys
root, ticks = sys.argv[1], int(sys.argv[2])
sys.path.insert(0, root)
spec = importlib.util.spec_from_file_location("bench_firmware", root + "/bench/bench_firmware.py")
bf = importlib.util.module_from_spec(spec)
spec.loader.exec_module(bf)
bf._CFG = bf.AgentConfig(estimator=bf.EstimatorParams(enabled=True))
bf._EST_KW["on"] = True
bf.bench_step_cpu(ticks, block=1000)
print(bf._accel.STATUS, file=sys.stderr)
"""


def _instructions(root: Path, ticks: int, compiled: bool) -> tuple[int, str]:
    """Instructions (callgrind ``Ir``) of a whole child run of ``ticks`` ticks, and the core's
    status line."""
    env = dict(os.environ, PYTHONHASHSEED="0", FORMATION_ACCEL="1" if compiled else "0")
    cmd = ["valgrind", "--tool=callgrind", "--callgrind-out-file=/dev/null",
           sys.executable, "-c", _CHILD, str(root), str(ticks)]  # fmt: skip
    out = subprocess.run(cmd, env=env, capture_output=True, text=True, check=True).stderr
    m = re.search(r"Collected : (\d+)", out)
    if m is None:
        raise RuntimeError(f"no instruction count in valgrind's output: {out[-500:]}")
    status = next((ln for ln in out.splitlines() if ln.startswith(("compiled", "pure"))), "?")
    return int(m.group(1)), status


def per_tick(root: Path, ticks: int, compiled: bool) -> tuple[float, str]:
    """Instructions per tick of ``root``'s firmware (compiled or pure), and the core's status."""
    base, _ = _instructions(root, BASE_TICKS, compiled)
    more, status = _instructions(root, BASE_TICKS + ticks, compiled)
    return (more - base) / ticks, status


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--ticks", type=int, default=10_000, help="extra ticks counted (10000)")
    ap.add_argument("--against", type=Path, help="a second source tree, counted the same way")
    ap.add_argument("--pure-only", action="store_true", help="only the pure-Python core")
    args = ap.parse_args(argv)
    if shutil.which("valgrind") is None:
        print("bench_firmware_instructions: valgrind is not installed; nothing measured")
        return 0
    trees = [("this tree", ROOT)]
    if args.against is not None:
        trees.append(("against", args.against.resolve()))
    cores = [False] if args.pure_only else [True, False]
    ticks = max(1000, args.ticks)
    results: dict[tuple[str, bool], float] = {}
    for compiled in cores:
        for name, root in trees:
            ir, status = per_tick(root, ticks, compiled)
            results[(name, compiled)] = ir
            print(f"{name:9s} {root}: {ir:9.0f} instructions/tick  ({status})")
    for compiled in cores:
        core = "compiled" if compiled else "pure"
        line = f"bench_firmware_instructions: {core} {results[('this tree', compiled)]:.0f} Ir/tick"
        if args.against is not None:
            base = results[("against", compiled)]
            ratio = results[("this tree", compiled)] / base
            line += f" against {base:.0f} ({100.0 * (ratio - 1.0):+.1f} %)"
        print(line)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
