"""The firmware's pose estimator (robot_agent/core/estimator.py) and its use in the firmware."""

from __future__ import annotations

import bisect
import dataclasses
import itertools
import math
import random

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from robot_agent.core.estimator import Estimator, propagate_pose
from robot_agent.core.estimator_math import chain_at, last_at_or_before
from robot_agent.core.firmware import Firmware, Mode, Pose, Setpoint
from robot_agent.core.params import AgentConfig, EstimatorParams
from sim_plant.core.encoders import WheelEncoders
from sim_plant.core.plant import Plant

DT = 0.02
P = EstimatorParams(enabled=True)


def _close(a: tuple[float, ...], b: tuple[float, ...], tol: float = 1e-12) -> bool:
    return all(abs(x - y) <= tol for x, y in zip(a, b, strict=True))


# ---------------------------------------------------------------- prediction


def test_prediction_is_the_exact_arc_of_a_constant_twist() -> None:
    est = Estimator(P)
    v, w = 0.1, 0.5  # a circle of radius 0.2 m
    est.add_command(0.0, v, w)
    assert est.add_measurement(0.0, 0.0, 0.0, 0.0, 0.0) is None
    t = 0.25  # within the dropout bound
    got = est.estimate(t)
    assert got is not None
    rad = v / w
    exp = (rad * math.sin(w * t), rad * (1.0 - math.cos(w * t)), w * t)
    assert _close(got[:3], exp, 1e-12)


def test_latency_is_compensated_from_the_capture_time() -> None:
    """A pose captured 60 ms ago is moved forward by the twist driven since then."""
    est = Estimator(P)
    est.add_command(0.0, 0.2, 0.0)
    est.add_measurement(0.06, 0.0, 1.0, 2.0, 0.0)
    got = est.estimate(0.06)
    assert got is not None
    assert got[0] == pytest.approx(1.0 + 0.2 * 0.06, abs=1e-12)
    assert got[1] == pytest.approx(2.0)


# ---------------------------------------------------------------- replay == batch


def _run_live_and_batch(
    twists: list[tuple[float, float]], meas: list[tuple[float, float, float, float, float]]
) -> tuple[tuple[float, ...], tuple[float, ...], Estimator]:
    """``meas`` = (capture t, arrival t, x, y, theta). The live estimator gets odometry every
    tick and each pose at its arrival tick; the batch one all odometry, then the poses in
    capture order."""
    params = dataclasses.replace(P, meas_pos_std_m=0.003, meas_theta_std_rad=0.01, gate_m=10.0)
    live = Estimator(params)
    n = len(twists)
    meas = [m for m in meas if m[1] <= n * DT]  # what arrives before the end
    for k in range(1, n + 1):
        now = k * DT
        v, w = twists[k - 1]
        live.add_odometry((k - 1) * DT, now, v, w)
        for t, arr, x, y, th in sorted(meas, key=lambda m: m[1]):
            if (k - 1) * DT < arr <= now:
                assert live.add_measurement(now, t, x, y, th) is None
    batch = Estimator(params)
    for k in range(1, n + 1):
        v, w = twists[k - 1]
        batch.add_odometry((k - 1) * DT, k * DT, v, w)
    for t, _, x, y, th in sorted(meas):
        assert batch.add_measurement(t, t, x, y, th) is None
    end = n * DT
    a = live.estimate(end)
    b = batch.estimate(end)
    assert a is not None and b is not None
    return a, b, live


