"""Role assignment at scale (coordinator.core.scale_assign) against the dense optimum."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.distance import cdist

from coordinator.core.assignment import SlotLike, assign_optimal, assignment_cost, natural_key
from coordinator.core.formation import (
    LEADER_SLOT,
    FormationSpec,
    SlotState,
    slot_arrays,
    slot_states,
)
from coordinator.core.scale_assign import (
    DEFAULT_DENSE_MAX_PAIRS,
    DEFAULT_K,
    SparseAssignment,
    assign_sparse,
    solve_sparse,
)
from coordinator.core.trajectory import LeaderState

Robots = dict[str, tuple[float, float]]
LEADER = LeaderState(0.0, 1.0, -2.0, 0.4, 0.1, 0.05)


def _objective(
    robots: Mapping[str, tuple[float, float]],
    slots: Sequence[SlotLike],
    assignment: Mapping[str, int],
    incumbent: Mapping[str, int] | None = None,
    hysteresis_m: float = 0.0,
) -> float:
    """What both solvers minimise (tie term aside): eq-6 distance less kept-incumbent hysteresis."""
    total = assignment_cost(robots, slots, assignment)
    if incumbent:
        total -= hysteresis_m * sum(1 for r, s in assignment.items() if incumbent.get(r) == s)
    return total


def _priority(slots: Sequence[SlotLike]) -> list[int]:
    def key(s: SlotLike) -> tuple[bool, int, int]:
        if isinstance(s, SlotState):
            return (s.slot != LEADER_SLOT, s.stage, s.slot)
        return (s[0] != LEADER_SLOT, 0 if s[0] == LEADER_SLOT else 1, s[0])

    return [s.slot if isinstance(s, SlotState) else s[0] for s in sorted(slots, key=key)]


def _check_valid(
    result: Mapping[str, int], robots: Mapping[str, object], slots: Sequence[SlotLike]
) -> None:
    """One to one, known robots only, exactly the first min(n_r, n_s) slots by priority, robots
    in natural id order (as assign_optimal returns them)."""
    n = min(len(robots), len(slots))
    assert set(result) <= set(robots)
    assert len(result) == n
    assert len(set(result.values())) == n
    assert sorted(result.values()) == sorted(_priority(slots)[:n])
    assert list(result) == sorted(result, key=natural_key)


def _graph_holds(
    robots: Robots,
    slots: Sequence[SlotLike],
    pairs: Mapping[str, int],
    k: int,
    incumbent: Mapping[str, int] | None,
) -> bool:
    """Whether every (robot, slot) of ``pairs`` is a candidate edge of the k-nearest graph: the
    slot is among the robot's k nearest filled slots, or the robot among the slot's k nearest
    robots, or the pair is incumbent. Computed independently of the module, from ranks."""
    ids = sorted(robots, key=natural_key)
    n = min(len(ids), len(slots))
    order = _priority(slots)[:n]
    pos: dict[int, tuple[float, float]] = {}
    for s in slots:
        if isinstance(s, SlotState):
            pos[s.slot] = (s.x, s.y)
        else:
            pos[s[0]] = (s[1], s[2])
    sxy = np.array([pos[j] for j in order], dtype=np.float64)
    rxy = np.array([robots[r] for r in ids], dtype=np.float64)
    d = cdist(sxy, rxy)
    rank_in_slot = d.argsort(axis=1).argsort(axis=1)  # robot's rank among the slot's robots
    rank_in_robot = d.argsort(axis=0).argsort(axis=0)  # slot's rank among the robot's slots
    row = {sid: j for j, sid in enumerate(order)}
    col = {rid: i for i, rid in enumerate(ids)}
    for rid, sid in pairs.items():
        j, i = row[sid], col[rid]
        inc = incumbent is not None and incumbent.get(rid) == sid
        if not (rank_in_slot[j, i] < k or rank_in_robot[j, i] < k or inc):
            return False
    return True


def _scatter(
    rng: np.random.Generator, slots_xy: np.ndarray, n_robots: int, noise_m: float
) -> Robots:
    """Robots around random slots (with replacement if more robots than slots), ids r1..rN."""
    pick = rng.choice(len(slots_xy), size=n_robots, replace=n_robots > len(slots_xy))
    pts = slots_xy[pick] + rng.normal(0.0, noise_m, size=(n_robots, 2))
    return {f"r{i + 1}": (float(p[0]), float(p[1])) for i, p in enumerate(pts)}


def _formation(kind: str, n: int) -> tuple[list[SlotState], np.ndarray]:
    spec: FormationSpec = getattr(FormationSpec, kind)(n, b_m=0.4)
    xy, _ = slot_arrays(spec, LEADER)
    return slot_states(spec, LEADER), xy


# --- agreement with the dense optimum ---------------------------------------------------------


@pytest.mark.parametrize("kind", ["chevron", "lattice"])
@pytest.mark.parametrize("noise_m", [0.05, 0.3, 1.0])
@pytest.mark.parametrize(("n_slots", "n_robots"), [(30, 30), (40, 25), (25, 40)])
def test_sparse_path_matches_dense_optimum(
    kind: str, noise_m: float, n_slots: int, n_robots: int
) -> None:
    """Forced onto the graph solver: exactly the dense optimum when the graph holds it, else
    (default k) within 1 %; and exact=True always reaches it, with a certificate."""
    rng = np.random.default_rng([n_slots, n_robots, int(noise_m * 100)])
    slots, xy = _formation(kind, n_slots)
    for k in (2, 4, DEFAULT_K):
        robots = _scatter(rng, xy, n_robots, noise_m)
        opt = assign_optimal(robots, slots, tie_tol_m=0.0)
        c_opt = _objective(robots, slots, opt)
        res = solve_sparse(robots, slots, k=k, tie_tol_m=0.0, dense_max_pairs=0)
        _check_valid(res.assignment, robots, slots)
        # A dense fallback only if even the 4k graph had no full matching (tiny k).
        assert res.method == "sparse" or (res.method == "dense" and k < DEFAULT_K)
        c = _objective(robots, slots, res.assignment)
        assert c >= c_opt - 1e-9  # nothing beats the optimum
        if res.method == "dense" or _graph_holds(robots, slots, opt, res.k, None):
            assert c == pytest.approx(c_opt, abs=1e-9)
        elif k == DEFAULT_K:
            assert c <= 1.01 * c_opt
        ex = solve_sparse(robots, slots, k=k, tie_tol_m=0.0, dense_max_pairs=0, exact=True)
        _check_valid(ex.assignment, robots, slots)
        assert ex.certified is True
        assert _objective(robots, slots, ex.assignment) == pytest.approx(c_opt, abs=1e-9)


def test_same_assignment_as_assign_optimal_with_tie_break() -> None:
    """With the default tie budget the optimum is unique (almost surely), and the sparse solver
    returns the very same mapping as assign_optimal."""
    rng = np.random.default_rng(7)
    for n in (12, 50, 120):
        slots, xy = _formation("lattice", n)
        robots = _scatter(rng, xy, n, 0.3)
        expected = assign_optimal(robots, slots)
        res = solve_sparse(robots, slots, dense_max_pairs=0, exact=True)
        assert res.method == "sparse"
        assert res.certified is True
        assert res.assignment == expected


@settings(max_examples=200, deadline=None)
@given(
    n_slots=st.integers(1, 14),
    n_robots=st.integers(0, 14),
    k=st.integers(1, 6),
    hysteresis_m=st.sampled_from([0.0, 0.05, 0.5]),
    tie_tol_m=st.sampled_from([0.0, 0.01]),
    seed=st.integers(0, 2**32 - 1),
    spread=st.sampled_from([0.1, 1.0, 10.0]),
    with_incumbent=st.booleans(),
)
def test_property_valid_and_optimal(
    n_slots: int,
    n_robots: int,
    k: int,
    hysteresis_m: float,
    tie_tol_m: float,
    seed: int,
    spread: float,
    with_incumbent: bool,
) -> None:
    """Any size (fewer, equal or more robots than slots), any k, any incumbent: a valid
    assignment whose cost is never below the dense optimum's, and with exact=True equal to it."""
    rng = np.random.default_rng(seed)
    slots: list[SlotLike] = [
        (j, float(x), float(y)) for j, (x, y) in enumerate(rng.normal(0.0, spread, (n_slots, 2)))
    ]
    robots = {
        f"r{i}": (float(x), float(y))
        for i, (x, y) in enumerate(rng.normal(0.0, spread, (n_robots, 2)))
    }
    # Coincident points and exact ties are legal input too.
    if n_robots >= 2 and seed % 3 == 0:
        robots["r1"] = robots["r0"]
    incumbent = None
    if with_incumbent and robots:
        ids = list(robots)
        perm = rng.permutation(n_slots).tolist()
        incumbent = {r: perm[i % n_slots] for i, r in enumerate(ids)}  # may repeat slots
    kw = {"incumbent": incumbent, "hysteresis_m": hysteresis_m, "tie_tol_m": tie_tol_m}
    opt = assign_optimal(robots, slots, **kw)  # type: ignore[arg-type]
    c_opt = _objective(robots, slots, opt, incumbent, hysteresis_m)
    for exact in (False, True):
        res = solve_sparse(robots, slots, k=k, dense_max_pairs=0, exact=exact, **kw)  # type: ignore[arg-type]
        _check_valid(res.assignment, robots, slots)
        # The dense solver only as the documented last resort, after two graphs failed.
        assert res.method != "dense" or res.attempts == 2
        c = _objective(robots, slots, res.assignment, incumbent, hysteresis_m)
        # Both minimise the same cost up to a tie term of total < tie_tol_m.
        assert c >= c_opt - tie_tol_m - 1e-9
        if exact:
            assert res.certified is True
            assert c <= c_opt + tie_tol_m + 1e-9


