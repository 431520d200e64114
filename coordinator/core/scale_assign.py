"""Minimum-total-distance role assignment for large fleets (N ~ 1000) within one 50 Hz tick.

Same problem, inputs, outputs and semantics as :func:`coordinator.core.assignment.assign_optimal`
(paper section 2.3 with the minimum-sum rule): robot ``r`` on slot ``s`` costs the Euclidean
distance of eq 6 (m) between the robot's reference point and the slot, less ``hysteresis_m`` if
``r`` is the slot's incumbent, plus assign_optimal's deterministic tie-break (at most
``tie_tol_m`` in total, favouring lower robot ids on higher-priority slots). With fewer robots
than slots only the first ``len(robots)`` slots in priority order are filled, leader first; extra
robots get no slot. Parsing and validation are assign_optimal's own helpers.

Why not the obvious tools: ``scipy.optimize.linear_sum_assignment`` on the dense 1000 x 1000
matrix takes 40-300 ms here. ``scipy.sparse.csgraph.min_weight_full_bipartite_matching``
(LAPJVsp) on a k-nearest-neighbour graph took 40 ms to 3 s (scipy 1.17, this machine), most of it
in the Hopcroft-Karp feasibility check it always runs first, and returns no duals.

How (numpy/scipy only; no Python loop over robots or edges):

1. **Candidate graph**: each robot's ``k`` nearest slots and each slot's ``k`` nearest robots
   (``scipy.spatial.cKDTree``), plus every incumbent pair.
2. **Exact primal-dual solver on that graph** (Hungarian method with Dijkstra, successive
   shortest paths): slot potentials ``u`` and robot potentials ``v`` with reduced cost
   ``c - u - v >= 0`` on every edge and ``= 0`` on matched ones. Start: row and column reduction,
   greedy matching on the zero-reduced-cost edges. Each *phase* is one multi-source
   ``scipy.sparse.csgraph.dijkstra`` from all unmatched slots over the residual graph; the
   potentials move by the distances found (reduced costs stay >= 0, the shortest path trees
   become tight) and every tree that reached a free robot flips its path to the nearest one; the
   trees are disjoint, so all those paths flip at once. 6-15 phases at N = 1000. The result is
   the optimum of the graph. More robots than slots: zero-cost dummy slots, one per extra robot,
   make the problem square; they are a few "spare" nodes of the residual graph.
3. **Quality**: at these formation densities the graph optimum is the dense optimum or within a
   fraction of a percent of it (bench/bench_assignment_scale.py: worst 0.5 % with ``k = 10`` for
   robots scattered 1 m, 2.5 slot spacings, around the formation; the paper's greedy rule is
   1.3-3x the optimum there). ``exact=True`` closes the gap and proves it: pairs outside the
   graph whose reduced cost the duals show negative are added and the affected slots re-solved
   (warm), until none is left, which proves by LP duality that the result is the dense optimum
   (:attr:`SparseAssignment.certified`). It is a verification tool (tests, offline checks):
   at N = 300-1000 it costs 1-6x the dense solver, mostly in searching for those pairs.
4. **Fallbacks**: no matching of all slots in the graph (e.g. all robots far off to one side):
   retry with ``4 k`` neighbours, then the dense solver.
5. **Warm start from the incumbent**: if every slot's incumbent, with its hysteresis bonus, is
   at least as cheap as any other robot (one 2-nearest-neighbour query), the incumbent is
   provably optimal (duals: ``u`` = its costs, ``v = 0``) and is returned without solving. This
   is the steady state of a formation holding its shape.

Small problems (``n_slots x n_robots <= dense_max_pairs``) go to the dense solver, faster there.

Limits (measured at N = 1000, robots 0.3 m around a lattice): with spare robots (1001-1200 robots
for 1000 slots) the dummy swaps take 25-80 phases, 40-140 ms, no faster than the dense solver,
and one graph optimum was 1.9 % above the dense one (1010 robots). With fewer robots than slots
but spread over the whole formation (900 robots, the first 900 slots filled) the k graph has no
full matching and the 4k one takes ~100 ms (dense: ~350 ms). Robots close to their slots, and a
robot or a few missing, stay fast (999 robots: 5 phases, ~15-20 ms).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Final, Literal

import numpy as np
import numpy.typing as npt
from scipy.sparse import csr_array
from scipy.sparse.csgraph import dijkstra
from scipy.spatial import cKDTree

from coordinator.core.matching import (
    SlotLike,
    assign_optimal,
    check_incumbent,
    check_tolerance,
    robots_xy,
    slots_xy,
)

__all__ = [
    "DEFAULT_DENSE_MAX_PAIRS",
    "DEFAULT_K",
    "SparseAssignment",
    "assign_sparse",
    "solve_sparse",
]

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]
Method = Literal["empty", "incumbent", "sparse", "dense"]

DEFAULT_K: Final = 10
"""Neighbours per robot and per slot in the candidate graph. Measured (bench/
bench_assignment_scale.py, N = 300 and 1000, robots up to 1 m around the formation): worst cost
over the dense optimum 1.0175 with k = 8, 1.0048 with k = 10, 1.0026 with k = 12, the time
growing ~10 % per step."""

DEFAULT_DENSE_MAX_PAIRS: Final = 40_000
"""Up to this many (slot, robot) pairs (200 x 200) the dense Hungarian solver is used: it is
faster than building a graph there and exact."""

FALLBACK_K_FACTOR: Final = 4
"""When the k-nearest graph has no full matching, retry once with this many times more
neighbours before the dense solver."""

CERT_NEIGHBOURS_PER_K: Final = 3
"""``exact=True``: each slot's ``3 k`` nearest robots are checked one by one against the duals,
the farther ones by a bound (searched wider only where the bound fails)."""

MAX_PRICING_ROUNDS: Final = 8
"""``exact=True``: rounds of "add the violating pairs and re-solve" before giving up the proof
(the result is then still the optimum of the grown graph, ``certified`` False)."""

_MAX_SEARCH: Final = 4
"""Widenings (x4 neighbours each) of a slot's violation search before it counts as unsettled."""

