"""Dump the firmware core's outputs over seeded random inputs, to compare two trees bit for bit.

A speed change of the per-tick code (``Firmware.step``, the safety filter, the estimator) must
not change a single bit of what they compute. This script runs deterministic random scenarios
through ``SafetyFilter.filter`` (neighbours as ``(x, y)`` and ``Neighbour`` entries, NaN /
infinite / large fields, obstacles, the arena, shared frames, gaps in the ticks, stuck robots and
tie-breaks, deadlock resets) and ``Firmware.step`` (estimator on and off, encoders or commands,
camera poses every tick or two in three, a role change, a neighbour inside the barrier), and
prints every output as exact hex floats with the status counters::

    PYTHONPATH=/path/to/before .venv/bin/python bench/firmware_outputs.py > before.txt
    .venv/bin/python bench/firmware_outputs.py > after.txt
    cmp before.txt after.txt    # identical, or the change is not a pure speed change

(``git archive <commit> | tar -x -C /path/to/before`` makes the tree before;
``bench/firmware_outputs.py`` runs this module of whichever tree comes first.) The compiled core
is checked the same way: ``FORMATION_ACCEL=0 python -m robot_agent.buildtools.core_outputs`` (pure)
against
``python -m robot_agent.buildtools.core_outputs`` (compiled, when built); ``accel_build build``
runs that
comparison before it installs a build, tests/unit/robot_agent/test_accel.py runs it again. It is a
tool, not a
test of properties: the tests check the properties; this checks that nothing moved.
"""

from __future__ import annotations

import argparse
import math
import random
import sys
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

from robot_agent.core import _accel
from robot_agent.core.firmware import Firmware
from robot_agent.core.firmware_types import Pose, Setpoint
from robot_agent.core.host_grid import NeighbourGrid, Seen
from robot_agent.core.neighbours import is_cooperative, is_current, neighbour
from robot_agent.core.params import AgentConfig, Arena, CircleObstacle, EstimatorParams, WorldMap
from robot_agent.core.safety_filter import Neighbour, SafetyFilter


def _fmt(v: object) -> str:
    return v.hex() if isinstance(v, float) else repr(v)


def _neighbour(rng: random.Random, px: float, py: float) -> tuple[float, float] | Neighbour:
    k = rng.random()
    x = px + rng.uniform(-0.8, 0.8)
    y = py + rng.uniform(-0.8, 0.8)
    if k < 0.5:
        return (x, y)
    if k < 0.53:
        return (math.nan, y)
    odd = [math.nan, math.inf, -math.inf, 10.0, -0.0, 0.0]
    th = rng.choice([math.nan, rng.uniform(-3, 3)])
    age = rng.choice([0.0, 0.033, rng.uniform(-0.1, 1.0), math.nan])
    vx = rng.uniform(-0.3, 0.3) * (rng.random() < 0.5) if rng.random() < 0.9 else rng.choice(odd)
    vy = rng.uniform(-0.3, 0.3) * (rng.random() < 0.5) if rng.random() < 0.9 else rng.choice(odd)
    rad = rng.choice([0.0, 0.02, 0.05]) if rng.random() < 0.9 else rng.choice(odd)
    return Neighbour(x, y, th, age, vx, vy, rng.random() < 0.5, rad)


def filter_lines(rng: random.Random, trials: int, ticks: int) -> list[str]:
    """``SafetyFilter.filter`` outputs, ``admissible`` and the status, tick by tick."""
    out: list[str] = []
    world = WorldMap(obstacles=(CircleObstacle(0.5, 0.5, 0.1),), arena=Arena(-1.5, -1.5, 1.5, 1.5))
    for shared in (False, True):
        for with_world in (False, True):
            cfg = AgentConfig()
            cfg = replace(cfg, safety_filter=replace(cfg.safety_filter, shared_frame=shared))
            if with_world:
                cfg = replace(cfg, world=world)
            for _ in range(trials):
                flt = SafetyFilter(cfg)
                px, py = rng.uniform(-1, 1), rng.uniform(-1, 1)
                t = 0.0
                nbs = [_neighbour(rng, px, py) for _ in range(rng.randint(0, 5))]
                stuck = rng.random() < 0.3
                for _ in range(ticks):
                    dt = 0.02
                    if rng.random() < 0.1:
                        dt = rng.choice([0.02, 0.02, 0.02, 0.0, 0.033, 0.6])
                    t += dt
                    ux, uy = rng.uniform(-0.3, 0.3), rng.uniform(-0.3, 0.3)
                    if stuck:  # pushed into a neighbour: deadlocks and tie-breaks
                        nbs = [(px + 0.2, py)]
                        ux, uy = 0.2, 0.0
                    obs = [(px + 0.3, py - 0.1, 0.05)] if rng.random() < 0.1 else []
                    frame = None
                    if rng.random() < 0.5:
                        frame = (px - 0.05, py, rng.uniform(-3, 3), rng.choice([0.0, 0.033]))
                    extra = rng.choice([0.0, 0.0, 0.01, 0.05])
                    fx, fy = flt.filter(t, px, py, ux, uy, ux, uy, nbs, obs, extra, dt, frame)
                    out.append(
                        f"{_fmt(fx)} {_fmt(fy)} {flt.admissible(ux * 0.5, uy)} {flt.status()!r}"
                    )
                    if not stuck:
                        px += fx * 0.02
                        py += fy * 0.02
                    if rng.random() < 0.02:
                        flt.reset_deadlock()
                    if rng.random() < 0.1:
                        nbs = [_neighbour(rng, px, py) for _ in range(rng.randint(0, 5))]
    return out