# --- fallbacks, hysteresis, priority -----------------------------------------------------------


def test_fallback_to_a_larger_graph() -> None:
    """k = 1: the three slots' nearest robot is the same one (r1), so slots 0 and 1 have r1 as
    their only candidate: no full matching. The retry with 4 neighbours solves it."""
    slots = [(0, 0.0, 0.0), (1, 1.0, 0.0), (2, 2.0, 0.0)]
    robots = {"r1": (10.0, 0.0), "r2": (10.1, 0.0), "r3": (10.2, 0.0)}
    res = solve_sparse(robots, slots, k=1, dense_max_pairs=0)
    assert (res.method, res.k, res.attempts) == ("sparse", 4, 2)
    _check_valid(res.assignment, robots, slots)
    assert res.assignment == assign_optimal(robots, slots)


def test_fallback_to_the_dense_solver() -> None:
    """Ten slots in a row, ten robots far to the right: with k = 1 and then 4 the six leftmost
    slots only ever see the four leftmost robots, so both graphs fail and the dense solver runs."""
    slots = [(j, float(j), 0.0) for j in range(10)]
    robots = {f"r{i + 1}": (100.0 + 0.1 * i, 0.0) for i in range(10)}
    res = solve_sparse(robots, slots, k=1, dense_max_pairs=0)
    assert (res.method, res.attempts) == ("dense", 2)
    assert res.certified is True
    assert res.assignment == assign_optimal(robots, slots)


