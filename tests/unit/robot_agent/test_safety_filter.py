"""The barrier-certificate safety filter (robot_agent.core.safety_filter) and its firmware
integration.

Pure properties (hypothesis): the QP's answer is feasible and optimal; for any state and any
nominal command within limits the filtered command satisfies every barrier condition in discrete
time (checked by moving the point, independent of the filter's own gradients), never increases
speed, and is the identity when nothing is near; the firmware's wheels after saturation still
satisfy them.

Closed loops (tests/unit/formation/test_safety_closed_loop.py) and the robot config's world and
filter keys.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from support.safety_cases import CFG, DS, GEOM, RB, TOUCH, L, seg_dist

from robot_agent.core.firmware import Firmware, Mode, Pose, Setpoint
from robot_agent.core.kinematics import ref_point_velocity, reference_point, twist_from_wheels
from robot_agent.core.params import (
    AgentConfig,
    Arena,
    CircleObstacle,
    SafetyFilterParams,
    SegmentObstacle,
    WorldMap,
)
from robot_agent.core.safety_filter import Neighbour, SafetyFilter, solve_qp
from scenario.robot_config import ConfigError, robot_config_from_dict

MARGIN = CFG.safety_filter.margin_m
BETA = CFG.safety_filter.noise_budget_m  # one position's noise, paid by the margin
GAMMA = CFG.safety_filter.gamma_per_s
VCAP = CFG.gains.max_ref_speed_mps
TOL = 1e-9

# ----------------------------------------------------------------------------- the QP

unit_angle = st.floats(min_value=-math.pi, max_value=math.pi)
speed = st.floats(min_value=0.0, max_value=0.3)


@st.composite
def constraint_sets(draw: st.DrawFn) -> list[tuple[float, float, float]]:
    m = draw(st.integers(min_value=0, max_value=6))
    out = []
    for _ in range(m):
        a = draw(unit_angle)
        out.append((math.cos(a), math.sin(a), draw(st.floats(min_value=-0.4, max_value=0.1))))
    return out


@settings(max_examples=100, deadline=None, derandomize=True)
@given(cons=constraint_sets(), ang=unit_angle, s=speed, seed=st.integers(0, 2**32 - 1))
def test_qp_is_feasible_never_faster_and_optimal(
    cons: list[tuple[float, float, float]], ang: float, s: float, seed: int
) -> None:
    ux, uy = s * math.cos(ang), s * math.sin(ang)
    x, y, ok = solve_qp(ux, uy, cons, s)
    assert math.isfinite(x) and math.isfinite(y)
    if not ok:
        assert (x, y) == (0.0, 0.0)
    else:
        assert math.hypot(x, y) <= s * (1 + 1e-9) + 1e-12
        for ax, ay, b in cons:
            assert ax * x + ay * y >= b - 1e-8
    # Optimality: no feasible point of a random sample of the disc is nearer to u_nom.
    rng = np.random.default_rng(seed)
    pts = rng.uniform(-s, s, size=(400, 2))
    d_best = math.hypot(x - ux, y - uy)
    for px, py in pts:
        if px * px + py * py > s * s:
            continue
        if all(ax * px + ay * py >= b for ax, ay, b in cons):
            assert ok, "a feasible point exists but the QP reported none"
            assert math.hypot(px - ux, py - uy) >= d_best - 1e-7


def test_qp_examples() -> None:
    # one half-plane: the projection
    assert solve_qp(0.2, 0.0, [(-1.0, 0.0, 0.0)], 0.2) == pytest.approx((0.0, 0.0, True))
    x, y, ok = solve_qp(0.2, 0.1, [(-1.0, 0.0, 0.0)], math.hypot(0.2, 0.1))
    assert ok and (x, y) == pytest.approx((0.0, 0.1))
    # a wedge whose apex is the only point: stop
    x, y, ok = solve_qp(0.2, 0.0, [(-0.8, 0.6, 0.0), (-0.8, -0.6, 0.0)], 0.2)
    assert ok and (x, y) == pytest.approx((0.0, 0.0), abs=1e-12)
    # infeasible (must move away at 0.1 m/s, only 0.05 allowed): the stop fallback
    assert solve_qp(0.05, 0.0, [(-1.0, 0.0, 0.1)], 0.05) == (0.0, 0.0, False)


# ----------------------------------------------------------------------------- barriers


def _dist_barrier(qx: float, qy: float, d: float) -> Callable[[float, float], float]:
    return lambda x, y: math.hypot(x - qx, y - qy) - d


def _seg_barrier(o: SegmentObstacle, d: float) -> Callable[[float, float], float]:
    return lambda x, y: seg_dist(x, y, o) - d


def barriers(
    px: float,
    py: float,
    nbrs: Sequence[Neighbour],
    world: WorldMap,
    cfg: AgentConfig = CFG,
    rho: float = 0.0,
) -> list[tuple[Callable[[float, float], float], float]]:
    """Independent statement of every barrier: (h as a function of the reference point, the
    share of gamma this robot must honour). An uncertainty radius counts only beyond the noise
    budget the margin already holds for each position (``noise_budget_m``)."""
    g = cfg.geometry
    ds = cfg.safety_distance_m
    beta = cfg.safety_filter.noise_budget_m
    rho = max(0.0, rho - beta)
    clear = g.body_radius_m + cfg.safety_filter.margin_m + g.ref_offset_m + rho
    vnb = cfg.safety_filter.neighbour_speed_mps or g.max_speed_mps
    out: list[tuple[Callable[[float, float], float], float]] = []
    for nb in nbrs:
        age = min(max(nb.age_s, 0.0), cfg.safety_filter.max_age_s)
        infl = vnb * age + max(0.0, nb.radius_m - beta) + rho
        if nb.cooperative and math.isfinite(nb.theta):
            qx = nb.x + g.ref_offset_m * math.cos(nb.theta)
            qy = nb.y + g.ref_offset_m * math.sin(nb.theta)
            d = ds + 2 * g.ref_offset_m + infl
            out.append((_dist_barrier(qx, qy, d), 0.5))
        else:
            d = ds + g.ref_offset_m + infl
            out.append((_dist_barrier(nb.x, nb.y, d), 1.0))
    for o in world.obstacles:
        if isinstance(o, CircleObstacle):
            d = o.radius_m + clear
            out.append((_dist_barrier(o.x, o.y, d), 1.0))
        else:
            d = o.radius_m + clear
            out.append((_seg_barrier(o, d), 1.0))
    a = world.arena
    if a is not None:
        out.append((lambda x, y: x - a.x_min - clear, 1.0))
        out.append((lambda x, y: a.x_max - x - clear, 1.0))
        out.append((lambda x, y: y - a.y_min - clear, 1.0))
        out.append((lambda x, y: a.y_max - y - clear, 1.0))
    return out


coord = st.floats(min_value=-1.0, max_value=1.0)
nbr = st.builds(
    Neighbour,
    x=coord,
    y=coord,
    theta=st.one_of(st.just(math.nan), unit_angle),
    age_s=st.floats(min_value=0.0, max_value=0.3),
    vx=st.just(0.0),
    vy=st.just(0.0),
    cooperative=st.booleans(),
    radius_m=st.floats(min_value=0.0, max_value=0.05),
    motion=st.none(),  # (motion claims: tests/unit/robot_agent/test_neighbour_motion.py)
)
circle = st.builds(
    CircleObstacle, x=coord, y=coord, radius_m=st.floats(min_value=0.0, max_value=0.3)
)
segment = st.builds(SegmentObstacle, x1=coord, y1=coord, x2=coord, y2=coord, radius_m=st.just(0.0))
arena = st.one_of(
    st.none(),
    st.builds(
        Arena,
        x_min=st.just(-1.5),
        y_min=st.just(-1.5),
        x_max=st.floats(min_value=0.5, max_value=1.5),
        y_max=st.floats(min_value=0.5, max_value=1.5),
    ),
)


@settings(max_examples=100, deadline=None, derandomize=True)
@given(
    px=coord,
    py=coord,
    ang=unit_angle,
    s=st.floats(min_value=0.0, max_value=VCAP),
    nbrs=st.lists(nbr, max_size=4),
    circles=st.lists(circle, max_size=2),
    segments=st.lists(segment, max_size=2),
    box=arena,
    rho=st.floats(min_value=0.0, max_value=0.05),
)
def test_filtered_command_keeps_every_barrier_and_never_speeds_up(
    px: float,
    py: float,
    ang: float,
    s: float,
    nbrs: list[Neighbour],
    circles: list[CircleObstacle],
    segments: list[SegmentObstacle],
    box: Arena | None,
    rho: float,
) -> None:
    """For any state with every barrier >= 0 (a safe state) and any nominal command within
    limits: h(p + u dt) >= (1 - share * gamma * dt) h(p) for every barrier and every dt with
    gamma * dt <= 1 (stationary neighbours: the worst case the filter must survive), and
    |u| <= |u_nom|."""
    world = WorldMap(obstacles=(*circles, *segments), arena=box)
    cfg = AgentConfig(world=world)
    hs = barriers(px, py, nbrs, world, cfg, rho)
    assume(all(h(px, py) >= 0.0 for h, _ in hs))
    flt = SafetyFilter(cfg)
    ux, uy = s * math.cos(ang), s * math.sin(ang)
    fx, fy = flt.filter(0.0, px, py, ux, uy, 0.0, 0.0, nbrs, (), rho, 0.02)
    assert math.isfinite(fx) and math.isfinite(fy)
    assert math.hypot(fx, fy) <= s * (1 + 1e-9) + 1e-12
    for dt in (0.01, 0.05, 1.0 / GAMMA):
        for h, share in hs:
            h0 = h(px, py)
            assert h(px + fx * dt, py + fy * dt) >= (1 - share * GAMMA * dt) * h0 - 1e-7


@settings(max_examples=150, deadline=None, derandomize=True)
@given(
    px=coord,
    py=coord,
    ang=unit_angle,
    s=st.floats(min_value=0.0, max_value=VCAP),
    q=st.tuples(coord, coord),
    v=st.tuples(st.floats(-0.3, 0.3), st.floats(-0.3, 0.3)),
)
def test_moving_non_cooperative_neighbour_with_known_velocity(
    px: float, py: float, ang: float, s: float, q: tuple[float, float], v: tuple[float, float]
) -> None:
    """A neighbour moving at a known velocity v (not running the filter): the robot takes the
    full responsibility, h(p + u dt, q + v dt) >= (1 - gamma dt) h, or stops if it cannot."""
    d0 = DS + L
    h = lambda x, y, qx, qy: math.hypot(x - qx, y - qy) - d0  # noqa: E731
    h0 = h(px, py, *q)
    assume(h0 >= 0.0)
    flt = SafetyFilter(CFG)
    nb = Neighbour(q[0], q[1], vx=v[0], vy=v[1])
    fx, fy = flt.filter(0.0, px, py, s * math.cos(ang), s * math.sin(ang), 0, 0, [nb], (), 0, 0.02)
    assert math.hypot(fx, fy) <= VCAP * (1 + 1e-9)
    if flt.status().infeasible:
        assert (fx, fy) == (0.0, 0.0)
        return
    for dt in (0.01, 0.05, 1.0 / GAMMA):
        after = h(px + fx * dt, py + fy * dt, q[0] + v[0] * dt, q[1] + v[1] * dt)
        assert after >= (1 - GAMMA * dt) * h0 - 1e-7


@settings(max_examples=150, deadline=None, derandomize=True)
@given(
    px=coord,
    py=coord,
    ux=st.floats(min_value=-VCAP / 1.5, max_value=VCAP / 1.5),
    uy=st.floats(min_value=-VCAP / 1.5, max_value=VCAP / 1.5),
    nbrs=st.lists(nbr, max_size=5),
    far=st.floats(min_value=0.01, max_value=5.0),
)
def test_identity_when_nothing_is_near(
    px: float, py: float, ux: float, uy: float, nbrs: list[Neighbour], far: float
) -> None:
    """Neighbours, obstacles and walls all beyond the filter's reach: exactly the nominal."""
    reach = DS + 2 * L + 0.1 + 0.05 + 0.3 * 0.5 + VCAP / (0.5 * GAMMA) + far
    moved = [nb._replace(x=px + reach + abs(nb.x), y=py - reach - abs(nb.y)) for nb in nbrs]
    world = WorldMap(
        obstacles=(CircleObstacle(px - reach - 0.2, py, 0.2),),
        arena=Arena(px - 10, py - 10, px + 10, py + 10),
    )
    flt = SafetyFilter(AgentConfig(world=world))
    assert flt.filter(0.0, px, py, ux, uy, 0.3, 0.0, moved, (), 0.0, 0.02) == (ux, uy)
    st_ = flt.status()
    assert st_.active_ticks == 0 and st_.constraints == 0 and st_.violations == 0


