"""Tests of sim_plant.core.plant: exact unicycle, wheel limits, motor lag, drag and teleport."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from robot_agent.core.params import RobotGeometry
from sim_plant.core import plant as plant_mod
from sim_plant.core.kinematics import unicycle_integrate, wrap_angles
from sim_plant.core.plant import Plant

GEOM = RobotGeometry()  # R = 0.03 m, L = 0.05 m, max 10 rad/s
R = GEOM.wheel_radius_m
L = GEOM.half_track_m


def run(plant: Plant, cmd: np.ndarray, duration_s: float, dt_s: float) -> None:
    steps = round(duration_s / dt_s)
    for _ in range(steps):
        plant.step(dt_s, cmd)


def test_straight_line_along_heading() -> None:
    th0 = 0.3
    plant = Plant([[0.1, -0.2, th0]], GEOM)
    run(plant, np.array([[5.0, 5.0]]), 2.0, 0.01)
    dist = R * 5.0 * 2.0  # v = R (wr + wl) / 2 = 0.15 m/s
    x, y, th = plant.truth[0]
    assert x == pytest.approx(0.1 + dist * math.cos(th0), abs=1e-12)
    assert y == pytest.approx(-0.2 + dist * math.sin(th0), abs=1e-12)
    assert th == pytest.approx(th0, abs=1e-15)
    assert plant.t_s == pytest.approx(2.0)
    np.testing.assert_allclose(plant.body_twist, [[0.15, 0.0]], atol=1e-15)


def test_rotate_in_place() -> None:
    plant = Plant([[0.5, 0.5, 0.0]], GEOM)
    run(plant, np.array([[5.0, -5.0]]), 0.5, 0.01)
    omega = R * 10.0 / (2.0 * L)  # 3 rad/s
    x, y, th = plant.truth[0]
    assert x == pytest.approx(0.5, abs=1e-12)
    assert y == pytest.approx(0.5, abs=1e-12)
    assert th == pytest.approx(float(wrap_angles(omega * 0.5)), abs=1e-12)


def test_arc_matches_analytic_circle() -> None:
    th0 = -0.7
    x0, y0 = 0.2, 0.4
    wr, wl = 6.0, 4.0
    v = R * (wr + wl) / 2.0  # 0.15 m/s
    omega = R * (wr - wl) / (2.0 * L)  # 0.6 rad/s
    radius = v / omega  # 0.25 m
    assert radius == pytest.approx(0.25)
    cx, cy = x0 - radius * math.sin(th0), y0 + radius * math.cos(th0)
    plant = Plant([[x0, y0, th0]], GEOM)
    dt = 0.037
    for k in range(1, 300):
        plant.step(dt, np.array([[wr, wl]]))
        x, y, th = plant.truth[0]
        t = k * dt
        assert math.hypot(x - cx, y - cy) == pytest.approx(radius, abs=1e-12)
        assert x == pytest.approx(cx + radius * math.sin(th0 + omega * t), abs=1e-11)
        assert y == pytest.approx(cy - radius * math.cos(th0 + omega * t), abs=1e-11)
        assert th == pytest.approx(float(wrap_angles(th0 + omega * t)), abs=1e-11)


@settings(max_examples=200, deadline=None)
@given(
    wr=st.floats(-10.0, 10.0),
    wl=st.floats(-10.0, 10.0),
    th0=st.floats(-math.pi, math.pi),
    n_sub=st.integers(1, 20),
)
def test_integration_exact_one_step_equals_many(
    wr: float, wl: float, th0: float, n_sub: int
) -> None:
    big = Plant([[0.0, 0.0, th0]], GEOM)
    small = Plant([[0.0, 0.0, th0]], GEOM)
    cmd = np.array([[wr, wl]])
    big.step(0.5, cmd)
    for _ in range(n_sub):
        small.step(0.5 / n_sub, cmd)
    a, b = big.truth[0], small.truth[0]
    np.testing.assert_allclose(a[:2], b[:2], atol=1e-12)
    assert float(wrap_angles(a[2] - b[2])) == pytest.approx(0.0, abs=1e-12)


def test_unicycle_integrate_near_zero_omega_is_smooth() -> None:
    pose = np.array([[0.0, 0.0, 0.4]] * 3)
    v = np.full(3, 0.2)
    out = unicycle_integrate(pose, v, np.array([0.0, 1e-12, -1e-12]), 1.0)
    np.testing.assert_allclose(out[1], out[0], atol=1e-12)
    np.testing.assert_allclose(out[2], out[0], atol=1e-12)
    assert np.all(np.isfinite(out))


def test_wheel_clamp_counts_and_limits() -> None:
    plant = Plant(np.zeros((3, 3)), GEOM)
    plant.step(0.01, np.array([[20.0, 5.0], [-30.0, -40.0], [10.0, -10.0]]))
    np.testing.assert_array_equal(plant.wheel_speeds, [[10.0, 5.0], [-10.0, -10.0], [10.0, -10.0]])
    np.testing.assert_array_equal(plant.saturated, [True, True, False])
    assert plant.clamp_count == 2
    plant.step(0.01, np.array([[20.0, 5.0], [0.0, 0.0], [0.0, 0.0]]))
    np.testing.assert_array_equal(plant.clamp_counts, [2, 1, 0])
    # The clamped robot moved as with (10, 5), not (20, 5).
    unlimited = Plant(np.zeros((1, 3)), GEOM, wheel_limit=False)
    unlimited.step(0.01, np.array([[20.0, 5.0]]))
    assert unlimited.clamp_count == 0
    np.testing.assert_array_equal(unlimited.wheel_speeds, [[20.0, 5.0]])


@settings(max_examples=200, deadline=None)
@given(
    cmd=st.lists(st.floats(allow_nan=True, allow_infinity=True, width=64), min_size=4, max_size=4),
    dt=st.floats(1e-4, 1.0),
)
def test_any_command_keeps_state_valid(cmd: list[float], dt: float) -> None:
    plant = Plant([[0.0, 0.0, 3.1], [1.0, 1.0, -3.1]], GEOM, motor_tau_s=0.05)
    plant.step(dt, np.array(cmd).reshape(2, 2))
    truth = plant.truth
    assert np.all(np.isfinite(truth))
    assert np.all(truth[:, 2] > -math.pi)
    assert np.all(truth[:, 2] <= math.pi)
    assert np.all(np.abs(plant.wheel_speeds) <= GEOM.max_wheel_radps)


def test_motor_lag_time_constant() -> None:
    tau = 0.1
    c = 5.0
    fine = Plant(np.zeros((1, 3)), GEOM, motor_tau_s=tau)
    run(fine, np.array([[c, c]]), tau, 0.001)
    assert fine.wheel_speeds[0, 0] == pytest.approx(c * (1.0 - math.exp(-1.0)), rel=1e-9)
    assert fine.wheel_speeds[0, 0] / c == pytest.approx(0.632, abs=1e-3)
    # Exact discretisation: one step of tau gives the same speed and the same distance.
    coarse = Plant(np.zeros((1, 3)), GEOM, motor_tau_s=tau)
    coarse.step(tau, np.array([[c, c]]))
    np.testing.assert_allclose(coarse.wheel_speeds, fine.wheel_speeds, rtol=1e-9)
    dist = R * c * (tau - tau * (1.0 - math.exp(-1.0)))  # integral of the lagged speed
    assert coarse.truth[0, 0] == pytest.approx(dist, rel=1e-9)
    assert fine.truth[0, 0] == pytest.approx(dist, rel=1e-9)
    # Without lag the wheels follow at once.
    ideal = Plant(np.zeros((1, 3)), GEOM)
    ideal.step(0.001, np.array([[c, -c]]))
    np.testing.assert_array_equal(ideal.wheel_speeds, [[c, -c]])


def test_motor_lag_heading_change_is_exact() -> None:
    tau = 0.2
    plant = Plant(np.zeros((1, 3)), GEOM, motor_tau_s=tau)
    plant.step(0.3, np.array([[2.0, -2.0]]))
    omega_c = R * 4.0 / (2.0 * L)
    expected = omega_c * (0.3 - tau * (1.0 - math.exp(-0.3 / tau)))
    assert plant.truth[0, 2] == pytest.approx(expected, rel=1e-12)
    np.testing.assert_allclose(plant.truth[0, :2], [0.0, 0.0], atol=1e-15)


def test_nonfinite_command_treated_as_zero_and_counted() -> None:
    plant = Plant([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]], GEOM)
    plant.step(1.0, np.array([[math.nan, 5.0], [5.0, 5.0]]))
    np.testing.assert_allclose(plant.truth[0], [0.0, 0.0, 0.0])
    np.testing.assert_allclose(plant.truth[1], [1.15, 0.0, 0.0])
    plant.step(1.0, np.array([[3.0, 3.0], [math.inf, -math.inf]]))
    assert plant.nonfinite_count == 2
    np.testing.assert_array_equal(plant.nonfinite_counts, [1, 1])
    np.testing.assert_array_equal(plant.wheel_speeds, [[3.0, 3.0], [0.0, 0.0]])
    assert plant.clamp_count == 0  # inf is not a clamp, it is rejected


def test_dt_zero_is_noop_negative_raises() -> None:
    plant = Plant([[0.0, 0.0, 0.0]], GEOM)
    plant.step(0.0, np.array([[5.0, 5.0]]))
    assert plant.t_s == 0.0
    np.testing.assert_array_equal(plant.truth, [[0.0, 0.0, 0.0]])
    np.testing.assert_array_equal(plant.wheel_speeds, [[0.0, 0.0]])
    for bad in (-0.01, math.nan, math.inf):
        with pytest.raises(ValueError):
            plant.step(bad, np.array([[5.0, 5.0]]))
    with pytest.raises(ValueError):
        plant.step(0.01, np.array([5.0, 5.0]))  # wrong shape
    assert plant.t_s == 0.0


def test_constructor_validation_and_wrap() -> None:
    with pytest.raises(ValueError):
        Plant(np.zeros((2, 2)), GEOM)
    with pytest.raises(ValueError):
        Plant([[0.0, math.nan, 0.0]], GEOM)
    with pytest.raises(ValueError):
        Plant(np.zeros((1, 3)), GEOM, motor_tau_s=-1.0)
    plant = Plant([[0.0, 0.0, 3.0 * math.pi], [0.0, 0.0, -math.pi]], GEOM)
    np.testing.assert_allclose(plant.truth[:, 2], [math.pi, math.pi])
    assert Plant(np.zeros((0, 3)), GEOM).n == 0


def test_truth_is_a_copy() -> None:
    plant = Plant([[0.0, 0.0, 0.0]], GEOM)
    t = plant.truth
    t[0, 0] = 99.0
    assert plant.truth[0, 0] == 0.0


def test_drag_moves_linearly_and_ignores_wheels() -> None:
    th0 = 0.5
    plant = Plant([[0.0, 0.0, th0], [1.0, 1.0, 0.0]], GEOM)
    dt = 0.03  # drag start 1.0 and end 3.0 fall inside steps: the split must be exact
    v = R * 5.0
    heading = np.array([math.cos(th0), math.sin(th0)])
    dx, dy = -0.5, 0.2
    plant.drag(0, dx, dy, duration_s=2.0, t_start_s=1.0)
    cmd = np.array([[5.0, 5.0], [5.0, 5.0]])
    start = v * 1.0 * heading
    for k in range(1, round(4.2 / dt) + 1):
        plant.step(dt, cmd)
        t = k * dt
        pos = plant.truth[0, :2]
        if t <= 1.0 - 1e-9:
            expected = v * t * heading
            assert not plant.carried[0]
        elif t < 3.0 - 1e-9:
            expected = start + np.array([dx, dy]) * (t - 1.0) / 2.0
            assert plant.carried[0]
        else:
            expected = start + np.array([dx, dy]) + v * (t - 3.0) * heading
            assert not plant.carried[0]
        np.testing.assert_allclose(pos, expected, atol=1e-9)
        assert plant.truth[0, 2] == pytest.approx(th0, abs=1e-12)
        assert not plant.carried[1]
    # The other robot drove the whole time.
    np.testing.assert_allclose(plant.truth[1, :2], [1.0 + v * plant.t_s, 1.0], atol=1e-9)


def test_drag_keeps_heading_while_wheels_turn() -> None:
    plant = Plant([[0.0, 0.0, 1.0]], GEOM, motor_tau_s=0.05)
    plant.drag(0, 0.3, 0.0, duration_s=1.0)
    run(plant, np.array([[10.0, -10.0]]), 0.5, 0.01)
    assert plant.truth[0, 2] == pytest.approx(1.0)
    np.testing.assert_allclose(plant.truth[0, :2], [0.15, 0.0], atol=1e-12)
    # The motors spin in the air while carried.
    assert plant.wheel_speeds[0, 0] > 9.9


def test_drag_split_with_motor_lag_is_exact_in_distance() -> None:
    tau, c = 0.1, 5.0
    t0, dur, dt, steps = 0.25, 0.5, 0.03, 33  # drag start and end fall inside steps
    plant = Plant(np.zeros((1, 3)), GEOM, motor_tau_s=tau)
    plant.drag(0, 0.0, 1.0, dur, t_start_s=t0)
    run(plant, np.array([[c, c]]), steps * dt, dt)

    def travelled(a: float, b: float) -> float:  # integral of R c (1 - exp(-s / tau)) over [a, b]
        return R * c * ((b - a) - tau * (math.exp(-a / tau) - math.exp(-b / tau)))

    t_end = steps * dt
    expected_x = travelled(0.0, t0) + travelled(t0 + dur, t_end)
    np.testing.assert_allclose(plant.truth[0], [expected_x, 1.0, 0.0], atol=1e-12)


def test_drag_zero_duration_and_validation() -> None:
    plant = Plant([[0.0, 0.0, 0.0]], GEOM)
    plant.drag(0, 0.1, -0.2, duration_s=0.0)
    plant.step(0.01, np.zeros((1, 2)))
    np.testing.assert_allclose(plant.truth[0, :2], [0.1, -0.2])
    assert not plant.carried[0]
    run(plant, np.array([[5.0, 5.0]]), 1.0, 0.01)
    assert plant.truth[0, 0] == pytest.approx(0.1 + 0.15)
    with pytest.raises(ValueError):
        plant.drag(0, 0.1, 0.0, 1.0, t_start_s=0.5)  # in the past
    with pytest.raises(ValueError):
        plant.drag(0, 0.1, 0.0, -1.0)
    with pytest.raises(IndexError):
        plant.drag(3, 0.1, 0.0, 1.0)


def test_teleport_sets_pose_and_cancels_drag() -> None:
    plant = Plant([[0.0, 0.0, 0.3], [1.0, 0.0, 0.0]], GEOM)
    plant.teleport(1, 2.0, 3.0)
    np.testing.assert_allclose(plant.truth[1], [2.0, 3.0, 0.0])
    plant.teleport(1, 2.0, 3.0, theta=2.0 * math.pi + 0.25)
    assert plant.truth[1, 2] == pytest.approx(0.25)
    plant.drag(0, 1.0, 0.0, duration_s=1.0)
    plant.step(0.5, np.zeros((2, 2)))
    assert plant.carried[0]
    plant.teleport(0, -1.0, -1.0)
    assert not plant.carried[0]
    plant.step(0.5, np.array([[5.0, 5.0], [0.0, 0.0]]))
    x, y, th = plant.truth[0]
    assert (x, y, th) == pytest.approx(
        (-1.0 + 0.075 * math.cos(0.3), -1.0 + 0.075 * math.sin(0.3), 0.3)
    )
    with pytest.raises(ValueError):
        plant.teleport(0, math.nan, 0.0)


def test_add_and_remove_robot() -> None:
    plant = Plant([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]], GEOM)
    plant.drag(1, 0.0, 1.0, duration_s=1.0)
    i = plant.add_robot([5.0, 5.0, 4.0])
    assert i == 2 and plant.n == 3
    assert plant.truth[2, 2] == pytest.approx(4.0 - 2.0 * math.pi)
    plant.remove_robot(0)
    assert plant.n == 2
    run(plant, np.array([[5.0, 5.0], [5.0, 5.0]]), 1.0, 0.01)
    # Former robot 1 (now 0) was carried, former robot 2 (now 1) drove.
    np.testing.assert_allclose(plant.truth[0, :2], [1.0, 1.0], atol=1e-9)
    heading = 4.0 - 2.0 * math.pi
    np.testing.assert_allclose(
        plant.truth[1, :2], [5.0 + 0.15 * math.cos(heading), 5.0 + 0.15 * math.sin(heading)]
    )


def _wheel_angle_run(
    seed: int, n: int, tau_s: float, small_n: int
) -> tuple[list[list[tuple[float, float]]], bytes]:
    """Wheel angles after each step of a run with a robot added (after step 10) and robot 0
    removed (after step 20; the angles just before the removal are the extra last entry),
    the command as pairs of floats (the loop's form), stepped in plain Python when the fleet
    is at most ``small_n`` robots and vectorised otherwise; and the final truth's bytes."""
    rng = np.random.default_rng(seed)
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(plant_mod, "SMALL_N", small_n)
        plant = Plant(rng.uniform(-1.0, 1.0, (n, 3)), GEOM, motor_tau_s=tau_s)
        angles = []
        before_removal = []
        for k in range(30):
            cmd = rng.uniform(-0.9, 0.9, (plant.n, 2)) * GEOM.max_wheel_radps
            plant.step(0.02, [(wr, wl) for wr, wl in cmd.tolist()])
            if k == 10:
                plant.add_robot([0.2, 0.1, 1.0])
            if k == 20:
                before_removal = plant.wheel_angles()
                plant.remove_robot(0)
            angles.append(plant.wheel_angles())
        return [*angles, before_removal], plant.truth.tobytes()


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(1, 5), st.sampled_from([0.0, 0.05]))
def test_wheel_angles_small_path_equals_vectorised(seed: int, n: int, tau_s: float) -> None:
    """The small-fleet step's wheel angles (built anew each step) are the vectorised step's
    bit for bit, and add_robot / remove_robot keep each robot's own angles."""
    small = _wheel_angle_run(seed, n, tau_s, small_n=64)
    assert small == _wheel_angle_run(seed, n, tau_s, small_n=0)
    angles = small[0]
    assert [len(a) for a in angles[9:12]] == [n, n + 1, n + 1]
    assert angles[10][-1] == (0.0, 0.0)  # the added robot has not turned yet
    assert angles[11][:n] != angles[10][:n]  # the others turned on
    assert angles[20] == angles[-1][1:]  # robot 0 gone: the others' angles moved down one
    assert len(angles[20]) == n