@settings(max_examples=60, deadline=None, derandomize=True)
@given(seed=st.integers(0, 10_000), latency_ticks=st.integers(0, 8))
def test_late_measurements_replayed_equal_the_batch_solution(seed: int, latency_ticks: int) -> None:
    rng = random.Random(seed)
    n = 40
    twists = [(rng.uniform(-0.3, 0.3), rng.uniform(-2.0, 2.0)) for _ in range(n)]
    meas = []
    x = y = th = 0.0
    for k in range(n):
        if k % 2 == 0:
            t = k * DT + rng.uniform(0.0, DT * 0.9)
            delay = rng.uniform(0.0, latency_ticks * DT)  # random: arrivals out of order
            meas.append((t, t + delay, x + rng.gauss(0, 0.003), y + rng.gauss(0, 0.003), th + 0.01))
        x, y, th = propagate_pose(x, y, th, *twists[k], DT)
    a, b, live = _run_live_and_batch(twists, meas)
    assert _close(a, b, 1e-9)
    arrivals = [m[0] for m in sorted(meas, key=lambda m: m[1]) if m[1] <= len(twists) * DT]
    if arrivals != sorted(arrivals):
        assert live.replayed > 0  # arrivals out of capture order were replayed


def test_cold_start_from_a_later_pose_replays_from_the_older_one() -> None:
    twists = [(0.2, 0.3)] * 20
    meas = [(0.05, 0.30, 0.01, 0.0, 0.0), (0.10, 0.12, 0.02, 0.0, 0.0)]
    a, b, live = _run_live_and_batch(twists, meas)
    assert live.replayed == 1
    assert _close(a, b, 1e-12)


def test_out_of_order_arrival_is_replayed_and_counted() -> None:
    twists = [(0.2, 0.3)] * 20
    meas = [
        (0.01, 0.02, 0.0, 0.0, 0.0),
        (0.05, 0.30, 0.01, 0.0, 0.0),
        (0.10, 0.12, 0.02, 0.0, 0.0),
    ]
    a, b, live = _run_live_and_batch(twists, meas)
    assert live.replayed == 1
    assert _close(a, b, 1e-12)


def test_odometry_for_an_interval_already_fused_replays() -> None:
    """Encoder speeds that arrive after a pose captured in their interval re-fuse that pose."""
    params = dataclasses.replace(P, meas_pos_std_m=0.003)
    late = Estimator(params)
    late.add_measurement(0.0, 0.0, 0.0, 0.0, 0.0)
    late.add_measurement(0.05, 0.05, 0.01, 0.0, 0.0)
    late.add_odometry(0.0, 0.05, 0.2, 0.0)  # covers the second pose's interval
    batch = Estimator(params)
    batch.add_measurement(0.0, 0.0, 0.0, 0.0, 0.0)
    batch.add_odometry(0.0, 0.05, 0.2, 0.0)
    batch.add_measurement(0.05, 0.05, 0.01, 0.0, 0.0)
    a, b = late.estimate(0.06), batch.estimate(0.06)
    assert a is not None and b is not None
    assert _close(a, b)
    assert late.replayed == 1