_SPARE_GROUPS: Final = 8
"""Spare nodes the dummy slots are spread over (see :class:`_Solver`): more let more paths
swap dummies per phase, each adds n_robots edges."""

_VECTOR_MIN_PATHS: Final = 8
"""Augmenting paths are flipped with numpy while more than this many remain, then in Python."""

_CERT_TOL_M: Final = 1e-9
"""Slack (m) allowed in the dual-feasibility certificate for floating-point rounding."""


@dataclass(frozen=True, slots=True)
class SparseAssignment:
    """Result of :func:`solve_sparse`.

    ``assignment``: robot id -> slot id, robots in natural id order (as ``assign_optimal``).
    ``method``: ``"empty"`` (no robot or no slot), ``"incumbent"`` (the incumbent was proven
    optimal and kept without solving), ``"sparse"`` (solved on the candidate graph) or
    ``"dense"`` (small problem, or fallback after the candidate graphs had no full matching).
    ``k``: neighbours per side of the graph that was solved (0 unless ``"sparse"``);
    ``attempts``: candidate graphs tried (0, 1 or 2); ``n_edges``: edges of the last graph;
    ``n_phases``: Dijkstra phases of the primal-dual solver (all rounds); ``certified``: True if
    the total cost is proven equal to the dense optimum (always for ``"incumbent"``, ``"dense"``
    and ``"empty"``), False if ``exact=True`` could not prove it within its rounds, None if not
    checked (``exact=False``, the default).
    """

    assignment: dict[str, int]
    method: Method
    k: int = 0
    attempts: int = 0
    n_edges: int = 0
    n_phases: int = 0
    certified: bool | None = True