def firmware_lines(rng: random.Random, trials: int, ticks: int) -> list[str]:
    """``Firmware.step`` commands tick by tick and the final status, estimator on and off."""
    out: list[str] = []
    for est_on in (True, False):
        for trial in range(trials):
            cfg = AgentConfig(estimator=EstimatorParams(enabled=est_on))
            if trial % 2:
                cfg = replace(cfg, safety_filter=replace(cfg.safety_filter, shared_frame=True))
            fw = Firmware(cfg)
            pose = None
            for k in range(ticks):
                now = k * 0.02
                th = 0.2 * now
                x, y = math.cos(th), math.sin(th)
                if k % 3 or trial < 2:  # else the pose of the tick before, presented again
                    nx, ny = rng.gauss(0, 0.003), rng.gauss(0, 0.003)
                    pose = Pose(x + nx, y + ny, th + math.pi / 2, now - 0.04)
                sp = Setpoint(x + 0.08, y + 0.03, -0.2 * y, 0.2 * x, th, 1 + k // 500, now - 0.02)
                nb: list[tuple[float, float] | Neighbour] = [
                    (x + 0.2, y + 0.05),
                    (x - 0.6, y + 0.4),
                    Neighbour(x + 1.5, y - 1.0, 0.3, 0.04, 0.0, 0.0, True),
                ]
                if k % 97 == 50:
                    nb = [(x + 0.12, y)]
                ws = (3.0 + rng.random(), 3.2) if trial % 3 else None
                cmd = fw.step(now, pose=pose, pose_rx_s=now - 0.01, setpoint=sp,
                              setpoint_rx_s=now - 0.02, neighbours=nb, pose_capture_s=now - 0.04,
                              wheel_speeds=ws)  # fmt: skip
                out.append(" ".join(_fmt(v) for v in cmd))
            out.append(repr(fw.status()))
    return out


def _coop_rule(ids: set[str]) -> Callable[[str, float], bool]:
    """A cooperative rule for ``NeighbourGrid``: the robots of ``ids``, at any time."""

    def rule(rid: str, now_s: float) -> bool:
        return rid in ids

    return rule


def neighbour_lines(rng: random.Random, trials: int, queries: int) -> list[str]:
    """The agent host's neighbour lists (``NeighbourGrid.neighbours_of``) and the rules of
    ``robot_agent.core.neighbours`` (``neighbour``, ``is_current``, ``is_cooperative``)."""
    out: list[str] = []
    for _ in range(trials):
        coop_ids = {f"r{k}" for k in range(40) if rng.random() < 0.5}
        grid = NeighbourGrid(rng.choice([0.3, 0.5, 1.1]), _coop_rule(coop_ids))
        t = 0.0
        for k in range(rng.randint(0, 40)):
            rx = rng.choice([None, t, t - 0.1, t - 2.0, t + 0.05])
            grid.seen[f"r{k}"] = Seen(
                rng.uniform(-2, 2), rng.uniform(-2, 2), rng.uniform(-3, 3), t - 0.04, rx, k
            )
        for q in range(queries):
            now = t + rng.choice([0.0, 0.02, 0.02, 0.5, 1.5])
            if q % 5 == 4:
                grid.invalidate()
            rid = f"r{rng.randint(0, 45)}"
            x, y = rng.uniform(-2.5, 2.5), rng.uniform(-2.5, 2.5)
            nbs = grid.neighbours_of(rid, x, y, now)
            out.append(" ".join(" ".join(_fmt(v) for v in nb) for nb in nbs) or "-")
            t = now
        grid.clear()
        out.append(repr(grid.neighbours_of("r0", 0.0, 0.0, t + 0.02)))
    for _ in range(trials * queries):
        now, rx = rng.uniform(0, 10), rng.uniform(0, 10)
        odd = rng.choice([0.0, -0.0, math.nan, math.inf, -math.inf, rng.uniform(-1, 1)])
        nb = neighbour(odd, 1.0, odd, now - rng.uniform(-0.1, 0.2), now, rng.random() < 0.5)
        out.append(
            f"{' '.join(_fmt(v) for v in nb)} {is_current(now, rx)} {is_current(now, now + odd)} "
            f"{is_cooperative(now, rng.random() < 0.5, rx)}"
        )
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=1234)
    ap.add_argument("--quick", action="store_true", help="a tenth of the ticks")
    args = ap.parse_args(argv)
    rng = random.Random(args.seed)
    div = 10 if args.quick else 1
    print(
        f"core_outputs: robot_agent from {Path(__file__).parent}, {_accel.STATUS}", file=sys.stderr
    )
    lines = filter_lines(rng, 60, 400 // div) + firmware_lines(rng, 6, 1500 // div)
    lines += neighbour_lines(rng, 60 // div, 200)
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
