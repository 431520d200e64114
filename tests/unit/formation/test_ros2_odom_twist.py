"""Issue 29: `/<id>/odom`'s twist is the robot's estimator twist (its status's `v_mps`,
`omega_radps`, or its host's batch) while a status received within TWIST_FRESH_S has it, else
the finite difference of consecutive poses; the twist covariance says which. And the agent and
the agent host publish that twist from the firmware's estimator."""

from __future__ import annotations

import math
from typing import Any

from hypothesis import given
from hypothesis import strategies as st

import runtime as rt
from bus_schemas import Clock, Pose, Setpoint, Status, StatusBatch, decode, encode, keys
from bus_schemas.fields import SPEED_MAX_MPS, TURN_RATE_MAX_RADPS
from bus_schemas.ros2 import msgs
from formation.live.ros2_bridge import (
    TWIST_COV_ESTIMATOR,
    TWIST_COV_FINITE_DIFFERENCE,
    TWIST_FRESH_S,
    BridgeCore,
)
from robot_agent.core.params import AgentConfig
from robot_agent.node.agent import AgentNode
from robot_agent.node.host_status import status_batches, status_row

NS = 1_000_000_000


def status(v: float | None, w: float | None) -> Status:
    return Status(t=1.0, seq=1, mode="tracking", slot=0, pid=1, host="h", rejected=0,
                  v_mps=v, omega_radps=w)  # fmt: skip


def batch(robots: tuple[str, ...], twist: dict[str, tuple[float, float]]) -> StatusBatch:
    n = len(robots)
    tr = tuple(twist)
    return StatusBatch(
        t=1.0, seq=1, pid=1, host="h", robots=robots, mode=("tracking",) * n, slot=(-1,) * n,
        rejected=(0,) * n, ex=(0.0,) * n, ey=(0.0,) * n,
        twist_robots=tr or None,
        v_mps=tuple(twist[r][0] for r in tr) or None,
        omega_radps=tuple(twist[r][1] for r in tr) or None,
    )  # fmt: skip


def odom_of(outs: list[Any], robot: str = "r1") -> msgs.Odometry:
    for o in outs:
        if o.topic == f"/{robot}/odom":
            odom = msgs.decode(o.payload, msgs.Odometry)
            assert isinstance(odom, msgs.Odometry)
            return odom
    raise AssertionError(f"no odometry of {robot}")


def twist_of(odom: msgs.Odometry) -> tuple[float, float, tuple[float, ...]]:
    tw = odom.twist
    return tw.twist.linear.x, tw.twist.angular.z, tuple(tw.covariance)


