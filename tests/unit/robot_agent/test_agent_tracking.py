"""Tracking law of robot_agent (eqs 21-22): PID with feed-forward, anti-windup, no kicks."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from robot_agent.core.params import TrackingGains
from robot_agent.core.tracking import AxisPID, PIDInfo, TrackingController

G = TrackingGains()
KP, TI, TD = G.kp, G.ti_s, G.td_s

errors = st.floats(min_value=-100.0, max_value=100.0, allow_nan=False)
any_float = st.floats(allow_nan=True, allow_infinity=True)


# ----------------------------------------------------------------------------- (a) the poles


def test_ideal_closed_loop_poles_are_the_papers_design() -> None:
    """(a) (1 + Kp Td) s^2 + Kp s + Kp/Ti from the defaults has roots -0.2 and -0.01."""
    g = TrackingGains()
    roots = np.roots([1.0 + g.kp * g.td_s, g.kp, g.kp / g.ti_s])
    assert np.all(np.abs(roots.imag) < 1e-12)
    fast, slow = sorted(roots.real)
    assert fast == pytest.approx(-0.2, abs=1e-3)
    assert slow == pytest.approx(-0.01, abs=1e-3)
    # The printed eqs 23-24 drop the Kp factors: (1 + Td) s^2 + s + 1/Ti. Not what we built.
    printed = sorted(np.roots([1.0 + g.td_s, 1.0, 1.0 / g.ti_s]).real)
    assert printed[0] == pytest.approx(-0.980, abs=1e-3)
    assert printed[1] == pytest.approx(-0.0096, abs=1e-4)
    assert abs(printed[0] - fast) > 0.5


def test_closed_loop_on_ideal_integrator_follows_design_response() -> None:
    """(a) The controller on p_r' = command, dt = 0.01, tracking a moving target with feed-forward:
    e(t) = 1.053 e0 exp(-0.2 t) - 0.053 e0 exp(-0.01 t) per axis within 2 % of e0 for 0..60 s."""
    ctl = TrackingController(TrackingGains())
    dt = 0.01
    e0 = (0.05, -0.03)

    def target(t: float) -> tuple[float, float, float, float]:
        # A straight run in x with a slow weave in y: position (m) and velocity (m/s).
        return 0.1 * t, 0.5 * math.sin(0.1 * t), 0.1, 0.05 * math.cos(0.1 * t)

    tx, ty, _, _ = target(0.0)
    px, py = tx - e0[0], ty - e0[1]
    worst = 0.0
    for k in range(6001):
        t = k * dt
        tx, ty, fx, fy = target(t)
        ex, ey = tx - px, ty - py
        for e, e_init in ((ex, e0[0]), (ey, e0[1])):
            model = 1.053 * e_init * math.exp(-0.2 * t) - 0.053 * e_init * math.exp(-0.01 * t)
            worst = max(worst, abs(e - model) / abs(e_init))
        ux, uy = ctl.update(ex, ey, fx, fy, dt)
        px += dt * ux
        py += dt * uy
    assert worst < 0.02
    # The integral peaked at ~5.3 e0 (0.26 m*s): the clamp (0.5) never bound.
    assert abs(ctl.x.integral_ms) < G.integral_limit_ms


def test_closed_loop_undershoot_matches_paper_math_note() -> None:
    """With the paper's gains the ideal loop overshoots to about -3.6 % of e0 near 30 s."""
    pid = AxisPID(TrackingGains())
    dt, e, e_min, t_min = 0.01, 1e-2, 0.0, 0.0
    e0 = e
    for k in range(1, 10001):
        e -= dt * pid.update(e, dt)  # target still: edot = -command
        if e < e_min:
            e_min, t_min = e, k * dt
    assert e_min / e0 == pytest.approx(-0.036, abs=0.003)
    assert 25.0 < t_min < 35.0


# ----------------------------------------------------------------------------- AxisPID


def test_all_zero() -> None:
    pid = AxisPID(G)
    assert pid.update(0.0, 0.01) == 0.0
    assert pid.integral_ms == 0.0
    ctl = TrackingController(G)
    assert ctl.update(0.0, 0.0, 0.0, 0.0, 0.01) == (0.0, 0.0)


def test_first_sample_has_no_derivative_kick() -> None:
    pid = AxisPID(G)
    out = pid.update(1.0, 0.01)
    assert out == pytest.approx(KP * (1.0 + 0.01 / TI))
    assert pid.snapshot().d_term == 0.0
    pid.reset()
    assert pid.update(-2.0, 0.01) == pytest.approx(KP * (-2.0 - 0.02 / TI))