def test_small_problems_go_to_the_dense_solver() -> None:
    slots, xy = _formation("chevron", 10)
    robots = _scatter(np.random.default_rng(3), xy, 10, 0.3)
    assert DEFAULT_DENSE_MAX_PAIRS >= 10 * 10
    res = solve_sparse(robots, slots)
    assert (res.method, res.attempts) == ("dense", 0)
    assert res.assignment == assign_optimal(robots, slots)


def test_hysteresis_keeps_the_incumbent_on_a_near_tie() -> None:
    """Two robots swapped across the midline, each 1 cm closer to the other's slot: without an
    incumbent the swap wins; with the incumbent and 5 cm hysteresis the roles stay."""
    slots = [(0, 0.0, 0.0), (1, 0.4, 0.0)]
    robots = {"r1": (0.21, 0.0), "r2": (0.19, 0.0)}  # r1 slightly nearer slot 1
    free = solve_sparse(robots, slots, tie_tol_m=0.0, dense_max_pairs=0)
    assert free.assignment == {"r1": 1, "r2": 0}
    inc = {"r1": 0, "r2": 1}
    kept = solve_sparse(robots, slots, incumbent=inc, hysteresis_m=0.05, dense_max_pairs=0)
    assert kept.assignment == inc
    assert kept.method == "incumbent"  # proven optimal without solving
    # A challenger more than the hysteresis closer takes over (solved, not kept).
    robots_far = {"r1": (0.45, 0.0), "r2": (-0.05, 0.0)}
    moved = solve_sparse(robots_far, slots, incumbent=inc, hysteresis_m=0.05, dense_max_pairs=0)
    assert moved.assignment == {"r1": 1, "r2": 0}
    assert moved.method == "sparse"


