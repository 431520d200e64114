"""Potential-field repulsion of robot_agent: magnitude law, cut-off, cap, never NaN."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from robot_agent.core.params import DEFAULT_K_REP, AgentConfig, RepulsionParams, RobotGeometry
from robot_agent.core.repulsion import repulsion_velocity, repulsion_velocity_counted

P = RepulsionParams()
coord = st.floats(min_value=-2.0, max_value=2.0, allow_nan=False)
any_float = st.floats(allow_nan=True, allow_infinity=True)


def law(d: float, p: RepulsionParams = P) -> float:
    return p.k_rep * (1.0 / d - 1.0 / p.influence_m) / d**2


def test_all_zero() -> None:
    assert repulsion_velocity(0.0, 0.0, [], [], P) == (0.0, 0.0)


def test_default_gain_gives_0p1_mps_at_contact() -> None:
    """Documented choice: two default robots touching (d = 2 * body radius = 0.15 m) push at
    about 0.1 m/s with d0 = 0.30 m (how k_rep was chosen)."""
    d = 2 * RobotGeometry().body_radius_m
    assert d == pytest.approx(0.15)
    p30 = RepulsionParams(d0_m=0.30)
    assert p30.k_rep == DEFAULT_K_REP
    vx, vy = repulsion_velocity(0.0, 0.0, [(d, 0.0)], [], p30)
    assert vy == 0.0
    assert vx == pytest.approx(-0.1, rel=0.01)
    assert p30.speed_at(d) == pytest.approx(0.1, rel=0.01)


def test_default_d0_is_derived_from_the_body_not_the_spacing() -> None:
    """d0 = 2 * body radius + 0.10 m: 0.25 m for the default body (0.08 m/s at contact), below a
    0.3 m formation spacing; AgentConfig derives it from its own geometry."""
    assert P.d0_m is None
    assert P.influence_m == pytest.approx(0.25)
    assert P.speed_at(0.15) == pytest.approx(0.08, rel=0.02)
    assert P.speed_at(0.3) == 0.0
    assert AgentConfig().repulsion.d0_m == pytest.approx(0.25)
    big = AgentConfig(geometry=RobotGeometry(body_radius_m=0.1))
    assert big.repulsion.d0_m == pytest.approx(0.30)
    assert AgentConfig(repulsion=RepulsionParams(d0_m=0.4)).repulsion.d0_m == 0.4


@pytest.mark.parametrize("d", [0.14, 0.2, 0.22, 0.245])
def test_magnitude_follows_khatib_law(d: float) -> None:
    ang = 0.7
    vx, vy = repulsion_velocity(0.0, 0.0, [(d * math.cos(ang), d * math.sin(ang))], [], P)
    assert math.hypot(vx, vy) == pytest.approx(law(d), rel=1e-12)
    # Pointing away from the neighbour.
    assert vx == pytest.approx(-law(d) * math.cos(ang))
    assert vy == pytest.approx(-law(d) * math.sin(ang))


@settings(max_examples=200, deadline=None, derandomize=True)
@given(px=coord, py=coord, nx=coord, ny=coord)
def test_zero_beyond_d0_and_pointing_away(px: float, py: float, nx: float, ny: float) -> None:
    vx, vy = repulsion_velocity(px, py, [(nx, ny)], [], P)
    d = math.hypot(px - nx, py - ny)
    if d >= P.influence_m:
        assert (vx, vy) == (0.0, 0.0)
    else:
        assert math.hypot(vx, vy) <= P.max_speed_mps * (1 + 1e-12)
        if d > 1e-9:
            # Along the unit vector away from the neighbour.
            dot = vx * (px - nx) + vy * (py - ny)
            assert dot > 0.0
            cross = vx * (py - ny) - vy * (px - nx)
            assert abs(cross) <= 1e-9 * max(1.0, math.hypot(vx, vy) * d)
            assert math.hypot(vx, vy) == pytest.approx(min(law(d), P.max_speed_mps), rel=1e-9)


def test_sum_is_capped_and_symmetric_pushes_cancel() -> None:
    ring = [(0.1 * math.cos(a), 0.1 * math.sin(a)) for a in (0.0, 0.3, 0.6)]
    vx, vy = repulsion_velocity(0.0, 0.0, ring, [], P)
    assert math.hypot(vx, vy) == pytest.approx(P.max_speed_mps)
    vx, vy = repulsion_velocity(0.0, 0.0, [(0.2, 0.0), (-0.2, 0.0)], [], P)
    assert (vx, vy) == pytest.approx((0.0, 0.0), abs=1e-15)


def test_coincident_point_pushes_deterministically_never_nan() -> None:
    a = repulsion_velocity(0.5, 0.5, [(0.5, 0.5)], [], P)
    b = repulsion_velocity(0.5, 0.5, [(0.5, 0.5)], [], P)
    assert a == b
    assert all(math.isfinite(v) for v in a)
    assert math.hypot(*a) == pytest.approx(P.max_speed_mps)
    # Nearly coincident (1e-12 m apart) still points away from the neighbour.
    vx, _ = repulsion_velocity(1e-12, 0.0, [(0.0, 0.0)], [], P)
    assert vx == pytest.approx(P.max_speed_mps)


def test_obstacle_uses_distance_to_surface() -> None:
    # Circle of radius 0.5 centred 0.7 m away: the surface is 0.2 m away.
    vx, vy = repulsion_velocity(0.0, 0.0, [], [(0.7, 0.0, 0.5)], P)
    assert vx == pytest.approx(-law(0.2))
    assert vy == 0.0
    # Surface 0.31 m away: no push even though the centre is inside d0 + r.
    assert repulsion_velocity(0.0, 0.0, [], [(0.81, 0.0, 0.5)], P) == (0.0, 0.0)
    # Inside the circle: pushed straight out at the cap.
    vx, vy = repulsion_velocity(0.0, 0.1, [], [(0.0, 0.0, 0.5)], P)
    assert (vx, vy) == pytest.approx((0.0, P.max_speed_mps))
    # At the centre: deterministic direction, never NaN.
    vx, vy = repulsion_velocity(0.0, 0.0, [], [(0.0, 0.0, 0.5)], P)
    assert math.hypot(vx, vy) == pytest.approx(P.max_speed_mps)


def test_disabled_gives_zero() -> None:
    off = RepulsionParams(enabled=False)
    assert repulsion_velocity(0.0, 0.0, [(0.01, 0.0)], [(0.0, 0.0, 1.0)], off) == (0.0, 0.0)


def test_non_finite_entries_are_skipped_and_counted() -> None:
    nbrs = [(math.nan, 0.0), (0.2, math.inf), (0.2, 0.0)]
    obs = [(0.0, 0.0, -1.0), (0.0, 0.0, math.nan), (math.nan, 0.0, 0.1)]
    vx, vy, skipped = repulsion_velocity_counted(0.0, 0.0, nbrs, obs, P)
    assert skipped == 5
    assert (vx, vy) == pytest.approx((-law(0.2), 0.0))
    assert repulsion_velocity_counted(math.nan, 0.0, nbrs, obs, P) == (0.0, 0.0, 0)


@settings(max_examples=200, deadline=None, derandomize=True)
@given(
    px=any_float,
    py=any_float,
    nbrs=st.lists(st.tuples(any_float, any_float), max_size=4),
    obs=st.lists(st.tuples(any_float, any_float, any_float), max_size=3),
)
def test_never_nan_and_capped_for_any_input(
    px: float,
    py: float,
    nbrs: list[tuple[float, float]],
    obs: list[tuple[float, float, float]],
) -> None:
    vx, vy = repulsion_velocity(px, py, nbrs, obs, P)
    assert math.isfinite(vx) and math.isfinite(vy)
    assert math.hypot(vx, vy) <= P.max_speed_mps * (1 + 1e-12)


def test_huge_gain_overflow_keeps_direction() -> None:
    p = RepulsionParams(k_rep=1e300)
    vx, vy = repulsion_velocity(0.0, 0.0, [(1e-9, 0.0), (0.0, 1e-10)], [], p)
    assert math.isfinite(vx) and math.isfinite(vy)
    assert vx < 0.0 and vy < 0.0
    assert math.hypot(vx, vy) == pytest.approx(p.max_speed_mps)


def test_params_validation() -> None:
    with pytest.raises(ValueError):
        RepulsionParams(d0_m=0.0)
    with pytest.raises(ValueError):
        RepulsionParams(k_rep=math.inf)
