"""The role assigner's shortcuts (coordinator.core.matching: kept_by_spacing, greedy_kept, the
optimal rule's incumbent check) give the rules' own answer, and slot_rows' heading memo gives
the bits of a fresh computation."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from coordinator.core.assignment import RoleAssigner
from coordinator.core.formation import FormationSpec, SlotRow, slot_rows
from coordinator.core.matching import (
    _optimal_kept,
    greedy_kept,
    greedy_py,
    kept_by_spacing,
    optimal_ordered,
)
from coordinator.core.trajectory import LeaderState

SHAPES = ("triangle", "chevron", "lattice")


def _spec(kind: str, n: int) -> FormationSpec:
    return FormationSpec.triangle() if kind == "triangle" else getattr(FormationSpec, kind)(n)


def _rows(slot_ids: Sequence[int]) -> dict[int, int]:
    return {sid: j for j, sid in enumerate(slot_ids)}


def _fleet(
    spec: FormationSpec, rng: np.random.Generator, noise_m: float, spares: int, theta: float
) -> tuple[list[str], list[tuple[float, float]], tuple[int, ...], list[SlotRow]]:
    """Robots near the slots of ``spec`` (``noise_m`` off, ids in natural order, a shuffled
    holder per slot) plus ``spares`` robots anywhere; the slots in priority order."""
    leader = LeaderState(
        0.0, float(rng.uniform(-3, 3)), float(rng.uniform(-3, 3)), theta, 0.05, 0.1
    )
    _, rows = slot_rows(spec, leader)
    slot_xy = [rows[r] for r in spec.priority_rows]
    n = len(slot_xy) + spares
    ids = [f"r{i + 1}" for i in range(n)]
    order = rng.permutation(len(slot_xy))
    xy = [(0.0, 0.0)] * n
    for i, j in enumerate(order):
        xy[i] = (
            slot_xy[j][0] + float(rng.normal(0.0, noise_m)),
            slot_xy[j][1] + float(rng.normal(0.0, noise_m)),
        )
    for i in range(len(slot_xy), n):
        xy[i] = (float(rng.uniform(-4, 4)), float(rng.uniform(-4, 4)))
    return ids, xy, spec.priority_slots, slot_xy


@settings(max_examples=150, deadline=None)
@given(
    kind=st.sampled_from(SHAPES),
    n=st.integers(2, 12),
    seed=st.integers(0, 2**32 - 1),
    noise_m=st.sampled_from([0.0, 0.01, 0.05, 0.15, 0.4]),
    spares=st.integers(0, 3),
    drop=st.integers(0, 2),
    method=st.sampled_from(["greedy", "optimal"]),
    hyst=st.sampled_from([0.0, 0.05, 0.3]),
    tol=st.sampled_from([0.0, 0.01, 0.3]),
    theta=st.sampled_from([0.0, -0.0, 1.0, -2.5, math.pi]),
)
def test_update_with_spacing_equals_the_rule(
    kind: str,
    n: int,
    seed: int,
    noise_m: float,
    spares: int,
    drop: int,
    method: str,
    hyst: float,
    tol: float,
    theta: float,
) -> None:
    """Tick after tick, with the incumbent of the last tick, an assigner given the slots'
    spacing returns what one without it returns (the rule run in full)."""
    spec = _spec(kind, n)
    rng = np.random.default_rng(seed)
    fast = RoleAssigner(method, hysteresis_m=hyst, tie_tol_m=tol)
    full = RoleAssigner(method, hysteresis_m=hyst, tie_tol_m=tol)
    ids, xy, sids, sxy = _fleet(spec, rng, noise_m, spares, theta)
    ids = ids[: max(1, len(ids) - drop)]  # fewer robots than slots, at times
    xy = xy[: len(ids)]
    for _ in range(4):
        got = fast.update_ordered(ids, xy, sids, sxy, spec.least_spacing_m)
        assert got == full.update_ordered(ids, xy, sids, sxy)
        assert list(got[0]) == list(full.assignment)  # the same order too
        xy = [(x + float(rng.normal(0, noise_m)), y + float(rng.normal(0, noise_m))) for x, y in xy]


@settings(max_examples=150, deadline=None)
@given(
    kind=st.sampled_from(SHAPES),
    n=st.integers(2, 12),
    seed=st.integers(0, 2**32 - 1),
    noise_m=st.sampled_from([0.0, 0.02, 0.1, 0.3]),
    spares=st.integers(0, 3),
    hyst=st.sampled_from([0.0, 0.05]),
    tol=st.sampled_from([0.0, 0.01, 0.3]),
)
def test_each_check_returns_the_rule_or_nothing(
    kind: str, n: int, seed: int, noise_m: float, spares: int, hyst: float, tol: float
) -> None:
    """kept_by_spacing, greedy_kept and the optimal rule's check, given any incumbent, return
    None or the solver's answer."""
    spec = _spec(kind, n)
    rng = np.random.default_rng(seed)
    ids, xy, sids, sxy = _fleet(spec, rng, noise_m, spares, float(rng.uniform(-math.pi, math.pi)))
    k = min(len(ids), len(sids))
    perm = rng.permutation(len(ids))
    inc = {ids[int(i)]: sids[j] for j, i in enumerate(perm[:k])}
    greedy = greedy_py(ids, xy, sids, sxy, k, inc, hyst, tol)
    optimal = optimal_ordered(ids, xy, sids, sxy, inc, hyst, tol)
    for got in (
        kept_by_spacing(ids, xy, sxy, k, inc, _rows(sids), hyst, tol, spec.least_spacing_m),
        greedy_kept(ids, xy, sids, sxy, k, inc, hyst, tol),
    ):
        assert got is None or (got == greedy and list(got) == list(greedy))
    gap = tol / k if tol > 0.0 else 0.0
    cost = [[math.hypot(r[0] - x, r[1] - y) for x, y in xy] for r in sxy[:k]]
    for j, sid in enumerate(sids[:k]):
        for i, rid in enumerate(ids):
            if hyst > 0.0 and inc.get(rid) == sid:
                cost[j][i] -= hyst
    for got in (
        kept_by_spacing(ids, xy, sxy, k, inc, _rows(sids), hyst, gap, spec.least_spacing_m),
        _optimal_kept(ids, sids, k, inc, cost, tol),
        _optimal_kept(ids, sids, k, inc, np.array(cost), tol),
    ):
        assert got is None or (got == optimal and list(got) == list(optimal))


