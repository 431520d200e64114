"""``formation sim --scenario NAME|FILE [--robots N] [--spares K] [--seed N] [--out DIR]``: the
closed loop in one process. Ctrl-C ends the run between two ticks; metrics and figures of what
was simulated so far are still written (one line says so) and the exit status is 130."""

from __future__ import annotations

import argparse
import signal
import sys
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

import scenario as scenario_mod
from runtime.files import os_error_text

CONFIRM_DURATION_S = 3600.0
"""Sim durations above this (1 h of sim time) need ``--yes``: the run log grows with it."""
MAX_DURATION_S = 1e6
"""Sim durations above this are refused (the bound a scenario file's ``duration_s`` has)."""

EPILOG = """\
examples:
  formation sim                                   # paper-exp2, writes runs/paper-exp2/
  formation sim --scenario chevron7 --duration 30 --seed 4 --out runs/c7
  formation sim --scenario my.toml --no-figures --quiet

durations: > 0 and finite; above 3600 s of sim time needs --yes; above 1e6 s is refused.
Progress (with an ETA) goes to stderr: redrawn on a terminal, a line every 10 s otherwise."""


def build_parser() -> argparse.ArgumentParser:
    from runtime.args import HelpFormatter, non_negative_int, positive_float

    p = argparse.ArgumentParser(
        prog="formation sim",
        description="Run a scenario in-process (no Zenoh): deterministic for a seed, "
        "much faster than real time. Writes metrics.json and PNG figures.",
        epilog=EPILOG,
        formatter_class=HelpFormatter,
    )
    p.add_argument(
        "--scenario",
        default="paper-exp2",
        help=f"built-in name ({', '.join(scenario_mod.builtin_names())}) or a TOML file",
    )
    p.add_argument(
        "--robots",
        type=non_negative_int,
        default=None,
        metavar="N",
        help="grow (or cut) the formation to N slots by the paper's staged rule (Fig 2b) with "
        "robots r1..rN (default: the scenario's)",
    )
    p.add_argument(
        "--spares",
        type=non_negative_int,
        default=0,
        metavar="K",
        help="add K idle hot spares behind the formation (default 0)",
    )
    p.add_argument(
        "--seed", type=non_negative_int, default=None, help="override the scenario's seed (>= 0)"
    )
    p.add_argument(
        "--duration",
        type=positive_float,
        default=None,
        metavar="S",
        help="override the duration in s of sim time (default: the scenario's)",
    )
    p.add_argument("--out", type=Path, default=None, help="output folder (default: runs/<name>)")
    p.add_argument("--no-figures", action="store_true", help="skip the PNG figures")
    p.add_argument(
        "--yes", action="store_true", help=f"run durations above {CONFIRM_DURATION_S:g} s"
    )
    p.add_argument("--quiet", action="store_true", help="print nothing but errors")
    return p


def check_duration(duration_s: float, yes: bool) -> str | None:
    """Why ``duration_s`` of sim time is refused (an error message), or None if it may run."""
    if duration_s > MAX_DURATION_S:
        return f"--duration: {duration_s:g} s is more than the {MAX_DURATION_S:g} s limit"
    if duration_s > CONFIRM_DURATION_S and not yes:
        return (
            f"--duration: {duration_s:g} s of sim time is long (the run log grows with it); "
            f"add --yes to run more than {CONFIRM_DURATION_S:g} s"
        )
    return None


def run_and_write(
    scn: scenario_mod.Scenario,
    out: Path,
    seed: int | None = None,
    duration: float | None = None,
    figures: bool = True,
    stop: threading.Event | None = None,
    progress: Callable[[float, float], None] | None = None,
) -> dict[str, Any]:
    """Run ``scn`` in-process and write metrics.json, run.npz and the figures to ``out``; the
    metrics' ``meta.interrupted`` is True if ``stop`` ended the run early."""
    from formation.outputs import metrics
    from formation.outputs.recovery import fault_recovery
    from formation.sim import simulate

    result = simulate.run(scn, seed=seed, duration_s=duration, stop=stop, progress=progress)
    # the same settling time as `formation up` / `formation report` for this duration
    settle_s = metrics.settle_for(scn.settle_s, scn.duration_s if duration is None else duration)
    m = metrics.compute(result.log, settle_s, scn.settle_tol_m)
    m["faults"] = fault_recovery(result.log, scn.settle_tol_m)  # each fault, with its recovery
    m["meta"]["realtime_factor"] = result.realtime_factor
    m["firmware"] = result.firmware_status
    m["meta"]["interrupted"] = result.interrupted
    from formation.outputs.plan_view import add_plan

    plan = add_plan(m, scn.trajectory, result.log, scn.settle_tol_m)  # issue 27: the plan's figures
    from formation.outputs.files import save_npz_atomic, write_metrics

    write_metrics(out, m)  # whole or not at all (a full disk leaves no cut file)
    save_npz_atomic(result.log, out / "run.npz")
    if figures:
        from formation.outputs import figures as fig_mod
        from formation.outputs.snapshots import events_of

        cut = ""
        if result.interrupted:
            cut = f" (interrupted after {float(result.log.t_s[-1] - result.log.t_s[0]):.1f} s)"
        fig_mod.write_all(
            result.log,
            out,
            title=f"{scn.name}{cut}: reference points (solid), virtual trajectories (dashed)",
            settle_s=settle_s,
            events=events_of(scn.disturbances),
            plan=plan,
        )
    return m


