"""Virtual-leader trajectories: consistency of v/omega with the path, limits, purity, validation."""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from coordinator.core.trajectory import (
    TRAJECTORY_KINDS,
    Circle,
    FigureEight,
    LeaderState,
    StraightLine,
    Trajectory,
    Waypoints,
    make_trajectory,
    wrap_angle,
)

SQUARE = [(0.0, 0.0), (2.0, 0.0), (2.0, 2.0), (0.0, 2.0)]
ZIGZAG = [(0.0, 0.0), (1.0, 0.0), (1.5, 0.8), (2.5, 0.2), (3.5, 1.5)]


def _trajectories() -> list[tuple[str, Trajectory, float]]:
    """(name, trajectory, time span to check) for every kind and its variants."""
    wp_open = Waypoints(ZIGZAG, speed_mps=0.1, max_turn_radps=0.8, t_start_s=1.0)
    wp_loop = Waypoints(SQUARE, speed_mps=0.2, max_turn_radps=0.5, loop=True)
    return [
        ("line", StraightLine(0.5, -1.0, 2.0, 0.07), 60.0),
        ("circle-ccw", Circle(1.0, 2.0, 0.8, 0.1, start_angle_rad=0.3), 120.0),
        ("circle-cw", Circle(-1.0, 0.0, 1.5, 0.2, ccw=False, t_start_s=2.0), 120.0),
        ("figure8", FigureEight(0.0, 0.0, 1.2, 60.0), 120.0),
        ("figure8-rot", FigureEight(1.0, -1.0, 0.7, 40.0, rotation_rad=2.5), 80.0),
        ("waypoints", wp_open, wp_open.t_start_s + wp_open.duration_s),
        ("waypoints-loop", wp_loop, 2.5 * wp_loop.duration_s),
    ]


TRAJ = _trajectories()
TRAJ_IDS = [name for name, _, _ in TRAJ]


def _knots(traj: Trajectory, t_end: float) -> np.ndarray:
    """Times where omega may jump (piece junctions of a Waypoints path), over [0, t_end]."""
    if not isinstance(traj, Waypoints):
        return np.array([getattr(traj, "t_start_s", 0.0)])
    base = np.array(traj.knot_times_s) - traj.t_start_s
    laps = int(t_end / traj.duration_s) + 1 if traj.loop else 0
    all_k = [traj.t_start_s + base + k * traj.duration_s for k in range(laps + 1)]
    return np.concatenate([*all_k, [traj.t_start_s + traj.duration_s]])


@pytest.mark.parametrize(("name", "traj", "span"), TRAJ, ids=TRAJ_IDS)
def test_velocity_and_turn_rate_match_numerical_derivatives(
    name: str, traj: Trajectory, span: float
) -> None:
    """v cos(theta), v sin(theta), omega equal d/dt of x, y, theta (eqs 1-2, thetadot = omega)."""
    rng = np.random.default_rng(7)
    h = 1e-4
    knots = _knots(traj, span)
    checked = 0
    for t in rng.uniform(0.0, span, 400):
        if np.min(np.abs(knots - t)) < 3 * h:
            continue
        a, b, s = traj.sample(t - h), traj.sample(t + h), traj.sample(t)
        if s.v_mps == 0.0:  # held start/end: position must not move either
            assert (a.x, a.y) == pytest.approx((b.x, b.y), abs=1e-12)
            continue
        vx, vy = (b.x - a.x) / (2 * h), (b.y - a.y) / (2 * h)
        dtheta = wrap_angle(b.theta - a.theta) / (2 * h)
        assert vx == pytest.approx(s.v_mps * math.cos(s.theta), abs=1e-6), (name, t)
        assert vy == pytest.approx(s.v_mps * math.sin(s.theta), abs=1e-6), (name, t)
        assert dtheta == pytest.approx(s.omega_radps, abs=1e-6), (name, t)
        assert s.vx == pytest.approx(s.v_mps * math.cos(s.theta))
        checked += 1
    assert checked > 200


@pytest.mark.parametrize(("name", "traj", "span"), TRAJ, ids=TRAJ_IDS)
def test_pure_function_of_time(name: str, traj: Trajectory, span: float) -> None:
    """A standby coordinator constructing the same trajectory reproduces it bit for bit, in any
    query order."""
    kind = {StraightLine: "line", Circle: "circle", FigureEight: "figure8", Waypoints: "waypoints"}
    params = {f.name: getattr(traj, f.name) for f in dataclasses.fields(traj) if f.init}  # type: ignore[arg-type]
    twin = make_trajectory(kind[type(traj)], params)
    assert twin == traj and twin is not traj
    times = np.linspace(-5.0, span, 101)
    forward = [traj.sample(float(t)) for t in times]
    backward = [twin.sample(float(t)) for t in times[::-1]][::-1]
    assert forward == backward
    assert all(isinstance(s, LeaderState) for s in forward)
    assert all(-math.pi < s.theta <= math.pi for s in forward)


