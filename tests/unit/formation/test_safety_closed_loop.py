"""The safety filter in closed loops (the plant and the firmware directly, no Zenoh), each with
and without camera noise, camera latency and a delayed command link: a stationary robot in the
path (aligned, offset, from many headings), a head-on swap, an e-stopped robot in a moving
formation, a robot dragged through a formation, 7 robots from 100 random starts, a corridor with
obstacles. In every one the centres never come closer than 2 x body radius (and never into an
obstacle or out of the arena), and the deadlock tie-break gets the robots to their goals.

The filter's pure properties: tests/unit/robot_agent/test_safety_filter.py.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from support.safety_cases import DS, RB, TOUCH, L, seg_dist
from support.safety_runs import SENSING, GoalFn, closed_loop, random_starts_run, static_goals

from robot_agent.core.params import (
    AgentConfig,
    Arena,
    CircleObstacle,
    SegmentObstacle,
    WorldMap,
)

# ----------------------------------------------------------------------------- closed loops


@SENSING
@pytest.mark.parametrize("lateral_m", [0.0, 0.01, 0.03, 0.05])
@pytest.mark.parametrize("start_m", [1.2, 3.0])
def test_stationary_robot_in_the_path(
    sensing: dict[str, float], lateral_m: float, start_m: float
) -> None:
    """The issue's cases: an idle robot 1.2 m or 3 m straight ahead (or 1-5 cm off the line),
    the slot 0.6 m beyond it. Before: closest approach 0.000-0.105 m, or stuck at 0.136 m."""
    initial = [(0.0, 0.0, 0.0), (-start_m, lateral_m, 0.0)]
    goals = [None, (0.6, lateral_m)]
    out = closed_loop(initial, static_goals(goals), 30.0 + 10 * start_m, sensing)
    assert out.min_sep >= TOUCH, out.min_sep
    assert out.min_sep >= DS - 0.01, out.min_sep  # the filter's own distance, up to noise
    assert out.errs[1] < 0.03, out.errs  # got past and reached its slot (the tie-break)


@SENSING
def test_stationary_robot_approached_from_many_headings(sensing: dict[str, float]) -> None:
    for k in range(8):
        a = 2 * math.pi * k / 8 + 0.3
        initial = [(0.0, 0.0, 1.0), (-1.0 * math.cos(a), -1.0 * math.sin(a), a + 0.5 * (k % 3))]
        goals = [None, (0.5 * math.cos(a), 0.5 * math.sin(a))]
        out = closed_loop(initial, static_goals(goals), 35.0, sensing, seed=k)
        assert out.min_sep >= TOUCH, (k, out.min_sep)
        assert out.errs[1] < 0.03, (k, out.errs)


@SENSING
def test_head_on_swap(sensing: dict[str, float]) -> None:
    """Two robots swap places along one line: both reach the other's start (pass on the right)."""
    initial = [(-0.8, 0.0, 0.0), (0.8, 0.0, math.pi)]
    goals = [(0.8 + L, 0.0), (-0.8 - L, 0.0)]
    out = closed_loop(initial, static_goals(goals), 40.0, sensing)
    assert out.min_sep >= TOUCH, out.min_sep
    assert max(out.errs) < 0.03, out.errs


def _line_formation(n: int, spacing: float, speed: float) -> GoalFn:
    """Slots on a line across the direction of travel (+x), moving at ``speed``."""

    def goal(i: int, t: float) -> tuple[float, float, float, float]:
        return (-1.0 + speed * t, (i - (n - 1) / 2) * spacing, speed, 0.0)

    return goal


