"""Issue 30, "Realtime precision": motion claims (robot_agent/core/neighbour_motion.py).

A robot with a motion bound ``A`` changes its command's body twist by at most ``A`` times the
elapsed time in every mode and publishes each command's reference-point velocity; a neighbour
extrapolates it with that velocity and inflates it by what the bound lets it deviate. These
tests try to break that: the limiter against any command sequence and every mode (an e-stop
included), the reachable set against any motion the bound allows, and the barrier against
neighbours that move adversarially within what they published, whose claims go stale, or whose
claims are absurd. Separation never goes below the barrier's distance.
"""

from __future__ import annotations

import itertools
import math
import random

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from robot_agent.core.firmware import Firmware, Mode, Pose, Setpoint
from robot_agent.core.neighbour_motion import (
    CLOCK_TOL_S,
    Claim,
    MotionLimiter,
    motion_view,
    view_is_sane,
)
from robot_agent.core.neighbours import ClaimRing, neighbour
from robot_agent.core.params import AgentConfig, EstimatorParams, SafetyFilterParams
from robot_agent.core.safety_filter import SafetyFilter

GEOM = AgentConfig().geometry
L_M = GEOM.ref_offset_m
VMAX = GEOM.max_speed_mps
WMAX = GEOM.max_wheel_radps
TOL = 1e-9


def _twist(wr: float, wl: float) -> tuple[float, float]:
    r = GEOM.wheel_radius_m
    return 0.5 * r * (wr + wl), L_M * r * (wr - wl) / (2.0 * GEOM.half_track_m)


def _limiter(a: float) -> MotionLimiter:
    return MotionLimiter(a, GEOM.wheel_radius_m, GEOM.half_track_m, L_M, WMAX)


wheel = st.floats(-WMAX, WMAX)


@settings(max_examples=200, deadline=None)
@given(
    a=st.floats(0.05, 20.0),
    steps=st.lists(
        st.tuples(st.floats(0.0, 0.3), wheel, wheel, st.floats(-4.0, 4.0)),
        min_size=1,
        max_size=40,
    ),
)
def test_limiter_bounds_every_change_and_claims_what_it_commands(
    a: float, steps: list[tuple[float, float, float, float]]
) -> None:
    lim = _limiter(a)
    now = 0.0
    prev = (0.0, 0.0)  # at rest before the first tick
    first = True
    for dt, wr, wl, th in steps:
        now += dt
        out_r, out_l = lim.limit(now, wr, wl, th)
        assert abs(out_r) <= WMAX and abs(out_l) <= WMAX  # exactly: power within [-1, 1]
        b = _twist(out_r, out_l)
        room = 0.0 if first else a * dt
        assert math.hypot(b[0] - prev[0], b[1] - prev[1]) <= room + 1e-12
        c = lim.claim
        assert c is not None and c.t_s == now and c.accel_mps2 == a
        # u = R(theta) (v, l omega) (eq 16 read backwards)
        assert c.ux_mps == pytest.approx(math.cos(th) * b[0] - math.sin(th) * b[1], abs=1e-12)
        assert c.uy_mps == pytest.approx(math.sin(th) * b[0] + math.cos(th) * b[1], abs=1e-12)
        prev = b
        first = False


def test_limiter_rejects_a_bound_out_of_range() -> None:
    for a in (0.0, -1.0, math.nan, math.inf, 101.0):
        with pytest.raises(ValueError):
            _limiter(a)


def _run_firmware(cfg: AgentConfig, estop_at: int, ticks: int) -> list[tuple[float, float]]:
    """A robot driven by a setpoint running away from it, e-stopped at tick ``estop_at``, its
    setpoint gone stale 10 ticks before the e-stop: TRACKING, HOLD, ESTOP. The wheels per tick."""
    fw = Firmware(cfg)
    out = []
    dt = 0.033
    x = y = th = 0.0
    for k in range(ticks):
        now = k * dt
        if k == estop_at:
            fw.engage_estop()
        sp_t = now if k < estop_at - 10 else (estop_at - 10) * dt
        sp = Setpoint(x + 0.5, y + 0.2, 0.2, 0.0, 0.0, 0, sp_t)
        cmd = fw.step(now, pose=Pose(x, y, th, now), pose_rx_s=now, setpoint=sp,
                      setpoint_rx_s=sp_t, pose_capture_s=now)  # fmt: skip
        out.append((cmd.omega_r, cmd.omega_l))
        v, lw = _twist(cmd.omega_r, cmd.omega_l)
        th += lw / L_M * dt
        x += v * math.cos(th) * dt
        y += v * math.sin(th) * dt
    assert fw.mode is Mode.ESTOP
    return out