@dataclass(frozen=True, slots=True)
class _Problem:
    """Validated numeric input: ``sxy`` (n_s, 2) the filled slots in priority order, ``rxy``
    (n_r, 2) the robots in natural id order (m); ``inc_row_of_col[i]``: the slot row robot ``i``
    is incumbent on, -1 if none; ``hysteresis_m`` (m) and ``tie_scale`` (m, = tie_tol_m)."""

    sxy: FloatArray
    rxy: FloatArray
    inc_row_of_col: IntArray
    hysteresis_m: float
    tie_scale: float
    robot_tree: cKDTree
    slot_tree: cKDTree

    @property
    def n_s(self) -> int:
        return len(self.sxy)

    @property
    def n_r(self) -> int:
        return len(self.rxy)

    def cost(self, rows: IntArray, cols: IntArray) -> FloatArray:
        """The minimised cost (m) of pairs (slot row, robot column): the eq-6 Euclidean distance
        (as cdist computes it), less ``hysteresis_m`` for an incumbent pair, plus
        assign_optimal's tie-break ``(tol / n_s) * (1 - row / n_s) * (col / n_r)``."""
        dx = self.sxy[rows, 0] - self.rxy[cols, 0]
        dy = self.sxy[rows, 1] - self.rxy[cols, 1]
        c: FloatArray = np.sqrt(dx * dx + dy * dy)
        if self.hysteresis_m > 0.0:
            c -= self.hysteresis_m * (self.inc_row_of_col[cols] == rows)
        if self.tie_scale > 0.0:
            n_s, n_r = self.n_s, self.n_r
            c += (self.tie_scale / n_s) * (1.0 - rows / n_s) * (cols / n_r)
        return c


def _knn(tree: cKDTree, pts: FloatArray, k: int) -> tuple[FloatArray, IntArray]:
    """(distances (m), indices), each (len(pts), k): the k nearest tree points to each point."""
    dist, idx = tree.query(pts, k)
    n = len(pts)
    return np.asarray(dist, dtype=np.float64).reshape(n, k), np.asarray(idx).reshape(n, k)


def _candidates(p: _Problem, k: int) -> tuple[IntArray, IntArray]:
    """Candidate pairs (slot rows, robot columns), each once: every robot's k nearest slots,
    every slot's k nearest robots, and every incumbent pair."""
    n_s, n_r = p.n_s, p.n_r
    kr, ks = min(k, n_s), min(k, n_r)
    _, ir = _knn(p.slot_tree, p.rxy, kr)  # each robot's kr nearest slots
    _, js = _knn(p.robot_tree, p.sxy, ks)  # each slot's ks nearest robots
    slot_idx = np.arange(n_s)
    # A slot-side pair (j, js[j, q]) is already a robot-side pair iff j is in ir[js[j, q]].
    keep = ~(ir[js] == slot_idx[:, None, None]).any(axis=2).ravel()
    rows = np.concatenate([ir.ravel(), np.repeat(slot_idx, ks)[keep]])
    cols = np.concatenate([np.repeat(np.arange(n_r), kr), js.ravel()[keep]])
    inc_cols = np.flatnonzero(p.inc_row_of_col >= 0)
    if inc_cols.size:
        inc_rows = p.inc_row_of_col[inc_cols]
        known = (ir[inc_cols] == inc_rows[:, None]).any(axis=1) | (
            js[inc_rows] == inc_cols[:, None]
        ).any(axis=1)
        rows = np.concatenate([rows, inc_rows[~known]])
        cols = np.concatenate([cols, inc_cols[~known]])
    return rows, cols


