"""``formation report``: metrics and the paper's figures from an MCAP recording.

Usage::

    formation report FILE.mcap [--out DIR] [--settle S] [--tol M] [--scenario NAME|FILE]
                     [--no-figures] [--quiet]

The recording (``formation record`` or ``formation up --record``) is read back in the order the
recorder received it, and every bus sample is fed to the same
:class:`formation.record.collector.RunCollector` that ``formation up`` feeds live, so the RunLog,
and
``formation.outputs.metrics.compute`` on it, are those of the live run. On top of those metrics:

* ``leader_loss``: for every leader whose liveliness token vanished while the run went on, the
  recovery time: from the token's DELETE to the moment after which the formation error (eqs
  17-18, reference point to assigned slot, from truth) of every remaining robot stays within
  ``--tol`` until the end of the run or the next loss (the settling-time rule of
  ``formation.outputs.metrics``); ``null`` if it never comes back within the band.
* ``latency``: per wheel command, ``rx_latency_ms`` (recorder receive time of the wheels minus
  recorder receive time of the pose it was computed from: bus + agent, one clock) and
  ``pose_age_ms`` (realtime: wheels receive time minus the pose's capture time ``pose_t``, which
  adds the camera latency; lockstep: wheels ``t`` minus ``pose_t`` in sim time); p50/p99/max,
  overall and per robot.
* ``power_peaks``: per robot and wheel, the peak |motor power| (fraction of max) and when.
* ``plan`` (issue 27): for a ``kind = "plan"`` trajectory, the plan's figures (plan time,
  length against the straight line, least planned clearance, time to goal as planned and as
  run) and the replans (:mod:`formation.outputs.plan_view`); null otherwise. The trajectories
  figure draws the planned leader path, the footprint corridor and each replan.

Writes ``metrics.json`` and the figures of ``formation.outputs.figures.write_all`` (trajectories
with
the virtual trajectories, motor power per wheel, formation error over time, role timeline) to
``--out`` (default: ``<FILE stem>-report/`` next to the file). A recording cut short (recorder
killed, no MCAP footer) is read up to its last complete chunk.

Which run: the ``formation.run`` metadata record written by the recorder (the scenario's TOML
text, lockstep, the settling time the live run used); ``--scenario`` overrides it. Without
either, robots and slots are those seen on the bus, the geometry is the default one and lockstep
is detected from the ``clock`` key.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final

import numpy as np

import scenario as scenario_mod
from bus_schemas import DecodeError, PlantStatus, decode, keys
from formation.outputs import metrics as metrics_mod
from formation.outputs.plan_view import PlanView, add_plan
from formation.outputs.recovery import fault_recovery
from formation.outputs.runlog import RunLog
from formation.record.collector_plant import inexact_line
from formation.record.latency import LatencySample
from formation.record.replay import (
    LivenessChange,
    Recording,
    Replay,
    ReportError,
    has_clock,
    make_collector,
    natural_order,
    read_recording,
    replay,
    scenario_of,
)

MIN_RUN_AFTER_LOSS_S: Final = 1.0
"""A leader's token loss counts only if the run went on at least this long after it (s): the
tokens that vanish while ``formation up`` shuts everything down are not losses."""
SATURATED_POWER: Final = 0.999


# --------------------------------------------------------------------------------------------
# Extra metrics
# --------------------------------------------------------------------------------------------


def _percentiles(values: Sequence[float]) -> dict[str, Any]:
    arr = np.asarray([v for v in values if math.isfinite(v)], dtype=float)
    if arr.size == 0:
        return {"n": 0, "p50": None, "p99": None, "max": None, "mean": None}
    return {
        "n": int(arr.size),
        "p50": float(np.percentile(arr, 50)),
        "p99": float(np.percentile(arr, 99)),
        "max": float(arr.max()),
        "mean": float(arr.mean()),
    }


def latency_stats(samples: Iterable[LatencySample], lockstep: bool) -> dict[str, Any]:
    """p50/p99/max/mean of ``rx_latency_ms`` and ``pose_age_ms``, overall and per robot."""
    by_robot: dict[str, list[LatencySample]] = {}
    for s in samples:
        by_robot.setdefault(s.robot, []).append(s)

    def block(items: list[LatencySample]) -> dict[str, Any]:
        rx = [s.rx_latency_s * 1e3 for s in items if s.rx_latency_s is not None]
        age = [s.pose_age_s * 1e3 for s in items]
        return {
            "rx_latency_ms": _percentiles(rx),
            "pose_age_ms": _percentiles(age),
            "commands": len(items),
            "unmatched": sum(s.rx_latency_s is None for s in items),
        }

    every = [s for items in by_robot.values() for s in items]
    return {
        "clock": "lockstep: pose_age in sim time" if lockstep else "realtime: monotonic",
        **block(every),
        "robots": {rid: block(by_robot[rid]) for rid in sorted(by_robot, key=natural_order)},
    }


def power_peaks(log: RunLog) -> dict[str, Any]:
    """Per robot and wheel: peak |power| (fraction of max), its time (s), share of saturated
    ticks (|power| >= 0.999)."""
    out: dict[str, Any] = {}
    if log.t_s.size == 0:
        return out
    for j, rid in enumerate(log.robot_ids):
        wheels: dict[str, Any] = {}
        for w, name in enumerate(("right", "left")):
            p = np.abs(log.power[:, j, w])
            k = int(np.argmax(p))
            wheels[name] = {
                "peak": float(p[k]),
                "t_s": float(log.t_s[k]),
                "saturated_fraction": float(np.mean(p >= SATURATED_POWER)),
            }
        out[rid] = wheels
    return out


def _t0_bus(rp: Replay, robot_ids: Sequence[str]) -> float | None:
    """Realtime: the bus time of the log's first row (first frame after which every robot has
    been seen), the collector's default origin."""
    seen: set[str] = set()
    for t in sorted(rp.truth_t):
        seen |= rp.truth_t[t]
        if seen.issuperset(robot_ids):
            return t
    return None


