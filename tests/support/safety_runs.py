"""Closed loops of firmware and plant for the safety filter's tests: :func:`closed_loop` runs
robots to goals (:func:`static_goals`) among obstacles and returns the :class:`Outcome`;
:func:`random_starts_run` from seeded random starts."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np
import pytest

from robot_agent.core.firmware import Firmware, Mode, Pose, Setpoint
from robot_agent.core.kinematics import reference_point
from robot_agent.core.params import (
    AgentConfig,
)
from robot_agent.core.safety_filter import Neighbour
from sim_plant.core.plant import Plant
from sim_plant.core.sensors import Camera, CommandLink
from support.safety_cases import CFG, DS, TOUCH, L

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


def static_goals(goals: Sequence[tuple[float, float] | None]) -> GoalFn:
    def goal(i: int, t: float) -> tuple[float, float, float, float] | None:
        g = goals[i]
        return None if g is None else (g[0], g[1], 0.0, 0.0)

    return goal


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
        out = closed_loop(initial, static_goals(goals), 25.0, sensing, cfg=cfg, dt=0.05, seed=trial)
        seps.append(out.min_sep)
        assert out.min_sep >= TOUCH, (trial, out.min_sep)
        reached += sum(e < 0.05 for e in out.errs)
    return min(seps), reached, trials * n, seps
