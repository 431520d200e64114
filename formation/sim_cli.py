"""``formation sim --scenario NAME|FILE [--robots N] [--spares K] [--seed N] [--out DIR]``: the
closed loop in one process. Ctrl-C ends the run between two ticks; metrics and figures of what
was simulated so far are still written (one line says so) and the exit status is 130."""

from __future__ import annotations

import argparse
import json
import signal
import sys
import threading
from pathlib import Path
from typing import Any

import scenario as scenario_mod


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="formation sim",
        description="Run a scenario in-process (no Zenoh): deterministic for a seed, "
        "much faster than real time. Writes metrics.json and PNG figures.",
    )
    p.add_argument(
        "--scenario",
        default="paper-exp2",
        help=f"built-in name ({', '.join(scenario_mod.builtin_names())}) or a TOML file",
    )
    p.add_argument(
        "--robots",
        type=int,
        default=None,
        metavar="N",
        help="grow (or cut) the formation to N slots by the paper's staged rule (Fig 2b) with "
        "robots r1..rN (default: the scenario's)",
    )
    p.add_argument(
        "--spares",
        type=int,
        default=0,
        metavar="K",
        help="add K idle hot spares behind the formation (default 0)",
    )
    p.add_argument("--seed", type=int, default=None, help="override the scenario's seed")
    p.add_argument("--duration", type=float, default=None, help="override the duration (s)")
    p.add_argument("--out", type=Path, default=None, help="output folder (default runs/<name>)")
    p.add_argument("--no-figures", action="store_true", help="skip the PNG figures")
    p.add_argument("--quiet", action="store_true")
    return p


def run_and_write(
    scn: scenario_mod.Scenario,
    out: Path,
    seed: int | None = None,
    duration: float | None = None,
    figures: bool = True,
    stop: threading.Event | None = None,
) -> dict[str, Any]:
    """Run ``scn`` in-process and write metrics.json, run.npz and the figures to ``out``; the
    metrics' ``meta.interrupted`` is True if ``stop`` ended the run early."""
    from formation import metrics, simulate

    result = simulate.run(scn, seed=seed, duration_s=duration, stop=stop)
    # the same settling time as `formation up` / `formation report` for this duration
    settle_s = metrics.settle_for(scn.settle_s, scn.duration_s if duration is None else duration)
    m = metrics.compute(result.log, settle_s, scn.settle_tol_m)
    m["meta"]["realtime_factor"] = result.realtime_factor
    m["firmware"] = result.firmware_status
    m["meta"]["interrupted"] = result.interrupted
    out.mkdir(parents=True, exist_ok=True)
    (out / "metrics.json").write_text(json.dumps(m, indent=2, sort_keys=True) + "\n")
    result.log.save_npz(str(out / "run.npz"))
    if figures:
        from formation import figures as fig_mod

        cut = ""
        if result.interrupted:
            cut = f" (interrupted after {float(result.log.t_s[-1] - result.log.t_s[0]):.1f} s)"
        fig_mod.write_all(
            result.log,
            out,
            title=f"{scn.name}{cut}: reference points (solid), virtual trajectories (dashed)",
            settle_s=settle_s,
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
    for w in m.get("meta", {}).get("path_warnings", []):
        lines.append(f"warning: {w}")
    return "\n".join(lines)


def main(argv: list[str]) -> int:
    args = build_parser().parse_args(argv)
    try:
        if args.robots is not None or args.spares:
            scn = scenario_mod.load_with_robots(args.scenario, args.robots, args.spares)
        else:
            scn = scenario_mod.load(args.scenario)
    except scenario_mod.ScenarioError as exc:
        print(f"formation sim: {exc}", file=sys.stderr)
        return 2
    out = args.out or Path("runs") / scn.name
    stop = threading.Event()
    previous = signal.getsignal(signal.SIGINT)
    signal.signal(signal.SIGINT, lambda *_: stop.set())  # ends the run between two ticks
    try:
        m = run_and_write(
            scn, out, args.seed, args.duration, figures=not args.no_figures, stop=stop
        )
    finally:
        signal.signal(signal.SIGINT, previous)
    if m["meta"]["interrupted"]:
        what = "metrics" if args.no_figures else "metrics and figures"
        print(
            f"formation sim: interrupted: {what} of the {m['run']['duration_s']:.1f} s simulated "
            f"so far in {out}/",
            file=sys.stderr,
        )
        return 130
    if not args.quiet:
        print(f"scenario {scn.name}: {scn.description}")
        print(summary(m))
        print(f"{m['meta']['realtime_factor']:.0f}x real time; metrics and figures in {out}/")
    return 0
