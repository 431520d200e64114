"""Run a study's cases over the machine's cores, case by case into a results file.

Each case is one in-process run (:func:`formation.sim.simulate.run`, what ``formation sim``
runs) measured by :mod:`formation.sweep.case_metrics`. Cases run in worker processes
(``multiprocessing``, forked, one case at a time each); the parent appends every finished case
to ``cases.jsonl`` at once (one JSON object a line, flushed), so:

* Ctrl-C (SIGINT; the workers ignore it, the parent stops them) loses only the cases running at
  that moment, and running the study again skips every case already in the file (matched by the
  case's key, :class:`formation.sweep.study.Case`);
* a case that raises is written as ``failed`` with one line saying why, and the study goes on;
  a failed case is finished too (``--retry-failed`` runs it again).

Every case is seeded, so the table does not depend on the number of workers or the order they
finish in (the table is written in the study's order, without wall-clock times).
"""

from __future__ import annotations

import json
import math
import multiprocessing
import os
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final, TextIO

from formation.outputs.progress import LINE_PERIOD_S, TTY_PERIOD_S
from formation.sweep.study import Case

__all__ = ["RESULTS_FILE", "CaseProgress", "SweepRun", "read_results", "run_case", "run_cases"]

RESULTS_FILE: Final = "cases.jsonl"

CaseSpec = tuple[str, int, dict[str, Any], str, int, float | None]
"""What a worker needs of a case: key, index, scenario table, source, seed, duration."""


def _spec(case: Case) -> CaseSpec:
    return (case.key, case.index, dict(case.data), case.source, case.seed, case.duration_s)


def _clean(v: Any) -> Any:
    """NaN and inf as None (JSON has neither)."""
    if isinstance(v, float) and not math.isfinite(v):
        return None
    return v


def run_case(spec: CaseSpec) -> dict[str, Any]:
    """Run one case in this process and return its record (never raises: a failure is a record
    with ``status = "failed"`` and the error in one line)."""
    key, index, data, source, seed, duration_s = spec
    t0 = time.perf_counter()
    record: dict[str, Any] = {"key": key, "index": index, "seed": seed}
    try:
        from formation.outputs.metrics import settle_for
        from formation.sim import simulate
        from formation.sweep.case_metrics import compute
        from scenario import parse

        scn = parse(data, source=source)
        result = simulate.run(scn, seed=seed, duration_s=duration_s)
        duration = scn.duration_s if duration_s is None else duration_s
        settle_s = settle_for(scn.settle_s, duration)
        values = compute(result.log, settle_s, scn.settle_tol_m)
        record["status"] = "ok"
        record["error"] = ""
        record["metrics"] = {k: _clean(v) for k, v in values.items()}
    except Exception as exc:  # a failing case is reported, never stops the study
        record["status"] = "failed"
        record["error"] = f"{type(exc).__name__}: {exc}".splitlines()[0][:300]
        record["metrics"] = {}
    record["wall_s"] = time.perf_counter() - t0
    return record


def read_results(path: Path) -> dict[str, dict[str, Any]]:
    """Case key -> record of a results file (a torn last line, from a kill, is ignored)."""
    out: dict[str, dict[str, Any]] = {}
    if not path.exists():
        return out
    for line in path.read_text().splitlines():
        try:
            rec = json.loads(line)
        except ValueError:
            continue
        if isinstance(rec, dict) and isinstance(rec.get("key"), str):
            out[rec["key"]] = rec
    return out


def _clock(s: float) -> str:
    s = max(0.0, s)
    if s < 60:
        return f"{s:.0f} s"
    if s < 3600:
        return f"{int(s // 60)} min {int(s % 60):02d} s"
    return f"{int(s // 3600)} h {int(s % 3600 // 60):02d} min"


class CaseProgress:
    """``12/40 cases (1 failed), ETA 1 min 05 s`` on stderr: redrawn on a terminal, a line every
    :data:`LINE_PERIOD_S` otherwise (the same rule as ``formation sim``'s progress)."""

    def __init__(self, total: int, *, enabled: bool = True, stream: TextIO | None = None) -> None:
        self.total = total
        self.stream = stream if stream is not None else sys.stderr
        self.enabled = enabled
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.period = TTY_PERIOD_S if self.tty else LINE_PERIOD_S
        self.start = time.monotonic()
        self.last = self.start
        self.printed = False

    def text(self, done: int, failed: int, elapsed_s: float) -> str:
        out = f"formation sweep: {done}/{self.total} cases"
        if failed:
            out += f" ({failed} failed)"
        if 0 < done < self.total and elapsed_s > 0:
            out += f", ETA {_clock(elapsed_s / done * (self.total - done))}"
        return out

    def update(self, done: int, failed: int) -> None:
        if not self.enabled:
            return
        now = time.monotonic()
        if now - self.last < self.period and done < self.total:
            return
        self.last = now
        text = self.text(done, failed, now - self.start)
        self.stream.write(("\r\x1b[K" + text) if self.tty else text + "\n")
        self.stream.flush()
        self.printed = True

    def close(self) -> None:
        if self.enabled and self.tty and self.printed:
            self.stream.write("\n")
            self.stream.flush()