def test_age_inflates_a_neighbour() -> None:
    """A neighbour just outside the barrier when fresh constrains a robot heading at it once its
    position is 0.2 s old (it could have come 0.3 m/s * 0.2 s = 6 cm closer)."""
    flt = SafetyFilter(CFG)
    gap = DS + L + 0.05
    fresh = Neighbour(gap, 0.0, age_s=0.0)
    old = Neighbour(gap, 0.0, age_s=0.2)
    assert flt.filter(0.0, 0.0, 0.0, 0.2, 0.0, 1.0, 0.0, [fresh]) == (0.2, 0.0)
    fx, _ = SafetyFilter(CFG).filter(0.0, 0.0, 0.0, 0.2, 0.0, 1.0, 0.0, [old])
    assert fx <= 0.0  # inside the inflated barrier: no approach at all
    # and the plain (x, y) tuple is a fresh, non-cooperative neighbour
    assert SafetyFilter(CFG).filter(0.0, 0.0, 0.0, 0.2, 0.0, 1.0, 0.0, [(gap, 0.0)]) == (0.2, 0.0)


def test_extra_radius_and_obstacles_given_per_tick() -> None:
    flt = SafetyFilter(CFG)
    gap = RB + MARGIN + L + 0.2 + 0.03  # 3 cm outside a 0.2 m circle's barrier
    fx, _ = flt.filter(0.0, 0.0, 0.0, 0.25, 0.0, 1.0, 0.0, (), [(gap, 0.0, 0.2)])
    assert 0.0 < fx < 0.25  # may approach at gamma * 3 cm = 0.3 m/s... capped by the nominal
    fx2, _ = flt.filter(0.02, 0.0, 0.0, 0.25, 0.0, 1.0, 0.0, (), [(gap, 0.0, 0.2)], 0.05)
    assert fx2 <= 0.0  # own uncertainty 5 cm: already inside, must not approach
    assert flt.status().violations == 1