def run_start(rec: Recording, fleet: str) -> float | None:
    """Realtime: the bus time the plant started its run (``t - sim_t`` of its first status
    while running), so a recording attached from outside, after the start, measures times and
    the settling window from the run's start as ``formation up`` does; None without one."""
    key = keys.plant_status_key(fleet)
    for ev in rec.events:
        if ev.key != key or ev.payload is None:
            continue
        st = decode(ev.payload, PlantStatus)
        if isinstance(st, DecodeError) or st.state != "running" or st.mode != "realtime":
            continue
        return float(st.t - st.sim_t)
    return None


def leader_losses(
    log: RunLog,
    rp: Replay,
    fleet: str,
    tol_m: float,
    dt_s: float | None,
    origin_s: float | None = None,
) -> list[dict[str, Any]]:
    """Every loss of the leader's liveliness token during the run, with its recovery time.

    Recovery: from the loss to the moment after which the formation error of every remaining
    (alive) robot stays <= ``tol_m`` until the next loss or the end of the log (None: never).
    """
    if log.t_s.size == 0:
        return []
    if rp.lockstep:
        origin = 0.0
    elif origin_s is not None:
        origin = origin_s
    else:
        t0 = _t0_bus(rp, log.robot_ids)
        if t0 is None:
            return []
        origin = t0
    robot_alive_prefix = keys.alive_robots_pattern(fleet)[:-1]  # ".../alive/robot/"
    plant_key = keys.alive_plant_key(fleet)
    losses: list[tuple[float, str, LivenessChange]] = []
    for ch in rp.changes:
        if ch.alive or ch.bus_t is None or not ch.key.startswith(robot_alive_prefix):
            continue
        robot = ch.key[len(robot_alive_prefix) :]
        if robot != ch.leader:
            continue
        t_loss = ch.bus_t - origin
        if float(log.t_s[-1]) - t_loss < MIN_RUN_AFTER_LOSS_S or plant_key not in ch.alive_after:
            continue  # shutdown, not a loss during the run
        losses.append((t_loss, robot, ch))
    err = metrics_mod.formation_error(log)
    out: list[dict[str, Any]] = []
    for n, (t_loss, robot, ch) in enumerate(losses):
        t_end = losses[n + 1][0] if n + 1 < len(losses) else math.inf
        rows = (log.t_s >= t_loss - 1e-9) & (log.t_s < t_end)
        remaining = [
            j
            for j, rid in enumerate(log.robot_ids)
            if rid != robot and (robot_alive_prefix + rid) in ch.alive_after
        ]
        entry: dict[str, Any] = {
            "robot": robot,
            "t_s": round(t_loss, 6),
            "remaining": [log.robot_ids[j] for j in remaining],
            "recovery_s": None,
            "recovered_at_s": None,
            "peak_error_m": None,
            "new_leader": None,
        }
        if rows.any() and remaining:
            seg = err[rows][:, remaining]
            finite = np.isfinite(seg)
            worst = np.where(
                finite.any(axis=1), np.nanmax(np.where(finite, seg, -np.inf), 1), np.nan
            )
            t_seg = log.t_s[rows]
            settled = metrics_mod.settling_time(t_seg, worst, tol_m)
            if settled is not None:
                entry["recovered_at_s"] = round(settled, 6)
                entry["recovery_s"] = round(settled - t_loss, 6)
            if np.isfinite(worst).any():
                entry["peak_error_m"] = float(np.nanmax(worst))
            last = np.flatnonzero(rows)[-1]
            holders = np.flatnonzero(log.slot_of[last] == 0)
            entry["new_leader"] = log.robot_ids[int(holders[0])] if holders.size else None
        if dt_s is not None:
            entry["tick"] = round(t_loss / dt_s)
        out.append(entry)
    return out


