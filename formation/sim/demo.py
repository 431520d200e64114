"""``formation demo``: the paper's experiment 2 over Zenoh, beside its in-process reference.

Usage::

    formation demo [--out runs/demo] [--endpoint tcp/127.0.0.1:PORT] [--duration S]
                   [--no-figures] [--no-record]

1. ``paper-exp2`` as separate processes (router, plant, coordinator, one agent per robot) over an
   embedded Zenoh router, in lockstep: exactly what ``formation up --scenario paper-exp2
   --lockstep --record <out>/paper-exp2-zenoh/run.mcap`` runs (the same function,
   :func:`formation.launch.up.run_up`). Output in ``<out>/paper-exp2-zenoh/``, the MCAP recording of
   every bus message of the run in ``<out>/paper-exp2-zenoh/run.mcap`` (open it in Foxglove).
2. ``formation report`` on that recording: metrics.json and the paper's figures rebuilt from the
   MCAP file alone, in ``<out>/paper-exp2-zenoh/report/``, checked against the live run's
   metrics and against the in-process simulator's.
3. The same scenario and seed in one process (``formation sim``), output in
   ``<out>/paper-exp2-inprocess/``.
4. A comparison of the two: lockstep makes the distributed run reproduce the in-process one
   tick for tick (docs/runtime.md), so the truth trajectories should agree to the last bit, and
   the two metrics.json (``robots`` and ``run``: error RMS, settling, separation, collisions,
   role changes, motor power peaks) are equal; the exit status is 1 if they are not.

Without ``--endpoint`` the router listens on a free loopback port, so the demo does not clash
with a ``formation up`` already running on the default port. Exit status: that of the
distributed run (0 when every process started, ran and stopped cleanly).
"""

from __future__ import annotations

import argparse
import asyncio
import socket
import sys
from pathlib import Path
from typing import Any

import numpy as np

import scenario as scenario_mod
from formation.record import report as report_mod
from formation.record.collector_plant import inexact_line
from formation.sim.command import run_and_write, summary

SCENARIO = "paper-exp2"


def free_endpoint() -> str:
    """A loopback TCP endpoint whose port was free a moment ago."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.bind(("127.0.0.1", 0))
        return f"tcp/127.0.0.1:{sock.getsockname()[1]}"


def compare_runs(a_dir: Path, b_dir: Path) -> dict[str, Any]:
    """Compare two runs' ``run.npz`` (truth, commands, assignment) at the times both logged.

    Rows are matched by time (to the microsecond): a lockstep bus run logs every tick like the
    simulator, a realtime one the plant's truth frames. Returns ``rows_a``, ``rows_b``,
    ``common`` (rows compared), ``truth_max_abs_m`` (largest x/y difference, m),
    ``theta_max_abs_rad``, ``power_max_abs`` (fraction of max), ``leader_max_abs_m``,
    ``slot_of_equal`` and ``identical`` (truth, power, assignment, slots and leader equal bit for
    bit).
    """
    a, b = np.load(a_dir / "run.npz"), np.load(b_dir / "run.npz")
    ka = np.round(a["t_s"] * 1e6).astype(np.int64)
    kb = np.round(b["t_s"] * 1e6).astype(np.int64)
    _, ia, ib = np.intersect1d(ka, kb, assume_unique=True, return_indices=True)

    def pair(name: str) -> tuple[np.ndarray, np.ndarray]:
        return a[name][ia], b[name][ib]

    def max_abs(x: np.ndarray, y: np.ndarray) -> float:
        return float(np.nanmax(np.abs(x - y))) if x.size else 0.0

    ta, tb = pair("truth")
    same = {
        name: bool(np.array_equal(*pair(name), equal_nan=True))
        for name in ("truth", "power", "slot_of", "slot_xy", "leader")
    }
    return {
        "rows_a": int(a["t_s"].size),
        "rows_b": int(b["t_s"].size),
        "common": int(ia.size),
        "truth_max_abs_m": max_abs(ta[..., :2], tb[..., :2]),
        "theta_max_abs_rad": max_abs(ta[..., 2], tb[..., 2]),
        "power_max_abs": max_abs(*pair("power")),
        "leader_max_abs_m": max_abs(*(x[:, :2] for x in pair("leader"))),
        "slot_of_equal": same["slot_of"],
        "identical": all(same.values()),
    }


def metrics_differences(a: dict[str, Any], b: dict[str, Any]) -> list[str]:
    """Where the metrics computed from truth, commands and assignment (``robots`` and ``run`` of
    two metrics.json) differ, ``path: a != b``; ``meta`` (mode, wall time, collector counters)
    is not compared. Empty when equal."""
    parts = ("robots", "run")
    return report_mod.differences({k: a[k] for k in parts}, {k: b[k] for k in parts})


def _comparison_text(ma: dict[str, Any], mb: dict[str, Any], cmp: dict[str, Any]) -> str:
    lines = [
        f"{'':<28}{'over Zenoh':>14}{'in-process':>14}",
        f"{'final leader':<28}{ma['run']['final_leader']!s:>14}{mb['run']['final_leader']!s:>14}",
        f"{'min separation (m)':<28}{ma['run']['min_separation_m']:>14.4f}"
        f"{mb['run']['min_separation_m']:>14.4f}",
        f"{'collisions':<28}{ma['run']['collisions']:>14}{mb['run']['collisions']:>14}",
        f"{'role changes':<28}{ma['run']['role_change_count']:>14}"
        f"{mb['run']['role_change_count']:>14}",
    ]
    for rid in ma["robots"]:
        for key, label, scale in (
            ("formation_error_rms_m", "error RMS (cm)", 100.0),
            ("settling_time_s", "settling (s)", 1.0),
        ):
            va, vb = ma["robots"][rid][key], mb["robots"].get(rid, {}).get(key)
            fa = "-" if va is None else f"{va * scale:.3f}"
            fb = "-" if vb is None else f"{vb * scale:.3f}"
            lines.append(f"{rid + ' ' + label:<28}{fa:>14}{fb:>14}")
    verdict = (
        "identical (truth, commands, assignment and slots equal bit for bit)"
        if cmp["identical"]
        else f"largest truth difference {cmp['truth_max_abs_m'] * 1000:.3f} mm, "
        f"{cmp['theta_max_abs_rad']:.2e} rad; motor power {cmp['power_max_abs']:.2e}; "
        f"assignment {'equal' if cmp['slot_of_equal'] else 'DIFFERS'}"
    )
    lines.append(
        f"at the {cmp['common']} instants both logged ({cmp['rows_a']} truth frames over "
        f"Zenoh, {cmp['rows_b']} simulator ticks): {verdict}"
    )
    plant = ma.get("meta", {}).get("plant")
    inexact = inexact_line(plant)
    if plant is None:
        lines.append("the plant's account of the lockstep run is missing (meta.plant)")
    elif inexact is not None:  # the line formation up printed: the runs need not be identical
        lines.append(f"{inexact}; the two runs are not expected to be identical")
    else:
        lines.append("the plant waited for every answer of every tick (meta.plant.timeouts 0)")
    return "\n".join(lines)


def report_recording(path: Path, live: dict[str, Any], figures: bool = True) -> bool:
    """``formation report PATH --out <dir>/report --compare-sim`` in-process, printed; True when
    the report's metrics equal the live run's and the simulator's."""
    out = path.parent / "report"
    print(f"\n== formation report {path} --out {out} --compare-sim")
    try:
        rep = report_mod.analyze(report_mod.read_recording(path))
        _, cmp = report_mod.compare_with_simulator(rep)
    except (OSError, ValueError) as exc:  # ReportError, ScenarioError
        print(f"formation demo: report of {path}: {exc}", file=sys.stderr)
        return False
    rep.metrics["simulator_comparison"] = cmp
    report_mod.write(rep, out, figures=figures)
    print(report_mod.summary(rep.metrics))
    live_diffs = metrics_differences(rep.metrics, live)
    same_live = not live_diffs
    verdict = "equal" if same_live else f"DIFFER ({len(live_diffs)}: MCAP != live)"
    print(f"metrics from the MCAP file vs the live run's metrics.json: {verdict}")
    if not same_live:
        print(report_mod.differences_text(live_diffs))
    print(report_mod.comparison_line(cmp))
    print(f"metrics.json{' and figures' if figures else ''} in {out}/")
    return same_live and cmp["robots_equal"] and cmp["run_equal"]


