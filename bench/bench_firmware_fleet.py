"""The firmware's cost per robot in a fleet: ``Firmware.step`` replayed on a 30-robot chevron's
recorded inputs (29 neighbours each), timed and counted.

``bench_firmware.py`` times one robot with 3 hand-made neighbours; ``bench_sim.py`` times the
firmware inside the whole loop (its stage timers wrap every call). This records the inputs of
every ``Firmware.step`` call of an in-process run of ``bench_sim.py``'s chevron (``--robots``,
default 30; ``--seconds`` of sim, default 10: the robots settle into the formation and then
follow the leader) and replays them, tick by tick and robot by robot as the loop calls them, on
fresh ``Firmware`` objects: only the firmware runs, on exactly the inputs of the run. The
first replay of each child is checked against the recorded commands, bit for bit (a replay that
differs stops the bench): the figure is the cost of the very work the simulator asks for.

Figures: thread CPU time per robot-tick (``time.thread_time_ns``, robust when other processes
compete for the cores: best and median of ``--repeats`` replays), and with ``--instructions``
the CPU instructions per robot-tick counted by valgrind's callgrind (``Ir``: the difference of
a child that replays 3 times and one that replays once, divided by the extra robot-ticks, so the
recording, the check, the imports and the interpreter's start cancel out; ``PYTHONHASHSEED=0``;
the recording is frozen out of the garbage collector before the replays).

``--against DIR`` measures a second source tree (e.g. ``git archive <commit>`` unpacked, with
its own compiled build) in alternating pairs, the baseline beside the figure; ``--pure`` runs
both with ``FORMATION_ACCEL=0``. Each tree is measured in its own child process.

Run: ``.venv/bin/python bench/bench_firmware_fleet.py [--against DIR] [--pure] [--pairs N]
[--instructions]``. A measurement, not a test: the exit code is 0 unless it crashes (or a replay
differs from its recording).
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import statistics
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

# The child: record one run's step calls in tree ROOT, replay them REPLAYS times (checked),
# print the thread CPU time of each replay.
_CHILD = r"""
import gc, math, sys, time
root, robots, seconds, replays = sys.argv[1], int(sys.argv[2]), float(sys.argv[3]), int(sys.argv[4])
sys.path.insert(0, root)
sys.path.insert(0, root + "/bench")
import bench_sim
from formation.sim import simulate
from robot_agent.core import _accel
from robot_agent.core.firmware import Firmware

scn = bench_sim.chevron_scenario(robots, duration_s=seconds)
calls = []  # (robot, args, kwargs, command)
index = {}
original = Firmware.__dict__["step"]


def recording(self, *args, **kwargs):
    cmd = original(self, *args, **kwargs)
    calls.append((index.setdefault(id(self), len(index)), args, kwargs, cmd))
    return cmd


Firmware.step = recording
try:
    simulate.run(scn, duration_s=seconds)
finally:
    Firmware.step = original
ticks = len(calls) // robots


def same(a, b):
    return all(x == y or (x != x and y != y) for x, y in zip(a, b, strict=True))


def replay(check):
    fws = [Firmware(scn.agent) for _ in range(robots)]
    steps = [fw.step for fw in fws]
    plan = [(steps[i], a, kw) for i, a, kw, _ in calls]
    cpu = time.thread_time_ns
    t0 = cpu()
    out = [step(*a, **kw) for step, a, kw in plan]
    dt = cpu() - t0
    if check:
        for got, (_, _, _, want) in zip(out, calls, strict=True):
            if not same(got, want):
                raise SystemExit(f"replay differs from the recording: {got} != {want}")
    return dt


# the recording's objects out of the collector's way (a full collection inside a replay would
# walk them all)
gc.collect()
gc.freeze()
print("core:", _accel.STATUS, file=sys.stderr)
print("robot-ticks:", len(calls), file=sys.stderr)
for k in range(replays):  # (the first replay checked, the others not: callgrind's extra)
    print("replay_ns:", replay(k == 0), file=sys.stderr)
