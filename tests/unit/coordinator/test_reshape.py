"""Runtime reshaping (coordinator.core.reshape): shapes, plans with a separation guarantee, and
the coordinator's tick through a reshape (continuity, no role change)."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from coordinator.core.assignment import RoleAssigner
from coordinator.core.coordinator import CoordinatorCore
from coordinator.core.formation import FormationSpec
from coordinator.core.reshape import (
    MIN_TRANSITION_S,
    RESHAPE_SPEED_MPS,
    SHAPE_KINDS,
    Transition,
    plan_reshape,
    shape_spec,
)
from coordinator.core.trajectory import Circle

DT = 0.02
SAFETY_M = 0.2  # 2 x 0.075 m body radius + the filter's margin, as the scenarios' default
L_M = 0.05


def _min_gap(points: np.ndarray) -> float:
    return min(
        (math.dist(a, b) for a, b in itertools.combinations(points.tolist(), 2)), default=math.inf
    )


@pytest.mark.parametrize("kind", SHAPE_KINDS)
@pytest.mark.parametrize("n", [1, 2, 3, 5, 7])
def test_every_shape_keeps_its_spacing(kind: str, n: int) -> None:
    spec = shape_spec(kind, n, 0.4)
    assert len(spec) == n and spec.slot_ids[0] == 0
    off = spec.body_offsets_m
    assert tuple(off[0]) == (0.0, 0.0)
    assert _min_gap(off) >= 0.4 - 1e-9


def test_column_and_line_are_what_they_say() -> None:
    col = shape_spec("column", 4, 0.5).body_offsets_m
    assert np.allclose(col, [[0, 0], [-0.5, 0], [-1.0, 0], [-1.5, 0]])
    line = shape_spec("line", 5, 0.5).body_offsets_m
    assert np.allclose(sorted(line[:, 1]), [-1.0, -0.5, 0.0, 0.5, 1.0])
    assert np.allclose(line[:, 0], 0.0)


@pytest.mark.parametrize("bad", [math.nan, -0.4, 0.0, 1e300])
def test_bad_spacing_and_kind_are_refused(bad: float) -> None:
    spec = FormationSpec.triangle(0.4)
    assert plan_reshape(spec, "column", bad, SAFETY_M) == "bad_shape"
    assert plan_reshape(spec, "zigzag", 0.4, SAFETY_M) == "bad_shape"


def test_a_reshape_that_cannot_keep_the_safety_distance_is_refused() -> None:
    spec = FormationSpec.triangle(0.4)
    assert plan_reshape(spec, "column", 0.4, safety_m=0.5) == "unsafe"


@settings(max_examples=25, deadline=None)
@given(
    n=st.integers(2, 7),
    a=st.sampled_from(SHAPE_KINDS),
    b=st.sampled_from(SHAPE_KINDS),
    spacing=st.floats(0.3, 0.8),
)
def test_a_plan_keeps_the_leader_the_slot_ids_and_the_separation(
    n: int, a: str, b: str, spacing: float
) -> None:
    running = shape_spec(a, n, 0.4)
    plan = plan_reshape(running, b, spacing, SAFETY_M)
    assert isinstance(plan, Transition), plan
    assert set(plan.target.slot_ids) == set(running.slot_ids)
    assert plan.least_separation_m >= SAFETY_M
    assert tuple(plan.end[0]) == (0.0, 0.0)  # the virtual leader stays the leader slot
    # the target's offsets, by slot id, are where the plan ends
    by_id = dict(zip(plan.target.slot_ids, plan.target.body_offsets_m.tolist(), strict=True))
    for r, sid in enumerate(running.slot_ids):
        assert np.allclose(by_id[sid], plan.end[r])
    assert plan.duration_s >= MIN_TRANSITION_S
    # no slot faster than the reshape speed (sampled), and the separation holds when sampled
    prev = None
    for k in range(0, int(plan.duration_s / DT) + 2):
        off, rate, _ = plan.progress(k * DT)
        assert float(np.hypot(*rate.T).max()) <= RESHAPE_SPEED_MPS + 1e-9
        assert _min_gap(off) >= SAFETY_M - 1e-3
        if prev is not None:  # the rates are the derivative of the offsets
            assert np.allclose((off - prev) / DT, rate, atol=2e-3)
        prev = off
    assert plan.progress(plan.duration_s)[2] and np.allclose(plan.progress(1e9)[0], plan.end)


def _core() -> CoordinatorCore:
    traj = Circle(cx=0.0, cy=0.0, radius_m=2.0, speed_mps=0.05)
    return CoordinatorCore(traj, FormationSpec.triangle(0.4), RoleAssigner(), ref_offset_m=L_M)


def _on_setpoints(out: object) -> dict[str, tuple[float, float, float]]:
    """Robots exactly on their setpoints (perfect followers)."""
    poses = {}
    for rid, slot in out.assignment.items():  # type: ignore[attr-defined]
        sp = out.setpoint_for(rid)  # type: ignore[attr-defined]
        poses[rid] = (sp.x - L_M * math.cos(sp.theta), sp.y - L_M * math.sin(sp.theta), sp.theta)
        del slot
    return poses


def test_triangle_column_triangle_while_moving_keeps_roles_and_separation() -> None:
    core = _core()
    start = core.tick(0.0, {})
    poses = {
        rid: (row[0] - L_M, row[1], 0.0)
        for rid, row in zip(("r1", "r2", "r3"), start.rows, strict=True)
    }
    out = core.tick(DT, poses)
    first = dict(out.assignment)
    assert len(first) == 3
    history = [out]
    k = 2
    for kind in ("column", "triangle"):
        assert core.reshape(kind, 0.4, SAFETY_M) is None
        n_done = len(core.reshapes)
        while len(core.reshapes) == n_done or core.reshaping is not None:
            out = core.tick(k * DT, _on_setpoints(history[-1]))
            history.append(out)
            k += 1
            assert k < 100_000
        for _ in range(50):
            out = core.tick(k * DT, _on_setpoints(history[-1]))
            history.append(out)
            k += 1
    # no role change: every tick the same robot on the same slot
    assert all(o.assignment == first for o in history), "a reshape changed the assignment"
    # separation of the slots never below the safety distance, and no jump of a slot
    for a, b in itertools.pairwise(history):
        pa = {sid: row for sid, row in zip(a.slot_ids, a.rows, strict=True)}
        pb = {sid: row for sid, row in zip(b.slot_ids, b.rows, strict=True)}
        assert _min_gap(np.array([r[:2] for r in pb.values()])) >= SAFETY_M - 1e-3
        for sid, (x, y, vx, vy) in pb.items():
            x0, y0, vx0, vy0 = pa[sid]
            assert math.hypot(x - x0, y - y0) <= (0.05 + 0.05 * 1.0 + RESHAPE_SPEED_MPS) * DT
            # feed-forward consistent: the displacement is the velocity over the tick
            assert math.hypot((x - x0) / DT - vx, (y - y0) / DT - vy) < 5e-3
            assert math.hypot(vx - vx0, vy - vy0) < 0.01
    assert [r["kind"] for r in core.reshapes] == ["column", "triangle"]
    for r in core.reshapes:
        assert r["least_separation_m"] >= SAFETY_M and r["transition_s"] >= MIN_TRANSITION_S
    # back in the triangle: the scenario's shape again, same slot ids
    final = {sid: row for sid, row in zip(out.slot_ids, out.rows, strict=True)}
    lead = final[0]
    assert math.hypot(final[1][0] - lead[0], final[1][1] - lead[1]) == pytest.approx(0.4)


def test_a_reshape_during_a_reshape_starts_from_where_the_slots_are() -> None:
    core = _core()
    out = core.tick(0.0, {})
    assert core.reshape("column", 0.4, SAFETY_M) is None
    for k in range(1, 60):
        out = core.tick(k * DT, {})
    mid = {sid: row for sid, row in zip(out.slot_ids, out.rows, strict=True)}
    assert core.reshape("line", 0.4, SAFETY_M) is None
    out = core.tick(60 * DT, {})
    after = {sid: row for sid, row in zip(out.slot_ids, out.rows, strict=True)}
    for sid, row in after.items():
        assert math.hypot(row[0] - mid[sid][0], row[1] - mid[sid][1]) < 0.01