@settings(max_examples=80, deadline=None, derandomize=True)
@given(
    seed=st.integers(0, 10_000),
    latency_ticks=st.integers(0, 4),
    odometry=st.booleans(),
    delay_s=st.sampled_from([0.0, 0.007, 0.02]),
)
def test_tick_is_bit_for_bit_the_three_calls(
    seed: int, latency_ticks: int, odometry: bool, delay_s: float
) -> None:
    """``Estimator.tick`` (the firmware's one call per step, hot paths inlined) gives exactly the
    bits of ``add_odometry`` / ``add_command``, ``add_measurement`` and ``estimate``, with
    capture times on and off the ticks, late, out of order, repeated, implausible or
    non-finite, gaps in the camera and encoder speeds, and rejections."""
    rng = random.Random(seed)
    params = dataclasses.replace(P, meas_pos_std_m=0.003, meas_theta_std_rad=0.01)
    calls, tick = Estimator(params), Estimator(params)
    x = y = 0.0
    th = 3.0  # crosses +-pi: wrapping on both paths
    last = math.nan
    for k in range(120):
        now = k * DT
        v, w = rng.uniform(-0.3, 0.3), rng.uniform(-3.0, 3.0)
        seg = last if (k > 0 and rng.random() < 0.9) else math.nan
        if seg == seg:
            if odometry:
                calls.add_odometry(seg, now, v, w)
            else:
                seg = now - DT + delay_s
                calls.add_command(seg, v, w)
        cap: float | None = None
        r = rng.random()
        if r < 0.75:  # a pose captured 0..latency ticks ago, on a tick or between
            cap = now - rng.randint(0, latency_ticks) * DT - (0.0 if r < 0.5 else 0.003)
        elif r < 0.8:
            cap = now - rng.uniform(0.0, 0.3)  # late: replayed
        mx, my, mth = x + rng.gauss(0, 0.003), y + rng.gauss(0, 0.003), th + rng.gauss(0, 0.01)
        if rng.random() < 0.03:
            mx = math.nan
        elif rng.random() < 0.03:
            mx += 1.0  # implausible
        want_reason = None
        if cap is not None:
            want_reason = calls.add_measurement(now, cap, mx, my, mth)
        want = calls.estimate(now)
        got = tick.tick(now, seg, v, w, odometry, cap, mx, my, mth)
        assert got == want, (k, got, want)
        if cap is not None:
            assert tick.last_reason == want_reason
        assert tick.status() == calls.status()
        # the head (the chain at _head_t, reused by the next segment) is the chain there while
        # the node it was computed from is still the newest
        for est in (calls, tick):
            if est._nodes and est._head_t == est._head_t and est._nodes[-1].t == est._head_nt:
                head = (est._h_ox, est._h_oy, est._h_oth, est._h_d, est._h_tu, est._h_q)
                assert head == chain_at(
                    est._nodes, est._node_t, params.cmd_pos_var_per_s, est._head_t
                )
        x, y, th = propagate_pose(x, y, th, v, w, DT)
        last = now


# ---------------------------------------------------------------- dropout bound, uncertainty


@pytest.mark.parametrize("odometry", [False, True])
def test_dropout_bound_valid_up_to_it_invalid_after(odometry: bool) -> None:
    est = Estimator(P)
    est.add_measurement(0.0, 0.0, 0.0, 0.0, 0.0)
    bound = P.max_dropout_odom_s if odometry else P.max_dropout_cmd_s
    prev = 0.0
    unc = []
    k = 1
    while True:
        now = k * DT
        if odometry:
            est.add_odometry(prev, now, 0.1, 0.0)
        else:
            est.add_command(prev, 0.1, 0.0)
        prev = now
        got = est.estimate(now)
        if now <= bound - 1e-9:
            assert got is not None, now
            unc.append(got[3])
        elif now > bound + 1e-9:
            assert got is None, now
            break
        k += 1
    assert all(b > a for a, b in itertools.pairwise(unc))  # grows with time


def test_odometry_stops_counting_after_its_timeout() -> None:
    est = Estimator(P)
    est.add_measurement(0.0, 0.0, 0.0, 0.0, 0.0)
    est.add_odometry(0.0, 0.02, 0.0, 0.0)
    assert est.estimate(0.02 + P.odom_timeout_s) is not None
    # no encoder speeds for longer than the timeout and past the commanded-only bound
    assert est.estimate(P.max_dropout_cmd_s + 0.05) is None


def test_odometry_drift_bounded_with_quantised_slipping_encoders() -> None:
    """1.5 s on encoders alone (1000 counts/rev, 2 % slip) around a curve: the estimate stays
    within 2 cm of the truth and within its own reported uncertainty."""
    from robot_agent.core.params import RobotGeometry

    geom = RobotGeometry()
    plant = Plant(np.array([[0.0, 0.0, 0.3]]), geom)
    enc = WheelEncoders(1, 1000.0, 0.02, np.random.default_rng(3))
    enc.slip = [(0.02, -0.02)]  # the worst case of the draw, fixed
    est = Estimator(P)
    est.add_measurement(0.0, 0.0, 0.0, 0.0, 0.3)
    enc.read(0.0, plant.wheel_angles())
    cmd = (6.0, 4.0)
    for k in range(1, round(1.5 / DT) + 1):
        plant.step(DT, [cmd])
        now = k * DT
        wr, wl = enc.read(now, plant.wheel_angles())[0]  # type: ignore[index]
        r, half = geom.wheel_radius_m, geom.half_track_m
        est.add_odometry(now - DT, now, 0.5 * r * (wr + wl), 0.5 * r * (wr - wl) / half)
        got = est.estimate(now)
        assert got is not None
        x, y, _ = plant.truth_rows()[0]
        err = math.hypot(got[0] - x, got[1] - y)
        assert err < 0.02
        assert err <= got[3]


