"""Firmware of robot_agent: mode machine, staleness, estop latch, pipeline, PID resets, repulsion.

Bad input, time and the estimator's ride-through:
tests/unit/robot_agent/test_agent_firmware_inputs.py.
"""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from support.firmware_cases import (
    CFG,
    DT,
    EST,
    INF,
    NAN,
    WMAX,
    is_zero,
    make_sp,
    tick,
    tracking_fw,
)

from robot_agent.core.firmware import Firmware, Mode, Pose, Setpoint
from robot_agent.core.firmware_modes import _TRANSITIONS
from robot_agent.core.kinematics import (
    ref_point_velocity,
    reference_point,
    saturate_wheels,
    twist_from_ref_velocity,
    twist_from_wheels,
    wheels_from_twist,
)
from robot_agent.core.params import (
    AgentConfig,
    RepulsionParams,
    SafetyFilterParams,
    SafetyParams,
)
from robot_agent.core.repulsion import repulsion_velocity
from robot_agent.core.safety_filter import SafetyFilter
from robot_agent.core.tracking import TrackingController

GEOM = CFG.geometry
L_REF = GEOM.ref_offset_m
# ----------------------------------------------------------------------------- basics


def test_all_zero() -> None:
    """At the goal with no feed-forward: TRACKING with exactly zero wheels."""
    fw = Firmware(CFG)
    for k in range(3):
        cmd = tick(fw, k * DT, Pose(0.0, 0.0, 0.0, k * DT), make_sp(x=L_REF))
        assert cmd.mode is Mode.TRACKING
        assert is_zero(cmd)
        assert not cmd.saturated
    st_ = fw.status()
    assert (st_.ex, st_.ey) == (0.0, 0.0)
    assert st_.saturated_count == 0 and st_.rejected_count == 0


def test_idle_until_first_setpoint() -> None:
    fw = Firmware(CFG)
    assert fw.mode is Mode.IDLE
    cmd = tick(fw, 0.0, Pose(0.0, 0.0, 0.0, 7.0), None)
    assert cmd.mode is Mode.IDLE and is_zero(cmd)
    cmd = tick(fw, DT, Pose(0.0, 0.0, 0.0, 7.0), make_sp())
    assert cmd.mode is Mode.TRACKING
    assert cmd.pose_t == 7.0


def test_tracking_drives_straight_to_a_goal_ahead() -> None:
    fw = Firmware(CFG)
    cmd = tick(fw, 0.0, Pose(0.0, 0.0, 0.0, 0.0), make_sp(x=0.55))
    # First tick: dt = 0, so P + FF only: 0.21 * 0.5 = 0.105 m/s straight ahead.
    assert cmd.omega_r == pytest.approx(cmd.omega_l)
    v, w = twist_from_wheels(cmd.omega_r, cmd.omega_l, GEOM)
    assert v == pytest.approx(CFG.gains.kp * 0.5)
    assert w == pytest.approx(0.0, abs=1e-12)
    assert cmd.power_r == pytest.approx(cmd.omega_r / WMAX)


def test_goal_to_the_left_turns_left() -> None:
    fw = Firmware(CFG)
    cmd = tick(fw, 0.0, Pose(0.0, 0.0, 0.0, 0.0), make_sp(x=L_REF, y=0.2))
    assert cmd.omega_r > 0.0 > cmd.omega_l  # rotate left (counter-clockwise)


def test_pose_t_is_echoed() -> None:
    fw = Firmware(CFG)
    cmd = tick(fw, 10.0, Pose(0.0, 0.0, 0.0, 123.25), make_sp(), pose_rx=10.0)
    assert cmd.pose_t == 123.25
    assert fw.status().last_pose_t == 123.25


def test_feed_forward_moves_robot_with_the_setpoint() -> None:
    fw = Firmware(CFG)
    cmd = tick(fw, 0.0, Pose(0.0, 0.0, 0.0, 0.0), make_sp(x=L_REF, vx=0.1))
    v, w = twist_from_wheels(cmd.omega_r, cmd.omega_l, GEOM)
    assert (v, w) == pytest.approx((0.1, 0.0))


