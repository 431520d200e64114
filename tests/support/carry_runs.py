"""A spare carried through a formation, in-process (issue 30's movers): the closed loop
tests/unit/formation/test_movers_closed_loop.py asserts on and bench/bench_movers.py tabulates."""

from __future__ import annotations

import dataclasses
import math
from functools import cache

import numpy as np

import scenario as scenario_mod
from formation.sim import simulate
from scenario import Scenario
from scenario.assemble import coordinator_core
from scenario.load import Disturbance, parse

BODY_RADIUS_M = 0.075
TOUCH_M = 2 * BODY_RADIUS_M  # centres of two bodies that touch
SETTLE_S = 2.0  # the carry starts this long after the run (the fleet started in its slots)
RUN_M = 0.9  # it starts this far from the robot it is aimed at (outside the formation)


@cache
def formation(kind: str) -> Scenario:
    """A triangle (paper-exp1, the issue's measurement) or a five-robot chevron started in its
    slots, on a slow line."""
    if kind == "triangle":
        return scenario_mod.load("paper-exp1")
    data = {
        "name": "chevron5",
        "duration_s": 20.0,
        "seed": 3,
        "robots": {"count": 5},
        "trajectory": {"kind": "line", "x0": 0.4, "y0": 0.0, "heading": 0.0, "speed_mps": 0.02},
        "formation": {"kind": "chevron", "n": 5, "b_m": 0.4},
        "assignment": {"method": "optimal", "hysteresis_m": 0.05, "tie_tol_m": 0.01},
    }
    sc = parse(data)
    out = coordinator_core(sc).tick(0.0, {})
    l_m = sc.agent.geometry.ref_offset_m
    starts = tuple((row[0] - l_m, row[1], 0.0) for row in out.rows)
    return dataclasses.replace(sc, initial=starts)


@cache
def where(kind: str, t_s: float) -> tuple[tuple[float, float], ...]:
    """Each fleet robot's centre at ``t_s`` without a mover (where the body is aimed)."""
    sc = dataclasses.replace(formation(kind), duration_s=t_s)
    truth = np.asarray(simulate.run(sc).log.truth)
    return tuple((float(x), float(y)) for x, y, _ in truth[-1])


def carry(
    kind: str, target: int, heading_rad: float, speed_mps: float, offset_m: float = 0.0
) -> tuple[float, float, np.ndarray]:
    """An idle spare carried in a straight line at ``speed_mps`` along ``heading_rad`` through
    robot ``target``'s place (``offset_m`` to the side), from ``RUN_M`` before it to ``RUN_M``
    past it. Returns the least centre distance from the spare to the fleet, the fleet's own
    least separation (from the start of the carry) and the spare's slot per tick."""
    base = formation(kind)
    lead_s = round(RUN_M / speed_mps, 2)
    t_pass = SETTLE_S + lead_s
    tx, ty = where(kind, t_pass)[target]
    c, s = math.cos(heading_rad), math.sin(heading_rad)
    run_m = lead_s * speed_mps
    sx, sy = tx - run_m * c - offset_m * s, ty - run_m * s + offset_m * c
    spare = f"r{len(base.robot_ids) + 1}"
    t0 = SETTLE_S
    sc = dataclasses.replace(
        base,
        robot_ids=(*base.robot_ids, spare),
        initial=(*base.initial, (sx, sy, heading_rad + math.pi)),
        disturbances=(
            Disturbance(
                t_s=t0,
                robot=spare,
                kind="drag",
                dx=2 * run_m * c,
                dy=2 * run_m * s,
                duration_s=2 * lead_s,
            ),
        ),
        duration_s=t_pass + lead_s + 1.0,
    )
    res = simulate.run(sc)
    log = res.log
    xy = np.asarray(log.truth)[:, :, :2]
    k0 = round(t0 / sc.dt_s)
    n = len(base.robot_ids)
    d_body = np.hypot(*(xy[k0:, :n] - xy[k0:, n : n + 1]).transpose(2, 0, 1))
    fleet = min(
        float(np.hypot(*(xy[k0:, i] - xy[k0:, j]).T).min())
        for i in range(n)
        for j in range(i + 1, n)
    )
    return float(d_body.min()), fleet, np.asarray(log.slot_of)[:, n]