# ---------------------------------------------------------------- rejections


def test_non_finite_future_old_and_duplicate_poses_rejected_and_counted() -> None:
    est = Estimator(P)
    assert est.add_measurement(1.0, 1.0, 0.0, 0.0, 0.0) is None
    for bad in (math.nan, math.inf, -math.inf):
        assert est.add_measurement(1.0, 1.0, bad, 0.0, 0.0) is not None
        assert est.add_measurement(1.0, bad, 0.0, 0.0, 0.0) is not None
    assert est.rejected_nonfinite == 6
    assert est.add_measurement(1.0, 1.1, 0.0, 0.0, 0.0) is not None  # from the future
    assert est.rejected_future == 1
    assert est.add_measurement(2.0, 1.0 - P.max_latency_s - 0.5, 0.0, 0.0, 0.0) is not None
    assert est.add_measurement(1.0, 1.0, 0.0, 0.0, 0.0) is None  # the same pose again: ignored
    assert est.add_measurement(1.0, 1.0, 0.01, 0.0, 0.0) is not None  # same stamp, other pose
    assert est.rejected_duplicate == 1
    # after a gap the history holds only the newest pose: an older one cannot be replayed
    assert est.add_measurement(3.0, 3.0, 0.0, 0.0, 0.0) is None
    assert est.add_measurement(3.0, 2.9, 0.0, 0.0, 0.0) is not None
    assert est.rejected_old == 2
    assert est.status().rejected == 10
    assert est.accepted == 2


def test_non_finite_or_backwards_odometry_rejected_and_counted() -> None:
    est = Estimator(P)
    est.add_measurement(0.0, 0.0, 0.0, 0.0, 0.0)
    assert est.add_odometry(0.0, DT, 0.1, 0.0)
    before = est.estimate(DT)
    for t0, t1, v, w in ((DT, 2 * DT, math.nan, 0.0), (DT, 2 * DT, 0.1, math.inf),
                         (math.nan, 2 * DT, 0.1, 0.0), (2 * DT, DT, 0.1, 0.0)):  # fmt: skip
        assert not est.add_odometry(t0, t1, v, w)
    assert est.rejected_odometry == 4
    assert est.status().rejected == 4
    assert est.estimate(DT) == before  # nothing of them was used


def test_firmware_counts_bad_wheel_speeds_and_rides_on_the_prediction() -> None:
    fw = Firmware(CFG)
    sp = _sp(0.05, 0.0, 0.0, 0.0, 0.0)
    pose = Pose(0.0, 0.0, 0.0, 0.0)
    fw.step(0.0, pose=pose, pose_rx_s=0.0, pose_capture_s=0.0, setpoint=sp, setpoint_rx_s=0.0)
    bad: list[object] = [
        (math.nan, 1.0),
        (1.0, math.inf),
        ("a", 1.0),
        (1.0,),
        None,
        (1e308, -1e308),
    ]
    for k, ws in enumerate(bad, start=1):
        now = k * DT
        cmd = fw.step(now, pose=pose, pose_rx_s=0.0, pose_capture_s=0.0, setpoint=sp,
                      setpoint_rx_s=now, wheel_speeds=ws)  # type: ignore[arg-type]  # fmt: skip
        assert cmd.mode is Mode.TRACKING
        assert all(math.isfinite(c) for c in cmd[:4])
    st_ = fw.status()
    assert st_.rejected_count == 5  # None means "no encoders": not a rejection
    assert st_.last_reject_reason == "bad wheel speeds"


