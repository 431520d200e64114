"""Benchmark: role assignment at scale, sparse (coordinator.core.scale_assign) vs dense optimal.

For N = 10, 100, 300, 1000 robots and slots in a chevron and a lattice formation (b = 0.4 m),
robots scattered around the slots (each robot's reference point = a random slot + Gaussian noise
of 0.05, 0.3 or 1.0 m per axis, ids shuffled), and the steady state: every robot 2 cm (per axis)
from the slot it held on the previous tick, that assignment passed as the incumbent with a
5 cm hysteresis. Prints the median wall time (and CPU time) of one call of
``assign_optimal`` (dense Hungarian) and of ``assign_sparse`` (default path: dense below
``DEFAULT_DENSE_MAX_PAIRS``; "forced" = the sparse graph solver even on small N), the path taken,
the graph's edges and Dijkstra phases, and the total cost (eq 6 distance less hysteresis, m) of
sparse, forced and greedy over dense. The goal it tracks: N = 1000
in under 20 ms, within 1 % of the optimum; the paper's greedy rule is shown for reference.
Measures only; asserts nothing.

Run: .venv/bin/python bench/bench_assignment_scale.py [--runs 7] [--seed 1] [--k 10]
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from coordinator.core.assignment import SlotLike, assign_greedy, assign_optimal, assignment_cost
from coordinator.core.formation import FormationSpec, slot_arrays, slot_states
from coordinator.core.scale_assign import (
    DEFAULT_DENSE_MAX_PAIRS,
    DEFAULT_K,
    SparseAssignment,
    solve_sparse,
)
from coordinator.core.trajectory import LeaderState

SIZES = (10, 100, 300, 1000)
NOISES_M = (0.05, 0.3, 1.0)
STEADY_NOISE_M = 0.02
STEADY_HYSTERESIS_M = 0.05


def _times_s(fn: Callable[[], object], runs: int) -> tuple[float, float]:
    """(median wall time, median CPU time of this process) of ``runs`` calls, after one warm-up
    call. On a shared machine the CPU time shows the cost without the waits for a core."""
    fn()
    wall, cpu = [], []
    for _ in range(runs):
        c0, t0 = time.process_time(), time.perf_counter()
        fn()
        wall.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    return statistics.median(wall), statistics.median(cpu)


def _cost(
    robots: Mapping[str, tuple[float, float]],
    slots: Sequence[SlotLike],
    assignment: Mapping[str, int],
    incumbent: Mapping[str, int] | None,
    hysteresis_m: float,
) -> float:
    """The minimised objective: total eq-6 distance (m) less the hysteresis of kept pairs."""
    total = assignment_cost(robots, slots, assignment)
    if incumbent:
        total -= hysteresis_m * sum(1 for r, s in assignment.items() if incumbent.get(r) == s)
    return total


def _case(
    kind: str,
    n: int,
    label: str,
    slots: Sequence[SlotLike],
    robots: dict[str, tuple[float, float]],
    incumbent: dict[str, int] | None,
    hyst: float,
    k: int,
    runs: int,
) -> float:
    """Measure one case, print its row, return the sparse / optimal cost ratio."""

    def dense() -> dict[str, int]:
        return assign_optimal(robots, slots, incumbent=incumbent, hysteresis_m=hyst)

    def sparse(dense_max_pairs: int = DEFAULT_DENSE_MAX_PAIRS) -> SparseAssignment:
        return solve_sparse(
            robots,
            slots,
            k=k,
            incumbent=incumbent,
            hysteresis_m=hyst,
            dense_max_pairs=dense_max_pairs,
        )

    opt = dense()
    res = sparse()
    forced = sparse(dense_max_pairs=0)
    greedy = assign_greedy(robots, slots, incumbent=incumbent, hysteresis_m=hyst)
    c_opt = _cost(robots, slots, opt, incumbent, hyst)

    def ratio(a: Mapping[str, int]) -> float:
        return _cost(robots, slots, a, incumbent, hyst) / c_opt if c_opt > 0 else 1.0

    td, _ = _times_s(dense, runs)
    ts, ts_cpu = _times_s(sparse, runs)
    tf, _ = _times_s(lambda: sparse(dense_max_pairs=0), runs)
    print(
        f"{kind:<9} {n:>5} {label:>7} | {td * 1e3:>8.2f} {ts * 1e3:>9.2f} {ts_cpu * 1e3:>7.2f} "
        f"{tf * 1e3:>9.2f} | {res.method:<9} {forced.n_edges:>6} {forced.n_phases:>6} "
        f"{ratio(res.assignment):>8.5f} {ratio(forced.assignment):>9.5f} {ratio(greedy):>10.3f}",
        flush=True,
    )
    return max(ratio(res.assignment), ratio(forced.assignment))


def main() -> None:
    ap = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    ap.add_argument("--runs", type=int, default=7, help="runs per measurement (median reported)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--k", type=int, default=DEFAULT_K, help="neighbours per side of the graph")
    args = ap.parse_args()
    print("$ " + " ".join([Path(sys.executable).name, *sys.argv]))
    load = " ".join(f"{x:.2f}" for x in os.getloadavg())
    print(f"runs={args.runs} seed={args.seed} k={args.k} b=0.4 m tie_tol=0.01 m; load {load}\n")
    rng = np.random.default_rng(args.seed)
    leader = LeaderState(0.0, 0.0, 0.0, 0.3, 0.1, 0.05)
    header = (
        f"{'formation':<9} {'N':>5} {'case':>7} | {'dense ms':>8} {'sparse ms':>9} {'(cpu)':>7} "
        f"{'forced ms':>9} | {'path':<9} {'edges':>6} {'phases':>6} "
        f"{'sp/opt':>8} {'forced/opt':>9} {'greedy/opt':>10}"
    )
    print(header)
    print("-" * len(header))
    worst = 1.0
    for kind in ("chevron", "lattice"):
        for n in SIZES:
            spec: FormationSpec = getattr(FormationSpec, kind)(n, b_m=0.4)
            slots = slot_states(spec, leader)
            xy, _ = slot_arrays(spec, leader)
            cases: list[tuple[str, float, bool]] = [(f"{s:g} m", s, False) for s in NOISES_M]
            cases.append(("steady", STEADY_NOISE_M, True))
            for label, noise, steady in cases:
                ids = [f"r{i + 1}" for i in range(n)]
                pick = rng.permutation(n)
                noisy = xy[pick] + rng.normal(0.0, noise, size=(n, 2))
                robots = {r: (float(p[0]), float(p[1])) for r, p in zip(ids, noisy, strict=True)}
                incumbent: dict[str, int] | None = None
                hyst = 0.0
                if steady:  # previous tick: each robot held the slot it is now 2 cm from
                    incumbent = {r: slots[int(j)].slot for r, j in zip(ids, pick, strict=True)}
                    hyst = STEADY_HYSTERESIS_M
                worst = max(
                    worst,
                    _case(kind, n, label, slots, robots, incumbent, hyst, args.k, args.runs),
                )
    load = " ".join(f"{x:.2f}" for x in os.getloadavg())
    print(f"\nworst sparse or forced / opt cost ratio: {worst:.6f}; load average at end: {load}")
    print(
        "ms: wall time of one call, median of runs; (cpu): median CPU time of the sparse call.\n"
        "sparse: assign_sparse defaults (dense solver up to 200 x 200); forced: the graph solver "
        "even for small N\n(dense_max_pairs=0); path: of the default call: incumbent (proven "
        "optimal, kept) | sparse | dense;\nedges, phases: candidate-graph edges and Dijkstra "
        "phases of the forced call.\n"
        "x/opt: objective (eq-6 distance less hysteresis of kept incumbents, m) over the dense "
        "optimum's."
    )


if __name__ == "__main__":
    main()