small = st.floats(min_value=-1.0, max_value=1.0)


@settings(max_examples=200, deadline=None, derandomize=True)
@given(
    x=small, y=small, th=st.floats(min_value=-4.0, max_value=4.0), gx=small, gy=small,
    fx=st.floats(min_value=-0.2, max_value=0.2), fy=st.floats(min_value=-0.2, max_value=0.2),
    nx=small, ny=small,
)  # fmt: skip
def test_pipeline_is_the_composition_of_the_public_functions(
    x: float, y: float, th: float, gx: float, gy: float, fx: float, fy: float, nx: float, ny: float
) -> None:
    """step() = eqs 10-11 -> PID+FF -> cap -> repulsion -> safety filter -> eq 16 -> eq 8 ->
    saturation (uniform rescale if keeping the turn leaves the filter's constraints), bit for
    bit (the firmware inlines eqs 16 and 8 for speed)."""
    fw = Firmware(CFG)
    ctl = TrackingController(CFG.gains)
    flt = SafetyFilter(CFG)
    sat_prev = False
    for k in range(3):
        now = k * DT
        dt = now - (k - 1) * DT if k else 0.0
        cmd = tick(fw, now, Pose(x, y, th, now), make_sp(x=gx, y=gy, vx=fx, vy=fy),
                   neighbours=[(nx, ny)])  # fmt: skip
        xr, yr = reference_point(x, y, th, L_REF)
        vx, vy = ctl.update(gx - xr, gy - yr, fx, fy, DT if k else 0.0, sat_prev)
        rvx, rvy = repulsion_velocity(x, y, [(nx, ny)], [], CFG.repulsion)
        ux, uy = flt.filter(now, xr, yr, vx + rvx, vy + rvy, gx - xr, gy - yr, [(nx, ny)], (),
                            0.0, dt)  # fmt: skip
        v, w = twist_from_ref_velocity(ux, uy, th, L_REF)
        wr0, wl0 = wheels_from_twist(v, w, GEOM)
        wr, wl, sat = saturate_wheels(wr0, wl0, WMAX)
        if sat and flt.in_range:
            sv, sw = twist_from_wheels(wr, wl, GEOM)
            if not flt.admissible(*ref_point_velocity(sv, sw, th, L_REF)):
                f = WMAX / max(abs(wr0), abs(wl0))
                wr, wl = wr0 * f, wl0 * f
        sat_prev = sat
        assert (cmd.omega_r, cmd.omega_l, cmd.saturated) == (wr, wl, sat)
        assert (cmd.power_r, cmd.power_l) == (wr / WMAX, wl / WMAX)


# ----------------------------------------------------------------------------- staleness


def test_stale_pose_gives_zero_wheels_within_one_step() -> None:
    fw, now = tracking_fw()
    now += DT
    cmd = tick(fw, now, Pose(0.0, 0.0, 0.0, 0.0), make_sp(), pose_rx=now - 0.21)
    assert cmd.mode is Mode.HOLD and is_zero(cmd)
    assert fw.status().reason == "pose stale"


def test_stale_setpoint_gives_zero_wheels_within_one_step() -> None:
    fw, now = tracking_fw()
    now += DT
    cmd = tick(fw, now, Pose(0.0, 0.0, 0.0, now), make_sp(), sp_rx=now - 0.21)
    assert cmd.mode is Mode.HOLD and is_zero(cmd)
    assert fw.status().reason == "setpoint stale"


def test_receive_time_in_the_future_is_not_fresh() -> None:
    fw, now = tracking_fw()
    now += DT
    cmd = tick(fw, now, Pose(0.0, 0.0, 0.0, now), make_sp(), pose_rx=now + 5.0)
    assert cmd.mode is Mode.HOLD and is_zero(cmd)