@dataclass
class SweepRun:
    """What :func:`run_cases` did: records by key (old and new), how many ran now, whether
    Ctrl-C cut it short, the wall time and the CPU time the new cases took."""

    records: dict[str, dict[str, Any]]
    ran: int
    skipped: int
    interrupted: bool
    wall_s: float
    case_wall_s: float


def _worker_init() -> None:
    """A worker: SIGINT ignored (the parent decides and stops the workers). Where workers are
    spawned (no fork), also the parent's ``sys.path`` without the compiled core's build root,
    which ``robot_agent.core._accel.activate`` appends after ``robot_agent`` is imported: on a
    fresh interpreter's path it would shadow the package (its ``robot_agent/`` holds only the
    compiled modules); the child's own ``activate`` adds it back."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if "robot_agent" not in sys.modules:
        sys.path[:] = [p for p in sys.path if Path(p).name != "_compiled"]


def _single_threaded() -> bool:
    """Whether this process has one OS thread (native threads included), where the OS says."""
    try:
        return len(os.listdir("/proc/self/task")) == 1
    except OSError:
        return threading.active_count() == 1


def _results_in_order(
    specs: Sequence[CaseSpec], jobs: int, runner: Callable[[CaseSpec], dict[str, Any]]
) -> Iterator[dict[str, Any]]:
    if jobs <= 1 or len(specs) <= 1:
        for s in specs:
            yield runner(s)
        return
    # fork where it is safe: the workers start at once with the modules already imported, and no
    # resource-tracker process outlives the pool (spawn starts one for the pool's locks). A fork
    # is safe only from a process with one thread: `formation sweep` has one (the progress line
    # and the plots are drawn in this thread), but a caller with Zenoh's or BLAS's threads (a
    # test run, a notebook) can fork a child that waits for ever on a lock another thread held.
    methods = multiprocessing.get_all_start_methods()
    fork = "fork" in methods and _single_threaded()
    ctx = multiprocessing.get_context("fork" if fork else "spawn")
    pool = ctx.Pool(min(jobs, len(specs)), initializer=_worker_init)
    try:
        yield from pool.imap_unordered(runner, specs, chunksize=1)
        pool.close()
    finally:
        pool.terminate()  # Ctrl-C or an error: the running cases are dropped
        pool.join()


def run_cases(
    cases: Iterable[Case],
    results_path: Path,
    *,
    jobs: int = 1,
    retry_failed: bool = False,
    progress: CaseProgress | None = None,
    runner: Callable[[CaseSpec], dict[str, Any]] = run_case,
) -> SweepRun:
    """Run every case not already finished in ``results_path``, appending each record as it
    arrives. ``runner`` must be a module-level function (it is sent to spawned workers)."""
    t0 = time.perf_counter()
    cases = list(cases)
    done = read_results(results_path)
    todo = [
        c
        for c in cases
        if c.key not in done or (retry_failed and done[c.key].get("status") != "ok")
    ]
    finished = len(cases) - len(todo)
    failed = sum(1 for c in cases if c.key in done and done[c.key].get("status") != "ok")
    if retry_failed:
        failed = 0
    results_path.parent.mkdir(parents=True, exist_ok=True)
    ran = 0
    case_wall = 0.0
    interrupted = False
    if progress is not None:
        progress.update(finished, failed)
    with results_path.open("a") as f:
        try:
            for rec in _results_in_order([_spec(c) for c in todo], jobs, runner):
                f.write(json.dumps(rec, sort_keys=True) + "\n")
                f.flush()
                done[rec["key"]] = rec
                ran += 1
                finished += 1
                case_wall += float(rec.get("wall_s", 0.0))
                if rec.get("status") != "ok":
                    failed += 1
                if progress is not None:
                    progress.update(finished, failed)
        except KeyboardInterrupt:
            interrupted = True
    if progress is not None:
        progress.close()
    return SweepRun(
        records=done,
        ran=ran,
        skipped=len(cases) - len(todo),
        interrupted=interrupted,
        wall_s=time.perf_counter() - t0,
        case_wall_s=case_wall,
    )