# --------------------------------------------------------------------------------------------
# The report
# --------------------------------------------------------------------------------------------


@dataclass
class Report:
    """A recording measured: the RunLog and the metrics dictionary written as metrics.json."""

    recording: Recording
    log: RunLog
    metrics: dict[str, Any]
    settle_s: float
    tol_m: float
    title: str
    plan: PlanView | None = None


def analyze(
    rec: Recording,
    *,
    scenario: str | None = None,
    settle_s: float | None = None,
    tol_m: float | None = None,
) -> Report:
    """Build the RunLog through the collector and compute every metric (see module docstring).

    ``settle_s`` defaults to the live run's (``formation.run`` metadata), else the scenario's
    (half the run if that is longer than the run), else half the run; ``tol_m`` to the
    scenario's ``settle_tol_m``, else 0.05 m.
    """
    fleet = rec.fleet
    if fleet is None:
        raise ReportError(f"{rec.path}: no fleet traffic in the recording")
    scn = scenario_of(rec, scenario)
    lockstep_meta = rec.run.get("lockstep")
    lockstep = lockstep_meta == "true" if lockstep_meta else has_clock(rec, fleet)
    collector = make_collector(rec, fleet, scn, lockstep)
    rp = replay(rec, collector, lockstep)
    meta: dict[str, Any] = {
        "scenario": scn.name if scn is not None else None,
        "mode": "lockstep" if lockstep else "realtime",
        "dt_s": collector.dt_s if lockstep else (scn.dt_s if scn is not None else None),
        "fleet": fleet,
        "source": "recording",
        "disturbances": [
            {"t_s": d.t_s, "kind": d.kind, "robot": d.robot}
            for d in (scn.disturbances if scn is not None else ())
        ],
    }
    for name in ("seed", "duration_s"):
        if name in rec.run:
            meta[name] = rec.run[name]
    start = None if lockstep or "settle_s" in rec.run else run_start(rec, fleet)
    if start is not None:  # attached from outside: the run's own time base (the plant's start)
        collector.t0_s = start
        meta["time_base"] = "plant start (from its status)"
    log = collector.build(meta)
    if log.t_s.size == 0:
        raise ReportError(f"{rec.path}: no complete truth frame of fleet {fleet!r}")
    if scn is not None:  # safety accounting (issue 14): from the truth; the filter counters
        # come from the agents' status (formation.record.collector, metrics.safety_metrics)
        metrics_mod.attach_agent(log, scn.agent)
    # the run's length so far (its time base: from the plant's start when known)
    duration = float(log.t_s[-1] if start is not None else log.t_s[-1] - log.t_s[0])
    if settle_s is None:
        if "settle_s" in rec.run:
            settle_s = float(rec.run["settle_s"])
        elif scn is not None:
            settle_s = metrics_mod.settle_for(scn.settle_s, duration)
        else:
            settle_s = duration / 2.0
    if tol_m is None:
        tol_m = scn.settle_tol_m if scn is not None else 0.05
    m = metrics_mod.compute(log, settle_s, tol_m)
    m["faults"] = fault_recovery(log, tol_m)  # each fault sent, with its recovery
    m["leader_loss"] = leader_losses(log, rp, fleet, tol_m, collector.dt_s, start)
    m["latency"] = latency_stats(rp.latency, lockstep)
    m["power_peaks"] = power_peaks(log)
    # issue 27: the plan of the run's scenario (a deterministic function of it) and the
    # replans the run reported (log.replans); null without a plan or a scenario
    try:
        plan = add_plan(m, scn.trajectory, log, tol_m) if scn is not None else None
    except ValueError as exc:  # a --scenario whose trajectory does not plan
        raise ReportError(f"the scenario's plan: {exc}") from exc
    m.setdefault("plan", None)
    m["recording"] = {
        "file": str(rec.path),
        "complete": rec.complete,
        "source": rec.source,
        "events": len(rec.events),
        "topics": len(rec.topics),
        "messages": sum(rec.topics.values()),
        "bad_json": rec.bad_json,
        "recorder": dict(rec.stats),
        "liveliness_changes": len(rp.changes),
    }
    name = scn.name if scn is not None else rec.path.stem
    title = f"{name} (recording, {meta['mode']}): reference points (solid), virtual (dashed)"
    return Report(rec, log, m, settle_s, tol_m, title, plan)