def test_age_at_the_limit_is_still_fresh() -> None:
    fw, now = tracking_fw()
    now += DT
    cmd = tick(fw, now, Pose(0.0, 0.0, 0.0, now), make_sp(), pose_rx=now - 0.19)
    assert cmd.mode is Mode.TRACKING and not is_zero(cmd)


def test_missing_pose_or_setpoint_holds() -> None:
    fw, now = tracking_fw()
    cmd = tick(fw, now + DT, None, make_sp())
    assert cmd.mode is Mode.HOLD and is_zero(cmd)
    fw, now = tracking_fw()
    cmd = tick(fw, now + DT, Pose(0.0, 0.0, 0.0, now), None)
    assert cmd.mode is Mode.HOLD and is_zero(cmd)
    # Setpoint but never a pose: HOLD from IDLE.
    fw = Firmware(CFG)
    assert tick(fw, 0.0, None, make_sp()).mode is Mode.HOLD


def test_hold_then_fresh_data_resumes_tracking() -> None:
    fw, now = tracking_fw()
    now += DT
    assert tick(fw, now, None, make_sp()).mode is Mode.HOLD
    now += DT
    cmd = tick(fw, now, Pose(0.0, 0.0, 0.0, now), make_sp())
    assert cmd.mode is Mode.TRACKING and not is_zero(cmd)


# ----------------------------------------------------------------------------- estop


def test_estop_latches_until_released() -> None:
    fw, now = tracking_fw()
    fw.engage_estop()
    assert fw.mode is Mode.ESTOP and fw.status().estop_latched
    for _ in range(5):  # fresh data does not leave ESTOP
        now += DT
        cmd = tick(fw, now, Pose(0.0, 0.0, 0.0, now), make_sp())
        assert cmd.mode is Mode.ESTOP and is_zero(cmd)
    fw.release_estop()
    assert fw.mode is Mode.HOLD
    now += DT
    cmd = tick(fw, now, Pose(0.0, 0.0, 0.0, now), make_sp())
    assert cmd.mode is Mode.TRACKING and not is_zero(cmd)


def test_estop_release_with_stale_data_stays_stopped() -> None:
    fw, now = tracking_fw()
    fw.engage_estop()
    fw.release_estop()
    now += 1.0
    cmd = tick(fw, now, Pose(0.0, 0.0, 0.0, 0.0), make_sp(), pose_rx=0.0, sp_rx=0.0)
    assert cmd.mode is Mode.HOLD and is_zero(cmd)


def test_estop_release_before_any_setpoint_goes_idle() -> None:
    fw = Firmware(CFG)
    fw.engage_estop()
    assert tick(fw, 0.0, Pose(0.0, 0.0, 0.0, 0.0), make_sp()).mode is Mode.ESTOP
    fw.release_estop()
    assert fw.mode is Mode.IDLE
    assert tick(fw, DT, Pose(0.0, 0.0, 0.0, 0.0), make_sp()).mode is Mode.TRACKING


def test_release_without_estop_is_a_no_op() -> None:
    fw, _ = tracking_fw()
    fw.release_estop()
    assert fw.mode is Mode.TRACKING


def test_estop_resets_the_controller() -> None:
    fw, _ = tracking_fw(50)
    assert fw.tracker.x.integral_ms != 0.0
    fw.engage_estop()
    assert fw.tracker.x.integral_ms == 0.0


def test_transition_table_is_complete() -> None:
    step_events = {"fresh", "stale", "invalid", "no_setpoint", "estop"}
    for mode in Mode:
        assert {e.value for e in _TRANSITIONS[mode]} >= step_events
    # Only a release leaves ESTOP.
    leaving = {e.value for e, m in _TRANSITIONS[Mode.ESTOP].items() if m is not Mode.ESTOP}
    assert leaving == {"release", "release_unconfigured"}


# ----------------------------------------------------------------------------- PID resets


