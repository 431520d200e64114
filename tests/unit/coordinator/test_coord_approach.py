"""A robot assigned while the formation runs approaches its slot at a bounded speed (issue 13).

The rule is in ``coordinator.core.coordinator.CoordinatorCore`` (shared by the in-process simulator
and the
Zenoh coordinator): a spare that replaces a vanished robot gets an approach point that starts at
its own reference point and closes in on the slot at ``APPROACH_SPEED_MPS`` relative to it, so
its firmware never saturates the wheels on the way (the same robot given the far slot directly
does); robots assigned at the start go straight to their slots as in the paper.
"""

from __future__ import annotations

import math

from hypothesis import given, settings
from hypothesis import strategies as st

from coordinator.core.coordinator import APPROACH_JOIN_M, APPROACH_SPEED_MPS, CoordinatorCore
from robot_agent.core.firmware import Firmware, Mode, Pose, Setpoint
from robot_agent.core.kinematics import reference_point, twist_from_wheels
from robot_agent.core.params import AgentConfig
from scenario import load
from scenario.assemble import coordinator_core

SCN = load("paper-exp2")
L_M = SCN.agent.geometry.ref_offset_m
DT = 0.02


def pose_at(x_ref: float, y_ref: float, theta: float) -> tuple[float, float, float]:
    """The axle-centre pose whose reference point is (x_ref, y_ref)."""
    return (x_ref - L_M * math.cos(theta), y_ref - L_M * math.sin(theta), theta)


def formed(core: CoordinatorCore, t: float) -> dict[str, tuple[float, float, float]]:
    """r1..r3 standing exactly in the slots of the first tick's assignment."""
    out = core.tick(t, {"r1": (0.40, 0.02, 0.0), "r2": (0.1, 0.22, 0.0), "r3": (0.1, -0.2, 0.0)})
    assert not out.approach  # robots assigned at the start go straight to their slots
    by = out.slots_by_id
    return {r: pose_at(by[s].x, by[s].y, by[s].theta) for r, s in out.assignment.items()}


def test_a_spare_gets_an_approach_point_that_reaches_its_slot() -> None:
    core = coordinator_core(SCN)
    poses = formed(core, 0.0)
    far = pose_at(-1.5, 1.0, 2.0)
    del poses["r3"]  # r3 is gone, the spare r4 stands 1.5 m away
    poses["r4"] = far
    t = DT
    out = core.tick(t, poses)
    assert "r4" in out.assignment and set(out.approach) == {"r4"}
    sp = out.setpoint_for("r4")
    slot = out.slots_by_id[out.assignment["r4"]]
    assert sp is not None and (sp.slot, sp.role) == (slot.slot, slot.role)
    rx, ry = reference_point(*far, L_M)
    speed = math.hypot(slot.vx, slot.vy) + APPROACH_SPEED_MPS
    assert math.hypot(sp.x - rx, sp.y - ry) <= speed * DT + 1e-9  # starts at it
    steps = 0
    while "r4" in out.approach:
        t += DT
        steps += 1
        out = core.tick(t, poses)
        row = out.approach.get("r4")
        if row is not None:
            assert math.hypot(row[2], row[3]) <= speed + 1e-9  # bounded feed-forward
        assert steps < 2000
    slot = out.slots_by_id[out.assignment["r4"]]
    assert out.setpoint_for("r4") == slot  # reached: the slot itself
    dist = math.hypot(slot.x - rx, slot.y - ry)
    assert steps * DT <= dist / APPROACH_SPEED_MPS + 1.0  # closes in at the bounded speed


def test_robots_moving_between_slots_and_near_spares_go_straight() -> None:
    core = coordinator_core(SCN)
    poses = formed(core, 0.0)
    out = core.tick(DT, poses)
    slots = out.slots_by_id
    del poses["r1"]  # the leader vanishes: r2/r3 move between slots, no approach
    s = slots[out.assignment["r1"]]
    poses["r4"] = pose_at(s.x + APPROACH_JOIN_M / 2, s.y, 0.0)  # a spare right at r1's slot
    out = core.tick(2 * DT, poses)
    assert out.changed and not out.approach


def run_spare(approach: bool, start: tuple[float, float, float]) -> tuple[int, float]:
    """Closed loop (firmware + unicycle) of a spare sent to a slot ~1.5 m away: (ticks with
    saturated wheels, final distance of its reference point to the slot)."""
    core = coordinator_core(SCN)
    if not approach:
        core.approach_speed_mps = math.inf  # the approach point jumps onto the slot at once
    poses = formed(core, 0.0)
    del poses["r3"]
    x, y, th = start
    fw = Firmware(AgentConfig(geometry=SCN.agent.geometry))
    geom = SCN.agent.geometry
    saturated = 0
    t = 0.0
    out = None
    for _ in range(int(25.0 / DT)):
        t += DT
        poses["r4"] = (x, y, th)
        out = core.tick(t, poses)
        for rid in ("r1", "r2"):  # the others track their slots exactly
            s = out.setpoint_for(rid)
            assert s is not None
            poses[rid] = pose_at(s.x, s.y, s.theta)
        sp = out.setpoint_for("r4")
        assert sp is not None
        cmd = fw.step(
            t,
            pose=Pose(x, y, th, t),
            pose_rx_s=t,
            setpoint=Setpoint(sp.x, sp.y, sp.vx, sp.vy, sp.theta, sp.slot, t),
            setpoint_rx_s=t,
        )
        assert cmd.mode is Mode.TRACKING
        saturated += cmd.saturated
        v, w = twist_from_wheels(cmd.omega_r, cmd.omega_l, geom)
        x, y, th = x + v * math.cos(th) * DT, y + v * math.sin(th) * DT, th + w * DT
    assert out is not None
    slot = out.slots_by_id[out.assignment["r4"]]
    rx, ry = reference_point(x, y, th, L_M)
    return saturated, math.hypot(slot.x - rx, slot.y - ry)


@settings(max_examples=8, deadline=None)
@given(st.floats(-math.pi, math.pi))
def test_a_spare_never_sprints_and_still_joins(heading: float) -> None:
    saturated, dist = run_spare(True, (-1.2, 0.6, heading))
    assert saturated == 0 and dist < 0.02


def test_without_the_approach_the_same_spare_saturates() -> None:
    saturated, _ = run_spare(False, (-1.2, 0.6, 0.0))
    assert saturated > 0