@settings(max_examples=150, deadline=None, derandomize=True)
@given(
    px=coord,
    py=coord,
    ang=unit_angle,
    s=st.floats(min_value=0.0, max_value=VCAP),
    nbrs=st.lists(nbr, max_size=4),
    rho=st.floats(min_value=0.0, max_value=0.05),
    under=st.floats(min_value=0.0, max_value=1.0),
)
def test_uncertainty_counts_only_beyond_the_noise_budget(
    px: float,
    py: float,
    ang: float,
    s: float,
    nbrs: list[Neighbour],
    rho: float,
    under: float,
) -> None:
    """The margin pays for ``noise_budget_m`` of each position's uncertainty: an own extra
    radius or a neighbour radius within it changes nothing (it is not counted twice), and one
    beyond it acts exactly as its excess would with no budget at all (a camera dropout still
    inflates every barrier)."""
    box = Arena(-1.5, -1.5, 1.5, 1.5)
    cfg = AgentConfig(world=WorldMap(obstacles=(CircleObstacle(0.4, -0.3, 0.1),), arena=box))
    flat = AgentConfig(
        world=cfg.world, safety_filter=SafetyFilterParams(margin_m=MARGIN, noise_budget_m=0.0)
    )
    u = (s * math.cos(ang), s * math.sin(ang))

    def run(c: AgentConfig, nb: list[Neighbour], r: float) -> tuple[float, float]:
        return SafetyFilter(c).filter(0.0, px, py, *u, 0.3, 0.0, nb, (), r, 0.02)

    within = [n._replace(radius_m=under * BETA) for n in nbrs]
    zero = [n._replace(radius_m=0.0) for n in nbrs]
    assert run(cfg, within, under * BETA) == run(cfg, zero, 0.0)
    beyond = [n._replace(radius_m=BETA + n.radius_m) for n in nbrs]
    assert run(cfg, beyond, BETA + rho) == run(flat, nbrs, rho)