def test_role_change_resets_pid() -> None:
    fw, now = tracking_fw(30)
    assert fw.tracker.x.integral_ms > 0.0
    now += DT
    tick(fw, now, Pose(0.0, 0.0, 0.0, now), make_sp(slot=2))
    assert fw.tracker.x.integral_ms == pytest.approx(0.45 * DT)  # one tick since the reset
    assert fw.tracker.x.snapshot().d_term == 0.0
    s = fw.status()
    assert s.slot == 2 and s.role_changes == 1


def test_resume_after_hold_has_no_kick() -> None:
    """The first command after HOLD -> TRACKING equals that of a controller that never held
    (it was simply not run during the gap), and its derivative term is zero."""
    held, never = Firmware(CFG), Firmware(CFG)

    def inputs(k: float) -> tuple[Pose, Setpoint]:
        t = k * DT
        # A target moving at 0.05 m/s, the robot weaving a few cm behind it: the errors change
        # every tick (non-zero derivative) and stay small (the integral never clamps).
        pose = Pose(0.05 * t - 0.03 + 0.01 * math.sin(2.0 * t), 0.01 * math.cos(t), 0.0, t)
        return pose, make_sp(x=0.05 * t + L_REF, y=0.01, vx=0.05, t=t)

    for k in range(100):
        pose, sp = inputs(k)
        a = tick(held, k * DT, pose, sp)
        b = tick(never, k * DT, pose, sp)
        assert a == b
    i_before = (held.tracker.x.integral_ms, held.tracker.y.integral_ms)
    assert 0.0 < abs(i_before[0]) < CFG.gains.integral_limit_ms
    assert held.tracker.x.snapshot().edot_filtered != 0.0
    # 50 ticks with a pose received long ago: HOLD at once, wheels exactly zero, integrators
    # frozen.
    for k in range(100, 150):
        pose, sp = inputs(k)
        cmd = tick(held, k * DT, pose, sp, pose_rx=-1.0)
        assert cmd.mode is Mode.HOLD and is_zero(cmd)
    assert (held.tracker.x.integral_ms, held.tracker.y.integral_ms) == i_before
    # Resume.
    pose, sp = inputs(150)
    a = tick(held, 150 * DT, pose, sp)
    b = tick(never, 150 * DT, pose, sp)
    assert a.mode is Mode.TRACKING and b.mode is Mode.TRACKING
    assert held.tracker.x.snapshot().d_term == 0.0
    assert a.omega_r == pytest.approx(b.omega_r, abs=1e-3)
    assert a.omega_l == pytest.approx(b.omega_l, abs=1e-3)
    # And the integral part is bounded: the command differs from P + FF by at most Kp*Ilim/Ti.
    ex = held.status().ex
    g = CFG.gains
    assert held.tracker.x.snapshot().output - g.kp * ex == pytest.approx(
        g.kp * held.tracker.x.integral_ms / g.ti_s
    )
    assert abs(held.tracker.x.integral_ms) <= g.integral_limit_ms


def test_integrator_frozen_while_wheels_saturate() -> None:
    # Goal far to the side: eq 16 asks for a fast turn, the wheels saturate.
    cfg = AgentConfig(gains=CFG.gains.__class__(max_ref_speed_mps=10.0))
    fw = Firmware(cfg)
    sp = make_sp(x=L_REF, y=2.0)
    sat_seen = 0
    prev_i = 0.0
    for k in range(20):
        cmd = tick(fw, k * DT, Pose(0.0, 0.0, 0.0, k * DT), sp)
        i = fw.tracker.y.integral_ms
        if sat_seen:
            assert abs(i) <= abs(prev_i)  # frozen (may only shrink) after a saturated tick
        if cmd.saturated:
            sat_seen += 1
            assert max(abs(cmd.omega_r), abs(cmd.omega_l)) == pytest.approx(WMAX)
        prev_i = i
    assert sat_seen == fw.status().saturated_count == 20


