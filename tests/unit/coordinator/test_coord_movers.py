"""coordinator/core/movers.py (issue 30): which robots are movers, the slots kept for them, the
robots that make room and their refuges; and CoordinatorCore giving a mover no slot."""

from __future__ import annotations

import math
import random

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from coordinator.core.coordinator import CoordinatorCore
from coordinator.core.movers import MoverDetector, MoverParams

DT_S = 1.0 / 30.0  # a camera frame
L_M = 0.05


def _core() -> CoordinatorCore:
    return CoordinatorCore.from_config(
        {"kind": "line", "x0": 0.4, "y0": 0.0, "heading": 0.0, "speed_mps": 0.0},
        {"kind": "triangle", "b_m": 0.4},
        "greedy",
        0.05,
        0.01,
        L_M,
    )


def _in_slots(core: CoordinatorCore) -> dict[str, tuple[float, float, float]]:
    """Three robots with their reference points on the slots (facing +x)."""
    rows = core.tick(0.0, {}).rows
    return {f"r{k + 1}": (row[0] - L_M, row[1], 0.0) for k, row in enumerate(rows)}


@settings(max_examples=10, deadline=None, derandomize=True)
@given(seed=st.integers(0, 2**32 - 1))
def test_camera_noise_on_a_still_spare_is_not_motion(seed: int) -> None:
    """3 mm of noise per axis on a spare standing still: never a mover in 60 s of frames."""
    rng = random.Random(seed)
    det = MoverDetector()
    for k in range(1800):
        pose = (1.0 + rng.gauss(0, 0.003), 2.0 + rng.gauss(0, 0.003), 0.0)
        assert not det.update(k * DT_S, {"spare": pose}, {})


def test_a_spare_moving_is_a_mover_a_driven_robot_only_when_too_fast() -> None:
    p = MoverParams()
    det = MoverDetector(p)
    movers: frozenset[str] = frozenset()
    for k in range(60):  # 2 s
        t = k * DT_S
        poses = {
            "spare": (0.05 * t, 0.0, 0.0),  # carried at 0.05 m/s, no slot
            # (10 m apart: none makes room for another)
            "driver": (0.25 * t, 10.0, 0.0),  # its slot's robot, at top speed: driving
            "thrown": (0.6 * t, 20.0, 0.0),  # has a slot, faster than any robot drives
            "held": (0.0, 30.0 + 0.1 * t, 0.0),  # has a slot but e-stopped, carried
        }
        movers = det.update(t, poses, {"driver": 0, "thrown": 1, "held": 2}, held={"held"})
    assert det.movers == {"spare", "thrown", "held"}
    assert "driver" not in movers
    assert det.yielding == frozenset()
    assert det.reserved == {"thrown": 1, "held": 2}  # their slots, kept for them
    assert det.speed_mps("spare") == pytest.approx(0.05)
    assert det.velocity("thrown") == pytest.approx((0.6, 0.0))


def test_a_mover_stays_one_for_hold_s_after_it_stops() -> None:
    p = MoverParams()
    det = MoverDetector(p)
    t = 0.0
    x = 0.0
    for k in range(60):
        t = k * DT_S
        x = 0.2 * t
        det.update(t, {"spare": (x, 0.0, 0.0)}, {})
    assert det.movers == {"spare"}
    stopped = t
    while t < stopped + p.window_s + p.hold_s + 0.2:
        t += DT_S
        det.update(t, {"spare": (x, 0.0, 0.0)}, {})
        if t < stopped + p.hold_s:
            assert det.movers == {"spare"}
    assert det.movers == frozenset()
    assert det.reserved == {}


def test_non_finite_input_is_counted_and_skipped() -> None:
    det = MoverDetector()
    det.update(0.0, {"a": (math.nan, 0.0, 0.0)}, {})
    det.update(math.inf, {"a": (0.0, 0.0, 0.0)}, {})
    assert det.rejected == 2
    with pytest.raises(ValueError, match="still_mps"):
        MoverParams(still_mps=1.0, fast_mps=0.5)
    with pytest.raises(ValueError, match="window_s"):
        MoverParams(window_s=0.0)