@settings(max_examples=150, deadline=None, derandomize=True)
@given(
    gap=st.floats(min_value=0.0, max_value=0.05),
    bearing=unit_angle,
    heading=unit_angle,
    r_own=st.floats(min_value=0.0, max_value=0.04),
    r_nb=st.floats(min_value=0.0, max_value=0.04),
    err_own=st.tuples(unit_angle, st.floats(min_value=0.0, max_value=1.0)),
    err_nb=st.tuples(unit_angle, st.floats(min_value=0.0, max_value=1.0)),
    coop=st.booleans(),
)
def test_true_centres_keep_ds_less_two_noise_budgets(
    gap: float,
    bearing: float,
    heading: float,
    r_own: float,
    r_nb: float,
    err_own: tuple[float, float],
    err_nb: tuple[float, float],
    coop: bool,
) -> None:
    """The guarantee the noise model leaves: on a state the filter finds safe (every barrier
    >= 0 on the positions it has), with the true positions anywhere within the stated
    uncertainty radii of the measured ones, the true centres are at least
    ``Ds - 2 noise_budget_m`` apart (bodies touch at ``2 r_b``, 2.2 cm less)."""
    th_nb = heading + 1.0
    # the neighbour's measured centre, and this robot's centre placed so the filter's barrier
    # for it is exactly ``gap`` (the cooperative row measures from the reference points)
    infl = max(0.0, r_own - BETA) + max(0.0, r_nb - BETA)
    ex, ey = math.cos(bearing), math.sin(bearing)
    if coop:
        qx, qy = L * math.cos(th_nb), L * math.sin(th_nb)
        d = DS + 2 * L + infl + gap
    else:
        qx = qy = 0.0
        d = DS + L + infl + gap
    px, py = qx + d * ex, qy + d * ey
    cx, cy = px - L * math.cos(heading), py - L * math.sin(heading)
    nb = Neighbour(0.0, 0.0, th_nb if coop else math.nan, 0.0, 0.0, 0.0, coop, r_nb)
    flt = SafetyFilter(CFG)
    flt.filter(0.0, px, py, 0.0, 0.0, 0.0, 0.0, [nb], (), r_own, 0.02)
    assert flt.status().min_clearance_m >= -1e-12
    # the truth: anywhere within the radii (a radius below the budget is the budget: the
    # margin's 3-sigma camera noise of a raw pose)
    ro, rn = max(r_own, BETA), max(r_nb, BETA)
    tx = cx + ro * err_own[1] * math.cos(err_own[0])
    ty = cy + ro * err_own[1] * math.sin(err_own[0])
    nx = rn * err_nb[1] * math.cos(err_nb[0])
    ny = rn * err_nb[1] * math.sin(err_nb[0])
    assert math.hypot(tx - nx, ty - ny) >= DS - 2 * BETA - 1e-9
    assert DS - 2 * BETA > TOUCH + 0.02