# ----------------------------------------------------------------------------- repulsion


def test_neighbour_ahead_slows_the_robot() -> None:
    """The potential field alone (safety filter off): the Khatib push at 0.15 m (contact)."""
    rep_only = AgentConfig(safety_filter=SafetyFilterParams(enabled=False))
    pose, sp = Pose(0.0, 0.0, 0.0, 0.0), make_sp(x=0.55)
    free = tick(Firmware(rep_only), 0.0, pose, sp)
    near = tick(Firmware(rep_only), 0.0, pose, sp, neighbours=[(0.15, 0.0)])
    far = tick(Firmware(rep_only), 0.0, pose, sp, neighbours=[(0.31, 0.0)])
    v_free, _ = twist_from_wheels(free.omega_r, free.omega_l, GEOM)
    v_near, _ = twist_from_wheels(near.omega_r, near.omega_l, GEOM)
    assert v_free - v_near == pytest.approx(rep_only.repulsion.speed_at(0.15), rel=0.02)
    assert far == free
    off = AgentConfig(
        repulsion=RepulsionParams(enabled=False), safety_filter=SafetyFilterParams(enabled=False)
    )
    assert tick(Firmware(off), 0.0, pose, sp, neighbours=[(0.15, 0.0)]) == free
    # with the filter on, a robot touching the one ahead does not drive on into it
    blocked = tick(Firmware(CFG), 0.0, pose, sp, neighbours=[(0.15, 0.0)])
    v_blocked, _ = twist_from_wheels(blocked.omega_r, blocked.omega_l, GEOM)
    assert v_blocked <= 1e-12


def test_obstacles_are_used() -> None:
    pose, sp = Pose(0.0, 0.0, 0.0, 0.0), make_sp(x=0.55)
    free = tick(Firmware(CFG), 0.0, pose, sp)
    near = tick(Firmware(CFG), 0.0, pose, sp, obstacles=[(0.4, 0.0, 0.25)])
    assert near.omega_r + near.omega_l < free.omega_r + free.omega_l


# ----------------------------------------------------------------------------- closed loop


def test_closed_loop_unicycle_converges_to_goal() -> None:
    """Integrate eq 9 with the firmware's wheels: the reference point reaches a goal 0.3 m away."""
    fw = Firmware(CFG)
    x, y, th = 0.0, 0.0, 0.5
    gx, gy = 0.2, -0.15
    dt = 0.02
    for k in range(1500):  # 30 s
        now = k * dt
        cmd = tick(fw, now, Pose(x, y, th, now), make_sp(x=gx, y=gy, t=now))
        assert cmd.mode is Mode.TRACKING
        v, w = twist_from_wheels(cmd.omega_r, cmd.omega_l, GEOM)
        x += v * math.cos(th) * dt
        y += v * math.sin(th) * dt
        th += w * dt
    err = math.hypot(gx - (x + L_REF * math.cos(th)), gy - (y + L_REF * math.sin(th)))
    assert err < 0.02


# ----------------------------------------------------------------------------- properties

vals = st.one_of(
    st.floats(min_value=-3.0, max_value=3.0),
    st.sampled_from([0.0, NAN, INF, -INF, 1e308, -1e308, 1e-320]),
)
poses = st.one_of(st.none(), st.builds(Pose, vals, vals, vals, vals))
setpoints = st.one_of(
    st.none(),
    st.builds(Setpoint, vals, vals, vals, vals, vals, st.sampled_from([0, 1, 2]), vals),
)
dts = st.one_of(st.just(DT), st.sampled_from([0.0, -0.5, 0.5, NAN, INF]))
steps = st.lists(
    st.tuples(
        dts, poses, setpoints, st.sampled_from([0.0, 0.1, 0.3, NAN]), st.sampled_from([0.0, 0.3])
    ),
    min_size=1,
    max_size=25,
)