class _Solver:
    """Exact minimum-cost assignment of every slot row on a sparse candidate graph.

    Primal-dual (Hungarian method with Dijkstra, successive shortest paths). Invariant: slot
    potentials ``u`` and robot potentials ``v`` with reduced cost ``cost - u[row] - v[col] >= 0``
    on every edge and ``= 0`` on every matched edge; so a matching of all slots is optimal on
    the graph (LP duality). With more robots than slots, ``n_r - n_s`` zero-cost dummy slots
    joined to every robot make the problem square; they are ``groups`` "spare" nodes in the
    graph (see :meth:`run`); the members of group ``g`` are the robots with
    ``col_m == n_s + g``.
    """

    def __init__(self, p: _Problem, rows: IntArray, cols: IntArray) -> None:
        self.n_s, self.n_r = n_s, n_r = p.n_s, p.n_r
        self.spare = n_r - n_s
        self.groups = min(self.spare, _SPARE_GROUPS)
        self.rows, self.cols = rows, cols
        self.cost = cost = p.cost(rows, cols)
        self.phases = 0
        u = np.full(n_s, np.inf)
        np.minimum.at(u, rows, cost)  # row reduction
        v = np.zeros(n_r)
        if self.spare == 0:  # column reduction (with dummies, v = 0 keeps them all tight)
            v_red = np.full(n_r, np.inf)
            np.minimum.at(v_red, cols, cost - u[rows])
            v = np.where(np.isfinite(v_red), v_red, 0.0)
        self.u, self.v = u, v
        # Matching: slot row -> robot, robot -> slot row (or n_s + g: a dummy of spare group g).
        self.row_m = row_m = np.full(n_s, -1, dtype=np.intp)
        self.col_m = col_m = np.full(n_r, -1, dtype=np.intp)
        # Greedy start on the tight edges: first tight slot per robot, then first robot per slot.
        tight = np.flatnonzero(cost - u[rows] - v[cols] <= 0.0)
        t_rows, t_cols = rows[tight], cols[tight]
        _, first = np.unique(t_cols, return_index=True)
        t_rows, t_cols = t_rows[first], t_cols[first]
        _, first = np.unique(t_rows, return_index=True)
        row_m[t_rows[first]] = t_cols[first]
        col_m[t_cols[first]] = t_rows[first]
        if self.spare > 0:
            # The dummies take the unmatched robots farthest from any unmatched slot (v = 0 for
            # all, so any choice is tight); the rest stay free, near the free slots.
            free_r = np.flatnonzero(col_m < 0)
            near = np.full(n_r, np.inf)
            to_free = row_m[rows] < 0
            np.minimum.at(near, cols[to_free], cost[to_free])
            take = free_r[np.argsort(-near[free_r], kind="stable")[: self.spare]]
            col_m[take] = n_s + np.arange(take.size) % self.groups

    @property
    def n_edges(self) -> int:
        return len(self.cols)

    def add_edges(self, rows: IntArray, cols: IntArray, cost: FloatArray) -> None:
        """Add edges (pairs not yet in the graph) whose reduced cost may be negative: each slot
        concerned has its potential lowered to keep every reduced cost >= 0, which unties its
        matched edge, so that slot and its robot are unmatched for :meth:`run` to re-assign."""
        n_r = self.n_r
        new = ~np.isin(rows * n_r + cols, self.rows * n_r + self.cols)
        rows, cols, cost = rows[new], cols[new], cost[new]
        if rows.size == 0:
            return
        self.rows = np.concatenate([self.rows, rows])
        self.cols = np.concatenate([self.cols, cols])
        self.cost = np.concatenate([self.cost, cost])
        u_new = self.u.copy()
        np.minimum.at(u_new, rows, cost - self.v[cols])
        lowered = np.flatnonzero(u_new < self.u)
        self.u = u_new
        robots = self.row_m[lowered]
        self.col_m[robots[robots >= 0]] = -1
        self.row_m[lowered] = -1

    def run(self) -> None:  # noqa: PLR0915 (the solver's Dijkstra phases, one hot loop)
        """Match every free slot (Dijkstra phases). Raises ``ValueError`` if the graph has no
        matching that covers every slot."""
        n_s, n_r, groups = self.n_s, self.n_r, self.groups
        u, v, row_m, col_m = self.u, self.v, self.row_m, self.col_m
        if not (row_m < 0).any():
            return
        order = np.argsort(self.rows, kind="stable")
        rows, cols, cost = self.rows[order], self.cols[order], self.cost[order]
        n_edges = len(cols)
        # Residual graph, one CSR whose structure is fixed for this call (only the data and the
        # robots' edge targets change per phase). Nodes: slots 0..n_s-1, the spare groups
        # n_s..n_s+groups-1 (if any), robots from r0.
        # * slot -> robot for every edge, at its reduced cost (a matched edge too: its slot is
        #   only reachable through its robot at the same distance, so it never shortens a path);
        # * spare group -> every robot at max(v) - v: a group stands for dummy slots, one per
        #   member robot with potential -v[member]; dual feasibility forces every member to have
        #   the largest v, so member -> group -> robot costs exactly a dummy's reduced cost. Each
        #   group lies in one shortest path tree per phase, so several groups let several paths
        #   swap dummies in the same phase;
        # * robot -> its slot or group at 0 if matched, else a harmless self-loop.
        r0 = n_s + groups
        n_nodes = r0 + n_r
        robot_nodes = np.arange(r0, n_nodes, dtype=np.int32)
        row_ptr = np.zeros(n_s + 1, dtype=np.intp)
        np.cumsum(np.bincount(rows, minlength=n_s), out=row_ptr[1:])
        spare_ptr = n_edges + n_r * np.arange(1, groups + 1)
        back_ptr = n_edges + n_r * groups + np.arange(1, n_r + 1)
        indptr = np.concatenate([row_ptr, spare_ptr, back_ptr]).astype(np.int32)
        spare_idx = np.tile(robot_nodes, groups)
        indices = np.concatenate([(cols + r0).astype(np.int32), spare_idx, robot_nodes])
        graph = csr_array((np.zeros(len(indices)), indices, indptr), shape=(n_nodes, n_nodes))
        # The arrays the CSR holds (the constructor may have copied): updated in place below.
        data_v, indices_v = graph.data, graph.indices
        back = indices_v[len(indices_v) - n_r :]  # each robot's single edge target
        red = np.empty(n_edges)
        while True:
            free = np.flatnonzero(row_m < 0)
            if free.size == 0:
                return
            self.phases += 1
            np.subtract(cost, u[rows], out=red)
            red -= v[cols]
            np.maximum(red, 0.0, out=data_v[:n_edges])  # rounding: >= 0 in exact arithmetic
            if groups:
                data_v[n_edges : n_edges + n_r * groups] = np.tile(
                    np.maximum(v.max() - v, 0.0), groups
                )
            back[:] = np.where(col_m >= 0, col_m, robot_nodes)
            dist, pred, src = dijkstra(graph, indices=free, min_only=True, return_predecessors=True)
            reached = np.isfinite(dist)
            # Shift the potentials by the distances, capped for unreached nodes: every reduced
            # cost stays >= 0 (d[b] <= d[a] + r for each edge a -> b) and the shortest path trees
            # become tight. A dummy's potential -v[member] follows its member's (same distance).
            dc = np.minimum(dist, dist[reached].max())
            u -= dc[:n_s]
            v += dc[r0:]
            free_r = np.flatnonzero((col_m < 0) & reached[r0:])
            if free_r.size == 0:
                raise ValueError("the candidate graph has no matching that covers every slot")
            # One path per shortest path tree, to its nearest free robot: the trees are disjoint,
            # so all those paths are flipped together, one step along each per iteration.
            free_r = free_r[np.argsort(dist[free_r + r0], kind="stable")]
            _, first = np.unique(src[free_r + r0], return_index=True)
            cur = free_r[first]
            while cur.size > _VECTOR_MIN_PATHS:
                x = pred[cur + r0]  # the slot (or spare group) each robot is reached from
                released = None
                at_g = x >= n_s
                if groups and at_g.any():
                    # A group takes this robot and releases the member it was reached from.
                    col_m[cur[at_g]] = x[at_g]
                    released = pred[x[at_g]] - r0
                    x, cur = x[~at_g], cur[~at_g]
                old = row_m[x]
                row_m[x] = cur
                col_m[cur] = x
                cur = old[old >= 0]
                if released is not None:
                    cur = np.concatenate([cur, released])
            # The last few (long) paths: the same steps one robot at a time, cheaper than numpy
            # calls on arrays of a few elements.
            for i in cur.tolist():
                while i >= 0:
                    x = int(pred[i + r0])
                    if x >= n_s:  # a spare group: takes robot i, releases a member
                        col_m[i] = x
                        i = int(pred[x]) - r0
                    else:
                        nxt = int(row_m[x])
                        row_m[x] = i
                        col_m[i] = x
                        i = nxt