def test_derivative_is_low_pass_filtered_difference() -> None:
    g = TrackingGains(kp=1.0, ti_s=1e9, td_s=1.0, d_filter_tau_s=0.1)
    pid = AxisPID(g)
    dt, rate = 0.01, 0.5  # error ramps at 0.5 m/s
    pid.update(0.0, dt)
    alpha = dt / (0.1 + dt)
    expected = 0.0
    for k in range(1, 200):
        pid.update(rate * k * dt, dt)
        expected += alpha * (rate - expected)
        assert pid.snapshot().edot_filtered == pytest.approx(expected, rel=1e-9)
    assert pid.snapshot().edot_filtered == pytest.approx(rate, rel=1e-6)


def test_unfiltered_derivative_when_tau_zero() -> None:
    pid = AxisPID(TrackingGains(kp=1.0, td_s=1.0, d_filter_tau_s=0.0, ti_s=1e9))
    pid.update(0.0, 0.1)
    pid.update(0.3, 0.1)
    assert pid.snapshot().edot_filtered == pytest.approx(3.0)


@pytest.mark.parametrize("dt", [0.0, -0.01, math.nan, math.inf, -math.inf])
def test_bad_dt_updates_no_state_and_returns_p_plus_stored_i(dt: float) -> None:
    pid = AxisPID(G)
    pid.update(0.2, 0.01)
    pid.update(0.3, 0.01)
    before = pid.snapshot()
    out = pid.update(5.0, dt)
    assert out == pytest.approx(KP * (5.0 + before.integral_ms / TI))
    after = pid.snapshot()
    assert after.integral_ms == before.integral_ms
    assert after.edot_filtered == before.edot_filtered
    assert after.d_term == 0.0
    # The previous error was not overwritten: the next derivative uses 0.3, not 5.0.
    pid.update(0.3, 0.01)
    assert pid.snapshot().edot_filtered == pytest.approx(before.edot_filtered * 0.1 / 0.11)


@pytest.mark.parametrize("err", [math.nan, math.inf, -math.inf])
def test_non_finite_error_returns_zero_and_keeps_state(err: float) -> None:
    pid = AxisPID(G)
    pid.update(0.4, 0.01)
    before = pid.snapshot()
    assert pid.update(err, 0.01) == 0.0
    assert pid.snapshot() == before


def test_integral_clamped() -> None:
    pid = AxisPID(G)
    for _ in range(2000):
        pid.update(10.0, 0.01)
    assert pid.integral_ms == G.integral_limit_ms
    assert pid.snapshot().limited
    for _ in range(2000):
        pid.update(-10.0, 0.01)
    assert pid.integral_ms == -G.integral_limit_ms


def test_frozen_integrator_may_only_shrink() -> None:
    pid = AxisPID(G)
    for _ in range(10):
        pid.update(1.0, 0.01)
    i0 = pid.integral_ms
    pid.update(1.0, 0.01, freeze_integrator=True)  # would grow: held
    assert pid.integral_ms == i0
    assert pid.snapshot().frozen
    pid.update(-1.0, 0.01, freeze_integrator=True)  # shrinks: allowed
    assert pid.integral_ms == pytest.approx(i0 - 0.01)


@settings(max_examples=200, deadline=None, derandomize=True)
@given(
    seq=st.lists(
        st.tuples(any_float, any_float, st.booleans()),
        min_size=1,
        max_size=60,
    )
)
def test_integrator_bounded_under_any_sequence(seq: list[tuple[float, float, bool]]) -> None:
    pid = AxisPID(G)
    for err, dt, freeze in seq:
        before = pid.integral_ms
        out = pid.update(err, dt, freeze)
        assert abs(pid.integral_ms) <= G.integral_limit_ms
        assert math.isfinite(pid.integral_ms)
        assert math.isfinite(pid.snapshot().edot_filtered)
        if freeze:
            assert abs(pid.integral_ms) <= abs(before)
        if math.isfinite(err):
            assert math.isfinite(out) or abs(err) > 1e300


# ----------------------------------------------------------------------------- TrackingController


def test_feed_forward_passes_through() -> None:
    ctl = TrackingController(G)
    assert ctl.update(0.0, 0.0, 0.1, -0.05, 0.01) == (0.1, -0.05)