def test_noise_budget_is_validated() -> None:
    """The margin must hold the budget for both positions of a pair."""
    assert SafetyFilterParams(margin_m=0.02, noise_budget_m=0.01).noise_budget_m == 0.01
    with pytest.raises(ValueError, match="noise_budget_m"):
        SafetyFilterParams(margin_m=0.02, noise_budget_m=0.011)
    with pytest.raises(ValueError, match="noise_budget_m"):
        SafetyFilterParams(noise_budget_m=-0.001)


def test_non_finite_entries_are_counted_and_never_nan() -> None:
    flt = SafetyFilter(CFG)
    bad = [Neighbour(math.nan, 0.0), (math.inf, 1.0), Neighbour(0.3, 0.0, age_s=math.nan)]
    fx, fy = flt.filter(0.0, 0.0, 0.0, 0.2, 0.0, 1.0, 0.0, bad, [(0.0, 0.0, math.nan)])
    assert math.isfinite(fx) and math.isfinite(fy)
    assert flt.status().rejected >= 3


def test_disabled_filter_is_the_identity() -> None:
    off = AgentConfig(safety_filter=SafetyFilterParams(enabled=False))
    flt = SafetyFilter(off)
    assert flt.filter(0.0, 0.0, 0.0, 0.2, 0.1, 1.0, 0.0, [(0.05, 0.0)]) == (0.2, 0.1)


