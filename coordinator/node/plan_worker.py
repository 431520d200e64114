"""The coordinator's planning worker: run-time plans computed off the 50 Hz tick (issue 27).

The core asks for a plan (``coordinator.core.planning.replan``: a plain-data ``PlanRequest``,
the switch time fixed when it is asked); this part computes it in ONE child process
(``coordinator.node.plan_server``: requests in on its stdin, answers out on its stdout) and
hands the answer back to the core at a tick:

* realtime: :meth:`PlanWorker.poll` at every tick delivers a finished plan; the tick never
  waits for it;
* lockstep: before the tick at which a plan is due the node waits for it
  (``poll(wait_s=...)``), so the switch happens at the tick fixed by the command's tick and the
  run stays equal to the in-process simulator, which plans at once.

Why a process: a planning THREAD shares the interpreter's lock with the tick, and parts of
the planner hold it for long stretches (the graph search, the geometry queries): with a plan
in flight the ticks started up to 330 ms late (bench/bench_replan.py, p99 290 ms, against 3 ms
idle). A plain child process (not multiprocessing: nothing else to reap at exit) is started at
the first plan and stopped with the node; one plan runs at a time and only the newest request
waits (a superseded one that has not started is never sent). A child that dies is one line in
the log and a "no plan" answer (the leader stops); the next plan starts a new child.
"""

from __future__ import annotations

import contextlib
import pickle
import subprocess
import sys
import threading
from concurrent.futures import Future
from typing import TYPE_CHECKING, Any, Final

import runtime as rt
from coordinator.node.plan_server import read_frame, timed_solve, write_frame

if TYPE_CHECKING:
    from coordinator.core.planning.replan import PlanRequest, Replanner

__all__ = ["PLAN_WAIT_S", "PlanWorker", "timed_solve"]

PLAN_WAIT_S: Final = 120.0
"""Lockstep: the longest wait for a due plan (s; the planner is bounded far below this on any
map it accepts); beyond it the plan is taken as failed (no way: the leader stops)."""


class PlanWorker:
    """The planning child process and the jobs for it (module docstring)."""

    def __init__(self, log: rt.NodeLog) -> None:
        self.log = log
        self._proc: subprocess.Popen[bytes] | None = None
        self._lock = threading.Lock()
        self._futures: dict[int, Future[tuple[Any, float | None]]] = {}
        self._running: int | None = None  # the request id the child is computing
        self._waiting: PlanRequest | None = None  # the newest request, not sent yet
        self._job: int | None = None  # the newest request id (the one the core waits for)
        self.submitted = 0
        self.failures = 0

    def submit(self, request: PlanRequest) -> None:
        """Compute ``request`` after the one running (a request waiting is replaced)."""
        fut: Future[tuple[Any, float | None]] = Future()
        with self._lock:
            self._futures[request.id] = fut
            if self._waiting is not None:  # superseded before it started: never sent
                self._futures.pop(self._waiting.id, None)
            self._waiting = request
            self._job = request.id
            self.submitted += 1
            self._send_locked()

    def _send_locked(self) -> None:
        if self._running is not None or self._waiting is None:
            return
        req, self._waiting = self._waiting, None
        try:
            proc = self._child_locked()
            assert proc.stdin is not None
            write_frame(proc.stdin, pickle.dumps(req, protocol=pickle.HIGHEST_PROTOCOL))
            self._running = req.id
        except (OSError, ValueError) as exc:
            self._fail_locked(req.id, exc)

    def _child_locked(self) -> subprocess.Popen[bytes]:
        proc = self._proc
        if proc is None or proc.poll() is not None:
            proc = self._proc = subprocess.Popen(
                [sys.executable, "-m", "coordinator.node.plan_server"],
                stdin=subprocess.PIPE,
                stdout=subprocess.PIPE,
            )
            threading.Thread(target=self._read, args=(proc,), daemon=True).start()
        return proc

    def _read(self, proc: subprocess.Popen[bytes]) -> None:
        """The child's answers (its own thread), until its output ends."""
        assert proc.stdout is not None
        while True:
            frame = read_frame(proc.stdout)
            if frame is None:
                break
            rid, answer, ms = pickle.loads(frame)
            with self._lock:
                fut = self._futures.get(rid)
                self._running = None
                if fut is not None:
                    fut.set_result((answer, ms))
                self._send_locked()
        with self._lock:  # the child is gone: what it was computing failed
            if self._running is not None and self._proc is proc:
                self._fail_locked(self._running, RuntimeError("the planning process ended"))
                self._running = None
                self._send_locked()

    def _fail_locked(self, rid: int, exc: BaseException) -> None:
        self.failures += 1
        self.log.info(f"planning worker failed: {type(exc).__name__}: {exc}")
        fut = self._futures.get(rid)
        if fut is not None and not fut.done():
            fut.set_result((f"no plan: the planning worker failed ({type(exc).__name__})", None))

    def poll(self, replanner: Replanner, wait_s: float | None = None) -> None:
        """Deliver the answers that are done to ``replanner`` (a superseded one too: it drops
        it, and counts its compute time); with ``wait_s``, wait that long for the newest."""
        with self._lock:
            rid = self._job
            fut = None if rid is None else self._futures.get(rid)
        if fut is not None and wait_s is not None and not fut.done():
            try:
                fut.result(timeout=wait_s)
            except TimeoutError as exc:
                with self._lock:
                    self._fail_locked(rid, exc)  # type: ignore[arg-type]
        with self._lock:
            done = sorted((i, f) for i, f in self._futures.items() if f.done())
            for i, _ in done:
                del self._futures[i]
            if any(i == rid for i, _ in done):
                self._job = None
        for i, f in done:
            answer, ms = f.result()
            replanner.deliver(i, answer, ms)

    def close(self) -> None:
        """Stop the child (a plan in flight is abandoned)."""
        proc, self._proc = self._proc, None
        if proc is None:
            return
        with contextlib.suppress(OSError):
            if proc.stdin is not None:
                proc.stdin.close()
        try:
            proc.wait(timeout=0.2)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