def _violations(
    p: _Problem, u: FloatArray, v: FloatArray, n_neighbours: int
) -> tuple[IntArray, IntArray, bool]:
    """Pairs outside the graph that break dual feasibility (``cost < u + v``), and whether the
    search was complete.

    Per slot, its ``n_neighbours`` nearest robots are checked exactly; every farther robot is
    not incumbent (incumbent pairs are in the graph) and costs at least the last one's distance,
    so the slot is settled if that distance is >= ``u + max(v)``. Unsettled slots are searched
    again with 4 times more neighbours, until settled or all robots were checked; so the search
    is complete (True) unless ``_MAX_SEARCH`` widenings were not enough.
    """
    n_r = p.n_r
    v_max = float(v.max())
    todo = np.arange(p.n_s)
    kq = n_neighbours
    bad_rows: list[IntArray] = []
    bad_cols: list[IntArray] = []
    for _ in range(_MAX_SEARCH):
        kq = min(kq, n_r)
        dist, idx = _knn(p.robot_tree, p.sxy[todo], kq)
        rows = np.repeat(todo, kq)
        cols = idx.ravel()
        slack = p.cost(rows, cols) - u[rows] - v[cols]
        hit = slack < -_CERT_TOL_M
        bad_rows.append(rows[hit])
        bad_cols.append(cols[hit])
        if kq == n_r:
            todo = todo[:0]
            break
        todo = todo[dist[:, -1] - v_max - u[todo] < -_CERT_TOL_M]
        if todo.size == 0:
            break
        kq *= 4
    return np.concatenate(bad_rows), np.concatenate(bad_cols), todo.size == 0


