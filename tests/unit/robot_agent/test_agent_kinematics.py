"""Kinematics of robot_agent: eqs 7-16 (corrected), saturation keeping the turn, wrap_angle."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from formation.outputs.runlog import reference_points
from robot_agent.core.kinematics import (
    axle_from_reference_point,
    ref_point_velocity,
    reference_point,
    saturate_wheels,
    twist_from_ref_velocity,
    twist_from_wheels,
    twist_from_wheels_raw,
    wheels_from_twist,
    wheels_from_twist_raw,
    wrap_angle,
)
from robot_agent.core.params import RobotGeometry

GEOM = RobotGeometry()
WMAX = GEOM.max_wheel_radps

finite = st.floats(min_value=-1e3, max_value=1e3, allow_nan=False, allow_infinity=False)
angles = st.floats(min_value=-20.0, max_value=20.0, allow_nan=False, allow_infinity=False)
offsets = st.floats(min_value=1e-3, max_value=1.0, allow_nan=False, allow_infinity=False)
any_float = st.floats(allow_nan=True, allow_infinity=True)


# ----------------------------------------------------------------------------- eqs 7-8


def test_all_zero() -> None:
    assert wheels_from_twist(0.0, 0.0, GEOM) == (0.0, 0.0)
    assert twist_from_wheels(0.0, 0.0, GEOM) == (0.0, 0.0)
    assert saturate_wheels(0.0, 0.0, WMAX) == (0.0, 0.0, False)
    assert twist_from_ref_velocity(0.0, 0.0, 1.0, GEOM.ref_offset_m) == (0.0, 0.0)
    assert ref_point_velocity(0.0, 0.0, 1.0, GEOM.ref_offset_m) == (0.0, 0.0)
    assert reference_point(0.0, 0.0, 0.0, 0.0) == (0.0, 0.0)


def test_corrected_eq7_eq8_numbers() -> None:
    # R = 0.03, L = 0.05: both wheels at 10 rad/s -> 0.3 m/s straight.
    assert twist_from_wheels(10.0, 10.0, GEOM) == pytest.approx((0.3, 0.0))
    # Opposite wheels at 10 rad/s: rotate in place at R*10/L = 6 rad/s (the printed eq 7 gives 3).
    assert twist_from_wheels(10.0, -10.0, GEOM) == pytest.approx((0.0, 6.0))
    # v = 0.1, omega = 1: wheels (0.1 +- 0.05) / 0.03.
    wr, wl = wheels_from_twist(0.1, 1.0, GEOM)
    assert wr == pytest.approx(0.15 / 0.03)
    assert wl == pytest.approx(0.05 / 0.03)


@settings(max_examples=200, deadline=None, derandomize=True)
@given(v=finite, w=finite)
def test_twist_wheels_round_trip(v: float, w: float) -> None:
    wr, wl = wheels_from_twist(v, w, GEOM)
    v2, w2 = twist_from_wheels(wr, wl, GEOM)
    assert v2 == pytest.approx(v, rel=1e-9, abs=1e-9)
    assert w2 == pytest.approx(w, rel=1e-9, abs=1e-9)


@settings(max_examples=200, deadline=None, derandomize=True)
@given(wr=finite, wl=finite)
def test_wheels_twist_round_trip(wr: float, wl: float) -> None:
    v, w = twist_from_wheels(wr, wl, GEOM)
    assert wheels_from_twist(v, w, GEOM) == pytest.approx((wr, wl), rel=1e-9, abs=1e-9)


# ----------------------------------------------------------------------------- saturation


def test_saturation_untouched_inside_limits() -> None:
    assert saturate_wheels(9.9, -3.0, WMAX) == (9.9, -3.0, False)
    assert saturate_wheels(10.0, 10.0, WMAX) == (10.0, 10.0, False)


def test_saturation_keeps_turn_reduces_forward() -> None:
    # common 12, differential 3: turn kept (r - l = 6), forward shrinks to 10 - 3 = 7.
    wr, wl, sat = saturate_wheels(15.0, 9.0, WMAX)
    assert sat
    assert wr - wl == pytest.approx(6.0)
    assert (wr, wl) == pytest.approx((10.0, 4.0))
    # Reversing: the forward part keeps its sign.
    wr, wl, sat = saturate_wheels(-9.0, -15.0, WMAX)
    assert sat
    assert (wr, wl) == pytest.approx((-4.0, -10.0))


def test_saturation_keeps_turn_sign_and_ratio() -> None:
    # Pure turn over the limit: scaled to the limit, sign kept, wheels opposite (ratio -1).
    wr, wl, sat = saturate_wheels(-30.0, 30.0, WMAX)
    assert sat
    assert (wr, wl) == (-10.0, 10.0)
    assert wr / wl == -1.0
    # Turn part alone over the limit with some forward part: forward dropped, turn at limit.
    wr, wl, sat = saturate_wheels(25.0, -15.0, WMAX)
    assert sat
    assert (wr, wl) == (10.0, -10.0)


def test_rotate_in_place() -> None:
    v, w = twist_from_wheels(*saturate_wheels(*wheels_from_twist(0.0, 3.0, GEOM), WMAX)[:2], GEOM)
    assert v == pytest.approx(0.0, abs=1e-12)
    assert w == pytest.approx(3.0)
    # Asking for 100 rad/s in place gives the fastest in-place turn, no forward motion.
    wr, wl, sat = saturate_wheels(*wheels_from_twist(0.0, 100.0, GEOM), WMAX)
    assert sat
    assert (wr, wl) == (WMAX, -WMAX)


@pytest.mark.parametrize(
    ("wr", "wl"),
    [(math.nan, 0.0), (0.0, math.nan), (math.inf, 0.0), (0.0, -math.inf), (math.inf, math.inf)],
)
def test_saturation_non_finite_is_safe(wr: float, wl: float) -> None:
    assert saturate_wheels(wr, wl, WMAX) == (0.0, 0.0, True)


@pytest.mark.parametrize("limit", [0.0, -1.0, math.nan, math.inf])
def test_saturation_bad_limit_is_safe(limit: float) -> None:
    assert saturate_wheels(1.0, 2.0, limit) == (0.0, 0.0, True)


@settings(max_examples=300, deadline=None, derandomize=True)
@given(wr=any_float, wl=any_float)
def test_saturation_within_limits_for_any_input(wr: float, wl: float) -> None:
    r, lft, sat = saturate_wheels(wr, wl, WMAX)
    assert math.isfinite(r) and math.isfinite(lft)
    assert abs(r) <= WMAX and abs(lft) <= WMAX
    if math.isfinite(wr) and math.isfinite(wl) and max(abs(wr), abs(wl)) <= WMAX:
        assert (r, lft, sat) == (wr, wl, False)
    else:
        assert sat


@settings(max_examples=300, deadline=None, derandomize=True)
@given(wr=finite, wl=finite)
def test_saturation_keeps_turn_direction(wr: float, wl: float) -> None:
    r, lft, sat = saturate_wheels(wr, wl, WMAX)
    turn_in, turn_out = wr - wl, r - lft
    fwd_in, fwd_out = wr + wl, r + lft
    # Turn: same sign; kept exactly unless it alone exceeds the limit.
    assert turn_out * turn_in >= 0.0
    if abs(turn_in) / 2 < WMAX:
        assert turn_out == pytest.approx(turn_in, rel=1e-12, abs=1e-12)
    else:
        assert abs(turn_out) == pytest.approx(2 * WMAX)
    # Forward: never grows and never changes sign.
    assert fwd_out * fwd_in >= 0.0
    assert abs(fwd_out) <= abs(fwd_in) + 1e-12
    if sat:
        assert max(abs(r), abs(lft)) == pytest.approx(WMAX)


# ----------------------------------------------------------------------------- eqs 10-16


def test_reference_point_eq10_11() -> None:
    assert reference_point(1.0, 2.0, 0.0, 0.05) == pytest.approx((1.05, 2.0))
    assert reference_point(1.0, 2.0, math.pi / 2, 0.05) == pytest.approx((1.0, 2.05))


@settings(max_examples=200, deadline=None, derandomize=True)
@given(x=finite, y=finite, th=angles, l_m=offsets)
def test_axle_from_reference_point_inverts_eq10_11(
    x: float, y: float, th: float, l_m: float
) -> None:
    xr, yr = reference_point(x, y, th, l_m)
    ax, ay = axle_from_reference_point(xr, yr, th, l_m)
    assert ax == pytest.approx(x, abs=1e-9) and ay == pytest.approx(y, abs=1e-9)


@settings(max_examples=100, deadline=None, derandomize=True)
@given(
    poses=st.lists(st.tuples(finite, finite, angles), min_size=1, max_size=12),
    l_m=offsets,
)
def test_vectorised_reference_points_equal_the_scalar_form(
    poses: list[tuple[float, float, float]], l_m: float
) -> None:
    """formation.outputs.runlog.reference_points (a whole log at once, numpy) is eqs 10-11 as
    kinematics.reference_point computes them, to an ulp of numpy's cos / sin; a NaN pose gives
    a NaN point."""
    truth = np.array([*poses, (math.nan, math.nan, math.nan)], dtype=np.float64)
    got = reference_points(truth.reshape(1, -1, 3), l_m)[0]
    assert got.shape == (len(poses) + 1, 2)
    for (x, y, th), (gx, gy) in zip(poses, got[:-1], strict=True):
        xr, yr = reference_point(x, y, th, l_m)
        assert gx == pytest.approx(xr, rel=1e-15, abs=1e-15)
        assert gy == pytest.approx(yr, rel=1e-15, abs=1e-15)
    assert np.isnan(got[-1]).all()


@settings(max_examples=200, deadline=None, derandomize=True)
@given(v=any_float, w=any_float)
def test_raw_forms_are_the_geometry_forms_bit_for_bit(v: float, w: float) -> None:
    """The firmware's per-tick forms (the geometry as two numbers) give the same bits as the
    RobotGeometry forms, NaN, infinities and signed zeros included."""
    half_track, radius = GEOM.half_track_m, GEOM.wheel_radius_m
    pairs = (
        (wheels_from_twist_raw(v, w, half_track, radius), wheels_from_twist(v, w, GEOM)),
        (twist_from_wheels_raw(v, w, half_track, radius), twist_from_wheels(v, w, GEOM)),
    )
    for got, want in pairs:
        assert [repr(a) for a in got] == [repr(b) for b in want]


@settings(max_examples=200, deadline=None, derandomize=True)
@given(v=finite, w=finite, th=angles, l_m=offsets)
def test_ref_velocity_inverse_round_trip(v: float, w: float, th: float, l_m: float) -> None:
    xd, yd = ref_point_velocity(v, w, th, l_m)
    v2, w2 = twist_from_ref_velocity(xd, yd, th, l_m)
    assert v2 == pytest.approx(v, rel=1e-9, abs=1e-9)
    assert w2 == pytest.approx(w, rel=1e-9, abs=1e-9 / l_m)


@settings(max_examples=200, deadline=None, derandomize=True)
@given(xd=finite, yd=finite, th=angles, l_m=offsets)
def test_ref_velocity_forward_round_trip(xd: float, yd: float, th: float, l_m: float) -> None:
    v, w = twist_from_ref_velocity(xd, yd, th, l_m)
    assert ref_point_velocity(v, w, th, l_m) == pytest.approx((xd, yd), rel=1e-9, abs=1e-9)


def test_ref_point_velocity_is_the_derivative_of_eq10_11() -> None:
    # Integrate a unicycle (eq 9) exactly over a short arc and difference eqs 10-11: this is
    # what eq 13 (misprinted in the paper) must equal.
    x, y, th, v, w, l_m, h = 0.3, -0.2, 0.7, 0.12, 0.9, 0.05, 1e-6

    def at(t: float) -> tuple[float, float]:
        tt = th + w * t
        xx = x + v / w * (math.sin(tt) - math.sin(th))
        yy = y - v / w * (math.cos(tt) - math.cos(th))
        return reference_point(xx, yy, tt, l_m)

    (x1, y1), (x0, y0) = at(h), at(-h)
    numeric = ((x1 - x0) / (2 * h), (y1 - y0) / (2 * h))
    assert ref_point_velocity(v, w, th, l_m) == pytest.approx(numeric, rel=1e-6, abs=1e-9)


def test_twist_from_ref_velocity_matches_robotarium_si_to_uni() -> None:
    """(b) eq 16 is the Robotarium si_to_uni map: dxu = [c dx + s dy, (-s dx + c dy) / l]."""
    rng = np.random.default_rng(1234)
    n = 500
    dxi = rng.uniform(-1.0, 1.0, size=(2, n))
    poses = rng.uniform(-5.0, 5.0, size=(3, n))
    for l_m in (0.02, 0.05, 0.08):
        cs, ss = np.cos(poses[2, :]), np.sin(poses[2, :])
        dxu = np.zeros((2, n))
        dxu[0, :] = cs * dxi[0, :] + ss * dxi[1, :]
        dxu[1, :] = (1.0 / l_m) * (-ss * dxi[0, :] + cs * dxi[1, :])
        ours = np.array(
            [
                twist_from_ref_velocity(float(dxi[0, i]), float(dxi[1, i]), float(poses[2, i]), l_m)
                for i in range(n)
            ]
        ).T
        np.testing.assert_allclose(ours, dxu, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("l_m", [0.0, -0.05])
def test_eq16_rejects_non_positive_offset(l_m: float) -> None:
    with pytest.raises(ValueError):
        twist_from_ref_velocity(0.1, 0.0, 0.0, l_m)


# ----------------------------------------------------------------------------- wrap_angle


def test_wrap_angle_edges() -> None:
    assert wrap_angle(0.0) == 0.0
    assert wrap_angle(math.pi) == pytest.approx(math.pi)
    assert wrap_angle(-math.pi) == pytest.approx(math.pi)  # (-pi, pi]: -pi maps to pi
    assert wrap_angle(3 * math.pi) == pytest.approx(math.pi)
    assert wrap_angle(2 * math.pi) == pytest.approx(0.0, abs=1e-15)
    assert wrap_angle(-math.pi / 2) == pytest.approx(-math.pi / 2)
    for bad in (math.nan, math.inf, -math.inf):
        assert math.isnan(wrap_angle(bad))


@settings(max_examples=200, deadline=None, derandomize=True)
@given(a=st.floats(min_value=-1e6, max_value=1e6, allow_nan=False))
def test_wrap_angle_range_and_equivalence(a: float) -> None:
    w = wrap_angle(a)
    assert -math.pi < w <= math.pi
    assert math.cos(w) == pytest.approx(math.cos(a), abs=1e-6)
    assert math.sin(w) == pytest.approx(math.sin(a), abs=1e-6)


# ----------------------------------------------------------------------------- params


@pytest.mark.parametrize(
    "kwargs",
    [
        {"wheel_radius_m": 0.0},
        {"half_track_m": -0.05},
        {"max_wheel_radps": math.nan},
        {"ref_offset_m": math.inf},
        {"body_radius_m": 0.0},
    ],
)
def test_geometry_validation(kwargs: dict[str, float]) -> None:
    with pytest.raises(ValueError):
        RobotGeometry(**kwargs)


def test_geometry_defaults() -> None:
    assert GEOM.max_speed_mps == pytest.approx(0.3)
    assert (GEOM.wheel_radius_m, GEOM.half_track_m, GEOM.ref_offset_m) == (0.03, 0.05, 0.05)
