"""Benchmark: greedy (paper) vs optimal (Hungarian) role assignment, and slot generation.

For N = 10, 100, 300, 1000 robots and slots: a chevron and a lattice formation (b = 0.4 m) and N
robots scattered around the slots (each robot's reference point = a random slot + Gaussian noise
of 0.3 m per axis, ids shuffled). Prints the median wall time of several runs and the total
distance (m, eq 6) of each method and the ratio greedy / optimal. Measures only; asserts nothing.

Run: .venv/bin/python bench/bench_assignment.py [--runs 7] [--seed 1]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from coordinator.core.assignment import assign_greedy, assign_optimal, assignment_cost
from coordinator.core.formation import FormationSpec, slot_arrays, slot_states
from coordinator.core.trajectory import LeaderState

SIZES = (10, 100, 300, 1000)


def _median_s(fn: Callable[[], object], runs: int) -> float:
    times = []
    for _ in range(runs):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def main() -> None:
    ap = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    ap.add_argument("--runs", type=int, default=7, help="runs per measurement (median reported)")
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    print("$ " + " ".join([Path(sys.executable).name, *sys.argv]))
    print(f"runs={args.runs} seed={args.seed} noise=0.3 m b=0.4 m hysteresis=0 tie_tol=0.01 m\n")
    rng = np.random.default_rng(args.seed)
    leader = LeaderState(0.0, 0.0, 0.0, 0.3, 0.1, 0.05)
    header = (
        f"{'formation':<9} {'N':>5} {'greedy ms':>10} {'optimal ms':>11} "
        f"{'greedy m':>10} {'optimal m':>10} {'ratio g/o':>9} {'slots ms':>9}"
    )
    print(header)
    print("-" * len(header))
    for kind in ("chevron", "lattice"):
        for n in SIZES:
            spec: FormationSpec = getattr(FormationSpec, kind)(n, b_m=0.4)
            slots = slot_states(spec, leader)
            xy, _ = slot_arrays(spec, leader)
            pick = rng.permutation(n)
            noisy = xy[pick] + rng.normal(0.0, 0.3, size=(n, 2))
            robots = {f"r{i + 1}": (float(p[0]), float(p[1])) for i, p in enumerate(noisy)}
            g = assign_greedy(robots, slots)
            o = assign_optimal(robots, slots)
            cg = assignment_cost(robots, slots, g)
            co = assignment_cost(robots, slots, o)
            tg = _median_s(lambda: assign_greedy(robots, slots), args.runs)  # noqa: B023
            to = _median_s(lambda: assign_optimal(robots, slots), args.runs)  # noqa: B023
            ts = _median_s(lambda: slot_states(spec, leader), args.runs)  # noqa: B023
            print(
                f"{kind:<9} {n:>5} {tg * 1e3:>10.2f} {to * 1e3:>11.2f} "
                f"{cg:>10.2f} {co:>10.2f} {cg / co:>9.3f} {ts * 1e3:>9.2f}"
            )
    print("\nms: median wall time of one call; m: total reference-point-to-slot distance;")
    print("slots ms: slot_states() for the formation (eqs 3-5 + feed-forward).")


if __name__ == "__main__":
    main()