def test_hysteresis_applies_inside_the_graph_solver() -> None:
    """Every robot nudged ~8 cm after an optimal assignment: the old one is no longer optimal
    and the cheap incumbent proof fails, so the graph solver runs; it must count the hysteresis
    like assign_optimal (same optimum) and keep more incumbent pairs the larger it is."""
    rng = np.random.default_rng(11)
    slots, xy = _formation("lattice", 60)
    robots = _scatter(rng, xy, 60, 0.3)
    prev = assign_optimal(robots, slots, tie_tol_m=0.0)
    nudged = {
        r: (p[0] + float(rng.normal(0, 0.08)), p[1] + float(rng.normal(0, 0.08)))
        for r, p in robots.items()
    }
    kept = []
    for hyst in (0.0, 0.05, 0.2):
        kw = {"incumbent": prev, "hysteresis_m": hyst, "tie_tol_m": 0.0}
        expected = assign_optimal(nudged, slots, **kw)  # type: ignore[arg-type]
        res = solve_sparse(nudged, slots, dense_max_pairs=0, exact=True, **kw)  # type: ignore[arg-type]
        assert (res.method, res.certified) == ("sparse", True)
        assert _objective(nudged, slots, res.assignment, prev, hyst) == pytest.approx(
            _objective(nudged, slots, expected, prev, hyst), abs=1e-9
        )
        kept.append(sum(prev.get(r) == s for r, s in res.assignment.items()))
    assert kept[0] < kept[1] < kept[2] == 60


def test_fewer_robots_than_slots_fill_the_leader_first() -> None:
    """Three robots, a 10-slot lattice: the leader slot and the two stage-1 slots are filled,
    whatever is nearer, and the leader slot is among them even when every robot is near the
    tail of the formation."""
    slots, xy = _formation("lattice", 10)
    tail = xy[-3:] + 0.01
    robots = {f"r{i + 1}": (float(p[0]), float(p[1])) for i, p in enumerate(tail)}
    res = solve_sparse(robots, slots, dense_max_pairs=0)
    assert res.method == "sparse"
    assert sorted(res.assignment.values()) == [0, 1, 2]
    assert LEADER_SLOT in res.assignment.values()
    assert res.assignment == assign_optimal(robots, slots)
    one = solve_sparse({"r7": (50.0, 50.0)}, slots, dense_max_pairs=0)
    assert one.assignment == {"r7": LEADER_SLOT}