@settings(max_examples=200, deadline=None, derandomize=True)
@given(seq=steps, nbrs=st.lists(st.tuples(vals, vals), max_size=3), estop=st.booleans())
def test_wheels_within_limits_for_any_input(
    seq: list[tuple[float, Pose | None, Setpoint | None, float, float]],
    nbrs: list[tuple[float, float]],
    estop: bool,
) -> None:
    fw = Firmware(CFG)
    now = 0.0
    for i, (dt, pose, sp, pose_age, sp_age) in enumerate(seq):
        now = now + dt if math.isfinite(now + dt) else now
        if estop and i == len(seq) // 2:
            fw.engage_estop()
        cmd = fw.step(
            now,
            pose=pose,
            pose_rx_s=now - pose_age,
            setpoint=sp,
            setpoint_rx_s=now - sp_age,
            neighbours=nbrs,
        )
        for v in (cmd.omega_r, cmd.omega_l, cmd.power_r, cmd.power_l):
            assert math.isfinite(v)
        assert abs(cmd.omega_r) <= WMAX and abs(cmd.omega_l) <= WMAX
        assert abs(cmd.power_r) <= 1.0 and abs(cmd.power_l) <= 1.0
        assert cmd.mode is fw.mode
        if cmd.mode is not Mode.TRACKING:
            assert is_zero(cmd)
        if estop and i >= len(seq) // 2:
            assert cmd.mode is Mode.ESTOP
        assert abs(fw.tracker.x.integral_ms) <= CFG.gains.integral_limit_ms


@settings(max_examples=150, deadline=None, derandomize=True)
@given(
    seq=steps,
    nbrs=st.lists(st.tuples(vals, vals), max_size=3),
    est=st.booleans(),
    wheels=st.one_of(st.none(), st.tuples(vals, vals)),
)
def test_step_positional_is_step(
    seq: list[tuple[float, Pose | None, Setpoint | None, float, float]],
    nbrs: list[tuple[float, float]],
    est: bool,
    wheels: tuple[float, float] | None,
) -> None:
    """``step_positional`` (the in-process loop's entry) is ``step`` with the same arguments by
    position: the same commands, bit for bit, and the same state after, on any input."""
    cfg = EST if est else CFG
    by_kw, by_pos = Firmware(cfg), Firmware(cfg)
    now = 0.0
    for dt, pose, sp, pose_age, sp_age in seq:
        now = now + dt if math.isfinite(now + dt) else now
        cap = None if pose is None else now - pose_age - 0.01
        a = by_kw.step(
            now,
            pose=pose,
            pose_rx_s=now - pose_age,
            setpoint=sp,
            setpoint_rx_s=now - sp_age,
            neighbours=nbrs,
            pose_capture_s=cap,
            wheel_speeds=wheels,
        )
        b = by_pos.step_positional(now, pose, now - pose_age, sp, now - sp_age, nbrs, cap, wheels)
        assert repr(a) == repr(b)  # repr: bit-exact floats (NaN included)
    assert repr(by_kw.status()) == repr(by_pos.status())
    assert repr(by_kw.pose_estimate) == repr(by_pos.pose_estimate)


# ----------------------------------------------------------------------------- status


def test_status_snapshot() -> None:
    fw, _ = tracking_fw(10)
    s = fw.status()
    assert s.mode is Mode.TRACKING and s.slot == 1 and s.steps == 10
    assert s.ex == pytest.approx(0.45) and s.ey == 0.0
    assert s.pid_x.p_term == pytest.approx(CFG.gains.kp * 0.45)
    d = s.as_dict()
    assert d["mode"] == "tracking" and d["slot"] == 1 and d["rejected"] == 0
    assert set(d["pid"]) == {"x", "y"}


def test_config_validation() -> None:
    with pytest.raises(TypeError):
        Firmware("not a config")  # type: ignore[arg-type]
    with pytest.raises(ValueError):
        SafetyParams(stale_pose_s=0.0)
