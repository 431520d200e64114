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
from collections.abc import Callable, Sequence

import numpy as np
import pytest
from test_safety_filter import CFG, DS, RB, TOUCH, L, seg_dist

from robot_agent.core.firmware import Firmware, Mode, Pose, Setpoint
from robot_agent.core.kinematics import reference_point
from robot_agent.core.params import (
    AgentConfig,
    Arena,
    CircleObstacle,
    SegmentObstacle,
    WorldMap,
)
from robot_agent.core.safety_filter import Neighbour
from sim_plant.core.plant import Plant
from sim_plant.core.sensors import Camera, CommandLink

# ----------------------------------------------------------------------------- closed loops

NOISY = {"pos_std_m": 0.003, "theta_std_rad": 0.01, "cam_latency_s": 0.03, "link_s": 0.01}
EXACT = {"pos_std_m": 0.0, "theta_std_rad": 0.0, "cam_latency_s": 0.0, "link_s": 0.0}
SENSING = pytest.mark.parametrize("sensing", [EXACT, NOISY], ids=["exact", "noisy"])

GoalFn = Callable[[int, float], tuple[float, float, float, float] | None]


class Outcome:
    def __init__(self, min_sep: float, truth: np.ndarray, fws: list[Firmware], errs: list[float]):
        self.min_sep = min_sep
        self.truth = truth
        self.fws = fws
        self.errs = errs  # final distance of each reference point to its goal (m)

    def tiebreaks(self) -> int:
        total = 0
        for fw in self.fws:
            st_ = fw.status().safety_filter
            assert st_ is not None
            total += st_.tiebreaks
        return total


def closed_loop(
    initial: Sequence[tuple[float, float, float]],
    goal: GoalFn,
    duration_s: float,
    sensing: dict[str, float],
    *,
    cfg: AgentConfig = CFG,
    dt: float = 0.04,
    seed: int = 1,
    estop: dict[int, float] | None = None,
    drag: tuple[int, float, float, float, float] | None = None,
    monitor: Callable[[np.ndarray], None] | None = None,
) -> Outcome:
    """The plant, a camera, a command link and one firmware per robot, stepped in lockstep.

    ``goal(i, t)`` gives robot i's setpoint (x, y, vx, vy) of the REFERENCE POINT, or None (the
    robot idles: stationary, not cooperative). ``estop`` latches robot i's e-stop at a time;
    ``drag = (i, t0, dx, dy, duration)`` carries robot i (its firmware keeps running).
    Neighbours are given as ``Neighbour`` with the age of the measurement, whether the robot was
    TRACKING on the previous tick, and (for a carried robot) its velocity from two frames.
    """
    rng = np.random.default_rng(seed)
    n = len(initial)
    plant = Plant(np.array(initial, dtype=float), cfg.geometry, motor_tau_s=0.0)
    cam = Camera(
        n,
        rate_hz=30.0,
        pos_std_m=sensing["pos_std_m"],
        theta_std_rad=sensing["theta_std_rad"],
        latency_s=sensing["cam_latency_s"],
        rng=rng,
    )
    link: CommandLink[tuple[float, float]] = CommandLink(
        latency_s=sensing["link_s"], jitter_s=0.0, loss_prob=0.0, rng=rng
    )
    fws = [Firmware(cfg) for _ in range(n)]
    est_on = cfg.estimator.enabled  # then the firmware gets each pose's capture time too
    poses: list[Pose | None] = [None] * n
    prev: list[Pose | None] = [None] * n
    rx = [-math.inf] * n
    applied = [(0.0, 0.0)] * n
    tracking = [False] * n
    min_sep = math.inf
    estop = estop or {}
    ticks = round(duration_s / dt)
    iu = np.triu_indices(n, 1)
    for k in range(ticks):
        t = k * dt
        if drag is not None and abs(t - drag[1]) < dt / 2:
            plant.drag(drag[0], drag[2], drag[3], drag[4])
        truth = plant.truth
        if n > 1:
            d = np.hypot(*(truth[:, None, :2] - truth[None, :, :2]).transpose(2, 0, 1))[iu]
            min_sep = min(min_sep, float(d.min()))
        if monitor is not None:
            monitor(truth)
        cam.capture(t, truth)
        for i, stamp, x, y, th in cam.poll(t):
            prev[i] = poses[i]
            poses[i] = Pose(x, y, th, stamp)
            rx[i] = t
        nbs: list[Neighbour | None] = []
        for j, p in enumerate(poses):
            if p is None:
                nbs.append(None)
                continue
            vx = vy = 0.0
            q = prev[j]
            if drag is not None and j == drag[0] and q is not None and p.t > q.t:
                vx, vy = (p.x - q.x) / (p.t - q.t), (p.y - q.y) / (p.t - q.t)
            nbs.append(Neighbour(p.x, p.y, p.theta, t - p.t, vx, vy, tracking[j]))
        cmds = []
        for i, fw in enumerate(fws):
            if i in estop and t >= estop[i] and fw.mode is not Mode.ESTOP:
                fw.engage_estop()
            g = goal(i, t)
            sp = None if g is None else Setpoint(g[0], g[1], g[2], g[3], 0.0, i, t)
            p = poses[i]
            cmd = fw.step(
                t,
                pose=p,
                pose_rx_s=rx[i],
                setpoint=sp,
                setpoint_rx_s=t,
                neighbours=[q for j, q in enumerate(nbs) if j != i and q is not None],
                pose_capture_s=p.t if est_on and p is not None else None,
            )
            cmds.append(cmd)
        tracking = [c.mode is Mode.TRACKING for c in cmds]
        link.send_all(t, [(c.omega_r, c.omega_l) for c in cmds])
        for i, wheels in link.poll(t):
            applied[i] = wheels
        plant.step(dt, applied)
    truth = plant.truth
    errs = []
    for i in range(n):
        g = goal(i, ticks * dt)
        if g is None:
            errs.append(0.0)
        else:
            rxp, ryp = reference_point(truth[i, 0], truth[i, 1], truth[i, 2], L)
            errs.append(math.hypot(g[0] - rxp, g[1] - ryp))
    return Outcome(min_sep, truth, fws, errs)