@SENSING
def test_estopped_robot_in_a_moving_formation(sensing: dict[str, float]) -> None:
    """Two ranks of robots moving at 0.1 m/s; the robot ahead of robot 4 is e-stopped at 8 s:
    robot 4 must go round it, never touch it, and catch up with its slot."""
    ranks = 2
    per = 3
    spacing = 0.4

    def goal(i: int, t: float) -> tuple[float, float, float, float]:
        r, c = divmod(i, per)
        return (-1.0 + 0.1 * t - 0.4 * r, (c - 1) * spacing, 0.1, 0.0)

    initial = [(goal(i, 0)[0] - L, goal(i, 0)[1], 0.0) for i in range(ranks * per)]
    out = closed_loop(initial, goal, 40.0, sensing, estop={1: 8.0})
    assert out.min_sep >= TOUCH, out.min_sep
    errs = [e for i, e in enumerate(out.errs) if i != 1]
    assert max(errs) < 0.05, out.errs


@SENSING
def test_robot_dragged_through_the_formation(sensing: dict[str, float]) -> None:
    """A robot carried by hand at 0.1 m/s straight through a line of robots holding their slots:
    they make way (its velocity is known from two frames) and return; no contact."""
    goals: list[tuple[float, float] | None] = [(-0.6 + 0.4 * i + L, 0.0) for i in range(4)]
    goals.append(None)
    initial = [(-0.6 + 0.4 * i, 0.0, 0.0) for i in range(4)] + [(-0.4, -1.0, math.pi / 2)]
    out = closed_loop(initial, static_goals(goals), 40.0, sensing, drag=(4, 2.0, 0.0, 2.0, 20.0))
    assert out.min_sep >= TOUCH, out.min_sep
    assert max(out.errs[:4]) < 0.05, out.errs


#: Random starts in ``make test`` (the issue's 100 are in bench/bench_safety.py: 0 contacts,
#: 92-95 % of the robots on their goals within 25 s; docs/benchmarks.md, "Issue 14").
TEST_STARTS = 6


@SENSING
def test_seven_robots_from_random_starts(sensing: dict[str, float]) -> None:
    """7 robots from random starts: contact never; most robots reach their goals within 25 s
    (the paper's slow gains take ~15 s from 1 m; the rest are multi-robot deadlocks the
    tie-break has not resolved yet)."""
    worst, reached, total, _ = random_starts_run(TEST_STARTS, sensing)
    print(f"7 robots x {TEST_STARTS} starts: min separation {worst:.3f} m, {reached}/{total}")
    assert worst >= TOUCH
    assert reached >= 0.75 * total  # 6 starts: 35-41 of 42 measured (bench: 100 starts)


@SENSING
def test_corridor_with_obstacles(sensing: dict[str, float]) -> None:
    """Two robots swap ends of a 1 m wide corridor (two walls) with a pillar in it, inside an
    arena: no contact, no centre within a body of a wall, the pillar or the arena's edge."""
    walls = (
        SegmentObstacle(-1.0, 0.5, 1.0, 0.5),
        SegmentObstacle(-1.0, -0.5, 1.0, -0.5),
    )
    pillar = CircleObstacle(0.0, 0.15, 0.05)
    box = Arena(-2.0, -1.0, 2.0, 1.0)
    cfg = AgentConfig(world=WorldMap(obstacles=(*walls, pillar), arena=box))
    worst = [math.inf]

    def monitor(truth: np.ndarray) -> None:
        for x, y, _ in truth:
            clear = min(
                seg_dist(x, y, walls[0]),
                seg_dist(x, y, walls[1]),
                math.hypot(x - pillar.x, y - pillar.y) - pillar.radius_m,
                x - box.x_min,
                box.x_max - x,
                y - box.y_min,
                box.y_max - y,
            )
            worst[0] = min(worst[0], clear)

    initial = [(-1.5, 0.0, 0.0), (1.5, 0.0, math.pi)]
    goals = [(1.5, 0.0), (-1.5, 0.0)]
    out = closed_loop(initial, static_goals(goals), 60.0, sensing, cfg=cfg, monitor=monitor)
    assert out.min_sep >= TOUCH, out.min_sep
    assert worst[0] >= RB, worst[0]
    assert max(out.errs) < 0.05, out.errs


# ----------------------------------------------------------------------------- robot config