@pytest.mark.parametrize(("name", "traj", "span"), TRAJ, ids=TRAJ_IDS)
def test_times_before_start_hold_the_start_pose(name: str, traj: Trajectory, span: float) -> None:
    t0 = getattr(traj, "t_start_s", 0.0)
    start = traj.sample(t0)
    for t in (-100.0, -1.0, 0.0, t0):
        s = traj.sample(t)
        assert s.t == t
        assert (s.x, s.y, s.theta) == (start.x, start.y, start.theta)
        assert (s.v_mps, s.omega_radps) == (0.0, 0.0)
    # Continuity of the pose across the start: the leader starts from where it was held.
    just_after = traj.sample(t0 + 1e-6)
    assert math.hypot(just_after.x - start.x, just_after.y - start.y) < 1e-5
    assert just_after.v_mps > 0.0


@pytest.mark.parametrize("bad_t", [math.nan, math.inf, -math.inf])
def test_sample_rejects_non_finite_time(bad_t: float) -> None:
    for _, traj, _ in TRAJ:
        with pytest.raises(ValueError, match="t_s must be a finite number"):
            traj.sample(bad_t)


def test_straight_line_position() -> None:
    line = StraightLine(1.0, 2.0, math.pi / 2, 0.05, t_start_s=4.0)
    s = line.sample(14.0)
    assert (s.x, s.y) == pytest.approx((1.0, 2.5))
    assert s.theta == pytest.approx(math.pi / 2)
    parked = StraightLine(0.0, 0.0, 0.0, 0.0)
    assert parked.sample(100.0) == LeaderState(100.0, 0.0, 0.0, 0.0, 0.0, 0.0)


@pytest.mark.parametrize("ccw", [True, False])
def test_circle_geometry(ccw: bool) -> None:
    c = Circle(1.0, -2.0, 0.5, 0.1, start_angle_rad=1.0, ccw=ccw)
    assert c.period_s == pytest.approx(2 * math.pi * 0.5 / 0.1)
    for t in np.linspace(0.001, 100.0, 50):
        s = c.sample(float(t))
        assert math.hypot(s.x - 1.0, s.y + 2.0) == pytest.approx(0.5)
        assert s.omega_radps == pytest.approx((1 if ccw else -1) * 0.2)
        # Heading is tangent: perpendicular to the radius.
        assert (s.x - 1.0) * math.cos(s.theta) + (s.y + 2.0) * math.sin(s.theta) == pytest.approx(
            0.0, abs=1e-12
        )
    a, b = c.sample(3.0), c.sample(3.0 + c.period_s)
    assert (a.x, a.y, a.theta) == pytest.approx((b.x, b.y, b.theta), abs=1e-12)
    # Default start: below the centre heading +x.
    d = Circle(0.0, 0.0, 1.0, 0.1).sample(0.0)
    assert (d.x, d.y, d.theta) == pytest.approx((0.0, -1.0, 0.0), abs=1e-15)


def test_circle_stays_accurate_after_a_long_run() -> None:
    c = Circle(0.0, 0.0, 0.3, 0.05)
    s = c.sample(1.0e7)  # ~115 days
    assert math.hypot(s.x, s.y) == pytest.approx(0.3, abs=1e-12)


def test_figure_eight_shape_and_bounds() -> None:
    f = FigureEight(0.5, 0.5, 1.0, 50.0)
    for t in (0.0, 25.0, 50.0, 100.0):
        s = f.sample(t)
        assert (s.x, s.y) == pytest.approx((0.5, 0.5), abs=1e-12)
    times = np.linspace(0.01, 50.0, 5001)
    states = [f.sample(float(t)) for t in times]
    xs = np.array([s.x for s in states])
    ys = np.array([s.y for s in states])
    assert xs.max() - xs.min() == pytest.approx(2.0, abs=1e-6)
    assert ys.max() - ys.min() == pytest.approx(1.0, abs=1e-3)
    vs = np.array([s.v_mps for s in states])
    ws = np.array([abs(s.omega_radps) for s in states])
    w = 2 * math.pi / 50.0
    assert vs.min() == pytest.approx(f.min_speed_mps, rel=1e-4)
    assert f.min_speed_mps == pytest.approx(math.sqrt(7) / 4 * 1.0 * w)
    assert vs.max() == pytest.approx(f.max_speed_mps, rel=1e-4)
    assert ws.max() == pytest.approx(f.max_turn_radps, rel=1e-4)
    # Both lobes: turns left on one and right on the other.
    omegas = np.array([s.omega_radps for s in states])
    assert omegas.max() > 0.0 > omegas.min()


