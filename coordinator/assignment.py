"""Role assignment: which robot fills which slot (paper section 2.3, eq 6).

Distances are Euclidean (eq 6 corrected) between a robot's **reference point** (eqs 10-11) and
the slot position, both in m: the points the tracking controller drives together.

* :func:`assign_greedy` is the paper's algorithm: slots in priority order (the leader slot first,
  then by stage and slot id); each takes the nearest robot not yet assigned; distances within
  ``tie_tol_m`` of the nearest count as equal and go to the lower robot id (natural order, so
  ``r2 < r10``).
* :func:`assign_optimal` minimises the total distance (Hungarian method,
  ``scipy.optimize.linear_sum_assignment``); it never does worse than greedy in total.
* Both take an ``incumbent`` assignment and a ``hysteresis_m``: the incumbent robot of a slot sees
  its distance to that slot reduced by the margin, so a challenger must be closer by more than
  ``hysteresis_m`` to take the slot. This stops roles chattering when two robots are nearly
  equidistant, as the paper's rule (re-run every loop) otherwise does.
* With fewer robots than slots only the first ``len(robots)`` slots in priority order are filled,
  leader first. With more robots than slots the extra robots get no slot (absent from the result).

:class:`RoleAssigner` keeps the incumbent between loops.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping, Sequence
from typing import Final, Literal

import numpy as np
import numpy.typing as npt
from scipy.optimize import linear_sum_assignment
from scipy.spatial.distance import cdist

from coordinator.formation import LEADER_SLOT, SlotState

__all__ = [
    "RoleAssigner",
    "SlotLike",
    "assign_greedy",
    "assign_optimal",
    "assignment_cost",
    "natural_key",
]

SlotLike = SlotState | tuple[int, float, float]
"""A slot for assignment: a :class:`SlotState`, or ``(slot, x, y)`` with x, y in m."""

FloatArray = npt.NDArray[np.float64]
Method = Literal["greedy", "optimal"]
METHODS: Final = ("greedy", "optimal")

_DIGITS = re.compile(r"(\d+)")


def natural_key(robot_id: str) -> tuple[tuple[str | int, ...], str]:
    """Sort key ordering ids naturally: ``r2 < r10``; the raw id breaks remaining ties."""
    parts = _DIGITS.split(robot_id)
    # re.split with one capturing group alternates text (even index) and digits (odd index), so
    # two keys always compare str with str and int with int.
    return tuple(int(p) if i % 2 else p for i, p in enumerate(parts)), robot_id


def _tolerance(name: str, value: float) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ValueError(f"{name} must be a number, got {value!r}")
    f = float(value)
    if not math.isfinite(f) or f < 0.0:
        raise ValueError(f"{name} must be finite and >= 0, got {value!r}")
    return f


def _robots(robots: Mapping[str, tuple[float, float]]) -> tuple[list[str], FloatArray]:
    """Robot ids in natural order and their positions (n, 2)."""
    if not isinstance(robots, Mapping):
        raise ValueError(f"robots must be a mapping id -> (x, y), got {type(robots).__name__}")
    for rid in robots:
        if not isinstance(rid, str):
            raise ValueError(f"robot ids must be strings, got {rid!r}")
    ids = sorted(robots, key=natural_key)
    xy = np.empty((len(ids), 2), dtype=np.float64)
    for i, rid in enumerate(ids):
        p = robots[rid]
        try:
            px, py = p
            xy[i, 0], xy[i, 1] = float(px), float(py)
        except (TypeError, ValueError):
            raise ValueError(f"robot {rid!r}: position must be (x, y) numbers, got {p!r}") from None
    if not np.all(np.isfinite(xy)):
        bad = [ids[i] for i in np.flatnonzero(~np.all(np.isfinite(xy), axis=1))]
        raise ValueError(f"non-finite position for robot(s) {', '.join(bad)}")
    return ids, xy


def _slots(slots: Sequence[SlotLike]) -> tuple[list[int], FloatArray]:
    """Slot ids in priority order and their positions (n, 2).

    Priority: the leader slot 0 first, then by stage (a ``SlotState``'s ``stage``; a tuple has
    none and counts as stage 1), then by slot id.
    """
    rows: list[tuple[tuple[bool, int, int], int, float, float]] = []
    seen: set[int] = set()
    for s in slots:
        if isinstance(s, SlotState):
            sid, x, y, stage = s.slot, s.x, s.y, s.stage
        else:
            try:
                sid_raw, x_raw, y_raw = s
                sid, x, y = int(sid_raw), float(x_raw), float(y_raw)
            except (TypeError, ValueError):
                raise ValueError(f"a slot must be a SlotState or (slot, x, y), got {s!r}") from None
            if sid != sid_raw:
                raise ValueError(f"slot id must be an integer, got {sid_raw!r}")
            stage = 0 if sid == LEADER_SLOT else 1
        if sid in seen:
            raise ValueError(f"duplicate slot id {sid}")
        if not (math.isfinite(x) and math.isfinite(y)):
            raise ValueError(f"slot {sid}: non-finite position ({x!r}, {y!r})")
        seen.add(sid)
        rows.append(((sid != LEADER_SLOT, stage, sid), sid, x, y))
    rows.sort(key=lambda r: r[0])
    ids = [r[1] for r in rows]
    xy = np.array([[r[2], r[3]] for r in rows], dtype=np.float64).reshape(len(rows), 2)
    return ids, xy


def _costs(
    robot_ids: list[str],
    rxy: FloatArray,
    slot_ids: list[int],
    sxy: FloatArray,
    incumbent: Mapping[str, int] | None,
    hysteresis_m: float,
) -> tuple[FloatArray, FloatArray]:
    """(distance, adjusted cost), each (n_slots, n_robots): eq 6 and eq 6 minus the incumbent's
    hysteresis margin."""
    dist: FloatArray = cdist(sxy, rxy)  # Euclidean
    cost = dist.copy()
    if incumbent and hysteresis_m > 0.0:
        row_of = {sid: j for j, sid in enumerate(slot_ids)}
        col_of = {rid: i for i, rid in enumerate(robot_ids)}
        for rid, sid in incumbent.items():
            j, i = row_of.get(sid), col_of.get(rid)
            if j is not None and i is not None:
                cost[j, i] -= hysteresis_m
    return dist, cost


def _check_incumbent(incumbent: Mapping[str, int] | None) -> None:
    if incumbent is None:
        return
    if not isinstance(incumbent, Mapping):
        raise ValueError(f"incumbent must be a mapping robot id -> slot, got {incumbent!r}")
    for rid, sid in incumbent.items():
        if not isinstance(rid, str) or isinstance(sid, bool) or not isinstance(sid, int):
            raise ValueError(f"incumbent entries must be str -> int, got {rid!r}: {sid!r}")


def assign_greedy(
    robots: Mapping[str, tuple[float, float]],
    slots: Sequence[SlotLike],
    *,
    tie_tol_m: float = 0.01,
    incumbent: Mapping[str, int] | None = None,
    hysteresis_m: float = 0.0,
) -> dict[str, int]:
    """The paper's role assignment (section 2.3): robot id -> slot id.

    Slots in priority order (leader first, then by stage and slot id) each take the unassigned
    robot with the smallest cost, the cost being the Euclidean distance of eq 6 (m) less
    ``hysteresis_m`` for the slot's incumbent robot. Costs within ``tie_tol_m`` (m) of the smallest
    are ties and go to the lowest robot id in natural order. Robots that get no slot are absent.
    O(n_slots x n_robots).
    """
    tol = _tolerance("tie_tol_m", tie_tol_m)
    hyst = _tolerance("hysteresis_m", hysteresis_m)
    _check_incumbent(incumbent)
    robot_ids, rxy = _robots(robots)
    slot_ids, sxy = _slots(slots)
    k = min(len(robot_ids), len(slot_ids))
    if k == 0:
        return {}
    _, cost = _costs(robot_ids, rxy, slot_ids[:k], sxy[:k], incumbent, hyst)
    out: dict[int, int] = {}  # robot column -> slot id
    taken = np.zeros(len(robot_ids), dtype=bool)
    for j in range(k):
        row = cost[j]  # each slot's row is used once: mark taken robots in it only
        row[taken] = np.inf
        best = row.min()
        # Columns are in natural id order, so the first tie is the lowest id.
        i = int(np.argmax(row <= best + tol))
        out[i] = slot_ids[j]
        taken[i] = True
    return {robot_ids[i]: out[i] for i in sorted(out)}


def assign_optimal(
    robots: Mapping[str, tuple[float, float]],
    slots: Sequence[SlotLike],
    *,
    tie_tol_m: float = 0.01,
    incumbent: Mapping[str, int] | None = None,
    hysteresis_m: float = 0.0,
) -> dict[str, int]:
    """Minimum-total-cost assignment (Hungarian method): robot id -> slot id.

    Same costs as :func:`assign_greedy` (eq 6 less the incumbent's ``hysteresis_m``), over the
    first ``min(n_robots, n_slots)`` slots in priority order. Near-ties are broken
    deterministically by adding a term, at most ``tie_tol_m`` (m) in total, that favours lower
    robot ids on higher-priority slots; so the result's total cost is within ``tie_tol_m`` of the
    minimum (exactly minimal with ``tie_tol_m = 0``).
    """
    tol = _tolerance("tie_tol_m", tie_tol_m)
    hyst = _tolerance("hysteresis_m", hysteresis_m)
    _check_incumbent(incumbent)
    robot_ids, rxy = _robots(robots)
    slot_ids, sxy = _slots(slots)
    n_r = len(robot_ids)
    k = min(n_r, len(slot_ids))
    if k == 0:
        return {}
    _, cost = _costs(robot_ids, rxy, slot_ids[:k], sxy[:k], incumbent, hyst)
    if tol > 0.0:
        # Sum over the k chosen pairs < tol. Minimising sum(rank_r * weight_slot) pairs low ranks
        # with high weights (rearrangement inequality): lower ids on higher-priority slots.
        rank = np.arange(n_r, dtype=np.float64) / n_r
        weight = 1.0 - np.arange(k, dtype=np.float64) / k
        cost += (tol / k) * weight[:, None] * rank[None, :]
    rows, cols = linear_sum_assignment(cost)
    pairs = sorted(zip(cols.tolist(), rows.tolist(), strict=True))
    return {robot_ids[i]: slot_ids[j] for i, j in pairs}


def assignment_cost(
    robots: Mapping[str, tuple[float, float]],
    slots: Sequence[SlotLike],
    assignment: Mapping[str, int],
) -> float:
    """Total Euclidean distance (m, eq 6) between the assigned robots and their slots."""
    slot_xy: dict[int, tuple[float, float]] = {}
    for s in slots:
        if isinstance(s, SlotState):
            slot_xy[s.slot] = (s.x, s.y)
        else:
            slot_xy[int(s[0])] = (float(s[1]), float(s[2]))
    total = 0.0
    for rid, sid in assignment.items():
        rx, ry = robots[rid]
        sx, sy = slot_xy[sid]
        total += math.hypot(float(rx) - sx, float(ry) - sy)
    return total


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
        self.method: Method = "greedy" if method == "greedy" else "optimal"
        self.hysteresis_m = _tolerance("hysteresis_m", hysteresis_m)
        self.tie_tol_m = _tolerance("tie_tol_m", tie_tol_m)
        self._assignment: dict[str, int] = {}
        self._n_updates = 0
        self._n_changes = 0

    def update(
        self, robots: Mapping[str, tuple[float, float]], slots: Sequence[SlotLike]
    ) -> tuple[dict[str, int], bool]:
        """Assign ``robots`` (id -> reference point (x, y), m) to ``slots``.

        Returns ``(robot id -> slot id, changed)``; ``changed`` is True when the mapping differs
        from the previous update's (so the first non-empty update reports a change).
        """
        fn = assign_greedy if self.method == "greedy" else assign_optimal
        new = fn(
            robots,
            slots,
            tie_tol_m=self.tie_tol_m,
            incumbent=self._assignment,
            hysteresis_m=self.hysteresis_m,
        )
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
