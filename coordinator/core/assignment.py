"""Role assignment re-run every loop, with memory of the incumbent (paper section 2.3).

:class:`RoleAssigner` keeps the incumbent between loops and dispatches to a solver: the paper's
greedy rule or the optimal (Hungarian) one of :mod:`coordinator.core.matching`, or the sparse solver
of :mod:`coordinator.core.scale_assign` for large fleets. The solver functions are re-exported here
(``from coordinator.core.assignment import assign_greedy`` keeps working).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

from coordinator.core.formation import LEADER_SLOT
from coordinator.core.matching import (
    GREEDY_PY_MAX_PAIRS,
    KEPT_CHECK_MIN_PAIRS,
    METHODS,
    Method,
    SlotLike,
    assign_greedy,
    assign_optimal,
    assignment_cost,
    check_finite,
    check_tolerance,
    greedy_kept,
    greedy_ordered,
    greedy_py,
    kept_by_spacing,
    natural_key,
    optimal_ordered,
    robots_xy,
    slots_xy,
)
from coordinator.core.scale_assign import assign_sparse

__all__ = [
    "METHODS",
    "RoleAssigner",
    "SlotLike",
    "assign_greedy",
    "assign_optimal",
    "assign_sparse",
    "assignment_cost",
    "natural_key",
]


class RoleAssigner:
    """Role assignment re-run every loop, with memory of the incumbent (paper section 2.3).

    ``update(robots, slots)`` assigns only the robots it is given (the ones alive, by reference
    point in m); robots not given lose their slot. When robots are missing the slots are filled in
    priority order, leader first. ``hysteresis_m`` (m) favours each slot's incumbent robot,
    ``tie_tol_m`` (m) is the tie tolerance of the greedy rule / the tie-break budget of the optimal
    one.
    """

    def __init__(
        self,
        method: str = "greedy",
        hysteresis_m: float = 0.05,
        tie_tol_m: float = 0.01,
    ) -> None:
        if method not in METHODS:
            raise ValueError(f"RoleAssigner: method must be one of {METHODS}, got {method!r}")
        self.method: Method = method  # type: ignore[assignment]  # checked just above
        self.hysteresis_m = check_tolerance("hysteresis_m", hysteresis_m)
        self.tie_tol_m = check_tolerance("tie_tol_m", tie_tol_m)
        self._assignment: dict[str, int] = {}
        self._n_updates = 0
        self._n_changes = 0
        # tuple of robot ids as given -> permutation into natural order (update_ordered)
        self._order_cache: dict[tuple[str, ...], tuple[int, ...] | None] = {}
        # slot id -> row of the slot ids last given as a tuple (the spec's, every tick)
        self._row_of: dict[int, int] = {}
        self._rows_for: tuple[int, ...] | None = None

    def update(
        self, robots: Mapping[str, tuple[float, float]], slots: Sequence[SlotLike]
    ) -> tuple[dict[str, int], bool]:
        """Assign ``robots`` (id -> reference point (x, y), m) to ``slots``.

        Returns ``(robot id -> slot id, changed)``; ``changed`` is True when the mapping differs
        from the previous update's (so the first non-empty update reports a change).
        """
        robot_ids, rxy = robots_xy(robots)
        slot_ids, sxy = slots_xy(slots)
        return self._commit(robot_ids, rxy, slot_ids, sxy)

    def seed_incumbent(self, assignment: Mapping[str, int]) -> None:
        """Take ``assignment`` (robot id -> slot id) as the incumbent of the next update, e.g.
        the assignment of the coordinator this one takes over from, so hysteresis keeps the
        same roles instead of re-deciding them from scratch."""
        self._assignment = {str(r): int(s) for r, s in assignment.items()}

    def update_ordered(
        self,
        robot_ids: Sequence[str],
        robot_xy: Sequence[tuple[float, float]],
        slot_ids: Sequence[int],
        slot_xy: Sequence[Sequence[float]],
        spacing_m: float | None = None,
    ) -> tuple[dict[str, int], bool]:
        """:meth:`update` for input the caller has already put in order (the per-tick hot path of
        :class:`~coordinator.core.coordinator.CoordinatorCore`).

        ``robot_ids`` (distinct strings) with ``robot_xy`` their reference points (m, floats); any
        order, they are sorted here. ``slot_ids`` (distinct) must be in priority order (leader
        first, then by stage and id: ``FormationSpec.priority_order()``) with ``slot_xy`` rows
        whose first two entries are x, y (m). Non-finite positions raise ``ValueError`` as in
        :meth:`update`; the order and uniqueness are the caller's contract and not checked.

        ``spacing_m``: no two of the slots are closer than this (m), when the caller knows it
        (a rigid formation: ``FormationSpec.least_spacing_m``). Then a formation that holds
        keeps its incumbents by a check in O(n) (``kept_by_spacing``: the same answer as the
        rule, proved) instead of the rule's O(n k).
        """
        n = len(robot_ids)
        if n != len(robot_xy) or len(slot_ids) != len(slot_xy):
            raise ValueError("update_ordered: ids and positions differ in length")
        key = tuple(robot_ids)
        try:
            perm = self._order_cache[key]
        except KeyError:
            for rid in key:
                if not isinstance(rid, str):
                    raise ValueError(f"robot ids must be strings, got {rid!r}") from None
            order = sorted(range(n), key=lambda i: natural_key(key[i]))
            perm = None if order == list(range(n)) else tuple(order)  # None: already in order
            if len(self._order_cache) >= 64:  # fleets change rarely; keep the cache small
                self._order_cache.clear()
            self._order_cache[key] = perm
        ids: Sequence[str]
        if perm is None:
            ids = key
            rxy = robot_xy
        else:
            ids = [key[i] for i in perm]
            rxy = [robot_xy[i] for i in perm]
        k = min(n, len(slot_ids))
        if spacing_m is not None and self.method != "sparse" and self._assignment:
            tol = self.tie_tol_m
            gap = tol if self.method == "greedy" else (tol / k if k and tol > 0.0 else 0.0)
            if slot_ids is not self._rows_for:  # slot id -> row, kept for the same tuple
                self._row_of = {sid: j for j, sid in enumerate(slot_ids)}
                # (only a tuple is kept: a list given again may have changed in between)
                self._rows_for = slot_ids if type(slot_ids) is tuple else None
            kept = kept_by_spacing(
                ids, rxy, slot_xy, k, self._assignment, self._row_of, self.hysteresis_m, gap,
                spacing_m,
            )  # fmt: skip
            if kept is not None:
                if k < len(slot_ids):  # the slots left over are not in the check
                    check_finite(ids, rxy, slot_ids, slot_xy)
                return self._store(kept)
        if self.method == "greedy" and n * k >= KEPT_CHECK_MIN_PAIRS:
            # a large fleet whose formation holds: the incumbent, proved in one numpy pass
            kept = greedy_kept(
                ids, rxy, slot_ids, slot_xy, k, self._assignment, self.hysteresis_m, self.tie_tol_m
            )
            if kept is not None:
                if k < len(slot_ids):  # the slots left over are not in the check
                    check_finite(ids, rxy, slot_ids, slot_xy)
                return self._store(kept)
        if self.method == "greedy" and 0 < n * k <= GREEDY_PY_MAX_PAIRS:
            # The greedy loop checks finiteness on the way (see greedy_py).
            new = greedy_py(
                ids, rxy, slot_ids, slot_xy, k, self._assignment, self.hysteresis_m,
                self.tie_tol_m, check=True,
            )  # fmt: skip
            return self._store(new)
        check_finite(ids, rxy, slot_ids, slot_xy)
        return self._commit(ids, rxy, slot_ids, slot_xy)

    def _commit(
        self,
        robot_ids: Sequence[str],
        rxy: Sequence[tuple[float, float]],
        slot_ids: Sequence[int],
        sxy: Sequence[Sequence[float]],
    ) -> tuple[dict[str, int], bool]:
        if self.method == "sparse":
            # The minimum-sum assignment at scale (coordinator.core.scale_assign): dense below its
            # size threshold, else the exact solver on a k-nearest candidate graph, warm-started
            # from the incumbent (which it returns at once when provably still optimal).
            robots = dict(zip(robot_ids, rxy, strict=True))
            slots = [(sid, row[0], row[1]) for sid, row in zip(slot_ids, sxy, strict=True)]
            new = assign_sparse(
                robots, slots, incumbent=self._assignment, hysteresis_m=self.hysteresis_m,
                tie_tol_m=self.tie_tol_m,
            )  # fmt: skip
            return self._store(new)
        fn = greedy_ordered if self.method == "greedy" else optimal_ordered
        new = fn(robot_ids, rxy, slot_ids, sxy, self._assignment, self.hysteresis_m, self.tie_tol_m)
        return self._store(new)

    def _store(self, new: dict[str, int]) -> tuple[dict[str, int], bool]:
        changed = new != self._assignment
        self._assignment = new
        self._n_updates += 1
        self._n_changes += int(changed)
        return dict(new), changed

    def reset(self) -> None:
        """Forget the incumbent assignment and the counters."""
        self._assignment = {}
        self._n_updates = 0
        self._n_changes = 0

    @property
    def assignment(self) -> dict[str, int]:
        """The current assignment (a copy)."""
        return dict(self._assignment)

    @property
    def leader(self) -> str | None:
        """The robot on the leader slot 0, or None."""
        for rid, sid in self._assignment.items():
            if sid == LEADER_SLOT:
                return rid
        return None

    @property
    def n_updates(self) -> int:
        return self._n_updates

    @property
    def n_changes(self) -> int:
        """Number of updates whose result differed from the previous one."""
        return self._n_changes