LOG_ARRAYS: Final = (
    "t_s",
    "truth",
    "ref",
    "target",
    "slot_of",
    "slot_xy",
    "leader",
    "power",
    "mode",
)


def at_instants(log: RunLog, t_s: np.ndarray) -> tuple[RunLog, int]:
    """The rows of ``log`` at the times ``t_s`` (matched to the microsecond), and their count.

    A lockstep plant publishes truth at every tick, so a recording's rows are the simulator's
    ticks and this is the identity; recordings made before that carry truth at the camera rate
    only (30 of the 50 ticks per second in the built-in scenarios), and this puts the simulator's
    log on their instants.
    """
    ka = np.round(np.asarray(t_s) * 1e6).astype(np.int64)
    kb = np.round(log.t_s * 1e6).astype(np.int64)
    _, _, ib = np.intersect1d(ka, kb, assume_unique=True, return_indices=True)
    rows = {name: getattr(log, name)[ib] for name in LOG_ARRAYS}
    return dataclasses.replace(log, **rows), int(ib.size)


def _short(v: Any) -> str:
    if isinstance(v, float):
        return f"{v:.6g}"
    if isinstance(v, list | tuple):
        return f"[{len(v)} items]"
    text = repr(v)
    return text if len(text) <= 40 else text[:37] + "..."


def differences(a: Any, b: Any, path: str = "") -> list[str]:
    """Every leaf where two nested dictionaries/lists differ, one short line each:
    ``path: a != b`` (numbers with their difference, ``b - a``; lists item by item, or their
    lengths when those differ), so a failed comparison names the metric and by how much."""
    if isinstance(a, dict) and isinstance(b, dict):
        out: list[str] = []
        for k in sorted(set(a) | set(b), key=str):
            out += differences(a.get(k), b.get(k), f"{path}.{k}" if path else str(k))
        return out
    if isinstance(a, list | tuple) and isinstance(b, list | tuple):
        if len(a) != len(b):
            return [f"{path}: {len(a)} items != {len(b)} items"]
        out = []
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            out += differences(x, y, f"{path}[{i}]")
        return out
    if a == b or (isinstance(a, float) and isinstance(b, float) and a != a and b != b):
        return []
    numbers = all(isinstance(v, int | float) and not isinstance(v, bool) for v in (a, b))
    if numbers:
        return [f"{path}: {_short(a)} != {_short(b)} (diff {b - a:+.3g})"]
    return [f"{path}: {_short(a)} != {_short(b)}"]


def differences_text(diffs: list[str], limit: int = 8) -> str:
    """At most ``limit`` differences, one per line, and how many more there are."""
    shown = [f"  {d}" for d in diffs[:limit]]
    if len(diffs) > limit:
        shown.append(f"  ... and {len(diffs) - limit} more")
    return "\n".join(shown)