def _incumbent_is_optimal(p: _Problem) -> bool:
    """Cheap proof that the incumbent is an optimal assignment: it fills every slot one to one,
    and each slot's incumbent cost (distance less the hysteresis, plus the tie term) is no more
    than its distance to any other robot, so ``u = incumbent cost, v = 0`` are optimal duals."""
    n_s, n_r = p.n_s, p.n_r
    inc_cols = np.flatnonzero(p.inc_row_of_col >= 0)
    if inc_cols.size != n_s:
        return False
    inc_rows = p.inc_row_of_col[inc_cols]
    if np.unique(inc_rows).size != n_s:
        return False
    robot_of = np.empty(n_s, dtype=np.intp)
    robot_of[inc_rows] = inc_cols
    own = p.cost(np.arange(n_s), robot_of)
    if n_r == 1:
        return True
    dist, idx = _knn(p.robot_tree, p.sxy, 2)
    other = np.where(idx[:, 0] == robot_of, dist[:, 1], dist[:, 0])
    return bool(np.all(own <= other))


def solve_sparse(
    robots: Mapping[str, tuple[float, float]],
    slots: Sequence[SlotLike],
    *,
    k: int = DEFAULT_K,
    incumbent: Mapping[str, int] | None = None,
    hysteresis_m: float = 0.0,
    tie_tol_m: float = 0.01,
    exact: bool = False,
    dense_max_pairs: int = DEFAULT_DENSE_MAX_PAIRS,
) -> SparseAssignment:
    """:func:`assign_sparse` with diagnostics (which path, graph size, phases, certificate).

    ``k`` (>= 1): neighbours per robot and per slot in the candidate graph.
    ``exact``: after solving on the graph, look for pairs outside it that the duals say could
    lower the cost, add them and re-solve (warm: only the slots concerned are re-assigned),
    until none is left, which proves the result equal to the dense optimum (``certified``); at
    most ``MAX_PRICING_ROUNDS`` rounds. Slower than the dense solver at N = 1000: for tests and
    offline checks. False (default): the graph optimum, unchecked (``certified`` None).
    ``dense_max_pairs`` (>= 0): problems with at most this many (slot, robot) pairs use the dense
    solver directly; 0 forces the sparse path (tests do, to exercise it on small cases).
    ``robots``, ``slots``, ``incumbent``, ``hysteresis_m`` (m), ``tie_tol_m`` (m): as
    :func:`coordinator.core.assignment.assign_optimal`. Raises ``ValueError`` on invalid input.
    """
    if isinstance(k, bool) or not isinstance(k, int) or k < 1:
        raise ValueError(f"k must be an int >= 1, got {k!r}")
    if isinstance(dense_max_pairs, bool) or not isinstance(dense_max_pairs, int):
        raise ValueError(f"dense_max_pairs must be an int >= 0, got {dense_max_pairs!r}")
    if dense_max_pairs < 0:
        raise ValueError(f"dense_max_pairs must be an int >= 0, got {dense_max_pairs!r}")
    tol = check_tolerance("tie_tol_m", tie_tol_m)
    hyst = check_tolerance("hysteresis_m", hysteresis_m)
    check_incumbent(incumbent)
    robot_ids, rxy_raw = robots_xy(robots)
    slot_ids, sxy_raw = slots_xy(slots)
    n_r = len(robot_ids)
    n_s = min(n_r, len(slot_ids))  # slots filled: the first n_s in priority order
    if n_s == 0:
        return SparseAssignment({}, "empty")

    def dense(attempts: int = 0, n_edges: int = 0) -> SparseAssignment:
        result = assign_optimal(
            robots, slots, tie_tol_m=tol, incumbent=incumbent, hysteresis_m=hyst
        )
        return SparseAssignment(result, "dense", attempts=attempts, n_edges=n_edges)

    if n_s * n_r <= dense_max_pairs:
        return dense()

    rxy = np.asarray(rxy_raw, dtype=np.float64).reshape(n_r, 2)
    sxy = np.asarray(sxy_raw, dtype=np.float64).reshape(len(slot_ids), 2)[:n_s]
    # Incumbent pairs among the slots being filled; the hysteresis applies to each.
    inc_row_of_col = np.full(n_r, -1, dtype=np.intp)
    if incumbent:
        row_of = {sid: j for j, sid in enumerate(slot_ids[:n_s])}
        for i, rid in enumerate(robot_ids):
            sid = incumbent.get(rid)
            if sid is not None:
                inc_row_of_col[i] = row_of.get(sid, -1)
    p = _Problem(sxy, rxy, inc_row_of_col, hyst, tol, cKDTree(rxy), cKDTree(sxy))

    def result(row_m: IntArray) -> dict[str, int]:
        pairs = sorted(zip(row_m.tolist(), range(n_s), strict=True))
        return {robot_ids[i]: slot_ids[j] for i, j in pairs}

    if _incumbent_is_optimal(p):
        inc_cols = np.flatnonzero(inc_row_of_col >= 0)
        row_m = np.empty(n_s, dtype=np.intp)
        row_m[inc_row_of_col[inc_cols]] = inc_cols
        return SparseAssignment(result(row_m), "incumbent")

    attempts = 0
    n_edges = 0
    for kk in (k, k * FALLBACK_K_FACTOR):
        attempts += 1
        solver = _Solver(p, *_candidates(p, kk))
        try:
            solver.run()
        except ValueError:
            n_edges = solver.n_edges
            continue
        certified: bool | None = None
        if exact:
            certified = False
            for _ in range(MAX_PRICING_ROUNDS):
                rows, cols, complete = _violations(
                    p, solver.u, solver.v, CERT_NEIGHBOURS_PER_K * kk
                )
                if rows.size == 0:
                    certified = complete
                    break
                solver.add_edges(rows, cols, p.cost(rows, cols))
                solver.run()  # cannot fail: the graph only grew
        return SparseAssignment(
            result(solver.row_m), "sparse", kk, attempts, solver.n_edges, solver.phases, certified
        )
    return dense(attempts, n_edges)