def main(argv: list[str]) -> int:
    """Entry point of ``formation demo`` (``make demo``)."""
    from runtime.args import positive_float

    p = argparse.ArgumentParser(prog="formation demo", description=__doc__.splitlines()[0])
    p.add_argument("--out", type=Path, default=Path("runs/demo"), help="output folder")
    p.add_argument(
        "--endpoint", default=None, help="router endpoint (default: a free loopback port)"
    )
    p.add_argument(
        "--duration",
        type=positive_float,
        default=None,
        help="sim seconds (default: the scenario's)",
    )
    p.add_argument("--no-figures", action="store_true", help="skip the PNG figures")
    p.add_argument(
        "--no-record", action="store_true", help="do not record the run to MCAP (no report)"
    )
    args = p.parse_args(argv)

    from formation.launch import up

    scn = scenario_mod.load(SCENARIO)
    zenoh_out = args.out / f"{SCENARIO}-zenoh"
    ref_out = args.out / f"{SCENARIO}-inprocess"
    cfg = up.UpConfig(
        scenario=SCENARIO,
        lockstep=True,
        duration_s=args.duration,
        endpoint=args.endpoint or free_endpoint(),
        out=zenoh_out,
        figures=not args.no_figures,
        record=None if args.no_record else zenoh_out / "run.mcap",
    )
    rec_arg = "" if cfg.record is None else f" --record {cfg.record}"
    print(
        f"== {SCENARIO} over Zenoh, lockstep "
        f"(formation up --scenario {SCENARIO} --lockstep{rec_arg})"
    )
    print(f"   {scn.description}")
    result = asyncio.run(up.run_up(cfg))
    if result.metrics is None:
        print("formation demo: the distributed run produced no metrics", file=sys.stderr)
        return result.exit_code or 1
    report_ok = True
    if cfg.record is not None:
        report_ok = report_recording(cfg.record, result.metrics, figures=not args.no_figures)

    print(f"\n== {SCENARIO} in-process (formation sim --scenario {SCENARIO}): the reference")
    ref = run_and_write(scn, ref_out, duration=args.duration, figures=not args.no_figures)
    print(summary(ref))
    print(f"{ref['meta']['realtime_factor']:.0f}x real time; metrics and figures in {ref_out}/")

    print("\n== comparison")
    cmp = compare_runs(zenoh_out, ref_out)
    print(_comparison_text(result.metrics, ref, cmp))
    diffs = metrics_differences(result.metrics, ref)
    same = not diffs
    verdict = "equal" if same else f"DIFFER ({len(diffs)}: over Zenoh != in-process)"
    print(f"metrics.json over Zenoh vs in-process (robots, run): {verdict}")
    if not same:
        print(report_mod.differences_text(diffs))
    print(f"\nfigures and metrics.json: {zenoh_out}/ (over Zenoh), {ref_out}/ (in-process)")
    if cfg.record is not None:
        print(
            f"recording: {cfg.record} (Foxglove: open local file); its report: {zenoh_out}/report/"
        )
    return result.exit_code or (0 if report_ok and same else 1)