def _m(x: float | None) -> str:
    return "-" if x is None else f"{x:.3f} m"


def summary(m: dict[str, Any]) -> str:
    run = m["run"]
    lines = [
        f"{'robot':<8}{'final slot':>11}{'err RMS (cm)':>14}{'settle (s)':>12}{'peak power':>12}"
    ]
    for rid, r in m["robots"].items():
        rms = r["formation_error_rms_m"]
        st = r["settling_time_s"]
        lines.append(
            f"{rid:<8}{r['final_slot']!s:>11}"
            f"{(f'{rms * 100:.2f}' if rms is not None else '-'):>14}"
            f"{(f'{st:.1f}' if st is not None else 'never'):>12}"
            f"{r['peak_motor_power'] * 100:>11.1f}%"
        )
    sep = run["min_separation_m"]
    lines.append(
        f"min separation {sep:.3f} m, collisions {run['collisions']}, "
        f"role changes {run['role_change_count']}, final leader {run['final_leader']}"
    )
    saf = m.get("safety")
    if saf:
        below = saf["time_below_ds_s"]
        act = saf["filter_active_fraction"]
        lines.append(
            f"safety: Ds {_m(saf['safety_distance_m'])}, time below Ds "
            f"{'-' if below is None else f'{below:.2f} s'}, boundary violations "
            f"{saf['boundary_violations']}, filter active "
            f"{'-' if act is None else f'{act * 100:.1f}%'}, tie-breaks "
            f"{'-' if saf['tiebreaks'] is None else saf['tiebreaks']}"
            + ("" if saf["filter_source"] else " (filter counters not reported: truth only)")
        )
    from formation.outputs.plan_view import plan_summary

    plan = plan_summary(m.get("plan"))
    if plan is not None:
        lines.append(plan)
    lines.extend(fault_lines(m))
    return "\n".join(lines)


def fault_lines(m: dict[str, Any]) -> list[str]:
    """One line per fault sent (with its recovery) and per fault that never fired."""
    out = []
    for f in m.get("faults", []):
        if f.get("undo"):
            continue
        rec = f.get("recovered_s")
        who = f" of {f['robot']}" if f.get("robot") else ""
        out.append(
            f"fault[{f['fault']}] {f['kind']}{who} at t={f['t_s']:.2f} s: "
            f"new leader {f.get('new_leader')}, back in formation "
            f"{'never' if rec is None else f'after {rec:.2f} s'}, peak error "
            f"{_m(f.get('peak_error_m'))}, least separation {_m(f.get('min_separation_m'))}"
        )
    return out


def pending_lines(m: dict[str, Any]) -> list[str]:
    """The faults of the scenario that never fired (a condition that never came)."""
    return [f"fault[{p['fault']}] {p['why']}" for p in m.get("meta", {}).get("faults_pending", [])]


def main(argv: list[str]) -> int:
    args = build_parser().parse_args(argv)
    try:
        if args.robots is not None or args.spares:
            scn = scenario_mod.load_with_robots(args.scenario, args.robots, args.spares)
        else:
            scn = scenario_mod.load(args.scenario)
        from scenario.check import check_cores

        check_cores(scn)
    except scenario_mod.ScenarioError as exc:
        print(f"formation sim: {exc}", file=sys.stderr)
        return 2
    why = check_duration(scn.duration_s if args.duration is None else args.duration, args.yes)
    if why is not None:
        print(f"formation sim: error: {why}", file=sys.stderr)
        return 2
    if not args.quiet:  # every check, BEFORE the run (not after its table)
        from scenario.preflight import preflight_warnings

        for w in preflight_warnings(scn, args.duration):
            print(f"warning: {w}", flush=True)
    out = args.out or Path("runs") / scn.name
    if out.exists() and not out.is_dir():
        print(f"formation sim: error: --out: {out} exists and is not a folder", file=sys.stderr)
        return 2
    from formation.outputs.progress import Progress

    bar = Progress("formation sim", enabled=not args.quiet)
    stop = threading.Event()
    previous = signal.getsignal(signal.SIGINT)
    signal.signal(signal.SIGINT, lambda *_: stop.set())  # ends the run between two ticks
    try:
        m = run_and_write(
            scn,
            out,
            args.seed,
            args.duration,
            figures=not args.no_figures,
            stop=stop,
            progress=bar.update,
        )
    except OSError as exc:  # a full or read-only disk: one line, status 1 (issue 30)
        where = exc.filename or out
        print(f"formation sim: {where} not written: {os_error_text(exc)}", file=sys.stderr)
        return 1
    finally:
        signal.signal(signal.SIGINT, previous)
        bar.close()
    if m["meta"]["interrupted"]:
        what = "metrics" if args.no_figures else "metrics and figures"
        print(
            f"formation sim: interrupted: {what} of the {m['run']['duration_s']:.1f} s simulated "
            f"so far in {out}/",
            file=sys.stderr,
        )
        return 130
    for line in pending_lines(m):  # a clear report at the end, even with --quiet
        print(f"formation sim: warning: {line}", file=sys.stderr)
    if not args.quiet:
        print(f"scenario {scn.name}: {scn.description}")
        print(summary(m))
        print(f"{m['meta']['realtime_factor']:.0f}x real time; metrics and figures in {out}/")
    return 0
