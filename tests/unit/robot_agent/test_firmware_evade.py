"""Issue 30, "Movers", part 1: a robot that does not track (IDLE, HOLD) still runs its safety
filter on a zero nominal command and gets out of the way of a body coming at it; only ESTOP and
a lost pose mean wheels at zero whatever approaches (robot_agent/core/firmware.py ``_evade``,
``SafetyFilter.evade``)."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from robot_agent.core.firmware import Firmware, Mode, Pose, Setpoint, WheelCommand
from robot_agent.core.kinematics import twist_from_wheels
from robot_agent.core.params import AgentConfig, EstimatorParams, SafetyFilterParams
from robot_agent.core.safety_filter import Neighbour, SafetyFilter

NO_EST = AgentConfig(estimator=EstimatorParams(enabled=False))
EST = AgentConfig()
GEOM = NO_EST.geometry
DT_S = 0.02
#: bodies touch at 2 x body radius
TOUCH_M = 2.0 * GEOM.body_radius_m
WMAX = GEOM.max_wheel_radps


def _is_zero(cmd: WheelCommand) -> bool:
    return (cmd.omega_r, cmd.omega_l, cmd.power_r, cmd.power_l) == (0.0, 0.0, 0.0, 0.0)


def _step(
    fw: Firmware,
    now_s: float,
    xyt: tuple[float, float, float],
    sp: Setpoint | None,
    sp_rx_s: float,
    neighbours: list[Neighbour],
) -> WheelCommand:
    return fw.step(
        now_s,
        pose=Pose(xyt[0], xyt[1], xyt[2], now_s),
        pose_rx_s=now_s,
        setpoint=sp,
        setpoint_rx_s=sp_rx_s,
        neighbours=neighbours,
        pose_capture_s=now_s,
    )


def _to_hold(fw: Firmware, xyt: tuple[float, float, float]) -> float:
    """Track a setpoint on the robot's own reference point for a few ticks, then let it go
    stale: the firmware is in HOLD with a fresh pose. Returns the last ``now_s``."""
    sp = Setpoint(xyt[0] + GEOM.ref_offset_m, xyt[1], 0.0, 0.0, 0.0, 0, 0.0)
    now = 0.0
    for k in range(3):
        now = k * DT_S
        _step(fw, now, xyt, sp._replace(t=now), now, [])
    assert fw.mode is Mode.TRACKING
    now += DT_S
    cmd = _step(fw, now, xyt, sp, -10.0, [])  # setpoint 10 s old
    assert cmd.mode is Mode.HOLD and _is_zero(cmd)
    return now


@pytest.mark.parametrize("cfg", [NO_EST, EST], ids=["measured", "estimator"])
def test_idle_and_hold_stand_still_when_nothing_comes(cfg: AgentConfig) -> None:
    """Nothing in range, or a still body outside the barrier: exactly zero wheels (the old
    output), in IDLE and in HOLD."""
    still = [Neighbour(0.6, 0.0), Neighbour(0.0, -0.5)]
    fw = Firmware(cfg)
    for k in range(5):
        cmd = _step(fw, k * DT_S, (0.0, 0.0, 0.0), None, 0.0, still)
        assert cmd.mode is Mode.IDLE and _is_zero(cmd)
    fw = Firmware(cfg)
    now = _to_hold(fw, (0.0, 0.0, 0.0))
    for k in range(1, 5):
        cmd = _step(fw, now + k * DT_S, (0.0, 0.0, 0.0), None, 0.0, still)
        assert cmd.mode is Mode.HOLD and _is_zero(cmd)
    assert fw.safety_filter.evasions == 0


@pytest.mark.parametrize("cfg", [NO_EST, EST], ids=["measured", "estimator"])
@pytest.mark.parametrize("hold", [False, True], ids=["idle", "hold"])
def test_a_robot_not_tracking_backs_away_from_a_body_inside_its_barrier(
    cfg: AgentConfig, hold: bool
) -> None:
    """A body 0.20 m ahead of the centre (inside the 0.24 m barrier of the reference point):
    the wheels drive the robot backwards, away from it, and the mode does not change."""
    fw = Firmware(cfg)
    now = _to_hold(fw, (0.0, 0.0, 0.0)) if hold else 0.0
    cmd = _step(fw, now + DT_S, (0.0, 0.0, 0.0), None, 0.0, [Neighbour(0.20, 0.0)])
    assert cmd.mode is (Mode.HOLD if hold else Mode.IDLE)
    v_mps, _ = twist_from_wheels(cmd.omega_r, cmd.omega_l, GEOM)
    assert v_mps < -0.01
    assert fw.safety_filter.evasions == 1


def test_estop_and_a_lost_pose_mean_zero_wheels_whatever_comes() -> None:
    body = [Neighbour(0.12, 0.0, vx=-0.3)]
    fw = Firmware(NO_EST)
    fw.engage_estop()
    cmd = _step(fw, 0.0, (0.0, 0.0, 0.0), None, 0.0, body)
    assert cmd.mode is Mode.ESTOP and _is_zero(cmd)
    fw = Firmware(NO_EST)
    cmd = fw.step(0.0, pose=None, pose_rx_s=0.0, setpoint=None, setpoint_rx_s=0.0,
                  neighbours=body)  # fmt: skip
    assert _is_zero(cmd)
    # a pose 10 s old (the stale-pose rule): a dead link
    cmd = fw.step(10.0, pose=Pose(0.0, 0.0, 0.0, 0.0), pose_rx_s=0.0, setpoint=None,
                  setpoint_rx_s=0.0, neighbours=body)  # fmt: skip
    assert _is_zero(cmd)
    off = AgentConfig(
        estimator=EstimatorParams(enabled=False),
        safety_filter=SafetyFilterParams(enabled=False),
    )
    fw = Firmware(off)
    assert _is_zero(_step(fw, 0.0, (0.0, 0.0, 0.0), None, 0.0, body))


def test_a_non_finite_pose_without_a_setpoint_is_counted_once() -> None:
    fw = Firmware(NO_EST)
    bad = Pose(math.nan, 0.0, 0.0, 0.0)
    for k in range(3):
        cmd = fw.step(k * DT_S, pose=bad, pose_rx_s=k * DT_S, setpoint=None, setpoint_rx_s=0.0)
        assert _is_zero(cmd)
    assert fw.status().rejected_count == 1


def test_evade_pinned_pushes_into_a_still_neighbour_by_at_most_the_spare_margin() -> None:
    """Pinned: a body inside the barrier ahead coming on, a still robot right behind: the
    command may approach the still one only as far as its row shifted by the spare margin
    (``0.9 (margin - 2 noise budget)``) allows, so the centres keep more than 2 body radii; and
    it is within the speed cap."""
    flt = SafetyFilter(NO_EST)
    sf = NO_EST.safety_filter
    push_m = 0.9 * (sf.margin_m - 2.0 * sf.noise_budget_m)
    gamma = sf.gamma_per_s
    px, py = 0.05, 0.0  # reference point of a robot at the origin facing +x
    for gap_m in (0.20, 0.25, 0.30):
        behind = Neighbour(-gap_m, 0.0)
        ux, uy = flt.evade(px, py, [Neighbour(0.25, 0.0), behind], (), 0.0, DT_S)
        dx, dy = px - behind.x, py - behind.y
        dist = math.hypot(dx, dy)
        h = dist - (flt.safety_distance_m + GEOM.ref_offset_m)
        assert (dx * ux + dy * uy) / dist >= -gamma * (h + push_m) - 1e-9
        assert math.hypot(ux, uy) <= NO_EST.gains.max_ref_speed_mps + 1e-9
    # the floor that shift leaves: safety distance - push - both noise budgets > touching
    assert flt.safety_distance_m - push_m - 2.0 * sf.noise_budget_m > TOUCH_M


def _carry(cfg: AgentConfig, speed_mps: float, heading_rad: float, offset_m: float) -> float:
    """A body carried in a straight line at ``speed_mps`` through where an IDLE robot stands
    (the robot sees it as a neighbour with no known velocity, as the fleet's rule gives it);
    the robot is integrated with its own wheels (eq 9). Returns the least centre distance."""
    fw = Firmware(cfg)
    x = y = 0.0
    th = 0.3
    c, s = math.cos(heading_rad), math.sin(heading_rad)
    # start 0.8 m before the robot, offset sideways; pass 1.6 m
    bx0, by0 = -0.8 * c - offset_m * s, -0.8 * s + offset_m * c
    least = math.inf
    ticks = round(1.6 / speed_mps / DT_S)
    for k in range(ticks):
        now = k * DT_S
        bx = bx0 + c * speed_mps * now
        by = by0 + s * speed_mps * now
        least = min(least, math.hypot(bx - x, by - y))
        cmd = _step(fw, now, (x, y, th), None, 0.0, [Neighbour(bx, by, math.nan, 0.0)])
        assert cmd.mode is Mode.IDLE
        assert abs(cmd.omega_r) <= WMAX and abs(cmd.omega_l) <= WMAX
        v, w = twist_from_wheels(cmd.omega_r, cmd.omega_l, GEOM)
        x += v * math.cos(th) * DT_S
        y += v * math.sin(th) * DT_S
        th += w * DT_S
    return least


@settings(max_examples=25, deadline=None, derandomize=True)
@given(
    speed_mps=st.floats(0.05, 0.2),
    heading_rad=st.floats(-math.pi, math.pi),
    offset_m=st.floats(-0.1, 0.1),
)
def test_a_body_carried_at_an_idle_robot_never_touches_it(
    speed_mps: float, heading_rad: float, offset_m: float
) -> None:
    """From any direction at 0.05-0.2 m/s (below the 0.25 m/s cap on the reference point's
    speed), the body never comes within touching distance of an idle robot that gets away."""
    assert _carry(NO_EST, speed_mps, heading_rad, offset_m) > TOUCH_M


def test_without_the_evasion_the_body_runs_into_the_robot() -> None:
    """The same pass against a robot whose filter is off (the old HOLD): contact. So the test
    above measures the evasion, not a body that misses."""
    off = AgentConfig(
        estimator=EstimatorParams(enabled=False),
        safety_filter=SafetyFilterParams(enabled=False),
    )
    assert _carry(off, 0.2, 0.0, 0.0) < 0.01
    assert _carry(NO_EST, 0.2, 0.0, 0.0) > TOUCH_M