@pytest.mark.parametrize("extra", [1, 15, 60])
def test_more_robots_than_slots_on_the_graph_solver(extra: int) -> None:
    """Spare robots are absorbed by zero-cost dummy slots (the spare node of the residual
    graph): solved on the graph, in phases, to the dense optimum."""
    rng = np.random.default_rng(extra)
    slots, xy = _formation("chevron", 60)
    robots = _scatter(rng, xy, 60 + extra, 0.5)
    opt = assign_optimal(robots, slots, tie_tol_m=0.0)
    res = solve_sparse(robots, slots, tie_tol_m=0.0, dense_max_pairs=0, exact=True)
    assert (res.method, res.attempts, res.certified) == ("sparse", 1, True)
    assert res.n_phases > 0
    _check_valid(res.assignment, robots, slots)
    assert _objective(robots, slots, res.assignment) == pytest.approx(
        _objective(robots, slots, opt), abs=1e-9
    )


def test_more_robots_than_slots_leave_the_farthest_out() -> None:
    slots = [(0, 0.0, 0.0), (1, 1.0, 0.0), (2, 2.0, 0.0)]
    robots = {"r1": (0.1, 0.0), "r2": (50.0, 0.0), "r3": (1.1, 0.0), "r4": (2.1, 0.1)}
    res = solve_sparse(robots, slots, k=1, dense_max_pairs=0)
    assert res.assignment == {"r1": 0, "r3": 1, "r4": 2}


def test_empty_inputs() -> None:
    slots = [(0, 0.0, 0.0)]
    assert solve_sparse({}, slots) == SparseAssignment({}, "empty")
    assert assign_sparse({"r1": (0.0, 0.0)}, []) == {}


@pytest.mark.parametrize(
    "kw",
    [
        {"k": 0},
        {"k": True},
        {"k": 2.0},
        {"dense_max_pairs": -1},
        {"dense_max_pairs": 1.5},
        {"tie_tol_m": -0.1},
        {"hysteresis_m": math.nan},
        {"incumbent": {"r1": "0"}},
    ],
)
def test_invalid_arguments_raise(kw: dict[str, object]) -> None:
    with pytest.raises(ValueError):
        assign_sparse({"r1": (0.0, 0.0)}, [(0, 0.0, 0.0)], **kw)  # type: ignore[arg-type]


def test_invalid_positions_raise() -> None:
    with pytest.raises(ValueError):
        assign_sparse({"r1": (math.inf, 0.0)}, [(0, 0.0, 0.0)])
    with pytest.raises(ValueError):
        assign_sparse({"r1": (0.0, 0.0)}, [(0, 0.0, 0.0), (0, 1.0, 0.0)])  # duplicate slot


# --- scale ---------------------------------------------------------------------------------------


@pytest.mark.parametrize("kind", ["chevron", "lattice"])
def test_thousand_robots(kind: str) -> None:
    """N = 1000 robots scattered 0.3 m around the formation: a valid assignment within 1 % of
    the dense optimum (the goal; the bench measures the time). The steady state next tick (each
    robot 2 cm from its slot, 5 cm hysteresis) keeps the incumbent without solving."""
    rng = np.random.default_rng(5)
    slots, xy = _formation(kind, 1000)
    robots = _scatter(rng, xy, 1000, 0.3)
    res = solve_sparse(robots, slots)
    assert res.method == "sparse"
    _check_valid(res.assignment, robots, slots)
    c_opt = _objective(robots, slots, assign_optimal(robots, slots))
    assert _objective(robots, slots, res.assignment) <= 1.01 * c_opt

    pos = {s.slot: (s.x, s.y) for s in slots}
    steady = {
        r: (pos[s][0] + float(rng.normal(0, 0.02)), pos[s][1] + float(rng.normal(0, 0.02)))
        for r, s in res.assignment.items()
    }
    nxt = solve_sparse(steady, slots, incumbent=res.assignment, hysteresis_m=0.05)
    assert nxt.method == "incumbent"
    assert nxt.assignment == res.assignment