def compare_with_simulator(
    report: Report, scenario: str | None = None
) -> tuple[dict[str, Any], dict[str, Any]]:
    """Run the in-process simulator (``formation.sim.simulate``) on this recording's scenario, seed
    and duration and compute its metrics with the report's settling time and band. Returns (the
    simulator's metrics, a comparison: ``instants`` matched, ``recording_rows``,
    ``simulator_ticks``, ``every_tick`` (the recording has truth at every simulator tick, so the
    simulator's metrics are those of ``formation sim``'s metrics.json, not a subset),
    ``robots_equal``, ``run_equal``, ``differences``).

    Only a lockstep recording is comparable (realtime timing is not reproducible); raises
    ReportError otherwise or when the scenario is unknown. Lockstep reproduces the simulator
    tick for tick (docs/runtime.md), so ``robots`` and ``run`` are expected to be equal. A
    recording from a plant that published truth at the camera rate only is compared at its
    instants (:func:`at_instants`).
    """
    from formation.sim import simulate

    if report.metrics["meta"].get("mode") != "lockstep":
        raise ReportError("only a lockstep recording can be compared with the simulator")
    scn = scenario_of(report.recording, scenario)
    if scn is None:
        raise ReportError("no scenario in the recording: give --scenario")
    run = report.recording.run
    seed = int(run["seed"]) if "seed" in run else None
    duration = float(run["duration_s"]) if "duration_s" in run else None
    if duration is None:
        duration = round(float(report.log.t_s[-1]) / scn.dt_s) * scn.dt_s
    sim = simulate.run(scn, seed=seed, duration_s=duration)
    every_tick = np.array_equal(report.log.t_s, sim.log.t_s)
    sub, n = (
        (sim.log, int(sim.log.t_s.size)) if every_tick else at_instants(sim.log, report.log.t_s)
    )
    m = metrics_mod.compute(sub, report.settle_s, report.tol_m)
    diffs = differences(
        {"robots": report.metrics["robots"], "run": report.metrics["run"]},
        {"robots": m["robots"], "run": m["run"]},
    )
    cmp = {
        "instants": n,
        "recording_rows": int(report.log.t_s.size),
        "simulator_ticks": int(sim.log.t_s.size),
        "every_tick": every_tick,
        "seed": seed if seed is not None else scn.seed,
        "duration_s": duration,
        "robots_equal": report.metrics["robots"] == m["robots"],
        "run_equal": report.metrics["run"] == m["run"],
        "differences": diffs[:20],
    }
    return m, cmp


def write(report: Report, out_dir: Path, *, figures: bool = True) -> list[Path]:
    """Write metrics.json (and the figures) to ``out_dir``; return the files written."""
    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / "metrics.json"
    path.write_text(json.dumps(report.metrics, indent=2, sort_keys=True) + "\n")
    written = [path]
    if figures:
        from formation.outputs import figures as fig_mod

        written += fig_mod.write_all(
            report.log, out_dir, report.title, report.settle_s, plan=report.plan
        )
    return written


def summary(m: dict[str, Any]) -> str:
    """Human-readable summary: the simulator's table plus leader loss and latency lines."""
    from formation.sim.command import summary as sim_summary

    lines = [sim_summary(m)]
    for loss in m.get("leader_loss", []):
        rec = loss["recovery_s"]
        lines.append(
            f"leader {loss['robot']} lost at {loss['t_s']:.2f} s: "
            + (f"recovered in {rec:.2f} s" if rec is not None else "never recovered")
            + f", new leader {loss['new_leader']}"
        )
    lat = m.get("latency", {})
    rx, age = lat.get("rx_latency_ms", {}), lat.get("pose_age_ms", {})
    if rx.get("n"):
        lines.append(
            f"pose->wheels latency p50 {rx['p50']:.2f} ms, p99 {rx['p99']:.2f} ms "
            f"({rx['n']} commands); pose age p50 {age['p50']:.1f} ms, p99 {age['p99']:.1f} ms"
        )
    return "\n".join(lines)


def comparison_line(cmp: dict[str, Any]) -> str:
    """One line on :func:`compare_with_simulator`'s result."""
    same = cmp["robots_equal"] and cmp["run_equal"]
    verdict = "equal" if same else f"DIFFER ({len(cmp['differences'])}+ fields)"
    where = (
        f"at every one of its {cmp['simulator_ticks']} ticks"
        if cmp.get("every_tick")
        else f"at the {cmp['instants']} recorded instants ({cmp['simulator_ticks']} ticks "
        "simulated)"
    )
    return (
        f"in-process simulator (seed {cmp['seed']}, {cmp['duration_s']:g} s) {where}: "
        f"metrics {verdict}"
    )