def test_a_carried_spare_never_takes_a_slot_and_the_formation_makes_room() -> None:
    """A spare carried at 0.2 m/s head-on through the leader's place: it never gets a slot,
    the three keep theirs, and while it passes their setpoints are refuges off its line (none
    on the body's side of it), on one side each for the whole pass."""
    core = _core()
    poses = _in_slots(core)
    leader_x = poses["r1"][0]
    sides: dict[str, set[bool]] = {"r1": set(), "r2": set(), "r3": set()}
    made_room = 0
    for k in range(round(12.0 / DT_S)):
        t = k * DT_S
        spare_x = leader_x + 1.2 - 0.2 * t
        out = core.tick(t, {**poses, "r4": (spare_x, 0.01, math.pi)})
        assert "r4" not in out.assignment
        assert {r: out.assignment[r] for r in poses} == {"r1": 0, "r2": 1, "r3": 2}
        for rid in poses:
            sp = out.setpoint_for(rid)
            assert sp is not None
            if rid in out.approach:
                made_room += 1
                # the refuge is at least clear_m from the body's line (y = 0.01) or it is
                # the robot's own point (nothing asks it to move)
                qx, qy = poses[rid][0] + L_M, poses[rid][1]
                off_line = abs(sp.y - 0.01) >= core.movers.params.clear_m - 1e-6
                assert off_line or (sp.x, sp.y) == pytest.approx((qx, qy))
                if off_line:
                    sides[rid].add(sp.y > 0.01)
    assert made_room > 0
    assert all(len(s) <= 1 for s in sides.values())  # never flips sides
    assert core.movers.movers == {"r4"}


def test_a_carried_leader_keeps_its_slot_for_itself() -> None:
    """The leader e-stopped and carried away: it is a mover, nobody else is sent to its slot
    (the spare standing by stays unassigned), and it gets no slot while carried."""
    core = _core()
    poses = _in_slots(core)
    poses["r4"] = (-1.0, -1.0, 0.0)  # a spare, far away and still
    for k in range(round(4.0 / DT_S)):
        t = k * DT_S
        x, y, th = poses["r1"]
        moved = {**poses, "r1": (x, y + (0.1 * (t - 1.0) if t > 1.0 else 0.0), th)}
        out = core.tick(t, moved, held={"r1"})
        if t > 2.0:
            assert "r1" not in out.assignment
            assert 0 not in out.assignment.values()
            assert "r4" not in out.assignment
    assert core.movers.reserved.get("r1") == 0


def test_the_same_inputs_give_the_same_decisions() -> None:
    """Deterministic: two cores fed the same ticks decide the same (what lets a lockstep run
    over Zenoh equal the in-process one, which feed the core the same poses)."""

    def run() -> list[tuple[dict[str, int], dict[str, tuple[float, ...]]]]:
        core = _core()
        poses = _in_slots(core)
        rng = random.Random(7)
        out = []
        for k in range(200):
            t = k * DT_S
            noisy = {r: (x + rng.gauss(0, 0.003), y, th) for r, (x, y, th) in poses.items()}
            o = core.tick(t, {**noisy, "r4": (1.5 - 0.25 * t, 0.0, 0.0)})
            out.append((dict(o.assignment), {r: tuple(v) for r, v in o.approach.items()}))
        return out

    assert run() == run()


def test_a_moving_tracked_object_is_a_mover_a_still_one_is_not() -> None:
    """A tracked object (not a fleet robot) moving is a mover, and the robots near it (not
    the objects) make room; a still object is not."""
    det = MoverDetector()
    excluded: frozenset[str] = frozenset()
    for k in range(60):
        t = k * DT_S
        excluded = det.update(
            t,
            {"near": (0.5, 0.3, 0.0), "far": (5.0, 5.0, 0.0)},
            {"near": 0, "far": 1},
            objects={"cart": (0.1 * t, 0.0), "box": (0.6, 0.6)},
        )
    assert det.movers == {"cart"}
    assert det.yielding == {"near"}
    assert excluded == {"cart", "near"}
    assert det.reserved == {"near": 0}


def _carry_past(
    det: MoverDetector,
    robots: dict[str, tuple[float, float]],
    v: tuple[float, float],
    start: tuple[float, float],
    ticks: int,
    wobble: float = 0.0,
) -> None:
    """A spare carried at velocity ``v`` from ``start`` past still ``robots`` (no slots)."""
    for k in range(ticks):
        t = k * DT_S
        # the first frames' direction is off by ``wobble`` (noise over a short displacement)
        off = wobble if k < 20 else 0.0
        x, y = start[0] + v[0] * t, start[1] + v[1] * t + off * t
        poses = {rid: (px, py, 0.0) for rid, (px, py) in robots.items()}
        det.update(t, {**poses, "spare": (x, y, 0.0)}, dict.fromkeys(robots, 0))