@pytest.mark.parametrize("kind", SHAPES)
def test_a_formation_that_holds_is_proved_kept(kind: str) -> None:
    """Robots within 2 cm of the slots they held: every check proves the incumbent (so the
    shortcut is taken, not only correct); one robot moved next to another's slot: the spacing
    proof no longer holds, and the rule decides."""
    spec = _spec(kind, 9)
    rng = np.random.default_rng(4)
    ids, xy, sids, sxy = _fleet(spec, rng, 0.005, 0, 0.7)
    k = len(sids)
    inc = greedy_py(ids, xy, sids, sxy, k, None, 0.0, 0.01)
    assert (
        kept_by_spacing(ids, xy, sxy, k, inc, _rows(sids), 0.05, 0.01, spec.least_spacing_m) == inc
    )
    assert greedy_kept(ids, xy, sids, sxy, k, inc, 0.05, 0.01) == inc
    assert optimal_ordered(ids, xy, sids, sxy, inc, 0.05, 0.01) == inc
    other = next(r for r in ids if inc[r] == sids[1])
    xy[ids.index(other)] = (sxy[0][0] + 0.01, sxy[0][1])  # next to the leader slot
    assert (
        kept_by_spacing(ids, xy, sxy, k, inc, _rows(sids), 0.05, 0.01, spec.least_spacing_m) is None
    )
    got = greedy_kept(ids, xy, sids, sxy, k, inc, 0.05, 0.01)
    assert got is None or got == greedy_py(ids, xy, sids, sxy, k, inc, 0.05, 0.01)