def build_parser() -> argparse.ArgumentParser:
    """The ``formation report`` argument parser."""
    p = argparse.ArgumentParser(
        prog="formation report",
        description="Metrics (formation error, settling, leader-loss recovery, latency, motor "
        "power) and the paper's figures from an MCAP recording.",
    )
    p.add_argument("file", type=Path, help="MCAP file from `formation record` / `up --record`")
    p.add_argument("--out", type=Path, default=None, help="output folder (default: <file>-report/)")
    p.add_argument(
        "--settle",
        type=float,
        default=None,
        metavar="S",
        help="settling time in s (default: the run's)",
    )
    p.add_argument(
        "--tol",
        type=float,
        default=None,
        metavar="M",
        help="error band in m (default: the scenario's)",
    )
    p.add_argument("--scenario", default=None, help="scenario of the run (overrides the file's)")
    p.add_argument("--no-figures", action="store_true", help="skip the PNG figures")
    p.add_argument(
        "--compare-sim",
        action="store_true",
        help="lockstep recordings: also run the in-process simulator (same scenario, seed, "
        "duration), compare its metrics with the recording's (metrics.json "
        "'simulator_comparison'); exit 3 if they differ",
    )
    p.add_argument(
        "--rosbag",
        type=Path,
        default=None,
        metavar="DIR",
        help="also write the run as a ROS 2 bag (MCAP storage) into the new folder DIR: "
        "per robot odom, /tf, the slots, the leader (docs/ros2.md)",
    )
    p.add_argument("--quiet", action="store_true", help="print nothing but errors")
    return p


def main(argv: list[str]) -> int:
    """``formation report``: 0 on success, 1 if the file cannot be used, 2 for bad arguments
    (a FILE that does not exist or is not a file counts as a bad argument)."""
    args = build_parser().parse_args(argv)
    if not args.file.is_file():
        what = "no such file" if not args.file.exists() else "not a file"
        print(f"formation report: {args.file}: {what}", file=sys.stderr)
        return 2
    if args.settle is not None and not (args.settle >= 0 and math.isfinite(args.settle)):
        print("formation report: --settle must be >= 0", file=sys.stderr)
        return 2
    if args.tol is not None and not (args.tol > 0 and math.isfinite(args.tol)):
        print("formation report: --tol must be > 0", file=sys.stderr)
        return 2
    if args.rosbag is not None and args.rosbag.exists():
        print(f"formation report: --rosbag {args.rosbag} exists", file=sys.stderr)
        return 2
    try:
        rec = read_recording(args.file)
        if args.rosbag is not None:
            from formation.record.rosbag import RosbagError, export_rosbag

            try:
                bag = export_rosbag(rec, args.rosbag)
            except RosbagError as exc:
                raise ReportError(f"--rosbag: {exc}") from exc
            if not args.quiet:
                print(bag.line())
        report = analyze(rec, scenario=args.scenario, settle_s=args.settle, tol_m=args.tol)
    except (OSError, ReportError, scenario_mod.ScenarioError) as exc:
        print(f"formation report: {exc}", file=sys.stderr)
        return 1
    out = args.out if args.out is not None else args.file.with_name(args.file.stem + "-report")
    cmp: dict[str, Any] | None = None
    if args.compare_sim:
        try:
            _, cmp = compare_with_simulator(report, args.scenario)
        except (ReportError, scenario_mod.ScenarioError) as exc:
            print(f"formation report: --compare-sim: {exc}", file=sys.stderr)
            return 1
        report.metrics["simulator_comparison"] = cmp
    write(report, out, figures=not args.no_figures)
    meta = report.metrics["meta"]
    inexact = inexact_line(meta.get("plant")) if meta.get("mode") == "lockstep" else None
    if inexact is not None:  # the recorded plant status says so
        print(f"formation report: {inexact}", file=sys.stderr)
    if not args.quiet:
        print(summary(report.metrics))
        if cmp is not None:
            print(comparison_line(cmp))
        if not rec.complete:
            print("note: the recording has no footer (recorder killed?); read what was complete")
        print(f"metrics{'' if args.no_figures else ' and figures'} in {out}/")
    if cmp is not None and not (cmp["robots_equal"] and cmp["run_equal"]):
        print("formation report: metrics differ from the simulator's:", file=sys.stderr)
        for d in cmp["differences"]:
            print(f"  {d}", file=sys.stderr)
        return 3
    return 0
