"""What a ``formation up`` run leaves behind: ``metrics.json``, ``run.npz``, the figures, and the
summary it prints (:func:`finish_run`, called by :mod:`formation.launch.launcher` once every
child has stopped: the exit status, the run's metadata (:func:`run_meta`) and the outputs
(:func:`write_results`))."""

from __future__ import annotations

import json
import sys
from collections.abc import Callable, Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any, Final

from formation.launch.children import Child
from formation.launch.intake import RunIntake
from formation.launch.journal import RunJournal
from formation.launch.plan import PLANT_STATS, Plan, UpConfig, UpResult
from formation.outputs.files import save_npz_atomic, write_metrics
from formation.outputs.runlog import RunLog
from formation.record.collector_plant import inexact_line
from runtime.files import os_error_text

EXIT_INTERRUPTED: Final = 130


def run_meta(
    cfg: UpConfig,
    plan: Plan,
    *,
    wall_s: float,
    run_wall_s: float | None,
    stop_s: float | None,
    interrupted: bool,
    failures: Sequence[str],
    events: Sequence[Mapping[str, Any]],
    children: Iterable[Child],
) -> dict[str, Any]:
    """The run's metadata (``RunLog.meta``, ``metrics.json``'s ``meta``): scenario, seed, mode,
    wall times (``wall_s``: the whole command; ``run_wall_s``: first to last truth frame;
    ``stop_s``: the shutdown), bus, outcome (``failures``, ``events``: deaths and respawns)
    and every child process (a respawned one as ``name.generation``)."""
    scn = plan.scenario
    return {
        "scenario": scn.name,
        "seed": plan.seed,
        "dt_s": scn.dt_s,
        "mode": "lockstep" if cfg.lockstep else "realtime",
        "wall_s": wall_s,
        "run_wall_s": run_wall_s,
        "stop_s": stop_s,
        "endpoint": cfg.endpoint,
        "secure": cfg.secure,
        "fleet": cfg.fleet,
        # the scheduled disturbances (the figures mark them; the faults come from the bus)
        "disturbances": [
            {"t_s": d.t_s, "kind": d.kind, "robot": d.robot} for d in scn.disturbances
        ],
        "record": None if cfg.record is None else str(cfg.record),
        "interrupted": interrupted,
        "failures": list(failures),
        "events": list(events),
        "children": {
            f"{c.name}.{c.generation}" if c.generation else c.name: {
                "pid": c.pid,
                "returncode": c.returncode,
                "ready_s": c.ready_s,
                "killed": c.killed,
                "stop_s": c.stop_s,
            }
            for c in children
        },
    }


def write_results(
    log: RunLog,
    cfg: UpConfig,
    plan: Plan,
    result: UpResult,
    run_wall_s: float | None,
    warn: Callable[[str], None],
) -> UpResult:
    """Compute the run's metrics from ``log`` (the collector's view of the bus), write them,
    the log and (``cfg.figures``) the figures to ``plan.out_dir``, print the summary (unless
    ``cfg.quiet``) and return ``result`` with its metrics set."""
    out_dir, scn, interrupted = plan.out_dir, plan.scenario, result.interrupted
    if log.t_s.size == 0:
        warn("no truth was received: no metrics written")
        return result
    from formation.outputs import metrics as metrics_mod
    from formation.outputs.recovery import fault_recovery

    metrics_mod.attach_agent(log, scn.agent)  # safety metrics (issue 14): truth only
    m = metrics_mod.compute(log, plan.settle_s, scn.settle_tol_m)
    m["faults"] = fault_recovery(log, scn.settle_tol_m)  # each fault sent, with its recovery
    sim_s = float(log.t_s[-1] - log.t_s[0])
    m["meta"]["realtime_factor"] = sim_s / run_wall_s if run_wall_s else None
    from formation.outputs.plan_view import add_plan

    plan_shown = add_plan(m, scn.trajectory, log, scn.settle_tol_m)  # issue 27
    result.metrics = m
    written: list[str] = []

    def output(name: str, write: Callable[[], object]) -> None:
        # a full or read-only disk: each output is tried, the ones not written are named
        try:
            write()
            written.append(name)
        except OSError as exc:
            text = f"{out_dir / name} not written: {os_error_text(exc)}"
            result.failures.append(text)
            result.exit_code = 1
            warn(text)

    output("metrics.json", lambda: write_metrics(out_dir, m))
    output("run.npz", lambda: save_npz_atomic(log, out_dir / "run.npz"))
    wrote = "metrics" if "metrics.json" in written else "nothing"
    if cfg.figures:
        from formation.outputs import figures as fig_mod

        cut = f", interrupted after {sim_s:.1f} s" if interrupted else ""

        def figures() -> None:
            try:
                fig_mod.write_all(
                    log,
                    out_dir,
                    title=f"{scn.name} over Zenoh ({m['meta']['mode']}{cut}): reference "
                    "points (solid), virtual trajectories (dashed)",
                    settle_s=plan.settle_s,
                    plan=plan_shown,
                )
            except OSError:
                raise
            except Exception as exc:  # a run cut after a few ticks may not make every figure
                if not interrupted:
                    raise
                warn(f"figures of the interrupted run failed: {exc!r}")

        output("figures", figures)
        if "figures" in written and wrote == "metrics":
            wrote = "metrics and figures"
    if interrupted:  # one line, even with --quiet: what was written is of a partial run
        print(
            f"formation up: interrupted: {wrote} of the {sim_s:.1f} s recorded so far "
            f"in {out_dir}/",
            file=sys.stderr,
            flush=True,
        )
    if not cfg.quiet:
        from formation.sim.command import summary

        print(summary(m))
        rf = m["meta"]["realtime_factor"]
        speed = f", {rf:.1f}x real time" if rf else ""
        print(f"{sim_s:.2f} s of {m['meta']['mode']} run{speed}; {wrote} in {out_dir}/")
    return result