def test_thousand_robots_vectorised() -> None:
    rng = np.random.default_rng(7)
    n = 1000
    x0 = np.column_stack([rng.uniform(-5, 5, n), rng.uniform(-5, 5, n), rng.uniform(-3, 3, n)])
    plant = Plant(x0, GEOM, motor_tau_s=0.05)
    cmd = rng.uniform(-12.0, 12.0, (n, 2))
    plant.drag(10, 1.0, 0.0, 0.5)
    for _ in range(100):
        plant.step(0.01, cmd)
    truth = plant.truth
    assert truth.shape == (n, 3)
    assert np.all(np.isfinite(truth))
    assert plant.clamp_count == 100 * int(np.count_nonzero(np.any(np.abs(cmd) > 10.0, axis=1)))
    # Per-robot result equals a single-robot plant: no cross-talk between rows.
    j = 123
    single = Plant(x0[j : j + 1], GEOM, motor_tau_s=0.05)
    for _ in range(100):
        single.step(0.01, cmd[j : j + 1])
    np.testing.assert_allclose(truth[j], single.truth[0], atol=1e-12)


def test_sim_plant_core_is_pure() -> None:
    """No clock, no global randomness, no I/O in the sim_plant core modules."""
    import ast
    import pathlib

    import sim_plant.core

    forbidden = {"time", "random", "asyncio", "zenoh", "logging", "datetime", "socket", "os"}
    root = pathlib.Path(sim_plant.core.__file__).parent
    for name in ("plant.py", "sensors.py", "accounting.py", "__init__.py"):
        tree = ast.parse((root / name).read_text())
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                mods = {a.name.split(".")[0] for a in node.names}
            elif isinstance(node, ast.ImportFrom):
                mods = {(node.module or "").split(".")[0]}
            else:
                mods = set()
            assert not mods & forbidden, f"{name} imports {mods & forbidden}"
            # Only the Generator type of np.random may appear (no global-state draws).
            if (
                isinstance(node, ast.Attribute)
                and isinstance(node.value, ast.Attribute)
                and node.value.attr == "random"
            ):
                assert node.attr == "Generator", f"{name} uses np.random.{node.attr}"
