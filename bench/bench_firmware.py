"""Benchmark of one robot's control tick: ``Firmware.step`` with 3 neighbours.

Prints the mean / p50 / p99 wall time of ``step`` over many ticks (each tick timed with
``time.perf_counter_ns``; the timer's own cost is measured and reported, not subtracted); the
same ticks timed in blocks with ``time.thread_time_ns`` (CPU time of this thread: robust when
other processes compete for the 2 cores); a breakdown of the pipeline stages timed in tight
loops; and one result line::

    bench_firmware: step mean=... us p50=... us p99=... us cpu=... us (200000 ticks, ...) PASS

The verdict compares the wall-clock p50 with the 10 us goal (the mean is inflated by any
preemption on a busy machine; both are printed).

Without ``--estimator`` the firmware runs with ``EstimatorParams(enabled=False)`` (the firmware
of before, the anchor of the issue 2 / 14 rows; the estimator is on by default).
``--estimator`` adds whole-tick medians of the same inputs with the safety filter off and with no
new camera pose (odometry only): their differences from the whole tick are what the filter and
the fusion of a camera pose cost inside the step.

Run: ``.venv/bin/python bench/bench_firmware.py [--ticks N] [--json] [--estimator]``. This is a
measurement, not a test: it never fails on speed (the exit code is 0 unless it crashes).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from robot_agent.core import (
    AgentConfig,
    EstimatorParams,
    Firmware,
    Pose,
    SafetyFilter,
    Setpoint,
    TrackingController,
    _accel,
    reference_point,
    repulsion_velocity_counted,
    saturate_wheels,
    twist_from_ref_velocity,
    wheels_from_twist,
)

GOAL_US = 10.0
# --estimator: the firmware with its pose estimator, fed a camera pose captured --latency-ms ago
# (default 40) and encoder speeds every tick (a fused camera pose, odometry and the latency
# compensation on every tick: the costly case).
_CFG_OFF = AgentConfig(estimator=EstimatorParams(enabled=False))  # the firmware of before
_CFG = _CFG_OFF
_EST_KW: dict[str, Any] = {}
LATENCY_S = [0.04]
DT_S = 0.02
RING = 1024  # pre-built inputs, cycled: the bench measures step(), not message construction


def _inputs(n: int) -> tuple[list[Pose], list[Setpoint], list[list[tuple[float, float]]]]:
    """A robot circling behind a moving slot with 3 neighbours, one inside the repulsion range."""
    poses, sps, nbrs = [], [], []
    for k in range(n):
        t = k * DT_S
        th = 0.2 * t
        x, y = math.cos(th), math.sin(th)
        poses.append(Pose(x, y, th + math.pi / 2, t))
        sps.append(Setpoint(x + 0.08, y + 0.03, -0.2 * y, 0.2 * x, th, 1, t))
        nbrs.append([(x + 0.2, y + 0.05), (x - 0.6, y + 0.4), (x + 1.5, y - 1.0)])
    return poses, sps, nbrs


_WHEELS = (3.0, 3.2)  # encoder speeds (rad/s) of the --estimator run


def _percentile(sorted_ns: list[int], q: float) -> float:
    i = min(len(sorted_ns) - 1, max(0, round(q * (len(sorted_ns) - 1))))
    return sorted_ns[i] / 1000.0


def bench_step(ticks: int) -> dict[str, float]:
    """Time ``Firmware.step`` tick by tick; returns statistics in microseconds."""
    fw = Firmware(_CFG)
    poses, sps, nbrs = _inputs(RING)
    clock = time.perf_counter_ns
    samples = [0] * ticks
    step = fw.step
    est = bool(_EST_KW)
    lat = LATENCY_S[0]
    for k in range(ticks):
        j = k % RING
        now = k * DT_S
        pose = poses[j]
        if est:  # keywords written out as a shell does (a **dict call costs ~0.4 us more)
            cap = now - lat
            t0 = clock()
            step(now, pose=pose, pose_rx_s=now, setpoint=sps[j], setpoint_rx_s=now,
                 neighbours=nbrs[j], pose_capture_s=cap, wheel_speeds=_WHEELS)  # fmt: skip
        else:
            t0 = clock()
            step(now, pose=pose, pose_rx_s=now, setpoint=sps[j], setpoint_rx_s=now,
                 neighbours=nbrs[j])  # fmt: skip
        samples[k] = clock() - t0
    status = fw.status()
    assert status.mode == "tracking", status
    samples.sort()
    # Cost of the timer pair alone, for reference.
    timer = [0] * 10000
    for k in range(10000):
        t0 = clock()
        timer[k] = clock() - t0
    timer.sort()
    return {
        "mean_us": sum(samples) / ticks / 1000.0,
        "p50_us": _percentile(samples, 0.50),
        "p99_us": _percentile(samples, 0.99),
        "max_us": samples[-1] / 1000.0,
        "timer_p50_us": _percentile(timer, 0.50),
        "saturated_ticks": float(status.saturated_count),
    }


def bench_step_cpu(ticks: int, block: int = 10_000) -> dict[str, float]:
    """CPU time (us/tick) of ``step`` in blocks of ``block`` ticks: best and median block."""
    fw = Firmware(_CFG)
    poses, sps, nbrs = _inputs(RING)
    cpu = time.thread_time_ns
    step = fw.step
    est = bool(_EST_KW)
    lat = LATENCY_S[0]
    means: list[float] = []
    k = 0
    for _ in range(max(1, ticks // block)):
        t0 = cpu()
        for _ in range(block):
            j = k % RING
            now = k * DT_S
            if est:
                cap = now - lat
                step(now, pose=poses[j], pose_rx_s=now, setpoint=sps[j], setpoint_rx_s=now,
                     neighbours=nbrs[j], pose_capture_s=cap, wheel_speeds=_WHEELS)  # fmt: skip
            else:
                step(now, pose=poses[j], pose_rx_s=now, setpoint=sps[j], setpoint_rx_s=now,
                     neighbours=nbrs[j])  # fmt: skip
            k += 1
        means.append((cpu() - t0) / block / 1000.0)
    means.sort()
    return {"cpu_best_us": means[0], "cpu_median_us": means[len(means) // 2]}


def _loop_us(fn: Callable[[], object], n: int) -> float:
    """Mean time (us) of ``fn()`` over ``n`` calls in a tight loop, minus the empty loop."""

    def empty() -> None:
        return None

    def run(f: Callable[[], object]) -> int:
        t0 = time.perf_counter_ns()
        for _ in range(n):
            f()
        return time.perf_counter_ns() - t0

    base = min(run(empty) for _ in range(3))
    best = min(run(fn) for _ in range(3))
    return max(0.0, (best - base) / n / 1000.0)


def _p50_us(fn: Callable[[], object], n: int) -> float:
    """Median wall time (us) of one ``fn()`` call over ``n`` calls, each timed (robust to the
    preemption a tight loop's mean takes in on a busy machine; the timer pair included)."""
    clock = time.perf_counter_ns
    samples = [0] * n
    for k in range(n):
        t0 = clock()
        fn()
        samples[k] = clock() - t0
    samples.sort()
    return _percentile(samples, 0.5)


def breakdown(n: int) -> dict[str, float]:
    """Per-stage mean cost (us) of one call, each in its own tight loop (the stages and the
    whole-tick lines without the estimator; with ``--estimator`` also the lines with it)."""
    cfg = _CFG_OFF
    g = cfg.geometry
    poses, sps, nbrs = _inputs(4)
    pose, sp, nb = poses[1], sps[1], nbrs[1]
    ctl = TrackingController(cfg.gains)
    flt = SafetyFilter(cfg)
    rx, ry = reference_point(pose.x, pose.y, pose.theta, g.ref_offset_m)
    fw = Firmware(cfg)
    hold = Firmware(cfg)
    clock = [0.0]

    def fw_step() -> object:
        clock[0] += DT_S
        now = clock[0]
        return fw.step(now, pose=pose, pose_rx_s=now, setpoint=sp, setpoint_rx_s=now, neighbours=nb)

    def hold_step() -> object:  # stale pose: the HOLD path
        clock[0] += DT_S
        now = clock[0]
        return hold.step(now, pose=pose, pose_rx_s=-1.0, setpoint=sp, setpoint_rx_s=now)

    parts: dict[str, float] = {}
    if _EST_KW:  # the estimator alone: what one Firmware.step asks of it (odometry, a 40 ms
        # old camera pose, the estimate at now), on the bench's poses
        from robot_agent.core import Estimator

        est = Estimator(EstimatorParams(enabled=True))
        ring, _, _ = _inputs(RING)
        r, half = cfg.geometry.wheel_radius_m, cfg.geometry.half_track_m
        v, w = 0.5 * r * (_WHEELS[0] + _WHEELS[1]), 0.5 * r * (_WHEELS[0] - _WHEELS[1]) / half
        k = [0]

        def est_tick() -> object:
            k[0] += 1
            now = k[0] * DT_S
            p = ring[k[0] % RING]
            return est.tick(now, now - DT_S, v, w, True, now - lat, p.x, p.y, p.theta)

        lat = LATENCY_S[0]
        parts[f"Estimator.tick (odometry, {lat * 1e3:g} ms old pose)"] = _loop_us(est_tick, n)
        # whole ticks of the --estimator run (its inputs: a new camera pose every tick, encoder
        # speeds) next to the same ticks with the safety filter off and with no new camera pose
        # (the pose object of the tick before presented again: odometry only): the difference
        # is what the filter / the fusion costs inside the step
        ring_sp, ring_nb = _inputs(RING)[1:]

        def whole(cfg_w: AgentConfig, new_pose: bool) -> Callable[[], object]:
            fw_w = Firmware(cfg_w)
            st = [0, 0]  # tick, tick of the pose presented

            def tick() -> object:
                k = st[0] = st[0] + 1
                if new_pose or k % 50 == 0:  # else a new pose every 50th tick (inside the bound)
                    st[1] = k
                kp = st[1]
                now = k * DT_S
                j = k % RING
                return fw_w.step(now, pose=ring[kp % RING], pose_rx_s=now, setpoint=ring_sp[j],
                                 setpoint_rx_s=now, neighbours=ring_nb[j],
                                 pose_capture_s=kp * DT_S - lat, wheel_speeds=_WHEELS)  # fmt: skip

            return tick

        off = replace(_CFG, safety_filter=replace(_CFG.safety_filter, enabled=False))
        parts["Firmware.step --estimator (whole tick, p50)"] = _p50_us(whole(_CFG, True), n)
        parts["  the same, safety filter off (p50)"] = _p50_us(whole(off, True), n)
        parts["  the same, no new camera pose (p50)"] = _p50_us(whole(_CFG, False), n)
    return parts | {
        "reference_point (eqs 10-11)": _loop_us(
            lambda: reference_point(pose.x, pose.y, pose.theta, g.ref_offset_m), n
        ),
        "TrackingController.update (eqs 21-22)": _loop_us(
            lambda: ctl.update(0.03, -0.02, 0.1, 0.05, DT_S), n
        ),
        "repulsion, 3 neighbours (1 in range)": _loop_us(
            lambda: repulsion_velocity_counted(pose.x, pose.y, nb, (), cfg.repulsion), n
        ),
        "safety filter, 3 neighbours (1 inside Ds)": _loop_us(
            lambda: flt.filter(1.0, rx, ry, 0.2, 0.05, 0.08, 0.03, nb, (), 0.0, DT_S), n
        ),
        "twist_from_ref_velocity (eq 16)": _loop_us(
            lambda: twist_from_ref_velocity(0.1, 0.05, pose.theta, g.ref_offset_m), n
        ),
        "wheels_from_twist (eq 8)": _loop_us(lambda: wheels_from_twist(0.1, 1.0, g), n),
        "saturate_wheels": _loop_us(lambda: saturate_wheels(12.0, 3.0, g.max_wheel_radps), n),
        "Firmware.step TRACKING (whole tick)": _loop_us(fw_step, n),
        "Firmware.step HOLD (stale pose)": _loop_us(hold_step, n),
        "Firmware.status() (not per tick)": _loop_us(fw.status, n // 10),
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ticks", type=int, default=200_000, help="ticks to time (default 200000)")
    ap.add_argument("--json", action="store_true", help="also print the results as JSON")
    ap.add_argument(
        "--estimator", action="store_true", help="enable the pose estimator (see _EST_KW)"
    )
    ap.add_argument(
        "--latency-ms",
        type=float,
        default=40.0,
        help="--estimator: age of the camera pose each tick (default 40 ms)",
    )
    ap.add_argument(
        "--both",
        action="store_true",
        help="also run the same benchmark on the pure-Python core (FORMATION_ACCEL=0) right "
        "after, and print both verdict lines (an anchor measured in the same minutes)",
    )
    args = ap.parse_args(argv)
    LATENCY_S[0] = args.latency_ms / 1000.0
    if args.estimator:
        global _CFG
        _CFG = AgentConfig(estimator=EstimatorParams(enabled=True))
        _EST_KW["on"] = True
    ticks = max(1000, args.ticks)

    print(f"python {platform.python_version()} ({platform.python_implementation()}), {ticks} ticks")
    print(f"firmware core: {_accel.STATUS}")
    stats = bench_step(ticks)
    print(
        f"Firmware.step per tick (wall): mean {stats['mean_us']:.2f} us, "
        f"p50 {stats['p50_us']:.2f} us, p99 {stats['p99_us']:.2f} us, "
        f"max {stats['max_us']:.1f} us (timer pair {stats['timer_p50_us']:.2f} us included)"
    )
    cpu = bench_step_cpu(ticks)
    stats.update(cpu)
    print(
        f"Firmware.step per tick (thread CPU time, blocks of 10000): "
        f"best {cpu['cpu_best_us']:.2f} us, median {cpu['cpu_median_us']:.2f} us"
    )
    parts = breakdown(max(10_000, ticks // 4))
    print("breakdown (mean per call, tight loop):")
    for name, us in parts.items():
        print(f"  {name:<44s} {us:6.2f} us")
    verdict = "PASS" if stats["p50_us"] < GOAL_US else "OVER"
    print(
        f"bench_firmware: step mean={stats['mean_us']:.2f} us p50={stats['p50_us']:.2f} us "
        f"p99={stats['p99_us']:.2f} us cpu={stats['cpu_median_us']:.2f} us "
        f"({ticks} ticks, 3 neighbours) goal<{GOAL_US:g}us {verdict} "
        f"core={'compiled' if _accel.ACTIVE else 'pure'}"
    )
    if args.json:
        print(json.dumps({"step": stats, "breakdown_us": parts}, sort_keys=True))
    if args.both:
        argv_pure = [a for a in (sys.argv[1:] if argv is None else argv) if a != "--both"]
        env = dict(os.environ, **{_accel.ENV: "0"})
        pure = subprocess.run(
            [sys.executable, __file__, *argv_pure], env=env, capture_output=True, text=True
        )
        last = [ln for ln in pure.stdout.splitlines() if ln.startswith("bench_firmware:")]
        print("the same on the pure-Python core (FORMATION_ACCEL=0):")
        print(last[-1] if last else f"  (pure run failed: {pure.stderr.strip()[-300:]})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