def test_aside_rows_carry_a_feed_forward_toward_the_refuge() -> None:
    """A robot making room gets its refuge with a velocity toward it: the top speed far from
    it (the slot gain alone moved it at 0.07 m/s), proportional near it, zero there."""
    p = MoverParams()
    det = MoverDetector(p)
    _carry_past(det, {"r1": (0.0, 0.0)}, (-0.3, 0.0), (1.0, 0.0), 30)
    assert "r1" in det.yielding
    ((rx, ry, vx, vy),) = det.aside_rows({"r1": (0.0, 0.0)}).values()
    assert math.hypot(rx, ry) == pytest.approx(p.clear_m, abs=1e-6)
    assert math.hypot(vx, vy) == pytest.approx(p.aside_mps)
    assert vx * rx + vy * ry > 0.0  # toward the refuge
    near = (rx * 0.95, ry * 0.95)
    ((_, _, vx, vy),) = det.aside_rows({"r1": near}).values()
    dist = math.hypot(rx - near[0], ry - near[1])
    assert math.hypot(vx, vy) == pytest.approx(p.aside_gain_per_s * dist)
    ((_, _, vx, vy),) = det.aside_rows({"r1": (rx, ry)}).values()
    assert (vx, vy) == (0.0, 0.0)


def test_a_robot_beside_a_movers_line_steps_away_on_its_own_side() -> None:
    """A body carried along y = -0.2 (-x): the robot at y = +0.2 (0.4 m off its line, past the
    formation's centre) keeps its side even when the first velocity estimate is skewed; the
    robot on the line steps out of the formation."""
    det = MoverDetector()
    robots = {"a": (0.0, 0.2), "b": (0.0, -0.2), "c": (-0.4, 0.2), "d": (-0.4, -0.2)}
    _carry_past(det, robots, (-0.3, 0.0), (1.0, -0.2), 40, wobble=0.3)
    rows = det.aside_rows(robots)
    assert rows["a"][1] >= 0.2 - 1e-9  # not across the line y = -0.2
    assert rows["b"][1] < -0.2 - 0.3  # off the line, away from the formation (-y)


def test_movers_are_reported_with_their_velocity() -> None:
    core = _core()
    poses = _in_slots(core)
    out = None
    for k in range(40):
        t = k * DT_S
        out = core.tick(t, {**poses, "r4": (1.5 - 0.3 * t, 0.0, math.pi)})
    assert out is not None
    ((mid, x, y, vx, vy),) = out.movers
    assert y == 0.0
    assert mid == "r4" and vx == pytest.approx(-0.3) and vy == pytest.approx(0.0, abs=1e-9)
    assert x == pytest.approx(1.5 - 0.3 * 39 * DT_S)
    assert "r4" not in out.assignment


def test_a_robot_turned_object_is_measured_from_then_on_and_a_mover_when_carried() -> None:
    """A robot whose agent died leaves the poses and is given as an object (its wheels are
    stopped): its driving before does not make it a mover (the window starts again), a hand
    carrying it afterwards does, with its velocity."""
    det = MoverDetector()
    for k in range(30):  # 1 s: driving its slot at 0.2 m/s (driven: no mover)
        t = k * DT_S
        det.update(t, {"dead": (0.2 * t, 0.0, 0.0), "r2": (0.0, 1.0, 0.0)}, {"dead": 0, "r2": 1})
    assert det.movers == frozenset()
    x0 = 0.2 * 29 * DT_S
    t_kill = 30 * DT_S
    for k in range(30, 60):  # its agent died: stopped, an object (no slot, not driven)
        t = k * DT_S
        det.update(t, {"r2": (0.0, 1.0, 0.0)}, {"r2": 0}, objects={"dead": (x0, 0.0)})
        assert det.movers == frozenset(), f"a stopped dead robot is no mover (t={t:.2f})"
    t_drag = 60 * DT_S
    for k in range(60, 90):  # carried back at 0.15 m/s
        t = k * DT_S
        obj = {"dead": (x0 - 0.15 * (t - t_drag), 0.0)}
        det.update(t, {"r2": (0.0, 1.0, 0.0)}, {"r2": 0}, objects=obj)
    assert det.movers == {"dead"}
    assert det.velocity("dead") == pytest.approx((-0.15, 0.0))
    assert t_kill < t_drag
