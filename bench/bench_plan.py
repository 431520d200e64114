"""Benchmark: planning the virtual leader of 7 robots across a 10 m x 10 m map of 50 obstacles.

The issue-27 goal: a plan for a 10 m x 10 m map with 50 obstacles and 7 robots (a two-stage
chevron, b = 0.4 m) in < 200 ms on one core, printed beside the straight-line case (the same
arena, no obstacle) measured in the same run. Each map is seeded: 50 obstacles, 60 % discs of
radius 0.1-0.35 m and 40 % walls 0.3-1.2 m long, none within 1.5 m of the start (1.5, 1.5) or
the goal (8.5, 8.5). Times the whole planner (``coordinator.core.planning.plan``: the world's
STRtree, the clearance grid, the heading-lattice search, shortcuts, squeeze and timing) and its
phases; prints the median over ``--runs`` for each map (wall time, and the process's CPU time: on
the shared 2-core machine the wall time also counts the other engineers' processes), and the
plan's length against the straight line. A map with no way for the formation prints "no
plan" (a clean answer, timed too). Measures only; asserts nothing. One core: the BLAS/OpenMP
thread pools are set to one thread before numpy loads (``OMP_NUM_THREADS=1`` and the like,
unless already set): with their default pools on the shared machine the same plans took 2-5x
the wall time (threads queueing behind the other engineers' processes).

Run: .venv/bin/python bench/bench_plan.py [--runs 5] [--maps 5] [--seed 1]
"""

from __future__ import annotations

import argparse
import math
import os
import statistics
import sys
import time
from pathlib import Path
from typing import Any

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")  # one core, before numpy loads

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from coordinator.core.formation import FormationSpec  # noqa: E402
from coordinator.core.planning import Footprint, NoPlan, PlanWorld, SlotLimits, plan  # noqa: E402
from coordinator.core.planning.search import make_grid  # noqa: E402
from coordinator.core.planning.trajectory import min_separation_m  # noqa: E402

START = (1.5, 1.5, math.pi / 4.0)
GOAL = (8.5, 8.5)
ARENA = {"x_min": 0.0, "y_min": 0.0, "x_max": 10.0, "y_max": 10.0}


def random_map(rng: np.random.Generator, n: int) -> list[dict[str, Any]]:
    out: list[dict[str, Any]] = []
    while len(out) < n:
        x, y = rng.uniform(0.3, 9.7, size=2)
        if min(math.hypot(x - START[0], y - START[1]), math.hypot(x - GOAL[0], y - GOAL[1])) < 1.5:
            continue
        if rng.random() < 0.6:
            out.append({"kind": "circle", "x": x, "y": y, "radius_m": rng.uniform(0.1, 0.35)})
        else:
            a = rng.uniform(0.0, math.pi)
            half = rng.uniform(0.15, 0.6)
            dx, dy = half * math.cos(a), half * math.sin(a)
            out.append({"kind": "segment", "x1": x - dx, "y1": y - dy, "x2": x + dx,
                        "y2": y + dy, "radius_m": 0.02})  # fmt: skip
    return out


def time_plan(obstacles: list[dict[str, Any]], runs: int) -> tuple[float, dict[str, float], str]:
    spec = FormationSpec.chevron(7, 0.4)
    fp = Footprint(spec.body_offsets_m, 0.075 + 0.05 + 0.04 + 0.02, min_separation_m(0.19, 0.05))
    limits = SlotLimits.from_robot(
        wheel_radius_m=0.03, half_track_m=0.05, max_wheel_radps=10.0, max_ref_speed_mps=0.25
    )
    totals: list[float] = []
    phases: dict[str, list[float]] = {"world": [], "grid": [], "cpu": []}
    what = ""
    for _ in range(runs):
        c0 = time.process_time()
        t0 = time.perf_counter()
        world = PlanWorld(obstacles, ARENA)
        t1 = time.perf_counter()
        try:
            r = plan(world, fp, START, GOAL, cruise_mps=0.05, limits=limits, min_pair_m=0.19)
            what = (
                f"length {r.stats.length_m:.2f} m (straight {r.stats.straight_m:.2f} m), "
                f"cell {r.stats.cell_m * 100:.1f} cm, {r.stats.corners} corners, "
                f"clearance {r.stats.min_clearance_m:.3f} m, to goal {r.stats.duration_s:.0f} s"
            )
        except NoPlan as exc:
            what = f"no plan: {exc}"
        t2 = time.perf_counter()
        phases["cpu"].append(time.process_time() - c0)
        make_grid(world, fp, fp.slot_radius_m, [START[:2], GOAL])
        t3 = time.perf_counter()
        totals.append(t2 - t0)
        phases["world"].append(t1 - t0)
        phases["grid"].append(t3 - t2)
    return statistics.median(totals), {k: statistics.median(v) for k, v in phases.items()}, what


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--runs", type=int, default=5, help="timed runs per map (median)")
    p.add_argument("--maps", type=int, default=5, help="random maps of 50 obstacles")
    p.add_argument("--seed", type=int, default=1)
    ns = p.parse_args()
    rng = np.random.default_rng(ns.seed)
    print("planning 7 robots (chevron, b = 0.4 m) across a 10 m x 10 m arena, median of "
          f"{ns.runs} runs; start {START[:2]}, goal {GOAL}")  # fmt: skip
    print(f"{'case':<24}{'plan (ms)':>11}{'CPU (ms)':>10}{'world (ms)':>12}{'grid (ms)':>11}"
          "  result")  # fmt: skip
    base, ph, what = time_plan([], ns.runs)
    base_cpu = ph["cpu"]
    print(f"{'straight line (0 obst.)':<24}{base * 1e3:>11.1f}{ph['cpu'] * 1e3:>10.1f}"
          f"{ph['world'] * 1e3:>12.2f}{ph['grid'] * 1e3:>11.1f}  {what}")  # fmt: skip
    worst = worst_cpu = 0.0
    for m in range(ns.maps):
        obstacles = random_map(rng, 50)
        t, ph, what = time_plan(obstacles, ns.runs)
        worst = max(worst, t)
        worst_cpu = max(worst_cpu, ph["cpu"])
        print(f"{f'map {m} (50 obstacles)':<24}{t * 1e3:>11.1f}{ph['cpu'] * 1e3:>10.1f}"
              f"{ph['world'] * 1e3:>12.2f}{ph['grid'] * 1e3:>11.1f}  {what}")  # fmt: skip
    print(
        f"worst map: {worst * 1e3:.1f} ms wall, {worst_cpu * 1e3:.1f} ms CPU (goal < 200 ms); "
        f"straight line {base * 1e3:.1f} ms wall, {base_cpu * 1e3:.1f} ms CPU"
    )


if __name__ == "__main__":
    main()
