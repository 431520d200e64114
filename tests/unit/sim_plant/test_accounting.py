"""Tests of sim_plant.core.accounting: minimum separation, single-count collisions, bounds."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sim_plant.core.accounting import BoundsMonitor, SeparationMonitor, contacts_and_min_distance


def brute(xy: np.ndarray, contact_m: float) -> tuple[set[tuple[int, int]], float]:
    """Reference: every pair by a double loop."""
    n = xy.shape[0]
    pairs = set()
    best = math.inf
    for i in range(n):
        for j in range(i + 1, n):
            d = math.dist(xy[i], xy[j])
            best = min(best, d)
            if d < contact_m:
                pairs.add((i, j))
    return pairs, best


def test_min_separation_three_robots() -> None:
    mon = SeparationMonitor(radius_m=0.075)
    mon.update(0.0, [[0.0, 0.0, 0.0], [0.4, 0.0, 1.0], [0.0, 0.3, 2.0]])
    assert mon.min_separation_m == pytest.approx(0.3)
    assert mon.min_clearance_m == pytest.approx(0.15)
    mon.update(1.0, [[0.0, 0.0, 0.0], [0.4, 0.0, 1.0], [0.0, 1.0, 2.0]])
    assert mon.last_min_separation_m == pytest.approx(0.4)
    assert mon.min_separation_m == pytest.approx(0.3)  # running minimum
    assert mon.min_separation_t_s == 0.0
    assert mon.collision_count == 0


def test_collision_counted_once_per_contact() -> None:
    mon = SeparationMonitor(radius_m=0.05)  # contact below 0.10 m
    events_at = []
    # Robot 1 approaches robot 0, overlaps for a while, leaves, comes back once more.
    path = [0.3, 0.2, 0.12, 0.09, 0.05, 0.02, 0.05, 0.09, 0.15, 0.3, 0.08, 0.3]
    for k, gap in enumerate(path):
        new = mon.update(k * 0.1, [[0.0, 0.0, 0.0], [gap, 0.0, 0.0], [5.0, 5.0, 0.0]])
        events_at.extend(new)
    assert mon.collision_count == 2
    ev = mon.collisions
    assert [(e.i, e.j) for e in ev] == [(0, 1), (0, 1)]
    assert ev[0].t_s == pytest.approx(0.3) and ev[0].distance_m == pytest.approx(0.09)
    assert ev[1].t_s == pytest.approx(1.0) and ev[1].distance_m == pytest.approx(0.08)
    assert events_at == ev
    assert mon.min_separation_m == pytest.approx(0.02)
    assert mon.in_contact == frozenset()


def test_exactly_touching_is_not_a_collision() -> None:
    for max_n in (64, 0):  # brute force and k-d tree paths
        mon = SeparationMonitor(radius_m=0.25, brute_force_max_n=max_n)
        mon.update(0.0, [[0.0, 0.0], [0.5, 0.0], [3.0, 0.0]])
        assert mon.collision_count == 0
        assert mon.min_separation_m == 0.5


def test_fewer_than_two_robots() -> None:
    mon = SeparationMonitor(radius_m=0.1)
    assert mon.update(0.0, np.zeros((1, 3))) == []
    assert mon.update(0.0, np.zeros((0, 3))) == []
    assert mon.min_separation_m == math.inf
    with pytest.raises(ValueError):
        mon.update(0.0, [[0.0, math.nan, 0.0], [1.0, 1.0, 0.0]])


@settings(max_examples=200, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    n=st.integers(2, 150),
    radius=st.floats(0.0, 0.3),
    snap=st.booleans(),
)
def test_kdtree_path_agrees_with_brute_force(seed: int, n: int, radius: float, snap: bool) -> None:
    rng = np.random.default_rng(seed)
    xy = rng.uniform(0.0, 3.0, (n, 2))
    if snap:  # lattice points: duplicates and pairs at exactly the contact distance
        xy = np.round(xy * 4.0) / 4.0
    contact = 2.0 * radius
    ref_pairs, ref_min = brute(xy, contact)
    for max_n in (0, 10_000):
        pairs, dists, min_d = contacts_and_min_distance(xy, contact, brute_force_max_n=max_n)
        assert {tuple(p) for p in pairs.tolist()} == ref_pairs
        assert pairs.shape[0] == len(ref_pairs)
        assert min_d == pytest.approx(ref_min, abs=1e-12)
        np.testing.assert_allclose(dists, np.hypot(*(xy[pairs[:, 0]] - xy[pairs[:, 1]]).T))
        assert np.all(pairs[:, 0] < pairs[:, 1])


def test_thousand_robots_match_brute_force() -> None:
    rng = np.random.default_rng(42)
    n = 1000
    mon = SeparationMonitor(radius_m=0.075)
    xy = rng.uniform(0.0, 20.0, (n, 2))
    truth = np.column_stack([xy, np.zeros(n)])
    mon.update(0.0, truth)
    diff = xy[:, None, :] - xy[None, :, :]
    dist = np.hypot(diff[..., 0], diff[..., 1])
    iu, ju = np.triu_indices(n, 1)
    d = dist[iu, ju]
    assert mon.min_separation_m == pytest.approx(float(d.min()), abs=1e-12)
    expected = {(int(a), int(b)) for a, b, dd in zip(iu, ju, d, strict=True) if dd < 0.15}
    assert {(e.i, e.j) for e in mon.collisions} == expected
    assert len(expected) > 0  # the layout is dense enough to test contacts
    # Same layout again: contacts persist, no new events.
    assert mon.update(0.1, truth) == []


def test_separation_monitor_robot_count_change() -> None:
    mon = SeparationMonitor(radius_m=0.1)
    mon.update(0.0, [[0.0, 0.0], [0.1, 0.0], [0.0, 0.1]])
    assert mon.collision_count == 3
    mon.update(0.1, [[0.0, 0.0], [0.1, 0.0]])
    assert mon.in_contact == frozenset({(0, 1)})
    assert mon.collision_count == 3


def test_bounds_monitor_counts_exits_once() -> None:
    mon = BoundsMonitor(0.0, 2.0, 0.0, 1.0, radius_m=0.1)
    xs = [0.5, 1.85, 1.95, 2.5, 1.5, 1.95]
    for k, x in enumerate(xs):
        mon.update(k * 1.0, [[x, 0.5, 0.0], [1.0, 0.5, 0.0]])
    assert mon.exit_count == 2
    assert [(e.t_s, e.i) for e in mon.exits] == [(2.0, 0), (5.0, 0)]
    np.testing.assert_array_equal(mon.outside, [True, False])
    mon.update(6.0, [[1.0, 0.5], [1.0, -0.5], [1.0, 2.0]])  # a third robot appears outside
    assert mon.exit_count == 4
    with pytest.raises(ValueError):
        BoundsMonitor(0.0, 0.1, 0.0, 1.0, radius_m=0.1)


@settings(max_examples=25, deadline=None)
@given(
    n=st.integers(min_value=2, max_value=9),
    seed=st.integers(min_value=0, max_value=2**31),
    block_elements=st.sampled_from([1, 7, 64, 1 << 16]),
    split=st.integers(min_value=0, max_value=120),
)
def test_update_many_in_blocks_equals_one_update_per_tick(
    n: int, seed: int, block_elements: int, split: int
) -> None:
    """The batch path (pair distances by robot, ticks in blocks of any size, a block without
    contact skipped) gives the per-tick path's events, minimum (value and first tick), contact
    state and last minimum, bit for bit; robots walk into and out of contact across blocks."""
    from sim_plant.core import accounting

    rng = np.random.default_rng(seed)
    ticks = 120
    walk = np.cumsum(rng.normal(0.0, 0.02, (ticks, n, 3)), axis=0)
    walk[:, :, :2] += rng.uniform(-0.3, 0.3, (1, n, 2))
    walk[30:70, n - 1, :2] = walk[30:70, 0, :2] + 0.05  # a contact from tick 30 to 69 at least
    t = np.arange(ticks) * 0.02
    one, batch = SeparationMonitor(0.075), SeparationMonitor(0.075)
    for k in range(ticks):
        one.update(float(t[k]), walk[k])
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(accounting, "PAIR_BLOCK_ELEMENTS", block_elements)
        batch.update_many(t[:split], walk[:split])  # two calls: the contact state carries over
        batch.update_many(t[split:], walk[split:])
    assert one.collision_count > 0
    assert batch.collisions == one.collisions
    assert batch.min_separation_m == one.min_separation_m
    assert batch.min_separation_t_s == one.min_separation_t_s
    assert batch.in_contact == one.in_contact
    assert batch.last_min_separation_m == one.last_min_separation_m
    assert batch.updates == one.updates == ticks


def test_update_many_minimum_tick_when_two_squares_share_a_root() -> None:
    """Two ticks whose closest pairs have different squared distances but the same distance: the
    minimum's time is the first of them, as with one update per tick (the batch path roots each
    tick's minimum square; the root is correctly rounded, so that is each tick's minimum
    distance, ties included)."""
    rng = np.random.default_rng(7)
    found = None
    for _ in range(1000):
        dx, dy = rng.uniform(0.2, 0.5, 2)
        r = float(np.sqrt(dx * dx + dy * dy))
        if r * r > dx * dx + dy * dy:  # tick 0 (r, 0): larger square, the same root
            found = (dx, dy, r)
            break
    assert found is not None
    dx, dy, r = found
    walk = np.array(
        [
            [[0.0, 0.0, 0.0], [r, 0.0, 0.0], [5.0, 5.0, 0.0]],
            [[0.0, 0.0, 0.0], [dx, dy, 0.0], [5.0, 5.0, 0.0]],
            [[0.0, 0.0, 0.0], [1.0, 1.0, 0.0], [5.0, 5.0, 0.0]],
        ]
    )
    t = np.array([0.0, 0.02, 0.04])
    one, batch = SeparationMonitor(0.05), SeparationMonitor(0.05)
    for k in range(3):
        one.update(float(t[k]), walk[k])
    batch.update_many(t, walk)
    assert one.min_separation_m == batch.min_separation_m == r
    assert one.min_separation_t_s == batch.min_separation_t_s == 0.0
    assert batch.last_min_separation_m == one.last_min_separation_m


_SMALL_FLEET = st.integers(2, 12).flatmap(
    lambda n: st.lists(
        st.tuples(
            st.floats(-50, 50, allow_nan=False, width=64),
            st.floats(-50, 50, allow_nan=False, width=64),
            st.floats(-4, 4, allow_nan=False),
        ),
        min_size=n,
        max_size=n,
    )
)


@given(st.lists(_SMALL_FLEET, min_size=1, max_size=6), st.floats(0.0, 2.0))
def test_update_with_an_array_equals_the_array_path_bit_for_bit(
    ticks: list[list[tuple[float, float, float]]], radius: float
) -> None:
    """A few robots' truth as an array takes the plain-Python path (the plant node's truth at
    every tick); its events, minimum and last separation equal those of the numpy path
    (``contacts_and_min_distance``: pdist) bit for bit."""
    fast, ref = SeparationMonitor(radius), SeparationMonitor(radius)
    ref_in_contact: set[tuple[int, int]] = set()
    for k, rows in enumerate(ticks):
        arr = np.array(rows, dtype=np.float64)
        new = fast.update(0.02 * k, arr)
        pairs, dists, min_d = contacts_and_min_distance(arr[:, :2], ref.contact_dist_m)
        expected = [
            (a, b, d)
            for (a, b), d in zip(pairs.tolist(), dists.tolist(), strict=True)
            if (a, b) not in ref_in_contact
        ]
        ref_in_contact = {(a, b) for a, b in pairs.tolist()}
        assert [(e.i, e.j, e.distance_m) for e in new] == expected
        assert fast.in_contact == frozenset(ref_in_contact)
        assert fast.last_min_separation_m == min_d
