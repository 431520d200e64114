"""The safety filter's inlined deadlock paths equal ``Deadlock.steer`` / ``Deadlock.observe``.

``SafetyFilter.filter`` skips the calls in their common cases (no tie-break under way: ``steer``
only records the time; nothing in range and no tie-break streak: ``observe`` only forgets the
stuck window; a tie-break with something in range: ``observe`` does nothing). Here a twin
``Deadlock`` is driven through the full methods with the same inputs, tick by tick, over random
runs that go through every case (stuck robots, tie-breaks right and left, gaps in the ticks,
resets): its state and the filtered commands must be the same bit for bit.
"""

from __future__ import annotations

import math
import random

import pytest

from robot_agent.core.deadlock import Deadlock
from robot_agent.core.params import AgentConfig
from robot_agent.core.qp import _TOL, solve_qp, solve_qp_relaxed
from robot_agent.core.safety_filter import SafetyFilter

CFG = AgentConfig()
_STATE = ("_last_now", "_stuck_since", "_stuck_e", "_tb_until", "_tb_streak", "tiebreaks")


def _state(d: Deadlock) -> tuple[float, ...]:
    # repr: NaN == NaN, and -0.0 told from 0.0
    return tuple(repr(getattr(d, k)) for k in _STATE)  # type: ignore[misc]


def _reference(cons: list[tuple[float, float, float]], ux: float, uy: float) -> tuple[float, ...]:
    """The filter's answer for these constraints (the QP; the closed form is tested to equal it
    in tests/unit/robot_agent/test_safety_filter.py), to compare the steered command that went
    into it."""
    if not cons:
        return ux, uy
    cap = math.hypot(ux, uy)
    if any(b > 0.0 for _, _, b in cons):
        cap = CFG.gains.max_ref_speed_mps
    fx, fy, ok = solve_qp(ux, uy, cons, cap)
    if not ok:  # the least-violation fallback (robot_agent/core/qp.py)
        fx, fy, _, _ = solve_qp_relaxed(ux, uy, cons, cap)
    return fx, fy


@pytest.mark.parametrize("seed", range(12))
def test_inlined_deadlock_paths_equal_the_methods(seed: int) -> None:
    rng = random.Random(seed)
    flt = SafetyFilter(CFG)
    twin = Deadlock(CFG.safety_filter, CFG.gains.max_ref_speed_mps)
    t = 0.0
    px, py = 0.0, 0.0
    tiebreaks = 0
    near, home_p = True, 0.0
    for _ in range(3000):
        r = rng.random()
        t += 0.02 if r < 0.97 else rng.choice([0.0, 0.3, 0.6, 2.0])
        if rng.random() < 0.002:
            flt.reset_deadlock()
            twin.reset()
        # a goal behind a neighbour: the robot gets stuck, tie-breaks start; now and then the
        # neighbour leaves (nothing in range) or the goal is reached (the streak ends)
        if rng.random() < 0.01:  # a new regime every ~100 ticks
            near = rng.random() < 0.8
            home_p = rng.choice([0.0, 0.0, 0.05])
        nbs = [(px + 0.2, py)] if near else [(px + 3.0, py)]
        home = rng.random() < home_p
        ex, ey = (0.01, 0.0) if home else (0.5, rng.uniform(-0.05, 0.05))
        ux, uy = 0.2, rng.uniform(-0.02, 0.02)
        sx, sy, tb = twin.steer(t, ux, uy, ex, ey)
        fx, fy = flt.filter(t, px, py, ux, uy, ex, ey, nbs, (), 0.0, 0.02)
        cons = flt.constraints(px, py, CFG.gains.max_ref_speed_mps, nbs, (), 0.0, 0.02)
        twin.observe(t, ex, ey, bool(cons), tb)
        assert _state(flt._deadlock) == _state(twin)
        ref = _reference(cons, sx, sy)
        assert abs(fx - ref[0]) <= 1e-12 and abs(fy - ref[1]) <= 1e-12 + _TOL
        tiebreaks = twin.tiebreaks
        # the robot creeps along its command (it stays next to its neighbour)
        px += 0.002 * fx
        py += 0.002 * fy
    assert tiebreaks > 0  # the runs do go through tie-breaks