def test_speed_cap_keeps_direction_and_freezes_integrator() -> None:
    ctl = TrackingController(G)
    vx, vy = ctl.update(3.0, 4.0, 0.0, 0.0, 0.01)
    assert math.hypot(vx, vy) == pytest.approx(G.max_ref_speed_mps)
    assert vx / vy == pytest.approx(3.0 / 4.0)
    assert ctl.speed_limited
    ix = ctl.x.integral_ms
    ctl.update(3.0, 4.0, 0.0, 0.0, 0.01)  # cap bound the previous output: integral frozen
    assert ctl.x.integral_ms == ix


@settings(max_examples=200, deadline=None, derandomize=True)
@given(ex=any_float, ey=any_float, fx=any_float, fy=any_float, dt=any_float)
def test_controller_output_bounded_and_finite(
    ex: float, ey: float, fx: float, fy: float, dt: float
) -> None:
    ctl = TrackingController(G)
    ctl.update(0.01, -0.02, 0.0, 0.0, 0.01)
    vx, vy = ctl.update(ex, ey, fx, fy, dt)
    assert math.isfinite(vx) and math.isfinite(vy)
    assert math.hypot(vx, vy) <= G.max_ref_speed_mps * (1 + 1e-12)
    if not all(math.isfinite(v) for v in (ex, ey, fx, fy)):
        assert (vx, vy) == (0.0, 0.0)
        assert not ctl.last_valid


def test_reset_and_snapshot() -> None:
    ctl = TrackingController(G)
    for _ in range(5):
        ctl.update(0.1, -0.1, 0.0, 0.0, 0.01)
    sx, sy = ctl.snapshot()
    assert isinstance(sx, PIDInfo)
    assert sx.output == pytest.approx(sx.p_term + sx.i_term + sx.d_term)
    assert sx.integral_ms == pytest.approx(0.005)
    assert sy.integral_ms == pytest.approx(-0.005)
    assert set(sx.as_dict()) >= {"p", "i", "d", "out", "integral"}
    ctl.reset()
    assert ctl.x.integral_ms == 0.0 and ctl.y.integral_ms == 0.0
    assert ctl.update(0.1, 0.0, 0.0, 0.0, 0.01)[0] == pytest.approx(KP * (0.1 + 0.001 / TI))


def test_gains_validation() -> None:
    with pytest.raises(ValueError):
        TrackingGains(ti_s=0.0)
    with pytest.raises(ValueError):
        TrackingGains(kp=math.nan)
    with pytest.raises(ValueError):
        TrackingGains(max_ref_speed_mps=-1.0)


def _bits(info: PIDInfo) -> tuple[object, ...]:
    """A snapshot's fields with every float as its exact bits (``float.hex``): NaN equals NaN.
    (``==`` on the snapshots compares NaN fields by identity, which only held while both read
    the same float object; compiled, every read boxes a new one.)"""
    return tuple(v.hex() if isinstance(v, float) else v for v in dataclasses.astuple(info))


@settings(max_examples=100, deadline=None, derandomize=True)
@given(
    seq=st.lists(
        st.tuples(
            st.floats(-2.0, 2.0),
            st.floats(-2.0, 2.0),
            st.floats(-0.3, 0.3),
            st.sampled_from([0.02, 0.01, 0.0, -0.02, math.nan, math.inf, 0.2]),
            st.booleans(),
        ),
        min_size=1,
        max_size=80,
    )
)
def test_controller_update_is_bit_for_bit_two_axis_updates(
    seq: list[tuple[float, float, float, float, bool]],
) -> None:
    """``TrackingController.update`` inlines ``AxisPID.update`` of both axes: the same bits,
    the same state and snapshots as two ``AxisPID``s plus the feed-forward and the speed cap."""
    ctl = TrackingController(G)
    ax, ay = AxisPID(G), AxisPID(G)
    limited = False
    for ex, ey, ff, dt, freeze in seq:
        got = ctl.update(ex, ey, ff, -ff, dt, freeze)
        fr = freeze or limited
        ux = ff + ax.update(ex, dt, fr)
        uy = -ff + ay.update(ey, dt, fr)
        speed = math.hypot(ux, uy)
        limited = speed > G.max_ref_speed_mps
        if limited:
            k = G.max_ref_speed_mps / speed
            ux, uy = ux * k, uy * k
        assert got == (ux, uy)
        assert ctl.speed_limited == limited
        sx, sy = ctl.snapshot()
        assert (_bits(sx), _bits(sy)) == (_bits(ax.snapshot()), _bits(ay.snapshot()))
        assert ctl.x._edot == ax._edot and ctl.y._prev_error == ay._prev_error