def assign_sparse(
    robots: Mapping[str, tuple[float, float]],
    slots: Sequence[SlotLike],
    *,
    k: int = DEFAULT_K,
    incumbent: Mapping[str, int] | None = None,
    hysteresis_m: float = 0.0,
    tie_tol_m: float = 0.01,
    exact: bool = False,
    dense_max_pairs: int = DEFAULT_DENSE_MAX_PAIRS,
) -> dict[str, int]:
    """Minimum-total-cost role assignment that scales to ~1000 robots: robot id -> slot id.

    Drop-in for :func:`coordinator.core.assignment.assign_optimal` (same costs: eq 6 distance in m
    less the incumbent's ``hysteresis_m``, plus the ``tie_tol_m`` tie-break; same priority fill
    with fewer robots than slots, leader first). Solved exactly on a k-nearest-neighbour candidate
    graph (``k`` per robot and per slot, incumbent pairs always included), which at these
    formation densities is the dense optimum or within a fraction of a percent of it.
    ``exact=True`` removes that gap and proves it (a verification tool, slower than the dense
    solver at N = 1000); ``dense_max_pairs``: problems up to
    this many (slot, robot) pairs go to the dense solver. See the module docstring, and
    :func:`solve_sparse` for the diagnostics. Raises ``ValueError`` on invalid input.
    """
    return solve_sparse(
        robots,
        slots,
        k=k,
        incumbent=incumbent,
        hysteresis_m=hysteresis_m,
        tie_tol_m=tie_tol_m,
        dense_max_pairs=dense_max_pairs,
        exact=exact,
    ).assignment
