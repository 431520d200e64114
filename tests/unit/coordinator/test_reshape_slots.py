"""A change of the number of slots while running (issue 28, deliverable 3) and a reshape a
standby continues at a takeover (coordinator.core.reshape, coordinator.core.reshaping)."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from coordinator.core.assignment import RoleAssigner
from coordinator.core.coordinator import CoordinatorCore, CoordinatorOutput
from coordinator.core.formation import FormationSpec
from coordinator.core.reshape import (
    MIN_TRANSITION_S,
    RESHAPE_SPEED_MPS,
    SHAPE_KINDS,
    Transition,
    plan_reshape,
    shape_spec,
)
from coordinator.core.reshaping import MID_RESHAPE, Reshaper
from coordinator.core.trajectory import StraightLine

DT = 0.02
SAFETY_M = 0.2
L_M = 0.05


def _min_gap(points: np.ndarray) -> float:
    return min(
        (math.dist(a, b) for a, b in itertools.combinations(points.tolist(), 2)), default=math.inf
    )


@settings(max_examples=30, deadline=None)
@given(
    n_old=st.integers(1, 6),
    n_new=st.integers(1, 7),
    a=st.sampled_from(SHAPE_KINDS),
    b=st.sampled_from(SHAPE_KINDS),
)
def test_a_plan_to_another_slot_count_keeps_ids_separation_and_speed(
    n_old: int, n_new: int, a: str, b: str
) -> None:
    running = shape_spec(a, n_old, 0.4)
    plan = plan_reshape(running, b, 0.4, SAFETY_M, slots=n_new)
    assert isinstance(plan, Transition), plan
    assert plan.slots == len(plan.target) == n_new
    old, new = set(running.slot_ids), set(plan.target.slot_ids)
    assert 0 in new and set(plan.dropped) == old - new and set(plan.added) == new - old
    assert not (plan.dropped and plan.added)
    assert all(s > max(old) for s in plan.added)  # fresh ids: nobody's slot is renamed
    # the dropped slots are the rearmost of the running ones (the least body x)
    if plan.dropped:
        x_of = dict(zip(running.slot_ids, running.body_offsets_m[:, 0].tolist(), strict=True))
        kept_x = [x_of[s] for s in new]
        assert max(x_of[s] for s in plan.dropped) <= min(kept_x) + 1e-9
    assert set(plan.spec.slot_ids) == old | new
    assert plan.least_separation_m >= SAFETY_M
    for k in range(0, int(plan.duration_s / DT) + 2):
        off, rate, _ = plan.progress(k * DT)
        assert float(np.hypot(*rate.T).max()) <= RESHAPE_SPEED_MPS + 1e-9
        assert _min_gap(off) >= SAFETY_M - 1e-3
    # where the plan ends is the target, slot by slot
    end = dict(zip(plan.spec.slot_ids, plan.end.tolist(), strict=True))
    for sid, off in zip(plan.target.slot_ids, plan.target.body_offsets_m.tolist(), strict=True):
        assert np.allclose(end[sid], off)
    assert plan.duration_s >= MIN_TRANSITION_S


def test_bad_slot_counts_are_refused() -> None:
    spec = FormationSpec.triangle(0.4)
    for bad in (0, -1, 10_000, 2.5, True):
        assert plan_reshape(spec, "column", 0.4, SAFETY_M, slots=bad) == "bad_slots"  # type: ignore[arg-type]
    r = Reshaper(spec)
    assert r.ask("column", 0.4, SAFETY_M, slots=4, robots=3) == "too_many_slots"
    assert r.ask("column", 0.4, SAFETY_M, slots=3, robots=3) is None


def _core() -> CoordinatorCore:
    traj = StraightLine(x0=0.0, y0=0.0, heading=0.0, speed_mps=0.05)
    return CoordinatorCore(traj, FormationSpec.triangle(0.4), RoleAssigner(), ref_offset_m=L_M)


def _follow(out: CoordinatorOutput, poses: dict[str, tuple[float, float, float]]) -> None:
    """Robots exactly on their setpoints (perfect followers); the others stand still."""
    for rid in out.assignment:
        sp = out.setpoint_for(rid)
        assert sp is not None
        poses[rid] = (sp.x - L_M * math.cos(sp.theta), sp.y - L_M * math.sin(sp.theta), sp.theta)


def test_a_spare_joins_a_slot_added_and_the_rearmost_robot_leaves_a_slot_dropped() -> None:
    core = _core()
    out = core.tick(0.0, {})
    poses = {
        rid: (row[0] - L_M, row[1], 0.0)
        for rid, row in zip(("r1", "r2", "r3"), out.rows, strict=True)
    }
    poses["r4"] = (-1.5, 0.0, 0.0)  # a spare behind the formation
    k = 1
    history: list[CoordinatorOutput] = []

    def run_until_settled() -> None:
        nonlocal k, out
        n_done = len(core.reshapes)
        while len(core.reshapes) == n_done or core.reshaping is not None:
            out = core.tick(k * DT, poses)
            history.append(out)
            _follow(out, poses)
            k += 1
            assert k < 100_000
        for _ in range(300):  # the spare reaches its slot on its approach point
            out = core.tick(k * DT, poses)
            history.append(out)
            _follow(out, poses)
            k += 1

    for _ in range(50):
        out = core.tick(k * DT, poses)
        history.append(out)
        _follow(out, poses)
        k += 1
    first = dict(out.assignment)
    assert first == {"r1": 0, "r2": 1, "r3": 2}
    assert core.reshape("chevron", 0.4, SAFETY_M, slots=4, robots=4) is None
    run_until_settled()
    grown = dict(out.assignment)
    assert {r: grown[r] for r in first} == first and grown["r4"] == 3  # the spare took slot 3
    assert core.reshape("column", 0.4, SAFETY_M, slots=2, robots=4) is None
    run_until_settled()
    cut = dict(out.assignment)
    assert len(cut) == 2 and cut["r1"] == 0
    # every robot changed role at most once per slot-count change: no flapping
    for rid in ("r1", "r2", "r3", "r4"):
        slots = [o.assignment.get(rid) for o in history]
        changes = sum(1 for a, b in itertools.pairwise(slots) if a != b)
        assert changes <= 2, (rid, changes)
    assert sum(1 for a, b in itertools.pairwise(history) if a.assignment != b.assignment) == 2
    # the slots never closer than the safety distance, before, during and after
    for o in history:
        assert _min_gap(np.array([r[:2] for r in o.rows])) >= SAFETY_M - 1e-3
    assert [r["slots"] for r in core.reshapes] == [4, 2]
    assert core.reshapes[0]["added"] == [3] and len(core.reshapes[1]["dropped"]) == 2
    for r in core.reshapes:
        assert r["least_separation_m"] >= SAFETY_M and r["transition_s"] >= MIN_TRANSITION_S


@pytest.mark.parametrize("slots", [None, 5, 2])
def test_a_standby_continues_a_running_reshape_at_its_start_time_bit_for_bit(
    slots: int | None,
) -> None:
    running = shape_spec("triangle", 3 if slots != 2 else 4, 0.4)
    active, standby = Reshaper(running), Reshaper(running)
    assert active.ask("column", 0.4, SAFETY_M, slots) is None
    assert standby.ask_standby("column", 0.4, SAFETY_M, slots) is None
    t = 10.0
    assert active.advance(t) is not None
    active.offsets(t)
    for k in range(1, 60):
        active.advance(t + k * DT)
        active.offsets(t + k * DT)
    state = active.state()
    assert state is not None and state.source is None and state.t0_s == t
    assert standby.take_over(state, SAFETY_M) == "continued"
    later = t + 100 * DT
    for r in (active, standby):
        r.advance(later)
    a_off, a_rate = active.offsets(later)
    b_off, b_rate = standby.offsets(later)
    assert np.array_equal(a_off, b_off) and np.array_equal(a_rate, b_rate)
    assert active.running == standby.running


def test_a_standby_that_cannot_match_the_running_reshape_settles_it() -> None:
    running = shape_spec("triangle", 3, 0.4)
    active, standby = Reshaper(running), Reshaper(running)
    assert active.ask("column", 0.4, SAFETY_M) is None
    for k in range(30):
        active.advance(k * DT)
        active.offsets(k * DT)
    assert active.ask("line", 0.4, SAFETY_M) is None  # during the first: from the blend
    active.advance(30 * DT)
    state = active.state()
    assert state is not None and state.source == MID_RESHAPE
    assert standby.ask_standby("column", 0.4, SAFETY_M) is None
    assert standby.ask_standby("line", 0.4, SAFETY_M) is None
    assert standby.take_over(state, SAFETY_M) == "finished"
    assert standby.transition is None and len(standby.formation) == 3
    line_offsets = sorted(map(tuple, shape_spec("line", 3, 0.4).body_offsets_m.tolist()))
    assert standby.shape == "line"
    assert sorted(map(tuple, standby.formation.body_offsets_m.tolist())) == line_offsets
    # a standby that saw neither command settles into the shape the state names
    blind = Reshaper(running)
    assert blind.take_over(state, SAFETY_M) == "finished" and blind.shape == "line"
    assert sorted(map(tuple, blind.formation.body_offsets_m.tolist())) == line_offsets
    # no reshape running at the takeover: the one kept is settled
    quiet = Reshaper(running)
    assert quiet.ask_standby("line", 0.4, SAFETY_M, slots=2) is None
    assert quiet.take_over(None, SAFETY_M) == "finished" and len(quiet.formation) == 2
    # a standby that missed the command re-plans it from the settled formation
    late = Reshaper(running)
    fresh = Reshaper(running)
    assert fresh.ask("chevron", 0.5, SAFETY_M, 3) is None
    fresh.advance(1.0)
    st_ = fresh.state()
    assert st_ is not None and late.take_over(st_, SAFETY_M) == "replanned"