"""


def _child(root: Path, robots: int, seconds: float, replays: int, pure: bool,
           valgrind: bool) -> str:  # fmt: skip
    """The child's stderr (its figures), run in ``root``."""
    env = dict(os.environ, PYTHONHASHSEED="0", OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1")
    env.pop("PYTHONPATH", None)
    env["FORMATION_ACCEL"] = "0" if pure else "1"
    cmd = [sys.executable, "-c", _CHILD, str(root), str(robots), str(seconds), str(replays)]
    if valgrind:
        cmd = ["valgrind", "--tool=callgrind", "--callgrind-out-file=/dev/null", *cmd]
    done = subprocess.run(cmd, env=env, cwd=root, capture_output=True, text=True)
    if done.returncode != 0:
        raise SystemExit(f"child in {root} failed:\n{done.stderr[-2000:]}")
    return done.stderr


def cpu_us(
    root: Path, robots: int, seconds: float, replays: int, pure: bool
) -> tuple[list[float], str]:
    """Thread CPU time (us) per robot-tick of each replay, and the core's status line."""
    err = _child(root, robots, seconds, replays, pure, valgrind=False)
    n = int(re.search(r"robot-ticks: (\d+)", err).group(1))  # type: ignore[union-attr]
    per = [int(v) / n / 1000.0 for v in re.findall(r"replay_ns: (\d+)", err)]
    status = next(ln for ln in err.splitlines() if ln.startswith("core:"))
    return per, status


def instructions(root: Path, robots: int, seconds: float, pure: bool) -> float:
    """Instructions (callgrind ``Ir``) per robot-tick: (3 replays - 1 replay) / extra."""
    counts = []
    for replays in (1, 3):
        err = _child(root, robots, seconds, replays, pure, valgrind=True)
        counts.append(int(re.search(r"Collected : (\d+)", err).group(1)))  # type: ignore[union-attr]
        n = int(re.search(r"robot-ticks: (\d+)", err).group(1))  # type: ignore[union-attr]
    return (counts[1] - counts[0]) / (2 * n)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--robots", type=int, default=30, help="fleet size (default 30)")
    ap.add_argument("--seconds", type=float, default=10.0, help="sim time recorded (10)")
    ap.add_argument("--repeats", type=int, default=5, help="replays per child (5)")
    ap.add_argument("--pairs", type=int, default=3, help="alternating pairs with --against (3)")
    ap.add_argument("--against", type=Path, help="a second source tree, measured alternately")
    ap.add_argument("--pure", action="store_true", help="FORMATION_ACCEL=0 in both trees")
    ap.add_argument("--instructions", action="store_true", help="also count with callgrind")
    args = ap.parse_args(argv)
    trees = [("this tree", ROOT)]
    if args.against is not None:
        trees.append(("against", args.against.resolve()))
    print(f"chevron{args.robots}, {args.seconds:g} s recorded, {args.repeats} replays a child; "
          f"{'pure' if args.pure else 'compiled if built'}")  # fmt: skip
    best: dict[str, list[float]] = {name: [] for name, _ in trees}
    for pair in range(args.pairs if args.against is not None else 1):
        for name, root in trees if pair % 2 == 0 else trees[::-1]:
            per, status = cpu_us(root, args.robots, args.seconds, args.repeats, args.pure)
            best[name].append(min(per))
            print(f"  {name:<10s} best {min(per):6.3f} us, median {statistics.median(per):6.3f} "
                  f"us a robot-tick (thread CPU)  [{status}]")  # fmt: skip
    for name, figures in best.items():
        print(f"{name}: median of the best replays {statistics.median(figures):.3f} us "
              f"a robot-tick over {len(figures)} children")  # fmt: skip
    if args.instructions:
        if shutil.which("valgrind") is None:
            print("valgrind is not installed: no instruction counts")
            return 0
        for name, root in trees:
            ir = instructions(root, args.robots, args.seconds, args.pure)
            print(f"{name}: {ir:,.0f} instructions a robot-tick (callgrind)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
