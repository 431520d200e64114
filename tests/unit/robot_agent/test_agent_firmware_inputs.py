"""Firmware of robot_agent on bad input (non-finite, wrong types, absurd values: rejected and
counted), odd time steps, and the pose estimator's ride-through rule (camera dropouts up to the
bound, then HOLD). The helpers are tests/unit/robot_agent/test_agent_firmware.py's."""

from __future__ import annotations

import math
from fractions import Fraction
from typing import Any

import numpy as np
import pytest
from support.firmware_cases import CFG, DT, EST, INF, NAN, WMAX, is_zero, make_sp, tick, tracking_fw

from robot_agent.core.firmware import Firmware, Mode, Pose

# ----------------------------------------------------------------------------- bad input

POSE_FIELDS = ["x", "y", "theta", "t"]
SP_FIELDS = ["x", "y", "vx", "vy", "theta", "t"]
BAD = [NAN, INF, -INF]


@pytest.mark.parametrize("bad", BAD)
@pytest.mark.parametrize("field", POSE_FIELDS)
def test_non_finite_pose_field_rejected_and_counted_once(field: str, bad: float) -> None:
    fw, now = tracking_fw()
    pose = Pose(0.0, 0.0, 0.0, now)._replace(**{field: bad})
    for _ in range(3):  # the same bad message presented three times counts once
        now += DT
        cmd = tick(fw, now, pose, make_sp())
        assert cmd.mode is Mode.HOLD and is_zero(cmd)
    assert fw.status().rejected_count == 1
    now += DT
    assert tick(fw, now, Pose(0.0, 0.0, 0.0, now), make_sp()).mode is Mode.TRACKING


@pytest.mark.parametrize("bad", BAD)
@pytest.mark.parametrize("field", SP_FIELDS)
def test_non_finite_setpoint_field_rejected_and_counted_once(field: str, bad: float) -> None:
    fw, now = tracking_fw()
    sp = make_sp()._replace(**{field: bad})  # type: ignore[arg-type]
    for _ in range(3):
        now += DT
        cmd = tick(fw, now, Pose(0.0, 0.0, 0.0, now), sp)
        assert cmd.mode is Mode.HOLD and is_zero(cmd)
    assert fw.status().rejected_count == 1


@pytest.mark.parametrize("bad", BAD)
@pytest.mark.parametrize("arg", ["now_s", "pose_rx_s", "setpoint_rx_s"])
def test_non_finite_time_rejected(arg: str, bad: float) -> None:
    fw, now = tracking_fw()
    now += DT
    kw: dict[str, Any] = {
        "pose": Pose(0.0, 0.0, 0.0, now),
        "pose_rx_s": now,
        "setpoint": make_sp(),
        "setpoint_rx_s": now,
    }
    if arg == "now_s":
        cmd = fw.step(bad, **kw)
    else:
        kw[arg] = bad
        cmd = fw.step(now, **kw)
    assert cmd.mode is Mode.HOLD and is_zero(cmd)
    assert fw.status().rejected_count == 1


def test_bad_setpoint_before_any_valid_one_stays_idle() -> None:
    fw = Firmware(CFG)
    cmd = tick(fw, 0.0, Pose(0.0, 0.0, 0.0, 0.0), make_sp(x=NAN))
    assert cmd.mode is Mode.IDLE and is_zero(cmd)
    assert fw.status().rejected_count == 1


@pytest.mark.parametrize("slot", [-1, 1.5, None, "2", True])
def test_bad_slot_rejected(slot: Any) -> None:
    fw, now = tracking_fw()
    cmd = tick(fw, now + DT, Pose(0.0, 0.0, 0.0, now), make_sp()._replace(slot=slot))
    assert cmd.mode is Mode.HOLD and is_zero(cmd)
    assert fw.status().rejected_count == 1


def test_wrong_types_never_raise() -> None:
    fw, now = tracking_fw()
    bad_pose = Pose("a", "b", "c", "d")  # type: ignore[arg-type]
    cmd = tick(fw, now + DT, bad_pose, make_sp())
    assert is_zero(cmd) and cmd.mode is Mode.HOLD
    cmd = fw.step(None, pose=None, pose_rx_s=0.0, setpoint=None, setpoint_rx_s=0.0)  # type: ignore[arg-type]
    assert is_zero(cmd)
    assert fw.status().rejected_count == 2