# ----------------------------------------------------------------------------- firmware


def test_firmware_keeps_the_old_signature_and_reports_the_filter() -> None:
    fw = Firmware(CFG)
    sp = Setpoint(1.0, 0.0, 0.0, 0.0, 0.0, 1, 0.0)
    cmd = fw.step(0.0, pose=Pose(0.0, 0.0, 0.0, 0.0), pose_rx_s=0.0, setpoint=sp, setpoint_rx_s=0.0)
    assert cmd.mode is Mode.TRACKING and cmd.omega_r > 0
    # a robot 0.2 m ahead (inside Ds + l of the reference point): no forward motion
    blocked = fw.step(
        0.02,
        pose=Pose(0.0, 0.0, 0.0, 0.02),
        pose_rx_s=0.02,
        setpoint=sp,
        setpoint_rx_s=0.02,
        neighbours=[Neighbour(0.2, 0.0)],
        extra_radius_m=0.01,
    )
    v, _ = twist_from_wheels(blocked.omega_r, blocked.omega_l, GEOM)
    assert v <= 1e-12
    d = fw.status().as_dict()["filter"]
    assert d["ticks"] == 2 and d["active"] == 1 and d["violations"] == 1


@settings(max_examples=150, deadline=None, derandomize=True)
@given(
    x=coord,
    y=coord,
    th=unit_angle,
    gx=st.floats(min_value=-3.0, max_value=3.0),
    gy=st.floats(min_value=-3.0, max_value=3.0),
    nbrs=st.lists(nbr, max_size=3),
    circles=st.lists(circle, max_size=2),
)
def test_firmware_wheels_after_saturation_keep_the_barriers(
    x: float,
    y: float,
    th: float,
    gx: float,
    gy: float,
    nbrs: list[Neighbour],
    circles: list[CircleObstacle],
) -> None:
    """End to end: the reference-point velocity of the wheels the firmware outputs (after eq 16,
    eq 8 and saturation) satisfies every barrier condition, for setpoints far enough away to
    saturate the wheels."""
    world = WorldMap(obstacles=tuple(circles))
    cfg = AgentConfig(world=world)
    px, py = reference_point(x, y, th, L)
    hs = barriers(px, py, nbrs, world, cfg)
    assume(all(h(px, py) >= 0.0 for h, _ in hs))
    fw = Firmware(cfg)
    sp = Setpoint(gx, gy, 0.0, 0.0, 0.0, 1, 0.0)
    cmd = fw.step(0.0, pose=Pose(x, y, th, 0.0), pose_rx_s=0.0, setpoint=sp, setpoint_rx_s=0.0,
                  neighbours=nbrs)  # fmt: skip
    v, w = twist_from_wheels(cmd.omega_r, cmd.omega_l, GEOM)
    ux, uy = ref_point_velocity(v, w, th, L)
    for dt in (0.01, 0.05):
        for h, share in hs:
            h0 = h(px, py)
            # the filter ran with gamma for an unknown dt (first tick): 1 / max_dt_s
            g = min(GAMMA, 1.0 / CFG.safety.max_dt_s)
            assert h(px + ux * dt, py + uy * dt) >= (1 - share * g * dt) * h0 - 1e-7