def test_implausible_jump_rejected_then_reset_after_a_run() -> None:
    est = Estimator(P)
    est.add_measurement(0.0, 0.0, 0.0, 0.0, 0.0)
    for k in range(1, P.reset_after):
        assert est.add_measurement(k * DT, k * DT, 1.0, 1.0, 0.0) is not None
    assert est.rejected_implausible == P.reset_after - 1
    assert est.add_measurement(P.reset_after * DT, P.reset_after * DT, 1.0, 1.0, 0.0) is None
    assert est.resets == 1
    got = est.estimate(P.reset_after * DT)
    assert got is not None and got[:2] == (1.0, 1.0)


@settings(max_examples=100, deadline=None, derandomize=True)
@given(
    vals=st.lists(
        st.tuples(
            st.floats(allow_nan=True, allow_infinity=True),
            st.floats(allow_nan=True, allow_infinity=True),
            st.floats(-10, 10),
        ),
        max_size=20,
    )
)
def test_estimate_never_non_finite_whatever_comes_in(
    vals: list[tuple[float, float, float]],
) -> None:
    est = Estimator(P)
    est.add_measurement(0.0, 0.0, 0.0, 0.0, 0.0)
    for k, (a, b, c) in enumerate(vals, start=1):
        now = k * DT
        est.add_odometry(now - DT, now, a, b)
        est.add_measurement(now, now - abs(c) * 0.01, a, b, c)
        got = est.estimate(now)
        if got is not None:
            assert all(math.isfinite(g) for g in got)


# ---------------------------------------------------------------- in the firmware

CFG = AgentConfig(estimator=EstimatorParams(enabled=True))


def _sp(x: float, y: float, vx: float, vy: float, t: float) -> Setpoint:
    return Setpoint(x, y, vx, vy, 0.0, 1, t)


def test_firmware_rides_through_a_dropout_then_holds() -> None:
    fw = Firmware(CFG)
    pose = Pose(0.0, 0.0, 0.0, 0.0)
    last_mode = None
    for k in range(40):
        now = k * DT
        cmd = fw.step(
            now,
            pose=pose,
            pose_rx_s=0.0,
            pose_capture_s=0.0,
            setpoint=_sp(0.05, 0.0, 0.0, 0.0, now),
            setpoint_rx_s=now,
        )
        last_mode = cmd.mode
        if now <= CFG.estimator.max_dropout_cmd_s - 1e-9:
            assert cmd.mode is Mode.TRACKING, now
            assert math.isfinite(fw.pose_uncertainty_m)
    assert last_mode is Mode.HOLD
    assert fw.status().reason == "pose estimate invalid"


def test_firmware_rejects_and_counts_bad_poses_but_keeps_the_estimate() -> None:
    fw = Firmware(CFG)
    kw = {"setpoint": _sp(0.05, 0.0, 0.0, 0.0, 0.0), "setpoint_rx_s": 0.0}
    fw.step(0.0, pose=Pose(0.0, 0.0, 0.0, 0.0), pose_rx_s=0.0, pose_capture_s=0.0, **kw)  # type: ignore[arg-type]
    bad = Pose(math.nan, 0.0, 0.0, DT)
    for k in (1, 2):  # the same object twice: counted once
        cmd = fw.step(k * DT, pose=bad, pose_rx_s=DT, pose_capture_s=DT, **kw)  # type: ignore[arg-type]
        assert cmd.mode is Mode.TRACKING
    assert fw.status().rejected_count == 1
    est = fw.estimator
    assert est is not None and est.rejected_nonfinite == 1


def test_setpoint_extrapolation_removes_the_one_tick_lag() -> None:
    """A setpoint computed one tick ago with feed-forward v: the firmware aims at x + v dt."""
    for extrap in (False, True):
        cfg = AgentConfig(estimator=EstimatorParams(extrapolate_setpoint=extrap))
        fw = Firmware(cfg)
        l_m = cfg.geometry.ref_offset_m
        now = 1.0
        fw.step(
            now,
            pose=Pose(0.1 - l_m, 0.0, 0.0, now),
            pose_rx_s=now,
            setpoint=_sp(0.1 - 0.05 * DT, 0.0, 0.05, 0.0, now - DT),
            setpoint_rx_s=now - DT,
        )
        ex = fw.status().ex
        assert (abs(ex) < 1e-12) == extrap, ex