@pytest.mark.parametrize(
    "arg, value",
    [
        ("now_s", "1.0"),
        ("now_s", b"1"),
        ("pose_rx_s", None),
        ("setpoint_rx_s", "0"),
        ("extra_radius_m", "x"),
        ("extra_radius_m", None),
        ("pose", 5),
        ("pose", (0.0, 0.0, 0.0)),
        ("pose", Pose(0.0, None, 0.0, 0.0)),  # type: ignore[arg-type]
        ("setpoint", "setpoint"),
        ("setpoint", make_sp()._replace(vx="0")),
    ],
)
def test_arguments_of_a_wrong_type_hold_and_count(arg: str, value: Any) -> None:
    """The firmware validates its arguments instead of trusting their annotations (compiled
    with mypyc, a typed parameter would raise at the call): each of these is one rejection and
    a zero command in HOLD, never an exception."""
    fw, now = tracking_fw()
    now += DT
    kw: dict[str, Any] = {"now_s": now, "pose": Pose(0.0, 0.0, 0.0, now), "pose_rx_s": now,
                          "setpoint": make_sp(), "setpoint_rx_s": now, arg: value}  # fmt: skip
    cmd = fw.step(**kw)
    assert cmd.mode is Mode.HOLD and is_zero(cmd)
    assert fw.status().rejected_count == 1


@pytest.mark.parametrize(
    "arg, value",
    [
        ("now_s", Fraction(1, 10)),
        ("now_s", np.float64(0.1)),
        ("pose_rx_s", np.float64(0.1)),
        ("setpoint_rx_s", Fraction(1, 10)),
        ("extra_radius_m", np.int64(0)),
        ("extra_radius_m", 0),
        ("pose", [0.0, 0.0, 0.0, 0.1]),
        ("pose", Pose(np.int64(0), 0, np.float32(0.0), 0.1)),  # type: ignore[arg-type]
        ("setpoint", list(make_sp())),
        ("setpoint", make_sp()._replace(x=Fraction(1, 2), vy=np.int64(0))),
    ],
)
def test_arguments_that_are_numbers_of_another_type_are_used(arg: str, value: Any) -> None:
    """A real number of another type than float (int, a numpy scalar, a Fraction) and a pose /
    setpoint given as a plain sequence are used as their float values, compiled or not: the
    same command as the float tick."""
    fw, now = tracking_fw()
    ref, _ = tracking_fw()
    now = 0.1  # (5 ticks of 20 ms: the float value of every time above)
    kw: dict[str, Any] = {"now_s": now, "pose": Pose(0.0, 0.0, 0.0, now), "pose_rx_s": now,
                          "setpoint": make_sp(), "setpoint_rx_s": now}  # fmt: skip
    want = ref.step(**kw)
    kw[arg] = value
    got = fw.step(**kw)
    assert got == want and type(got.omega_r) is float
    assert fw.status().rejected_count == 0


def test_malformed_neighbours_hold_and_count() -> None:
    fw, now = tracking_fw()
    cmd = tick(fw, now + DT, Pose(0.0, 0.0, 0.0, now), make_sp(), neighbours=[(1.0,)])
    assert cmd.mode is Mode.HOLD and is_zero(cmd)
    assert fw.status().rejected_count == 1
    assert "internal error" in fw.status().last_reject_reason


def test_non_finite_neighbour_is_skipped_and_counted() -> None:
    fw, now = tracking_fw()
    cmd = tick(
        fw, now + DT, Pose(0.0, 0.0, 0.0, now), make_sp(), neighbours=[(NAN, 0.0), (INF, 1.0)]
    )
    assert cmd.mode is Mode.TRACKING and not is_zero(cmd)
    assert fw.status().rejected_count == 2


def test_reject_counts_shell_drops() -> None:
    fw = Firmware(CFG)
    fw.reject("decode error: missing x")
    fw.reject("decode error: bad version")
    s = fw.status()
    assert s.rejected_count == 2
    assert s.last_reject_reason == "decode error: bad version"
    assert s.as_dict()["rejected"] == 2


def test_absurd_finite_values_do_not_overflow() -> None:
    fw, now = tracking_fw()
    cmd = tick(fw, now + DT, Pose(-1.7e308, 0.0, 0.0, now), make_sp(x=1.7e308))
    assert math.isfinite(cmd.omega_r) and math.isfinite(cmd.omega_l)
    assert abs(cmd.omega_r) <= WMAX and abs(cmd.omega_l) <= WMAX