def finish_run(
    cfg: UpConfig,
    plan: Plan,
    intake: RunIntake,
    journal: RunJournal,
    children: Iterable[Child],
    *,
    interrupted: bool,
    wall_s: float,
    stop_s: float | None,
) -> UpResult:
    """The stopped run's result: exit status (1 after a failure, else
    :data:`EXIT_INTERRUPTED` after a stop signal, else 0), metadata and outputs, from what
    ``intake``'s collector holds."""
    run_wall = intake.run_wall_s()
    code = 1 if journal.failures else (EXIT_INTERRUPTED if interrupted else 0)
    result = UpResult(
        exit_code=code,
        out_dir=plan.out_dir,
        failures=list(journal.failures),
        interrupted=interrupted,
        wall_s=wall_s,
        run_wall_s=run_wall,
    )
    collector = intake.collector
    first = collector.first_tick
    if cfg.lockstep and first not in (None, 0):
        journal.warn(f"the collector joined late: ticks 0..{first - 1} are missing from the log")
    meta = run_meta(
        cfg,
        plan,
        wall_s=wall_s,
        run_wall_s=run_wall,
        stop_s=stop_s,
        interrupted=interrupted,
        failures=journal.failures,
        events=journal.events,
        children=children,
    )
    log = collector.build(meta)
    if cfg.lockstep:
        plant = plant_account(plan.out_dir / PLANT_STATS, log.meta.get("plant"))
        if plant is not None:
            log.meta["plant"] = plant
        inexact = inexact_line(plant)
        if inexact is not None:  # one line, even with --quiet
            journal.warn(inexact)
    return write_results(log, cfg, plan, result, run_wall, journal.warn)


def plant_account(stats: Path, seen: Mapping[str, Any] | None) -> dict[str, Any] | None:
    """``metrics.json``'s ``meta.plant``: the plant's own last word (``stats``, the
    ``--stats-out`` file it writes as it exits, ``source`` ``"plant_stats.json"``), else what
    its status on the bus said (``seen``, formation.record.collector_plant: 5 Hz, so the last
    fifth of a second may be missing, and on a bus without ``--secure`` anyone can forge it;
    ``source`` ``"status"``). A lockstep plant is never respawned: its file covers the run."""
    try:
        data = json.loads(stats.read_text())
    except (OSError, ValueError):
        data = None
    if not isinstance(data, dict) or not isinstance(data.get("timeouts"), int):
        return None if seen is None else dict(seen)
    fields = ("mode", "state", "tick", "timeouts", "rejected", "internal_errors")
    out = {k: data.get(k) for k in fields}
    out["source"] = PLANT_STATS
    return out