def test_waypoints_respect_speed_and_turn_limits_densely() -> None:
    wp = Waypoints(ZIGZAG, speed_mps=0.15, max_turn_radps=0.6)
    dt = 0.01
    times = np.arange(0.0, wp.duration_s + 1.0, dt)
    st_ = [wp.sample(float(t)) for t in times]
    xy = np.array([(s.x, s.y) for s in st_])
    th = np.array([s.theta for s in st_])
    step = np.hypot(*np.diff(xy, axis=0).T)
    dth = np.abs([wrap_angle(float(d)) for d in np.diff(th)])
    assert step.max() <= 0.15 * dt * (1 + 1e-9)
    assert dth.max() <= 0.6 * dt * (1 + 1e-9)
    assert max(s.v_mps for s in st_) == pytest.approx(0.15)
    assert max(abs(s.omega_radps) for s in st_) == pytest.approx(0.6)
    # Ends at the last point, held there.
    end = wp.sample(wp.duration_s + 5.0)
    assert (end.x, end.y, end.v_mps, end.omega_radps) == pytest.approx((3.5, 1.5, 0.0, 0.0))
    start = wp.sample(0.0)
    assert (start.x, start.y, start.theta) == (0.0, 0.0, 0.0)


def test_waypoints_fillet_geometry() -> None:
    """Path length and corner clearance of the tangent-arc construction."""
    pts = [(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (2.0, 2.0)]
    wp = Waypoints(pts, speed_mps=0.1, max_turn_radps=0.5)
    r = wp.turn_radius_m
    assert r == pytest.approx(0.2)
    deltas = [math.pi / 2, -math.pi / 4]
    seg = 1.0 + 1.0 + math.sqrt(2.0)
    expected = seg - sum(2 * r * math.tan(abs(d) / 2) - r * abs(d) for d in deltas)
    assert wp.length_m == pytest.approx(expected)
    dense = np.array(
        [(s.x, s.y) for s in (wp.sample(float(t)) for t in np.linspace(0, wp.duration_s, 20001))]
    )
    for (cx, cy), d in zip(pts[1:3], deltas, strict=True):
        gap = np.hypot(dense[:, 0] - cx, dense[:, 1] - cy).min()
        assert gap == pytest.approx(r * (1 / math.cos(d / 2) - 1), abs=1e-4)


def test_waypoints_loop_is_periodic_and_closed() -> None:
    wp = Waypoints(SQUARE, speed_mps=0.2, max_turn_radps=0.5, loop=True)
    r = wp.turn_radius_m
    assert wp.length_m == pytest.approx(8.0 - 8 * r + 2 * math.pi * r)
    for t in (0.0, 3.3, 17.0):
        a, b = wp.sample(t + 1e-9), wp.sample(t + 1e-9 + 3 * wp.duration_s)
        assert (a.x, a.y, a.theta) == pytest.approx((b.x, b.y, b.theta), abs=1e-9)
    # Never stops.
    assert all(wp.sample(float(t)).v_mps == 0.2 for t in np.linspace(0.1, 200.0, 300))


@settings(max_examples=200, deadline=None)
@given(
    pts=st.lists(
        st.tuples(st.floats(-5, 5), st.floats(-5, 5)), min_size=2, max_size=6, unique=True
    ),
    speed=st.floats(0.02, 0.5),
    turn=st.floats(0.1, 3.0),
)
def test_waypoints_limits_hold_for_any_feasible_path(
    pts: list[tuple[float, float]], speed: float, turn: float
) -> None:
    try:
        wp = Waypoints(pts, speed_mps=speed, max_turn_radps=turn)
    except ValueError:  # infeasible corner (arcs do not fit): not this property's concern
        assume(False)
        return
    dt = wp.duration_s / 400
    prev = wp.sample(0.0)
    assert (prev.x, prev.y) == pytest.approx(pts[0])
    for k in range(1, 402):
        s = wp.sample(k * dt)
        assert 0.0 <= s.v_mps <= speed
        assert abs(s.omega_radps) <= turn * (1 + 1e-12)
        assert math.hypot(s.x - prev.x, s.y - prev.y) <= speed * dt * (1 + 1e-6) + 1e-12
        assert abs(wrap_angle(s.theta - prev.theta)) <= turn * dt * (1 + 1e-6) + 1e-12
        prev = s
    assert (prev.x, prev.y) == pytest.approx(pts[-1], abs=1e-9)


@pytest.mark.parametrize(
    ("make", "match"),
    [
        (lambda: StraightLine(0, 0, 0, -0.1), "speed_mps must be >= 0"),
        (lambda: StraightLine(0, math.nan, 0, 0.1), "y0 must be finite"),
        (lambda: StraightLine(0, 0, "north", 0.1), "heading must be a number"),  # type: ignore[arg-type]
        (lambda: StraightLine(0, 0, 0, 0.1, t_start_s=-1), "t_start_s must be >= 0"),
        (lambda: Circle(0, 0, 0.0, 0.1), "radius_m must be > 0"),
        (lambda: Circle(0, 0, 1.0, 0.0), "speed_mps must be > 0"),
        (lambda: Circle(0, 0, 1.0, math.inf), "speed_mps must be finite"),
        (lambda: Circle(0, 0, 1.0, 0.1, ccw=1), "ccw must be a bool"),  # type: ignore[arg-type]
        (lambda: FigureEight(0, 0, -1.0, 10.0), "a_m must be > 0"),
        (lambda: FigureEight(0, 0, 1.0, 0.0), "period_s must be > 0"),
        (lambda: FigureEight(True, 0, 1.0, 10.0), "cx must be a number"),
        (lambda: Waypoints([(0, 0)], 0.1, 1.0), "at least 2 points"),
        (lambda: Waypoints([(0, 0), (1, 0)], 0.1, 1.0, loop=True), "at least 3 points"),
        (lambda: Waypoints([(0, 0), (0, 0), (1, 0)], 0.1, 1.0), "zero length"),
        (lambda: Waypoints([(0, 0), (1, 0), (0, 0)], 0.1, 1.0), "U-turn"),
        (lambda: Waypoints([(0, 0), (0.1, 0), (0.1, 0.1)], 0.2, 0.5), "need .* of straight"),
        (lambda: Waypoints([(0, 0), (1, 0)], 0.0, 1.0), "speed_mps must be > 0"),
        (lambda: Waypoints([(0, 0), (1, 0)], 0.1, 0.0), "max_turn_radps must be > 0"),
        (lambda: Waypoints("abc", 0.1, 1.0), "points must be a list"),  # type: ignore[arg-type]
        (lambda: Waypoints([(0, 0), (1, 2, 3)], 0.1, 1.0), r"points\[1\] must be an \[x, y\]"),  # type: ignore[list-item]
        (lambda: Waypoints([(0, 0), (1, math.nan)], 0.1, 1.0), r"points\[1\]\[1\] must be fin"),
    ],
)
def test_invalid_parameters_raise_clear_errors(make: Any, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        make()


def test_make_trajectory_builds_every_kind() -> None:
    assert set(TRAJECTORY_KINDS) == {"line", "circle", "figure8", "waypoints", "plan"}
    line = make_trajectory("line", {"x0": 0, "y0": 1, "heading": 0.5, "speed_mps": 0.1})
    assert line == StraightLine(0.0, 1.0, 0.5, 0.1)
    circ = make_trajectory("circle", {"cx": 0, "cy": 0, "radius_m": 1, "speed_mps": 0.1})
    assert circ == Circle(0, 0, 1, 0.1)
    f8 = make_trajectory("Figure_Eight", {"cx": 0, "cy": 0, "a_m": 1, "period_s": 30})
    assert f8 == FigureEight(0, 0, 1, 30)
    wp = make_trajectory(
        "waypoints",
        {"points": [[0, 0], [1, 0], [1, 1]], "speed_mps": 0.1, "max_turn_radps": 1.0, "loop": True},
    )
    assert isinstance(wp, Waypoints) and wp.loop
    assert wp.points == ((0.0, 0.0), (1.0, 0.0), (1.0, 1.0))
    for t in (wp, line, circ, f8):
        assert isinstance(t, Trajectory)


@pytest.mark.parametrize(
    ("kind", "params", "match"),
    [
        ("spiral", {}, "unknown trajectory kind 'spiral'; expected one of line, circle"),
        (3, {}, "kind must be a string"),
        ("line", {"x0": 0, "y0": 0, "heading": 0}, "missing required parameter.*speed_mps"),
        ("line", {"x0": 0, "y0": 0, "heading": 0, "speed": 1}, "unknown parameter.*speed"),
        ("circle", {"cx": 0, "cy": 0, "radius_m": -1, "speed_mps": 0.1}, "radius_m must be > 0"),
        ("waypoints", {"points": [[0, 0], [1, 0]], "speed_mps": 0.1, "_pieces": 1}, "unknown"),
        ("line", [1, 2], "params must be a table"),
    ],
)
def test_make_trajectory_errors(kind: Any, params: Any, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        make_trajectory(kind, params)


def test_wrap_angle_range() -> None:
    assert wrap_angle(math.pi) == math.pi
    assert wrap_angle(-math.pi) == math.pi
    assert wrap_angle(3 * math.pi) == math.pi
    assert wrap_angle(2 * math.pi + 0.1) == pytest.approx(0.1)
    assert wrap_angle(-0.1) == -0.1