# ----------------------------------------------------------------------------- time


def test_zero_dt_integrates_nothing() -> None:
    fw, now = tracking_fw()
    i0 = fw.tracker.x.integral_ms
    cmd = tick(fw, now, Pose(0.0, 0.0, 0.0, now), make_sp())  # same now_s again
    assert cmd.mode is Mode.TRACKING
    assert fw.tracker.x.integral_ms == i0
    assert fw.status().dt_faults == 1


def test_negative_dt_integrates_nothing_and_recovers() -> None:
    fw, now = tracking_fw()
    i0 = fw.tracker.x.integral_ms
    cmd = tick(fw, now - 1.0, Pose(0.0, 0.0, 0.0, now), make_sp(), pose_rx=now - 1.0)
    assert cmd.mode is Mode.TRACKING and math.isfinite(cmd.omega_r)
    assert fw.tracker.x.integral_ms == i0
    cmd = tick(fw, now - 1.0 + DT, Pose(0.0, 0.0, 0.0, now), make_sp())
    assert fw.tracker.x.integral_ms == pytest.approx(i0 + 0.45 * DT)
    assert fw.status().dt_faults == 1


def test_stalled_loop_integrates_nothing() -> None:
    fw, now = tracking_fw()
    i0 = fw.tracker.x.integral_ms
    now += 1.0  # the loop stalled 1 s but data is fresh
    tick(fw, now, Pose(0.0, 0.0, 0.0, now), make_sp())
    assert fw.tracker.x.integral_ms == i0


# ----------------------------------------------------------------------------- ride-through
# The stale-pose tests above, ported to the estimator's rule (EstimatorParams.enabled): the age
# of the newest *capture* decides, not the receive age of the last message; the robot rides on
# the prediction up to the dropout bound (here max_dropout_cmd_s: no encoder speeds) and holds
# within one step beyond it; a rejected pose is counted and the estimate rides on.

BOUND = EST.estimator.max_dropout_cmd_s


def tracking_est(n: int = 5) -> tuple[Firmware, float]:
    """``tracking_fw`` with the estimator: a fresh pose captured every tick."""
    fw = Firmware(EST)
    now = 0.0
    for k in range(n):
        now = k * DT
        cmd = tick(fw, now, Pose(0.0, 0.0, 0.0, now), make_sp(t=now), pose_capture_s=now)
        assert cmd.mode is Mode.TRACKING
    return fw, now


def test_ride_through_a_pose_older_than_stale_pose_s_then_hold_beyond_the_bound() -> None:
    fw, now = tracking_est()
    last = Pose(0.0, 0.0, 0.0, now)  # the shell presents its latest pose again every tick
    cap = now
    assert CFG.safety.stale_pose_s < BOUND  # the old rule would have held in between
    while True:
        now += DT
        cmd = tick(fw, now, last, make_sp(), pose_rx=cap, pose_capture_s=cap)
        if now - cap <= BOUND - 1e-9:
            assert cmd.mode is Mode.TRACKING and not is_zero(cmd), now - cap
            assert 0.0 < fw.pose_uncertainty_m < EST.estimator.max_uncertainty_m
        elif now - cap > BOUND + 1e-9:  # one step past the bound: zero wheels at once
            assert cmd.mode is Mode.HOLD and is_zero(cmd)
            assert fw.status().reason == "pose estimate invalid"
            assert math.isnan(fw.pose_uncertainty_m)
            break


def test_ride_through_a_capture_in_the_future_is_rejected_not_used() -> None:
    fw, now = tracking_est()
    est = fw.estimator
    assert est is not None
    now += DT
    bad = Pose(1.0, 1.0, 0.0, now)  # a jump "captured" 5 s from now
    cmd = tick(fw, now, bad, make_sp(), pose_capture_s=now + 5.0)
    assert cmd.mode is Mode.TRACKING  # rides on the estimate, which ignored the pose
    assert est.rejected_future == 1 and fw.status().rejected_count == 1
    got = fw.pose_estimate
    assert got is not None and abs(got[0]) < 0.05 and abs(got[1]) < 0.05
    # with nothing else ever received, the same pose leaves the robot without a pose: HOLD
    fresh = Firmware(EST)
    cmd = tick(fresh, 0.0, Pose(0.0, 0.0, 0.0, 0.0), make_sp(), pose_capture_s=5.0)
    assert cmd.mode is Mode.HOLD and is_zero(cmd) and fresh.status().reason == "no pose"