def _static(goals: Sequence[tuple[float, float] | None]) -> GoalFn:
    def goal(i: int, t: float) -> tuple[float, float, float, float] | None:
        g = goals[i]
        return None if g is None else (g[0], g[1], 0.0, 0.0)

    return goal


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
    out = closed_loop(initial, _static(goals), 30.0 + 10 * start_m, sensing)
    assert out.min_sep >= TOUCH, out.min_sep
    assert out.min_sep >= DS - 0.01, out.min_sep  # the filter's own distance, up to noise
    assert out.errs[1] < 0.03, out.errs  # got past and reached its slot (the tie-break)


@SENSING
def test_stationary_robot_approached_from_many_headings(sensing: dict[str, float]) -> None:
    for k in range(8):
        a = 2 * math.pi * k / 8 + 0.3
        initial = [(0.0, 0.0, 1.0), (-1.0 * math.cos(a), -1.0 * math.sin(a), a + 0.5 * (k % 3))]
        goals = [None, (0.5 * math.cos(a), 0.5 * math.sin(a))]
        out = closed_loop(initial, _static(goals), 35.0, sensing, seed=k)
        assert out.min_sep >= TOUCH, (k, out.min_sep)
        assert out.errs[1] < 0.03, (k, out.errs)


@SENSING
def test_head_on_swap(sensing: dict[str, float]) -> None:
    """Two robots swap places along one line: both reach the other's start (pass on the right)."""
    initial = [(-0.8, 0.0, 0.0), (0.8, 0.0, math.pi)]
    goals = [(0.8 + L, 0.0), (-0.8 - L, 0.0)]
    out = closed_loop(initial, _static(goals), 40.0, sensing)
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
    out = closed_loop(initial, _static(goals), 40.0, sensing, drag=(4, 2.0, 0.0, 2.0, 20.0))
    assert out.min_sep >= TOUCH, out.min_sep
    assert max(out.errs[:4]) < 0.05, out.errs


def _random_starts(rng: np.random.Generator, n: int, box: float, min_d: float) -> list[tuple]:
    pts: list[tuple[float, float]] = []
    while len(pts) < n:
        p = tuple(rng.uniform(-box, box, 2))
        if all(math.hypot(p[0] - q[0], p[1] - q[1]) >= min_d for q in pts):
            pts.append((float(p[0]), float(p[1])))
    return pts


def random_starts_run(
    trials: int, sensing: dict[str, float], first: int = 0, cfg: AgentConfig = CFG
) -> tuple[float, int, int, list[float]]:
    """7 robots, random starts and headings, random goals (all at least 0.35 m apart) in a
    1.8 m square, 25 s each: (least separation, robots that reached their goals within 5 cm,
    robots in all, per-trial separations). Asserts no contact in any trial.
    bench/bench_safety.py runs the issue's 100 starts (``--estimator``: with ``cfg``'s
    estimator on)."""
    n = 7
    reached = 0
    seps: list[float] = []
    for trial in range(first, first + trials):
        rng = np.random.default_rng(1000 + trial)
        starts = _random_starts(rng, n, 0.9, DS + 2 * L + 0.02)
        goals = _random_starts(rng, n, 0.9, 0.35)
        initial = [(x, y, float(rng.uniform(-math.pi, math.pi))) for x, y in starts]
        out = closed_loop(initial, _static(goals), 25.0, sensing, cfg=cfg, dt=0.05, seed=trial)
        seps.append(out.min_sep)
        assert out.min_sep >= TOUCH, (trial, out.min_sep)
        reached += sum(e < 0.05 for e in out.errs)
    return min(seps), reached, trials * n, seps


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
    out = closed_loop(initial, _static(goals), 60.0, sensing, cfg=cfg, monitor=monitor)
    assert out.min_sep >= TOUCH, out.min_sep
    assert worst[0] >= RB, worst[0]
    assert max(out.errs) < 0.05, out.errs


# ----------------------------------------------------------------------------- robot config