def two_poses(core: BridgeCore, now_s: float | None) -> msgs.Odometry:
    core.on_pose("r1", 1.0, 0.0, 0.0, 0.0, 5 * NS, now_s)
    return odom_of(core.on_pose("r1", 1.1, 0.02, 0.0, 0.05, 5 * NS + NS // 10, now_s))


# the finite difference of the two poses (a bridge that never had a status)
FD = twist_of(two_poses(BridgeCore(), None))[:2]


def test_the_finite_difference_is_the_unicycles_between_the_poses() -> None:
    assert math.isclose(FD[0], 0.02 * math.cos(0.025) / 0.1, rel_tol=1e-12)
    assert math.isclose(FD[1], 0.05 / 0.1, rel_tol=1e-12)


def test_fresh_estimator_twist_is_used_and_said_by_the_covariance() -> None:
    core = BridgeCore()
    core.on_status("r1", status(0.3, -0.4), rx_s=100.0)
    v, w, cov = twist_of(two_poses(core, now_s=100.0 + 0.9 * TWIST_FRESH_S))
    assert (v, w, cov) == (0.3, -0.4, TWIST_COV_ESTIMATOR)
    assert cov[0] < TWIST_COV_FINITE_DIFFERENCE[0] and cov[35] < TWIST_COV_FINITE_DIFFERENCE[35]


def test_stale_missing_or_unknown_twist_falls_back_to_the_finite_difference() -> None:
    stale = BridgeCore()
    stale.on_status("r1", status(0.3, -0.4), rx_s=100.0)
    v, w, cov = twist_of(two_poses(stale, now_s=100.0 + TWIST_FRESH_S + 1e-3))
    assert (v, w) == FD and cov == TWIST_COV_FINITE_DIFFERENCE
    # a status older than the pose's clock says (received "later" than now): not fresh either
    early = BridgeCore()
    early.on_status("r1", status(0.3, -0.4), rx_s=100.0)
    assert twist_of(two_poses(early, now_s=99.0))[2] == TWIST_COV_FINITE_DIFFERENCE
    # no clock given (the pure calls of before): the finite difference
    none = BridgeCore()
    none.on_status("r1", status(0.3, -0.4), rx_s=100.0)
    assert twist_of(two_poses(none, now_s=None))[:2] == FD
    # a newer status without a twist (estimate invalid): unknown, the finite difference
    unknown = BridgeCore()
    unknown.on_status("r1", status(0.3, -0.4), rx_s=100.0)
    unknown.on_status("r1", status(None, None), rx_s=100.1)
    assert twist_of(two_poses(unknown, now_s=100.1)) == (*FD, TWIST_COV_FINITE_DIFFERENCE)
    # another robot's twist is not this one's
    other = BridgeCore()
    other.on_status("r2", status(0.3, -0.4), rx_s=100.0)
    assert twist_of(two_poses(other, now_s=100.0))[:2] == FD


def test_host_batch_twists_per_robot_in_a_poses_frame() -> None:
    from bus_schemas import PoseBatch

    core = BridgeCore()
    core.on_status_batch(batch(("r1", "r2"), {"r1": (0.1, 0.2)}), rx_s=50.0)
    frame = PoseBatch(t=1.0, seq=1, robots=("r1", "r2"), x=(0.0, 1.0), y=(0.0, 0.0),
                      theta=(0.0, 0.0), stamp=1.0)  # fmt: skip
    outs = core.on_poses(frame, 7, now_s=50.1)
    assert twist_of(odom_of(outs, "r1")) == (0.1, 0.2, TWIST_COV_ESTIMATOR)
    assert twist_of(odom_of(outs, "r2")) == (0.0, 0.0, TWIST_COV_FINITE_DIFFERENCE)
    # the host's next batch no longer knows r1's twist: unknown from then on
    core.on_status_batch(batch(("r1", "r2"), {"r2": (-0.1, 0.0)}), rx_s=50.2)
    frame2 = PoseBatch(t=1.1, seq=2, robots=("r1", "r2"), x=(0.0, 1.0), y=(0.0, 0.0),
                       theta=(0.0, 0.0), stamp=1.1)  # fmt: skip
    outs = core.on_poses(frame2, 8, now_s=50.3)
    assert twist_of(odom_of(outs, "r1")) == (0.0, 0.0, TWIST_COV_FINITE_DIFFERENCE)
    assert twist_of(odom_of(outs, "r2")) == (-0.1, 0.0, TWIST_COV_ESTIMATOR)


@given(
    v=st.floats(-SPEED_MAX_MPS, SPEED_MAX_MPS),
    w=st.floats(-TURN_RATE_MAX_RADPS, TURN_RATE_MAX_RADPS),
    age=st.floats(0.0, TWIST_FRESH_S),
)
def test_any_contract_twist_reaches_the_odometry_bit_for_bit(
    v: float, w: float, age: float
) -> None:
    sent = decode(encode(status(v, w)), Status)  # through the bus codec
    assert isinstance(sent, Status)
    core = BridgeCore()
    core.on_status("r1", sent, rx_s=0.0)
    odom = odom_of(core.on_pose("r1", 1.0, 0.0, 0.0, 0.0, NS, now_s=age))
    assert twist_of(odom)[:2] == (v, w)


# --- the agent and the agent host publish the estimator's twist -------------------------------


def lockstep_agent() -> tuple[AgentNode, list[tuple[str, bytes]]]:
    out: list[tuple[str, bytes]] = []
    node = AgentNode("r1", "demo", AgentConfig(), lambda k, p, q: out.append((k, p)),
                     lockstep=True)  # fmt: skip
    return node, out


def drive(node: AgentNode, ticks: int) -> None:
    """Lockstep ticks of 0.02 s with a pose and a setpoint ahead of the robot (it moves)."""
    for k in range(1, ticks + 1):
        t = 0.02 * k
        pose = Pose(t=t - 0.02, seq=k, x=0.0, y=0.0, theta=0.0, robot="r1")
        node.on_pose(rt.Received(keys.pose_key("demo", "r1"), encode(pose), t))
        sp = Setpoint(t=t - 0.02, seq=k, robot="r1", slot=1, role="follower", stage=1,
                      parent=0, x=0.3, y=0.05, theta=0.0, vx=0.05, vy=0.0, tick=k - 1)  # fmt: skip
        node.on_setpoint(rt.Received(keys.setpoint_key("demo", "r1"), encode(sp), t))
        clock = Clock(t=t, seq=k, tick=k)
        node.on_clock(rt.Received(keys.clock_key("demo"), encode(clock), t))


def test_agent_status_carries_its_estimators_twist() -> None:
    node, _ = lockstep_agent()
    before = node.status_message(0.0)
    assert (before.v_mps, before.omega_radps) == (None, None)  # no estimate yet: unknown
    drive(node, 25)
    est = node.firmware.estimator
    assert est is not None
    now = node.sim_t
    st = node.status_message(now)
    assert st.v_mps is not None and st.omega_radps is not None
    assert (st.v_mps, st.omega_radps) == est.twist(now)
    assert st.v_mps != 0.0  # the robot was driven toward its setpoint
    assert decode(encode(st), Status) == st


def test_host_status_batch_lists_only_the_robots_with_a_twist() -> None:
    moving, _ = lockstep_agent()
    drive(moving, 25)
    idle, _ = lockstep_agent()  # never saw a pose: its twist is unknown
    now = moving.sim_t
    rows = [status_row("r1", moving.firmware, now), status_row("r2", idle.firmware, now)]
    (msg,) = status_batches(rows, now, 0, 1, "h")
    est = moving.firmware.estimator
    assert est is not None
    tw = est.twist(now)
    assert tw is not None
    assert (msg.twist_robots, msg.v_mps, msg.omega_radps) == (("r1",), (tw[0],), (tw[1],))
    assert decode(encode(msg), StatusBatch) == msg
    (none,) = status_batches(rows[1:], now, 0, 1, "h")
    assert (none.twist_robots, none.v_mps, none.omega_radps) == (None, None, None)