def test_ride_through_a_missing_pose_and_hold_when_there_never_was_one() -> None:
    fw, now = tracking_est()
    cmd = tick(fw, now + DT, None, make_sp())
    assert cmd.mode is Mode.TRACKING and not is_zero(cmd)  # the estimate rides on
    fw, now = tracking_est()
    cmd = tick(fw, now + DT, Pose(0.0, 0.0, 0.0, now), None, pose_capture_s=now)
    assert cmd.mode is Mode.HOLD and is_zero(cmd)  # no setpoint: as before
    fw = Firmware(EST)  # a setpoint but never a pose: HOLD from IDLE
    assert tick(fw, 0.0, None, make_sp()).mode is Mode.HOLD
    assert fw.status().reason == "no pose"


def test_ride_through_hold_then_fresh_data_resumes_tracking() -> None:
    fw, now = tracking_est()
    while tick(fw, now, None, make_sp()).mode is not Mode.HOLD:  # the camera is lost
        now += DT
        assert now < 1.0
    now += DT
    cmd = tick(fw, now, Pose(0.0, 0.0, 0.0, now), make_sp(), pose_capture_s=now)
    assert cmd.mode is Mode.TRACKING and not is_zero(cmd)


@pytest.mark.parametrize("bad", BAD)
@pytest.mark.parametrize("field", POSE_FIELDS)
def test_ride_through_non_finite_pose_rejected_counted_once(field: str, bad: float) -> None:
    fw, now = tracking_est()
    pose = Pose(0.0, 0.0, 0.0, now)._replace(**{field: bad})
    for _ in range(3):  # the same bad message presented three times counts once
        now += DT
        cmd = tick(fw, now, pose, make_sp(), pose_capture_s=now)
        assert cmd.mode is Mode.TRACKING and all(math.isfinite(c) for c in cmd[:4])
    assert fw.status().rejected_count == 1
    now += DT
    cmd = tick(fw, now, Pose(0.0, 0.0, 0.0, now), make_sp(), pose_capture_s=now)
    assert cmd.mode is Mode.TRACKING


@pytest.mark.parametrize("bad", BAD)
def test_ride_through_non_finite_receive_time_rejected(bad: float) -> None:
    """Without ``pose_capture_s`` the receive time is the capture time: a non-finite one is
    rejected and counted, and the estimate rides on."""
    fw, now = tracking_est()
    now += DT
    cmd = fw.step(now, pose=Pose(0.0, 0.0, 0.0, now), pose_rx_s=bad, setpoint=make_sp(),
                  setpoint_rx_s=now)  # fmt: skip
    assert cmd.mode is Mode.TRACKING and all(math.isfinite(c) for c in cmd[:4])
    assert fw.status().rejected_count == 1
    est = fw.estimator
    assert est is not None and est.rejected_nonfinite == 1


def test_ride_through_resume_after_hold_has_no_kick() -> None:
    """HOLD (the camera lost beyond the bound) freezes the integrators; the first tick after a
    fresh pose has a zero derivative term and the integral part is bounded."""
    fw, now = tracking_est(30)
    i_before = (fw.tracker.x.integral_ms, fw.tracker.y.integral_ms)
    assert i_before[0] > 0.0
    held = 0
    while held < 10:  # lost: ride through, then hold for 10 ticks
        now += DT
        cmd = tick(fw, now, None, make_sp())
        if cmd.mode is Mode.HOLD:
            assert is_zero(cmd)
            if held == 0:
                i_before = (fw.tracker.x.integral_ms, fw.tracker.y.integral_ms)
            held += 1
    assert (fw.tracker.x.integral_ms, fw.tracker.y.integral_ms) == i_before
    now += DT
    cmd = tick(fw, now, Pose(0.0, 0.0, 0.0, now), make_sp(), pose_capture_s=now)
    assert cmd.mode is Mode.TRACKING
    assert fw.tracker.x.snapshot().d_term == 0.0
    g = EST.gains
    ex = fw.status().ex
    assert fw.tracker.x.snapshot().output - g.kp * ex == pytest.approx(
        g.kp * fw.tracker.x.integral_ms / g.ti_s
    )
    assert abs(fw.tracker.x.integral_ms) <= g.integral_limit_ms