def test_checks_refuse_positions_that_are_not_finite() -> None:
    spec = FormationSpec.chevron(9)
    ids, xy, sids, sxy = _fleet(spec, np.random.default_rng(1), 0.0, 1, 0.0)
    k = len(sids)
    inc = greedy_py(ids, xy, sids, sxy, k, None, 0.0, 0.01)
    for bad in (math.inf, math.nan):
        for i in (0, len(ids) - 1):  # a slot holder and the spare
            moved = list(xy)
            moved[i] = (bad, 0.0)
            assert kept_by_spacing(ids, moved, sxy, k, inc, _rows(sids), 0.05, 0.01, 0.4) is None
            assert greedy_kept(ids, moved, sids, sxy, k, inc, 0.05, 0.01) is None
            a = RoleAssigner("greedy")
            a.seed_incumbent(inc)
            with pytest.raises(ValueError, match="non-finite position for robot"):
                a.update_ordered(ids, moved, sids, sxy, spec.least_spacing_m)
    a = RoleAssigner("greedy")
    a.seed_incumbent(inc)
    with pytest.raises(ValueError, match="non-finite position"):  # a slot left over
        a.update_ordered(ids[:3], xy[:3], sids, [*sxy[:-1], (math.nan, 0.0)], 0.4)


def test_least_spacing_is_the_closest_pair() -> None:
    assert FormationSpec.triangle(b_m=0.4).least_spacing_m == pytest.approx(0.4)
    spec = FormationSpec.lattice(12, b_m=0.3)
    off = spec.body_offsets_m
    pairs = [math.dist(off[i], off[j]) for i in range(len(off)) for j in range(i)]
    assert spec.least_spacing_m == pytest.approx(min(pairs), abs=1e-12)
    assert FormationSpec.chevron(1).least_spacing_m == math.inf


def _bits(rows: Sequence[Sequence[float]]) -> list[str]:
    return [v.hex() for row in rows for v in row]


def test_slot_rows_memo_gives_the_bits_of_a_fresh_spec() -> None:
    """The heading memo: a spec reused over a sequence of headings (repeats, 0.0 and -0.0,
    NaN) gives what a spec that never saw a heading gives."""
    kept = FormationSpec.chevron(7)
    for theta in (0.0, 0.0, -0.0, -0.0, 0.0, 1.25, 1.25, -3.0, math.nan, math.nan, 1.25):
        leader = LeaderState(0.0, 0.3, -0.2, theta, 0.07, 0.02)
        t1, rows1 = slot_rows(kept, leader)
        t2, rows2 = slot_rows(FormationSpec.chevron(7), leader)
        assert t1.hex() == t2.hex()
        assert _bits(rows1) == _bits(rows2)


def test_a_slot_list_changed_in_place_is_read_again() -> None:
    """The assigner keeps the slot id -> row table for a tuple only: a list given again after
    an edit in place is read afresh."""
    spec = FormationSpec.triangle()
    ids, xy, sids, sxy = _fleet(spec, np.random.default_rng(3), 0.0, 0, 0.0)
    slot_ids = list(sids)
    a = RoleAssigner("greedy")
    first, _ = a.update_ordered(ids, xy, slot_ids, sxy, spec.least_spacing_m)
    slot_ids[1], slot_ids[2] = slot_ids[2], slot_ids[1]  # the same rows under swapped ids
    fresh = RoleAssigner("greedy")
    fresh.seed_incumbent(first)
    want = fresh.update_ordered(ids, xy, list(slot_ids), sxy)
    assert a.update_ordered(ids, xy, slot_ids, sxy, spec.least_spacing_m) == want
    assert want[0] != first