@pytest.mark.parametrize("est", [False, True])
def test_firmware_keeps_its_bound_in_every_mode_and_an_estop_ramps_down(est: bool) -> None:
    a = 0.5
    cfg = AgentConfig(
        safety_filter=SafetyFilterParams(accel_bound_mps2=a),
        estimator=EstimatorParams(enabled=est),
    )
    wheels = _run_firmware(cfg, estop_at=40, ticks=80)
    twists = [_twist(*w) for w in wheels]
    for (v0, w0), (v1, w1) in itertools.pairwise(twists):
        assert math.hypot(v1 - v0, w1 - w0) <= a * 0.033 + 1e-12
    assert max(abs(v) for v, _ in twists[:40]) > 0.1  # it did drive
    assert twists[40] != (0.0, 0.0)  # the e-stop ramps (0.5 m/s^2 from > 0.1 m/s)
    assert twists[-1] == (0.0, 0.0)  # and ends at rest
    # without a bound the e-stop is immediate: the default is unchanged
    free = _run_firmware(AgentConfig(estimator=EstimatorParams(enabled=est)), 40, 42)
    assert free[40] == (0.0, 0.0)


# ----------------------------------------------------------------- the neighbour's reachable set


def _simulate_neighbour(
    rng: random.Random, a: float, tick_s: float, horizon_s: float, fine_s: float
) -> tuple[list[Claim], list[tuple[float, float, float, float, float]]]:
    """A unicycle whose body twist changes at its ticks by at most ``a`` tick (any direction,
    adversarially random, within the wheel box), integrated finely. Returns its claims and
    samples ``(t, ref x, ref y, ux, uy)``."""
    x, y, th = 0.0, 0.0, rng.uniform(-math.pi, math.pi)
    v, lw = rng.uniform(-0.1, 0.1), rng.uniform(-0.05, 0.05)
    claims: list[Claim] = []
    samples = []
    t = 0.0
    next_tick = 0.0
    while t <= horizon_s + 1e-12:
        if t >= next_tick - 1e-12:
            ang = rng.uniform(-math.pi, math.pi)
            mag = a * tick_s * rng.choice((1.0, 1.0, rng.random()))
            nv, nlw = v + mag * math.cos(ang), lw + mag * math.sin(ang)
            wr = (nv + GEOM.half_track_m * nlw / L_M) / GEOM.wheel_radius_m
            wl = (nv - GEOM.half_track_m * nlw / L_M) / GEOM.wheel_radius_m
            if abs(wr) <= WMAX and abs(wl) <= WMAX:
                v, lw = nv, nlw
            c, s = math.cos(th), math.sin(th)
            claims.append(Claim(t, c * v - s * lw, s * v + c * lw, lw / L_M, a))
            next_tick += tick_s
        c, s = math.cos(th), math.sin(th)
        samples.append((t, x + L_M * c, y + L_M * s, c * v - s * lw, s * v + c * lw))
        th += lw / L_M * fine_s / 2
        x += v * math.cos(th) * fine_s
        y += v * math.sin(th) * fine_s
        th += lw / L_M * fine_s / 2
        t += fine_s
    return claims, samples


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 2**31),
    a=st.floats(0.1, 3.0),
    tick_s=st.floats(0.01, 0.06),
    latency_s=st.floats(0.0, 0.15),
    claim_delay_s=st.floats(0.0, 0.05),
)
def test_any_motion_the_bound_allows_stays_in_the_claimed_reachable_set(
    seed: int, a: float, tick_s: float, latency_s: float, claim_delay_s: float
) -> None:
    fine = 0.001
    claims, samples = _simulate_neighbour(random.Random(seed), a, tick_s, 0.4, fine)
    dt_next = 0.033
    for k in range(len(samples) // 3, len(samples) - int(dt_next / fine) - 1, 37):
        now, _, _, _, _ = samples[k]
        cap_k = max(0, k - int(latency_s / fine))
        t_cap, cx, cy, _, _ = samples[cap_k]
        known = [c for c in claims if c.t_s <= now - claim_delay_s]
        view = motion_view(known, t_cap, now, L_M, VMAX, 0.25)
        if view is None:
            continue
        assert view_is_sane(view)
        sx, sy, r, ux, uy, tau, e0, e1, e2 = view
        _, nx_, ny_, _, _ = samples[k]
        # the position now is within r of the capture plus the claimed shift
        assert math.hypot(nx_ - (cx + sx), ny_ - (cy + sy)) <= r + 1e-6
        # the velocity over the next tick is within e(tau + s) of the claimed one
        for j in range(k, k + int(dt_next / fine)):
            t, _, _, vx, vy = samples[j]
            tt = tau + (t - now)
            assert math.hypot(vx - ux, vy - uy) <= e0 + e1 * tt + e2 * tt * tt + 1e-9


def test_views_fall_back_to_the_worst_case_when_claims_are_missing_stale_or_absurd() -> None:
    good = [Claim(0.0, 0.05, 0.0, 0.0, 0.5), Claim(0.033, 0.05, 0.0, 0.0, 0.5)]
    assert motion_view(good, 0.01, 0.07, L_M, VMAX, 0.25) is not None
    assert motion_view([], 0.01, 0.07, L_M, VMAX, 0.25) is None  # missing
    assert motion_view(good, 0.01, 0.5, L_M, VMAX, 0.25) is None  # stale
    assert motion_view(good, -0.01, 0.07, L_M, VMAX, 0.25) is None  # none before the capture
    assert motion_view(good, 0.01, 0.0, L_M, VMAX, 0.25) is None  # from the future
    for bad in (
        Claim(0.033, math.nan, 0.0, 0.0, 0.5),
        Claim(0.033, 5.0, 0.0, 0.0, 0.5),  # faster than any robot
        Claim(0.033, 0.05, 0.0, 0.0, 0.0),  # no bound
        Claim(0.033, 0.05, 0.0, 0.0, 1e6),  # an absurd one
        Claim(0.033, 0.05, 0.0, math.inf, 0.5),
    ):
        assert motion_view([good[0], bad], 0.01, 0.07, L_M, VMAX, 0.25) is None
    for bad_view in ((0.0,) * 8, (math.nan,) * 9, (0.0, 0.0, -1.0, 0, 0, 0, 0, 0, 0), "x"):
        assert not view_is_sane(bad_view)


def test_a_ring_keeps_only_newer_claims() -> None:
    ring = ClaimRing()
    assert ring.add(Claim(1.0, 0.0, 0.0, 0.0, 0.5))
    assert not ring.add(Claim(1.0, 0.0, 0.0, 0.0, 0.5))  # a replay
    assert not ring.add(Claim(0.5, 0.0, 0.0, 0.0, 0.5))  # reordered
    assert ring.dropped == 2 and len(ring.claims) == 1


# ------------------------------------------------------------------ the barrier, in closed loop

CFG = AgentConfig(
    safety_filter=SafetyFilterParams(accel_bound_mps2=0.5),
    estimator=EstimatorParams(enabled=False),
)
D_COOP = CFG.safety_distance_m + 2.0 * L_M  # reference point to reference point
#: the neighbour's top speed here: a robot can flee only a neighbour that approaches slower
#: than its own cap (``max_ref_speed_mps``, 0.25 m/s) less the claim's error (~0.05 m/s)
VJ = 0.15


@settings(max_examples=30, deadline=None)
@given(
    seed=st.integers(0, 2**31),
    latency_s=st.floats(0.0, 0.12),
    claim_delay_s=st.floats(0.0, 0.03),
    phase_s=st.floats(0.0, 0.033),
    kind=st.sampled_from(["honest", "honest", "stale", "absurd"]),
    cooperative=st.booleans(),
    bearing=st.floats(-math.pi, math.pi),
)
def test_the_barrier_holds_against_a_neighbour_that_moves_any_way_its_claims_allow(
    seed: int,
    latency_s: float,
    claim_delay_s: float,
    phase_s: float,
    kind: str,
    cooperative: bool,
    bearing: float,
) -> None:
    """Robot i (a reference point that moves as commanded: the filter's model, eq 16) wants to
    drive through a neighbour j; j charges at i, swerves and brakes within its bound ``A``
    (single-integrator reference point, heading 0, up to ``VJ``), ticking at its own phase. Its
    claims reach i after ``claim_delay_s``, its poses after ``latency_s``; a stale neighbour
    stops publishing after 0.3 s, an absurd one publishes NaN (both: the worst case, the row of
    before, while j brakes to rest)."""
    rng = random.Random(seed)
    a = CFG.safety_filter.accel_bound_mps2
    filt = SafetyFilter(CFG)
    dt, fine = 0.033, 0.0033
    pi = [0.0, 0.0]
    pj = [pi[0] + 0.4 * math.cos(bearing), pi[1] + 0.4 * math.sin(bearing)]
    uj = [0.0, 0.0]
    ui = (0.0, 0.0)
    hist: list[tuple[float, float, float]] = []  # (t, ref x, ref y) of j
    claims: list[Claim] = []
    t, next_i, next_j = 0.0, 0.0, phase_s
    least = least_centre = math.inf
    goal = (-pj[0] + 2 * pi[0], -pj[1] + 2 * pi[1])  # i's goal: through j, beyond it
    while t < 2.5:
        hist.append((t, pj[0], pj[1]))
        if t >= next_j - 1e-12:  # j's tick: change its velocity by at most a dt_j
            if kind == "honest" or t < 0.3:  # charge, swerve, brake: anything within A
                dx, dy = pi[0] - pj[0], pi[1] - pj[1]
                ang = math.atan2(dy, dx) + rng.uniform(-1.5, 1.5)
                mag = a * dt * rng.choice((1.0, 1.0, rng.random()))
                nx_, ny_ = uj[0] + mag * math.cos(ang), uj[1] + mag * math.sin(ang)
                if math.hypot(nx_, ny_) <= VJ:
                    uj = [nx_, ny_]
            else:  # its claims stopped or went absurd: it brakes to rest (at A)
                sp = math.hypot(uj[0], uj[1])
                k = max(0.0, sp - a * dt) / sp if sp > 0.0 else 0.0
                uj = [uj[0] * k, uj[1] * k]
            if kind == "honest" or (kind == "stale" and t < 0.3):
                claims.append(Claim(t, uj[0], uj[1], 0.0, a))
            elif kind == "absurd":
                claims.append(Claim(t, math.nan, uj[1], 0.0, a))
            next_j += dt
        if t >= next_i - 1e-12:  # i's tick: its filter on what it knows now
            cap = [h for h in hist if h[0] <= t - latency_s]
            if cap:
                tc, cx, cy = cap[-1]
                known = [c for c in claims if c.t_s <= t - claim_delay_s]
                view = motion_view(known, tc, t, L_M, VMAX, CFG.safety_filter.claim_max_age_s)
                if kind != "honest":
                    assert view is None or kind == "stale"
                # (a cooperative neighbour without claims is trusted to run the filter: only
                # an honest one is flagged so)
                coop = cooperative and kind == "honest"
                nb = neighbour(cx - L_M, cy, 0.0, tc, t, coop, view)
                ex, ey = goal[0] - pi[0], goal[1] - pi[1]
                k = 0.25 / max(math.hypot(ex, ey), 1e-9)
                ui = filt.filter(t, pi[0], pi[1], ex * k, ey * k, ex, ey, [nb], dt_s=dt)
            next_i += dt
        pi[0] += ui[0] * fine
        pi[1] += ui[1] * fine
        pj[0] += uj[0] * fine
        pj[1] += uj[1] * fine
        t += fine
        least = min(least, math.hypot(pi[0] - pj[0], pi[1] - pj[1]))
        least_centre = min(least_centre, math.hypot(pi[0] - pj[0] + L_M, pi[1] - pj[1]))
    if kind == "honest":  # the claimed row: the barrier's distance, never below (no noise)
        assert least >= D_COOP - 1e-6, least
    else:  # the worst case (V a; the row of before): the safety distance between centres
        assert least_centre >= CFG.safety_distance_m - 1e-6, least_centre


def test_clock_tolerance_is_small_against_the_latency() -> None:
    assert 0.0 < CLOCK_TOL_S <= 0.005


def test_held_wheels_are_the_previous_twist() -> None:
    lim = _limiter(0.5)
    lim.limit(0.0, 0.0, 0.0, 0.0)
    wr, wl = lim.limit(1.0, 5.0, 3.0, 0.0)  # room 0.5 m/s: within it
    assert lim.held_wheels() == pytest.approx((wr, wl), abs=1e-12)


def test_a_moving_robot_without_a_heading_stops_claiming_after_half_a_second() -> None:
    lim = _limiter(0.5)
    lim.limit(0.0, 5.0, 5.0, 0.3)  # (the first tick: at rest, heading known)
    for k in range(1, 40):
        lim.limit(k * 0.033, 5.0, 5.0, math.nan if k > 5 else 0.3)
        moving = lim.claim is not None and math.hypot(lim.claim.ux_mps, lim.claim.uy_mps) > 0
        assert (lim.claim is not None) == (k <= 5 + int(0.5 / 0.033)), k
        assert k <= 5 or lim.claim is None or moving