def test_setpoint_lead_aims_where_the_slot_will_be_after_the_actuation_lag() -> None:
    """``setpoint_lead_s`` advances the setpoint by ff * (age + lead): a robot whose reference
    point sits at x + v (dt + lead) has zero error; without extrapolation no lead is applied."""
    lead = 0.08
    for extrap in (False, True):
        cfg = AgentConfig(
            estimator=EstimatorParams(extrapolate_setpoint=extrap, setpoint_lead_s=lead)
        )
        fw = Firmware(cfg)
        l_m = cfg.geometry.ref_offset_m
        now = 1.0
        x_sp = 0.1 - 0.05 * (DT + lead)
        fw.step(
            now,
            pose=Pose(0.1 - l_m, 0.0, 0.0, now),
            pose_rx_s=now,
            setpoint=_sp(x_sp, 0.0, 0.05, 0.0, now - DT),
            setpoint_rx_s=now - DT,
        )
        ex = fw.status().ex
        if extrap:
            assert abs(ex) < 1e-12, ex
        else:
            assert ex == pytest.approx(-0.05 * (DT + lead))
    with pytest.raises(ValueError):
        EstimatorParams(setpoint_lead_s=-0.01)


def test_firmware_with_encoder_speeds_uses_the_odometry_bound() -> None:
    fw = Firmware(CFG)
    for k in range(60):
        now = k * DT
        cmd = fw.step(
            now,
            pose=Pose(0.0, 0.0, 0.0, 0.0),
            pose_rx_s=0.0,
            pose_capture_s=0.0,
            setpoint=_sp(0.05, 0.0, 0.0, 0.0, now),
            setpoint_rx_s=now,
            wheel_speeds=(0.0, 0.0),
        )
        assert cmd.mode is Mode.TRACKING  # 1.2 s without a camera pose, on odometry


@settings(max_examples=60, deadline=None, derandomize=True)
@given(
    gaps=st.lists(st.integers(1, 30), min_size=1, max_size=8),
    latency=st.floats(0.0, 0.1),
    odometry=st.booleans(),
)
def test_firmware_never_moves_past_the_dropout_bound(
    gaps: list[int], latency: float, odometry: bool
) -> None:
    """Camera poses every ``gap`` ticks, ``latency`` s old: whenever the newest capture is older
    than the bound for the odometry state, the wheels are exactly zero (HOLD)."""
    fw = Firmware(CFG)
    p = CFG.estimator
    bound = p.max_dropout_odom_s if odometry else p.max_dropout_cmd_s
    dt = 0.1
    k = 0
    last_cap: float | None = None
    pose: Pose | None = None  # the shell presents its latest pose every tick
    for gap in gaps:
        for g in range(gap):
            now = k * dt
            if g == 0:
                last_cap = now - latency
                pose = Pose(0.0, 0.0, 0.0, last_cap)
            cmd = fw.step(
                now,
                pose=pose,
                pose_rx_s=now,
                pose_capture_s=last_cap,
                setpoint=_sp(0.3, 0.1, 0.05, 0.0, now),
                setpoint_rx_s=now,
                wheel_speeds=(0.0, 0.0) if odometry else None,
            )
            assert last_cap is not None
            if now - last_cap > bound + 1e-9:
                assert cmd.mode is Mode.HOLD
                assert (cmd.omega_r, cmd.omega_l) == (0.0, 0.0)
            k += 1


@given(
    st.lists(st.floats(-10.0, 10.0), max_size=40, unique=True).map(sorted),
    st.floats(-11.0, 11.0),
)
def test_last_at_or_before_is_bisect_right_minus_one(times: list[float], t: float) -> None:
    """The node lookup of a camera pose (a scan back from the newest) finds what bisect does."""
    assert last_at_or_before(times, t) == bisect.bisect_right(times, t) - 1
