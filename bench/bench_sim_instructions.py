"""Instructions per tick of the in-process simulator, counted by valgrind: a figure a busy machine
cannot blur.

``bench_sim.py`` times ``formation.sim.simulate.run``; on a shared 2-core machine its figures move
by tens of percent from run to run. This counts the CPU instructions of the same loop instead
(valgrind's callgrind, ``Ir``), which repeat closely whatever else runs.

Each count is the difference of two runs of one fleet (more sim time in the second), divided by
the extra ticks, so the interpreter's start, the imports, the setup and the first ticks cancel
out. One BLAS thread (an idle OpenBLAS worker spins, its count depending on timing) and
``PYTHONHASHSEED=0`` keep the interpreter's own work the same from run to run, and the objects of
the imports are frozen out of the garbage collector before the run (a full collection that
falls in one run's window would otherwise walk them all). Fleets: paper-exp2 (3 robots, the
ticks of 4-8 s) and the 30-robot chevron of ``bench_sim.py`` (the ticks of 1-3 s). Even so the
whole tick's count moves by about 10 % between repeats on this loop (docs/benchmarks.md): compare
several pairs.

``--no-gc`` counts with the garbage collector off during the run: the loop's own work (when
a collection falls depends on every allocation, so its share moves between two versions for
reasons of its own). ``--against DIR`` counts a second source tree (e.g. ``git archive
<commit>`` unpacked, with its own ``make accel`` builds) in the same run: the baseline beside the
figure. ``--pure`` counts with ``FORMATION_ACCEL=0`` (no compiled firmware, no compiled
simulator). Instructions are not time (a C call and a cache miss differ); read them beside
``bench_sim.py``'s figures.

Run: ``.venv/bin/python bench/bench_sim_instructions.py [--against DIR] [--pure] [--no-gc]
[--only NAME]``.
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

# fleet -> (first run's sim seconds, second run's)
FLEETS: dict[str, tuple[float, float]] = {"paper-exp2": (4.0, 8.0), "chevron30": (1.0, 3.0)}

# The child: one simulate.run of a fleet from one tree; prints the builds in use and the ticks.
_CHILD = """
import gc, sys
root, name, seconds, no_gc = sys.argv[1], sys.argv[2], float(sys.argv[3]), sys.argv[4] == "1"
sys.path.insert(0, root)
sys.path.insert(0, root + "/bench")
import scenario
from formation.sim import simulate
from robot_agent.core import _accel as fw
try:
    from sim_plant.core import _accel as sim
    sim_status = sim.status()[1]
except ImportError:
    sim_status = "pure Python (no simulator build in this tree)"
if name == "chevron30":
    import bench_sim
    scn = bench_sim.chevron_scenario(30, duration_s=seconds)
else:
    scn = scenario.load(name)
gc.collect()
gc.freeze()  # the imports' objects: a full collection in the counted window does not walk them
if no_gc:
    gc.disable()
res = simulate.run(scn, duration_s=seconds)
print("firmware:", fw.STATUS, "| simulator:", sim_status, file=sys.stderr)
print("ticks:", res.log.t_s.size, file=sys.stderr)
"""


def _instructions(
    root: Path, name: str, seconds: float, pure: bool, no_gc: bool
) -> tuple[int, int, str]:
    """Instructions (callgrind ``Ir``) of a whole child run, its ticks and the builds' status."""
    # one BLAS thread: an idle OpenBLAS worker spins for a while after each call, and its
    # instructions (counted too) would depend on the machine's timing
    env = dict(os.environ, PYTHONHASHSEED="0", OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1")
    env.pop("PYTHONPATH", None)
    if pure:
        env["FORMATION_ACCEL"] = "0"
    cmd = ["valgrind", "--tool=callgrind", "--callgrind-out-file=/dev/null", sys.executable,
           "-c", _CHILD, str(root), name, str(seconds), str(int(no_gc))]  # fmt: skip
    out = subprocess.run(cmd, env=env, cwd=root, capture_output=True, text=True, check=True).stderr
    ir = re.search(r"Collected : (\d+)", out)
    ticks = re.search(r"ticks: (\d+)", out)
    if ir is None or ticks is None:
        raise RuntimeError(f"no instruction count in valgrind's output: {out[-500:]}")
    status = next((ln for ln in out.splitlines() if ln.startswith("firmware:")), "?")
    return int(ir.group(1)), int(ticks.group(1)), status


def per_tick(root: Path, name: str, pure: bool, no_gc: bool = False) -> tuple[float, str]:
    """Instructions per tick of ``root``'s simulator on fleet ``name``, and the builds' status."""
    short_s, long_s = FLEETS[name]
    base, base_ticks, _ = _instructions(root, name, short_s, pure, no_gc)
    more, more_ticks, status = _instructions(root, name, long_s, pure, no_gc)
    return (more - base) / (more_ticks - base_ticks), status


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    ap.add_argument("--against", type=Path, help="a second source tree, counted the same way")
    ap.add_argument("--pure", action="store_true", help="FORMATION_ACCEL=0 (nothing compiled)")
    ap.add_argument("--only", choices=sorted(FLEETS), help="one fleet")
    ap.add_argument(
        "--no-gc", action="store_true", help="the loop's own work: the garbage collector off"
    )
    args = ap.parse_args(argv)
    if shutil.which("valgrind") is None:
        print("bench_sim_instructions: valgrind is not installed; nothing measured")
        return 0
    trees = [("this tree", ROOT)]
    if args.against is not None:
        trees.append(("against", args.against.resolve()))
    for name in FLEETS:
        if args.only and name != args.only:
            continue
        results = {}
        for label, root in trees:
            ir, status = per_tick(root, name, args.pure, args.no_gc)
            results[label] = ir
            print(f"{name:10s} {label:9s} {root}: {ir:10.0f} instructions/tick  ({status})")
        if args.against is not None:
            ratio = results["this tree"] / results["against"]
            print(f"{name:10s} this tree against: {100.0 * (ratio - 1.0):+.1f} %")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
