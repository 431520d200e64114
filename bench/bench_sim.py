"""Benchmark: real-time factor of the in-process closed loop (``formation.sim.simulate.run``).

Three fleets: paper-exp2 (3 robots, greedy, a drag mid-run), chevron7 (7 robots, optimal) and a
30-robot chevron built here with ``scenario.parse`` (robots start near their slots,
straight-line leader). For each: the real-time factor (sim seconds per wall second of the loop,
including building the log arrays; best and median of ``--runs`` runs, plus the process-CPU
figure, which is steadier on a shared machine), then the time per tick of each stage.

The stage breakdown comes from a separate run in which the components' methods are wrapped with
timers (the loop itself carries no instrumentation); the wrappers' own cost is measured on a no-op
and subtracted. "collector" is the youngest generation's collection every 500 ticks (the automatic
collections are paused over the loop: formation/sim/collector.py); "monitor" and "log arrays" run
once, at the end (the in-process loop's log converts its numbers to arrays every 250 ticks,
formation/sim/ticklog.py: that part is in "loop"). "loop" is the rest of that run's tick: setpoints,
neighbour lists, the fresh-pose set, log appends, allocation; with the compiled simulator (``make
accel``; the first lines say which builds run) also the camera, link and plant, which the compiled
loop calls natively. On a shared VM (CPU steal) figures vary by tens of percent from run to run;
compare stages within one run. Measures only; asserts nothing.

Run: .venv/bin/python bench/bench_sim.py [--runs 5] [--only paper-exp2]
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import statistics
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import scenario as scenario_mod
from coordinator.core import _accel as coord_accel
from coordinator.core import coordinator as coord_core
from coordinator.core import trajectory as traj_mod
from coordinator.core.assignment import RoleAssigner
from coordinator.core.formation import FormationSpec, slot_states
from coordinator.core.trajectory import make_trajectory
from formation.outputs.runlog import RunLog
from formation.sim import simulate
from formation.sim.collector import CollectorPause
from robot_agent.core import _accel as fw_accel
from robot_agent.core.firmware import Firmware
from sim_plant.core import _accel as sim_accel
from sim_plant.core.accounting import SeparationMonitor
from sim_plant.core.plant import Plant
from sim_plant.core.sensors import Camera, CommandLink

# Stages whose methods the compiled simulator (sim_plant.core._accel) calls natively: a wrapper
# set on the class is not seen, so with that build their time is part of "loop".
NATIVE_STAGES = ("camera", "link", "plant")
# Likewise inside the compiled coordinator (coordinator.core._accel): its time is "coordinator".
COORDINATOR_NATIVE_STAGES = ("  slots", "  assignment")


def chevron_scenario(n: int, duration_s: float = 60.0, seed: int = 5) -> scenario_mod.Scenario:
    """``n`` robots in a chevron (b = 0.4 m) behind a straight-line leader at 0.03 m/s, each
    starting 2-4 cm off its slot (reference point on the slot, heading along the line)."""
    trajectory = {"kind": "line", "x0": 0.0, "y0": 0.0, "heading": 0.0, "speed_mps": 0.03}
    spec = FormationSpec.chevron(n, b_m=0.4)
    leader = make_trajectory("line", {k: v for k, v in trajectory.items() if k != "kind"})
    l_m = 0.05  # RobotGeometry.ref_offset_m default: the axle is l behind the reference point
    initial = []
    for j, s in enumerate(slot_states(spec, leader.sample(0.0))):
        dx, dy = (0.02, -0.03) if j % 2 else (-0.03, 0.02)
        initial.append([s.x - l_m + dx, s.y + dy, 0.0])
    data: dict[str, Any] = {
        "name": f"chevron{n}",
        "description": f"{n} robots in a chevron behind a straight-line leader (benchmark)",
        "duration_s": duration_s,
        "dt_s": 0.02,
        "seed": seed,
        "settle_s": duration_s / 2,
        "robots": {"count": n, "initial": initial},
        "trajectory": trajectory,
        "formation": {"kind": "chevron", "n": n, "b_m": 0.4},
        "assignment": {"method": "greedy", "hysteresis_m": 0.05, "tie_tol_m": 0.01},
    }
    return scenario_mod.parse(data, source="<bench_sim>")


def realtime(scn: scenario_mod.Scenario, runs: int) -> tuple[list[float], list[float], float]:
    """(wall real-time factors, CPU real-time factors, sim seconds) over ``runs`` runs."""
    wall: list[float] = []
    cpu: list[float] = []
    sim_s = 0.0
    for _ in range(runs):
        c0 = time.process_time()
        res = simulate.run(scn)
        c1 = time.process_time()
        sim_s = float(res.log.t_s[-1] - res.log.t_s[0])
        wall.append(res.realtime_factor)
        cpu.append(sim_s / max(c1 - c0, 1e-9))  # includes setup: a lower bound
    return wall, cpu, sim_s


class StageTimer:
    """Wraps methods/functions with timers; totals per stage, wrapper overhead calibrated."""

    def __init__(self) -> None:
        self.total: dict[str, float] = {}
        self.calls: dict[str, int] = {}
        self.overhead_s = self._calibrate()

    def wrap(self, stage: str, fn: Callable[..., Any]) -> Callable[..., Any]:
        clock = time.perf_counter
        total, calls = self.total, self.calls
        total.setdefault(stage, 0.0)
        calls.setdefault(stage, 0)

        @functools.wraps(fn)
        def timed(*args: Any, **kwargs: Any) -> Any:
            t0 = clock()
            try:
                return fn(*args, **kwargs)
            finally:
                total[stage] += clock() - t0
                calls[stage] += 1

        return timed

    def _calibrate(self) -> float:
        """Seconds a wrapped call costs more than the bare call (measured on a no-op)."""

        def noop(*args: Any, **kwargs: Any) -> None:
            return None

        probe = StageTimer.__new__(StageTimer)
        probe.total, probe.calls = {}, {}
        wrapped = probe.wrap("noop", noop)
        n = 100_000
        best = float("inf")
        for _ in range(5):
            t0 = time.perf_counter()
            for _ in range(n):
                wrapped(1, k=2)
            t1 = time.perf_counter()
            for _ in range(n):
                noop(1, k=2)
            t2 = time.perf_counter()
            best = min(best, ((t1 - t0) - (t2 - t1)) / n)
        # The part of the overhead inside the timed window is about half of the wrapper's cost.
        return max(best, 0.0) / 2.0

    def net_s(self, stage: str) -> float:
        return max(self.total[stage] - self.calls[stage] * self.overhead_s, 0.0)


@contextlib.contextmanager
def patched(timer: StageTimer) -> Iterator[None]:
    """Temporarily wrap the components the loop calls (class attributes, module globals)."""
    targets: list[tuple[Any, str, str]] = [
        (Camera, "capture", "camera"),
        (Camera, "poll", "camera"),
        (coord_core.CoordinatorCore, "tick", "coordinator"),
        (RoleAssigner, "update_ordered", "  assignment"),
        (coord_core, "slot_rows", "  slots"),
        (Firmware, "step", "firmware"),
        (Firmware, "step_positional", "firmware"),  # the in-process loop's entry
        (CommandLink, "send_all", "link"),
        (CommandLink, "poll", "link"),
        (Plant, "step", "plant"),
        (SeparationMonitor, "update_many", "monitor"),
        (RunLog, "from_ticks", "log arrays"),
        (RunLog, "from_flat", "log arrays"),  # the in-process loop's (formation.sim.ticklog)
        (CollectorPause, "collect_young", "collector"),
    ]
    for cls in (traj_mod.StraightLine, traj_mod.Circle, traj_mod.Waypoints, traj_mod.FigureEight):
        targets.append((cls, "sample", "  leader"))
    saved = []
    for owner, attr, stage in targets:
        original = owner.__dict__[attr]
        saved.append((owner, attr, original))
        fn = original.__func__ if isinstance(original, classmethod) else original
        wrapped = timer.wrap(stage, fn)
        setattr(owner, attr, classmethod(wrapped) if isinstance(original, classmethod) else wrapped)
    try:
        yield
    finally:
        for owner, attr, original in reversed(saved):
            setattr(owner, attr, original)


def breakdown(scn: scenario_mod.Scenario) -> None:
    """Per-tick time of each stage, from one instrumented run (shares of that run's tick)."""
    timer = StageTimer()
    with patched(timer):
        res = simulate.run(scn)
    ticks = res.log.t_s.size
    order = [
        "camera",
        "coordinator",
        "  leader",
        "  slots",
        "  assignment",
        "firmware",
        "link",
        "plant",
        "monitor",
        "log arrays",
        "collector",
    ]
    top = [s for s in order if not s.startswith(" ")]
    overhead = sum(timer.calls[s] for s in top) * timer.overhead_s
    tick_us = (res.wall_s - overhead) / ticks * 1e6  # the tick without the timers' cost
    accounted = sum(timer.net_s(s) for s in top) / ticks * 1e6
    native = set(NATIVE_STAGES) if sim_accel.status()[0] else set()
    in_coordinator = set(COORDINATOR_NATIVE_STAGES) if coord_accel.status()[0] else set()
    print(f"  {'stage':<16}{'us/tick':>9}{'share':>8}{'calls/tick':>12}")
    for stage in order:
        if stage in native or stage in in_coordinator:
            where = "in loop" if stage in native else "in coord"
            print(f"  {stage:<16}{where:>9}   (compiled: called natively, not timed alone)")
            continue
        us = timer.net_s(stage) / ticks * 1e6
        print(
            f"  {stage:<16}{us:>9.2f}{us / tick_us * 100:>7.0f}%{timer.calls[stage] / ticks:>12.2f}"
        )
    rest = tick_us - accounted
    what = "camera, link, plant, " if native else ""
    print(
        f"  {'loop':<16}{rest:>9.2f}{rest / tick_us * 100:>7.0f}%   "
        f"({what}setpoints, neighbours, log)"
    )
    print(f"  {'tick':<16}{tick_us:>9.2f}   (instrumented run, timer cost removed)")
    # The firmware's steps alone bound the loop: were every other stage free, the real-time
    # factor could not exceed dt / (firmware time per tick).
    fw_us = timer.net_s("firmware") / ticks * 1e6
    if fw_us > 0.0:
        print(
            f"  ceiling with the firmware alone: {scn.dt_s * 1e6 / fw_us:.0f}x real time "
            f"({fw_us:.1f} us of firmware per tick, {fw_us / len(scn.robot_ids):.2f} us a robot)"
        )


def main() -> None:
    ap = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    ap.add_argument("--runs", type=int, default=5, help="runs per fleet (best and median shown)")
    ap.add_argument("--only", default=None, help="one of paper-exp2, chevron7, chevron30")
    args = ap.parse_args()
    print("$ " + " ".join([Path(sys.executable).name, *sys.argv]))
    print(f"firmware core: {fw_accel.STATUS}")
    print(f"simulator: {sim_accel.status()[1]}")
    print(f"coordinator: {coord_accel.status()[1]}")
    fleets = {
        "paper-exp2": lambda: scenario_mod.load("paper-exp2"),
        "chevron7": lambda: scenario_mod.load("chevron7"),
        "chevron30": lambda: chevron_scenario(30),
    }
    for name, make in fleets.items():
        if args.only and name != args.only:
            continue
        scn = make()
        wall, cpu, sim_s = realtime(scn, args.runs)
        ticks = round(sim_s / scn.dt_s) + 1
        best = max(wall)
        print(
            f"\n{name}: {len(scn.robot_ids)} robots, {sim_s:.0f} s of sim at "
            f"{1 / scn.dt_s:.0f} Hz ({ticks} ticks)"
        )
        print(
            f"  real-time factor: best {best:.0f}x, median {statistics.median(wall):.0f}x "
            f"(wall); best {max(cpu):.0f}x (process CPU, incl. setup)"
        )
        print(f"  best un-instrumented tick: {sim_s / best / ticks * 1e6:.1f} us")
        breakdown(scn)


if __name__ == "__main__":
    main()