def _robot(extra: dict[str, object]) -> dict[str, object]:
    return {"robot_id": "r1", "zenoh": {"endpoints": ["tcp/127.0.0.1:7447"]}, **extra}


def test_robot_config_reads_arena_obstacles_and_filter_params() -> None:
    cfg = robot_config_from_dict(
        _robot(
            {
                "safety_filter": {"margin_m": 0.05, "gamma_per_s": 8.0},
                "arena": {"x_min": -2, "y_min": -1.5, "x_max": 2.0, "y_max": 1.5},
                "obstacle": [
                    {"kind": "circle", "x": 0.5, "y": 0.0, "radius_m": 0.1},
                    {"kind": "segment", "x1": -1, "y1": 1, "x2": 1, "y2": 1},
                    {"kind": "polygon", "points": [[1, -1], [1.2, -1], [1.2, -0.8]]},
                ],
            }
        )
    )
    agent = cfg.agent
    assert agent.safety_filter.margin_m == 0.05 and agent.safety_filter.gamma_per_s == 8.0
    assert agent.world.arena == Arena(-2.0, -1.5, 2.0, 1.5)
    obs = agent.world.obstacles
    assert obs[0] == CircleObstacle(0.5, 0.0, 0.1)
    assert obs[1] == SegmentObstacle(-1.0, 1.0, 1.0, 1.0, 0.0)
    assert len(obs) == 2 + 3  # the polygon's three edges, closed
    assert obs[-1] == SegmentObstacle(1.2, -0.8, 1.0, -1.0, 0.0)
    # the firmware uses them: a robot at the arena's edge does not drive out
    fw = Firmware(agent)
    sp = Setpoint(3.0, 0.0, 0.0, 0.0, 0.0, 1, 0.0)
    x = 2.0 - RB - agent.safety_filter.margin_m - L  # reference point on the wall barrier
    cmd = fw.step(0.0, pose=Pose(x, 0.0, 0.0, 0.0), pose_rx_s=0.0, setpoint=sp, setpoint_rx_s=0.0)
    v, _ = twist_from_wheels(cmd.omega_r, cmd.omega_l, GEOM)
    assert v <= 1e-9


@pytest.mark.parametrize(
    ("extra", "needle"),
    [
        ({"arena": {"x_min": 1.0, "y_min": 0.0, "x_max": 0.0, "y_max": 1.0}}, "arena"),
        ({"arena": {"x_min": 0.0, "y_min": 0.0, "x_max": 1.0}}, "arena.y_max: required"),
        ({"arena": {"x_min": "a", "y_min": 0, "x_max": 1, "y_max": 1}}, "arena.x_min"),
        ({"obstacle": [{"kind": "blob"}]}, "obstacle[0].kind"),
        ({"obstacle": [{"kind": "circle", "x": 0, "y": 0}]}, "obstacle[0].radius_m: required"),
        ({"obstacle": [{"kind": "circle", "x": 0, "y": 0, "radius_m": -1}]}, "radius_m"),
        ({"obstacle": [{"kind": "circle", "x": math.nan, "y": 0, "radius_m": 1}]}, "obstacle[0].x"),
        (
            {"obstacle": [{"kind": "circle", "x": 0, "y": 0, "radius_m": 1, "z": 1}]},
            "obstacle[0].z",
        ),
        ({"obstacle": [{"kind": "polygon", "points": [[0, 0], [1, 0]]}]}, "obstacle[0].points"),
        ({"obstacle": {"kind": "circle"}}, "obstacle: expected an array"),
        ({"safety_filter": {"gamma_per_s": 0}}, "safety_filter"),
        ({"safety_filter": {"margin": 0.1}}, "safety_filter.margin: unknown key"),
    ],
)
def test_robot_config_rejects_bad_world_and_filter(extra: dict[str, object], needle: str) -> None:
    with pytest.raises(ConfigError) as exc:
        robot_config_from_dict(_robot(extra))
    assert any(needle in p for p in exc.value.problems), exc.value.problems
