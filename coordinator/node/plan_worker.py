"""The coordinator's planning worker: run-time plans computed off the 50 Hz tick (issue 27).

The core asks for a plan (``coordinator.core.planning.replan``: a plain-data ``PlanRequest``,
the switch time fixed when it is asked); this part computes it on ONE worker thread
(``concurrent.futures.ThreadPoolExecutor``) and hands the answer back to the core at a tick:

* realtime: :meth:`PlanWorker.poll` at every tick delivers a finished plan; the tick never
  waits for it. The planner's heavy parts (GEOS, the C graph search, numpy) release the GIL;
  its Python loops share it with the tick (the interpreter switches every 5 ms), which is
  what ``bench/bench_replan.py`` measures (tick p99 with and without a plan in flight). A
  worker PROCESS was tried: no GIL sharing, but it leaves multiprocessing's resource tracker
  and a worker to reap at every exit and costs a second interpreter's imports;
* lockstep: before the tick at which a plan is due the node waits for it
  (``poll(wait_s=...)``), so the switch happens at the tick fixed by the command's tick and the
  run stays equal to the in-process simulator, which plans at once.

The worker is started at the first plan (a coordinator that never plans never starts it) and
measures the plan's compute time itself (``plan_ms``). A plan superseded before it started is
cancelled (one plan runs at a time, and only the newest waits). A plan that fails is one line
in the log and a "no plan" answer (the leader stops).
"""

from __future__ import annotations

import time
from concurrent.futures import Future, ThreadPoolExecutor
from typing import TYPE_CHECKING, Any, Final

import runtime as rt

if TYPE_CHECKING:
    from coordinator.core.planning.replan import PlanRequest, Replanner

__all__ = ["PLAN_WAIT_S", "PlanWorker", "timed_solve"]

PLAN_WAIT_S: Final = 120.0
"""Lockstep: the longest wait for a due plan (s; the planner is bounded far below this on any
map it accepts); beyond it the plan is taken as failed (no way: the leader stops)."""


def timed_solve(request: PlanRequest) -> tuple[Any, float]:
    """The answer to ``request`` (``replan.solve``) and its compute time (ms)."""
    from coordinator.core.planning.replan import solve

    started = time.perf_counter()
    answer = solve(request)
    return answer, 1e3 * (time.perf_counter() - started)


class PlanWorker:
    """One planning worker thread and the job in flight (module docstring)."""

    def __init__(self, log: rt.NodeLog) -> None:
        self.log = log
        self._pool: ThreadPoolExecutor | None = None
        self._job: tuple[int, Future[tuple[Any, float]]] | None = None
        self.submitted = 0
        self.failures = 0

    def submit(self, request: PlanRequest) -> None:
        """Compute ``request`` (a job in flight before it is superseded: its answer is dropped
        by the core when it comes)."""
        if self._pool is None:
            self._pool = ThreadPoolExecutor(1, thread_name_prefix="planner")
        if self._job is not None:
            self._job[1].cancel()  # not started yet: never started (one plan at a time)
        self._job = (request.id, self._pool.submit(timed_solve, request))
        self.submitted += 1

    def poll(self, replanner: Replanner, wait_s: float | None = None) -> None:
        """Deliver the job's answer to ``replanner`` if it is done (or within ``wait_s``)."""
        job = self._job
        if job is None:
            return
        rid, fut = job
        if wait_s is None and not fut.done():
            return
        self._job = None
        try:
            answer, ms = fut.result(timeout=wait_s)
        except Exception as exc:  # a plan that failed or took too long
            self.failures += 1
            self.log.info(f"planning worker failed: {type(exc).__name__}: {exc}")
            answer, ms = f"no plan: the planning worker failed ({type(exc).__name__})", None
        replanner.deliver(rid, answer, ms)

    def close(self) -> None:
        """Stop the worker (a plan in flight is abandoned)."""
        if self._pool is not None:
            self._pool.shutdown(wait=False, cancel_futures=True)
            self._pool = None
