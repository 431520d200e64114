"""Benchmark: the coordinator's 50 Hz tick with and without a replan in flight (issue 27).

Replanning must never delay the tick: plans are computed off it (``coordinator.node.
plan_worker``) and switched in at a tick boundary. This measures, side by side in one run, a
coordinator core ticking at 50 Hz (the ``warehouse`` scenario's, its robots on their slots; the
node's work per tick: the plan worker polled, the core ticked) while

* ``idle``: no plan is computed (the baseline of the same run);
* ``process``: the node's planning child process (``coordinator.node.plan_worker``) computes
  plans back to back (bench_plan.py's 7-robot chevron across a 10 m x 10 m map of 50
  obstacles, ``replan.solve``), the whole time;
* ``thread``: the same plans on a thread of the ticking process (the alternative the node does
  not use: it shares the interpreter's lock with the tick).

For each: the tick's compute time (p50, p99, max, ms) and how late each tick STARTED against
its 20 ms schedule (p99, max, ms: a tick that waited for the GIL starts late), and the plans
finished meanwhile. On the shared 2-core machine every figure also counts the other engineers'
processes: compare the columns of one run, not runs. Measures only; asserts nothing.

Run: .venv/bin/python bench/bench_replan.py [--seconds 10] [--seed 1]
"""

from __future__ import annotations

import argparse
import math
import os
import statistics
import sys
import time
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import Any

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")  # one core, before numpy loads

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_plan import ARENA, GOAL, START, random_map  # noqa: E402

import runtime as rt  # noqa: E402
from coordinator.core.formation import FormationSpec  # noqa: E402
from coordinator.core.planning.replan import PlanRequest, PlanSetup  # noqa: E402
from coordinator.node.plan_worker import PlanWorker, timed_solve  # noqa: E402
from scenario import load  # noqa: E402
from scenario.assemble import coordinator_core, plan_setup  # noqa: E402

PERIOD_S = 0.02


def plan_request(seed: int) -> PlanRequest:
    """bench_plan.py's map ``seed``: a 7-robot chevron from (1.5, 1.5) to (8.5, 8.5)."""
    spec = FormationSpec.from_dict({"kind": "chevron", "b_m": 0.4, "n": 7})
    base = plan_setup(load("warehouse"))
    setup = PlanSetup(**{**base.__dict__, "arena": ARENA, "obstacles": ()})
    return PlanRequest(
        id=1, reason="bench", t_switch_s=0.0, start=START, v_start_mps=0.0, goal=GOAL,
        goal_heading=None, obstacles=tuple(random_map(np.random.default_rng(seed), 50)),
        offsets_m=tuple((float(a), float(b)) for a, b in spec.body_offsets_m), setup=setup,
    )  # fmt: skip


class _Sink:
    """Stands in for the core's replanner: counts the answers."""

    def __init__(self) -> None:
        self.answers = 0

    def deliver(self, _rid: int, _answer: Any, _ms: float | None) -> bool:
        self.answers += 1
        return True


def run(mode: str, seconds: float, request: PlanRequest) -> dict[str, Any]:
    """Tick at 50 Hz for ``seconds`` with ``mode``'s planning in flight."""
    sc = load("warehouse")
    core = coordinator_core(sc)
    l_m = sc.agent.geometry.ref_offset_m
    poses: dict[str, tuple[float, float, float]] = {
        r: (p[0], p[1], p[2]) for r, p in zip(sc.robot_ids, sc.initial, strict=True)
    }
    worker = PlanWorker(rt.NodeLog("bench"))
    sink = _Sink()
    pool: ThreadPoolExecutor | None = None
    fut: Future[Any] | None = None
    if mode == "thread":
        pool = ThreadPoolExecutor(1)
    if mode == "process":  # the child started (its imports) before the clock runs
        worker.submit(request)
        while worker._job is not None:
            time.sleep(0.05)
            worker.poll(sink)  # type: ignore[arg-type]
        sink.answers = 0
    compute: list[float] = []
    late: list[float] = []
    done = 0
    t0 = time.perf_counter()
    n = round(seconds / PERIOD_S)
    for k in range(n):
        due = t0 + k * PERIOD_S
        while (now := time.perf_counter()) < due:
            time.sleep(min(0.002, due - now))
        late.append(time.perf_counter() - due)
        if mode == "process" and worker._job is None:
            worker.submit(request)
        if mode == "thread" and (fut is None or fut.done()):
            if fut is not None:
                fut.result()
                done += 1
            assert pool is not None
            fut = pool.submit(timed_solve, request)
        started = time.perf_counter()
        worker.poll(sink)  # type: ignore[arg-type]
        out = core.tick(k * PERIOD_S, poses)
        compute.append(time.perf_counter() - started)
        for rid, slot in out.assignment.items():
            s = out.slots_by_id[slot]
            poses[rid] = (s.x - l_m * math.cos(s.theta), s.y - l_m * math.sin(s.theta), s.theta)
    worker.close()
    if pool is not None:
        pool.shutdown(wait=True, cancel_futures=True)
    return {"compute": compute, "late": late, "plans": done if mode == "thread" else sink.answers}


def _ms(values: list[float], q: float) -> float:
    ordered = sorted(values)
    return 1e3 * ordered[min(len(ordered) - 1, math.ceil(q * len(ordered)) - 1)]


def main(argv: list[str]) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seconds", type=float, default=10.0)
    p.add_argument("--seed", type=int, default=1)
    ns = p.parse_args(argv)
    request = plan_request(ns.seed)
    t = time.perf_counter()
    first = timed_solve(request)
    what = "no plan" if isinstance(first[0], str) else f"{first[0].stats.length_m:.2f} m"
    print(f"one plan of the map (seed {ns.seed}): {what}, {1e3 * (time.perf_counter() - t):.0f} ms")
    print(f"{'case':8} {'ticks':>6} {'tick p50':>9} {'tick p99':>9} {'tick max':>9} "
          f"{'late p99':>9} {'late max':>9} {'plans':>6}")  # fmt: skip
    for mode in ("idle", "process", "thread"):
        r = run(mode, ns.seconds, request)
        c, lt = r["compute"], r["late"]
        print(
            f"{mode:8} {len(c):6d} {1e3 * statistics.median(c):8.3f}  {_ms(c, 0.99):8.3f}  "
            f"{1e3 * max(c):8.3f}  {_ms(lt, 0.99):8.3f}  {1e3 * max(lt):8.3f}  {r['plans']:6d}"
        )
    print("ms; tick = the node's work per tick (poll the planner, the core's tick); late = how "
          "long after its 20 ms schedule the tick started")  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
