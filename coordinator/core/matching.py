"""Matching robots to slots (paper section 2.3, eq 6): the greedy and optimal solvers.

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

:class:`coordinator.core.assignment.RoleAssigner` keeps the incumbent between loops; the sparse
solver for large fleets is :mod:`coordinator.core.scale_assign`.

**Shortcuts that return the rules' own answer.** Re-run every tick, both rules almost always
return the incumbent: the formation holds. Three checks prove that without running the rule,
and return None (the rule runs) whenever they cannot: :func:`kept_by_spacing` (O(n), plain
Python: each slot's incumbent is closer than the formation's least slot spacing allows any
other robot to be, by the triangle inequality; the coordinator's tick gives it the spacing of a
rigid formation), :func:`greedy_kept` (one numpy pass over the (k, n) distances, from
:data:`KEPT_CHECK_MIN_PAIRS` pairs) and the optimal rule's check of its cost rows before the
Hungarian solver. Each proves that every challenger is farther than the incumbent's cost plus
the tie tolerance (and a 1 um margin, far above rounding), so the rule's comparisons, ties and
hysteresis included, pick the incumbent: the answer is the same dict, in the same order, as the
rule's (tests/unit/coordinator/test_assignment_kept.py checks it on random fleets).
"""

from __future__ import annotations

import functools
import math
import re
from collections.abc import Iterable, Mapping, Sequence
from typing import Any, Final, Literal

import numpy as np
import numpy.typing as npt
from scipy.optimize import linear_sum_assignment
from scipy.spatial.distance import cdist

from coordinator.core.formation import LEADER_SLOT, SlotState

__all__ = [
    "GREEDY_PY_MAX_PAIRS",
    "KEPT_CHECK_MIN_PAIRS",
    "METHODS",
    "Method",
    "SlotLike",
    "assign_greedy",
    "assign_optimal",
    "assignment_cost",
    "check_finite",
    "check_incumbent",
    "check_tolerance",
    "greedy_kept",
    "greedy_ordered",
    "greedy_py",
    "kept_by_spacing",
    "natural_key",
    "optimal_ordered",
    "robots_xy",
    "slots_xy",
]

SlotLike = SlotState | tuple[int, float, float]
"""A slot for assignment: a :class:`SlotState`, or ``(slot, x, y)`` with x, y in m."""

FloatArray = npt.NDArray[np.float64]
Method = Literal["greedy", "optimal", "sparse"]
METHODS: Final = ("greedy", "optimal", "sparse")

_DIGITS = re.compile(r"(\d+)")


def natural_key(robot_id: str) -> tuple[tuple[str | int, ...], str]:
    """Sort key ordering ids naturally: ``r2 < r10``; the raw id breaks remaining ties."""
    parts = _DIGITS.split(robot_id)
    # re.split with one capturing group alternates text (even index) and digits (odd index), so
    # two keys always compare str with str and int with int.
    return tuple(int(p) if i % 2 else p for i, p in enumerate(parts)), robot_id


def check_tolerance(name: str, value: float) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ValueError(f"{name} must be a number, got {value!r}")
    f = float(value)
    if not math.isfinite(f) or f < 0.0:
        raise ValueError(f"{name} must be finite and >= 0, got {value!r}")
    return f


# Below this many (slot, robot) pairs the greedy rule runs in plain Python: for a handful of
# robots numpy's per-call overhead (cdist, masking, argmax: ~1 us each) dwarfs the arithmetic.
# Both paths compute the same floats (cdist is sqrt(dx*dx + dy*dy), as here) and make the same
# comparisons, so they return the same assignment; tests check it. Measured on this project's
# 2.5 GHz Xeon: 26 vs 188 us for 10 x 10, 191 vs 547 us for 30 x 30, 1.10 vs 1.20 ms for
# 70 x 70, 2.29 vs 2.19 ms for 100 x 100.
GREEDY_PY_MAX_PAIRS: Final = 6400


def robots_xy(
    robots: Mapping[str, tuple[float, float]],
) -> tuple[list[str], list[tuple[float, float]]]:
    """Robot ids in natural order and their positions (m) as float pairs, validated."""
    if not isinstance(robots, Mapping):
        raise ValueError(f"robots must be a mapping id -> (x, y), got {type(robots).__name__}")
    keys: Iterable[object] = robots  # as given: the compiled build checks no declared type here
    for rid in keys:
        if not isinstance(rid, str):
            raise ValueError(f"robot ids must be strings, got {rid!r}")
    ids = sorted(robots, key=natural_key)
    xy: list[tuple[float, float]] = []
    bad: list[str] = []
    isfinite = math.isfinite
    given: Mapping[str, object] = robots
    for rid in ids:
        p: Any = given[rid]
        try:
            px, py = p
            fx, fy = float(px), float(py)
        except (TypeError, ValueError):
            raise ValueError(f"robot {rid!r}: position must be (x, y) numbers, got {p!r}") from None
        if not (isfinite(fx) and isfinite(fy)):
            bad.append(rid)
        xy.append((fx, fy))
    if bad:
        raise ValueError(f"non-finite position for robot(s) {', '.join(bad)}")
    return ids, xy


def slots_xy(slots: Sequence[SlotLike]) -> tuple[list[int], list[tuple[float, float]]]:
    """Slot ids in priority order and their positions (m) as float pairs, validated.

    Priority: the leader slot 0 first, then by stage (a ``SlotState``'s ``stage``; a tuple has
    none and counts as stage 1), then by slot id.
    """
    rows: list[tuple[tuple[bool, int, int], int, float, float]] = []
    seen: set[int] = set()
    entries: Iterable[object] = slots
    for s in entries:
        if isinstance(s, SlotState):
            sid, x, y, stage = s.slot, s.x, s.y, s.stage
        else:
            row: Any = s
            try:
                sid_raw, x_raw, y_raw = row
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
    return [r[1] for r in rows], [(r[2], r[3]) for r in rows]


def _as_array(xy: Sequence[Sequence[float]]) -> FloatArray:
    """(n, 2) float array of the first two entries of each row."""
    return np.array([(p[0], p[1]) for p in xy], dtype=np.float64).reshape(len(xy), 2)


def _costs(
    robot_ids: Sequence[str],
    rxy: FloatArray,
    slot_ids: Sequence[int],
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


def check_incumbent(incumbent: Mapping[str, int] | None) -> None:
    if incumbent is None:
        return
    if not isinstance(incumbent, Mapping):
        raise ValueError(f"incumbent must be a mapping robot id -> slot, got {incumbent!r}")
    entries: Iterable[tuple[object, object]] = incumbent.items()
    for rid, sid in entries:
        if not isinstance(rid, str) or isinstance(sid, bool) or not isinstance(sid, int):
            raise ValueError(f"incumbent entries must be str -> int, got {rid!r}: {sid!r}")


def greedy_ordered(
    robot_ids: Sequence[str],
    rxy: Sequence[tuple[float, float]],
    slot_ids: Sequence[int],
    sxy: Sequence[Sequence[float]],
    incumbent: Mapping[str, int] | None,
    hyst: float,
    tol: float,
) -> dict[str, int]:
    """The greedy rule on validated input: robots in natural id order, slots in priority order
    (only the first two entries of each ``sxy`` row, x and y in m, are read)."""
    k = min(len(robot_ids), len(slot_ids))
    if k == 0:
        return {}
    if len(robot_ids) * k >= KEPT_CHECK_MIN_PAIRS:
        kept = greedy_kept(robot_ids, rxy, slot_ids, sxy, k, incumbent, hyst, tol)
        if kept is not None:
            return kept
    if len(robot_ids) * k <= GREEDY_PY_MAX_PAIRS:
        return greedy_py(robot_ids, rxy, slot_ids, sxy, k, incumbent, hyst, tol)
    return _greedy_np(robot_ids, rxy, slot_ids, sxy, k, incumbent, hyst, tol)


def _incumbent_slots(
    robot_ids: Sequence[str], incumbent: Mapping[str, int] | None, hyst: float
) -> list[int | None] | None:
    """Each robot's incumbent slot (column order), or None when no hysteresis applies."""
    return list(map(incumbent.get, robot_ids)) if (incumbent and hyst > 0.0) else None


def _slot_costs(
    srow: Sequence[float],
    sid: int,
    rxy: Sequence[tuple[float, float]],
    cols: Iterable[int],
    inc: list[int | None] | None,
    hyst: float,
) -> list[float]:
    """The costs of slot ``sid`` at ``srow`` (x, y first) for the robots of columns ``cols``, in
    plain Python: eq 6 as cdist computes it (sqrt(dx*dx + dy*dy)), less the hysteresis margin
    ``hyst`` (m) where the robot is the slot's incumbent (``inc``: :func:`_incumbent_slots`).
    The one cost rule of the plain-Python greedy and optimal solvers."""
    sx = srow[0]
    sy = srow[1]
    out: list[float] = []
    for i in cols:
        rx, ry = rxy[i]
        dx = sx - rx
        dy = sy - ry
        c = math.sqrt(dx * dx + dy * dy)
        if inc is not None and inc[i] == sid:
            c -= hyst
        out.append(c)
    return out


def greedy_py(
    robot_ids: Sequence[str],
    rxy: Sequence[tuple[float, float]],
    slot_ids: Sequence[int],
    sxy: Sequence[Sequence[float]],
    k: int,
    incumbent: Mapping[str, int] | None,
    hyst: float,
    tol: float,
    check: bool = False,
) -> dict[str, int]:
    """Plain-Python greedy (small fleets): the arithmetic and comparisons of :func:`_greedy_np`.

    Per slot, the costs of the untaken robots (eq 6 as cdist computes it, less the margin on the
    incumbent: the rule of :func:`_slot_costs`, written out here because this loop runs every
    tick), then the first robot in natural order within ``tol`` of the smallest.

    ``check``: the positions are not validated yet. Every robot meets slot 0 and every used slot
    meets a robot, so a NaN/inf coordinate makes some cost non-finite: the sum of the costs is
    the check, and only if it fails (or slots are left over) are the positions inspected one by
    one, raising the errors of :meth:`RoleAssigner.update_ordered`.
    """
    n = len(robot_ids)
    inc = _incumbent_slots(robot_ids, incumbent, hyst)
    free = list(range(n))  # untaken columns, ascending = natural id order
    got: list[int | None] = [None] * n  # robot column -> slot id
    total = 0.0
    for j in range(k):
        sid = slot_ids[j]
        srow = sxy[j]
        sx = srow[0]
        sy = srow[1]
        costs: list[float] = []
        best = math.inf
        for i in free:
            rx, ry = rxy[i]
            dx = sx - rx
            dy = sy - ry
            c = math.sqrt(dx * dx + dy * dy)
            if inc is not None and inc[i] == sid:
                c -= hyst
            total += c
            if c < best:
                best = c
            costs.append(c)
        lim = best + tol
        pos = 0
        for c in costs:  # the first tie (lowest id) wins; best itself is one
            if c <= lim:
                break
            pos += 1
        if pos == len(costs):  # only NaN costs: a non-finite position
            break
        got[free.pop(pos)] = sid
    if check and (not math.isfinite(total) or k < len(slot_ids)):
        check_finite(robot_ids, rxy, slot_ids, sxy)
    return {rid: sid for rid, sid in zip(robot_ids, got, strict=True) if sid is not None}


# The incumbent kept at once (greedy_kept, optimal_kept): from this many (slot, robot) pairs one
# vectorised check of the incumbent is cheaper than the greedy loop (plain Python) or the
# Hungarian solver; below it the check costs more than the solvers save.
KEPT_CHECK_MIN_PAIRS: Final = 100
_KEPT_MARGIN_M: Final = 1e-6
"""The check's safety margin (m): far above the rounding of any cost here (1e-16 relative), so
the check's arithmetic need not be the solvers' bit for bit; a challenger within a micrometre
of the incumbent's bound sends the tick to the solver, which decides it exactly."""


def _kept_columns(
    robot_ids: Sequence[str], slot_ids: Sequence[int], k: int, incumbent: Mapping[str, int]
) -> list[int] | None:
    """Each of the first ``k`` slots' incumbent robot column, or None when a slot has none (or
    two robots claim one)."""
    col_of: dict[int, int] = {}
    get = incumbent.get
    for i, rid in enumerate(robot_ids):
        sid = get(rid)
        if sid is not None:
            if sid in col_of:
                return None
            col_of[sid] = i
    cols = [col_of.get(sid, -1) for sid in slot_ids[:k]]
    return None if -1 in cols else cols


def _kept_distances(
    rxy: Sequence[tuple[float, float]], sxy: Sequence[Sequence[float]], k: int, cols: list[int]
) -> tuple[FloatArray, FloatArray] | None:
    """(distance of each of the first ``k`` slots to its incumbent, (k, n) distances with the
    incumbents' entries set to +inf), or None when a position is not finite."""
    dist: FloatArray = cdist(_as_array(sxy[:k]), _as_array(rxy))
    if not math.isfinite(float(dist.sum())):
        return None
    rows = np.arange(k)
    own: FloatArray = dist[rows, cols]
    dist[rows, cols] = np.inf
    return own, dist


def kept_by_spacing(
    robot_ids: Sequence[str],
    rxy: Sequence[tuple[float, float]],
    sxy: Sequence[Sequence[float]],
    k: int,
    incumbent: dict[str, int] | None,
    row_of: dict[int, int],
    hyst: float,
    gap: float,
    spacing_m: float,
) -> dict[str, int] | None:
    """The incumbent, when the slots' spacing proves that the rules keep it; else None (then
    the caller runs the rule). O(n) where the rules cost O(n k): the per-tick check of a
    formation that holds.

    ``sxy``: the slots' rows (x, y first) in priority order, ``row_of`` slot id -> row;
    ``spacing_m``: no two of these slots are closer than this (m; a rigid formation's least
    slot-to-slot distance, ``FormationSpec.least_spacing_m``). ``gap`` (m): how much farther
    from a slot than its incumbent's cost a challenger must be: ``tol`` for the greedy rule,
    ``tol / k`` for the optimal one (its tie-break term lies in ``[0, tol / k)``). Input
    ordered as :func:`greedy_ordered`'s; a position that is not finite returns None.

    Why it holds: each of the first ``k`` slots has an incumbent robot (a distinct one), at
    distance ``d_j``; ``d`` is the largest. A robot holding slot ``j'`` is at least
    ``spacing_m - d`` from any other slot ``j`` (the triangle inequality), and the incumbent of
    ``j`` costs at most ``d - hyst``. So when ``spacing_m - d > d - hyst + gap`` (plus
    :data:`_KEPT_MARGIN_M`, far above the rounding of these sums) and every robot holding no
    slot now is farther than that from every slot (checked one by one), each slot's incumbent
    is the only robot within ``gap`` of its least cost: the greedy rule picks it slot after
    slot, and the incumbents take every row's least cost, the unique optimum.
    """
    if not incumbent or k == 0 or not spacing_m > 0.0:
        return None
    # (incumbent and row_of are dicts, whose get mypyc calls in C: the per-tick check; the
    # positions as lists, which mypyc indexes in C where a Sequence's every index is a Python
    # call compiled: the same values)
    robots: list[tuple[float, float]] = rxy if isinstance(rxy, list) else list(rxy)
    rows: list[Sequence[float]] = sxy if isinstance(sxy, list) else list(sxy)
    out: dict[str, int] = {}  # robot -> its slot, natural id order (as the rules return it)
    taken = [False] * k
    spare: list[int] = []
    far = 0.0
    total = 0.0
    for i, rid in enumerate(robot_ids):
        sid = incumbent.get(rid)
        j = -1 if sid is None else row_of.get(sid, -1)
        if j < 0 or j >= k or sid is None:  # no slot among the first k
            spare.append(i)
            continue
        if taken[j]:  # two robots hold one slot: the rule decides
            return None
        taken[j] = True
        out[rid] = sid
        srow = rows[j]
        rx, ry = robots[i]
        dx = srow[0] - rx
        dy = srow[1] - ry
        d = math.sqrt(dx * dx + dy * dy)
        total += d
        if d > far:
            far = d
    adj = far - hyst if hyst > 0.0 else far
    bound = adj + gap + _KEPT_MARGIN_M
    if len(out) != k or not (math.isfinite(total) and spacing_m - far > bound):
        return None
    isfinite = math.isfinite
    for i in spare:  # robots holding no slot now: each against every slot
        rx, ry = rxy[i]
        if not (isfinite(rx) and isfinite(ry)):
            return None
        for j in range(k):
            srow = sxy[j]
            dx = srow[0] - rx
            dy = srow[1] - ry
            if not math.sqrt(dx * dx + dy * dy) > bound:
                return None
    return out


def greedy_kept(
    robot_ids: Sequence[str],
    rxy: Sequence[tuple[float, float]],
    slot_ids: Sequence[int],
    sxy: Sequence[Sequence[float]],
    k: int,
    incumbent: Mapping[str, int] | None,
    hyst: float,
    tol: float,
) -> dict[str, int] | None:
    """The greedy rule's answer when it is provably the incumbent, else None (then the caller
    runs the rule). Validated input as :func:`greedy_ordered`'s; ``k`` slots are filled.

    Each of the first ``k`` slots has an incumbent robot (a distinct one) and every other robot
    is farther from that slot than the incumbent's cost (its distance less ``hyst``) plus
    ``tol`` (plus :data:`_KEPT_MARGIN_M`). Then, slot by slot in priority order, the incumbent
    is untaken (the earlier slots took their own), its cost is the least, and no other robot is
    within ``tol`` of it: the rule picks it, as it picks it when it runs. One numpy pass over the
    (k, n) distances, for large fleets (``KEPT_CHECK_MIN_PAIRS``) whose formation holds.
    """
    if not incumbent or k == 0:
        return None
    cols = _kept_columns(robot_ids, slot_ids, k, incumbent)
    if cols is None:
        return None
    got = _kept_distances(rxy, sxy, k, cols)
    if got is None:
        return None
    own, others = got
    adj = own - hyst if hyst > 0.0 else own
    if not bool((others.min(axis=1) > adj + (tol + _KEPT_MARGIN_M)).all()):
        return None
    return _in_id_order(robot_ids, slot_ids, cols)


def _in_id_order(
    robot_ids: Sequence[str], slot_ids: Sequence[int], cols: list[int]
) -> dict[str, int]:
    """robot id -> slot id for slot ``slot_ids[j]`` held by column ``cols[j]``, in column
    (natural id) order, as the solvers return it."""
    slot_at = dict(zip(cols, slot_ids, strict=False))
    return {robot_ids[i]: slot_at[i] for i in sorted(slot_at)}


def check_finite(
    robot_ids: Sequence[str],
    rxy: Sequence[tuple[float, float]],
    slot_ids: Sequence[int],
    sxy: Sequence[Sequence[float]],
) -> None:
    """Raise the ValueError of :func:`robots_xy` / :func:`slots_xy` for a non-finite position."""
    isfinite = math.isfinite
    bad = [r for r, (u, v) in zip(robot_ids, rxy, strict=True) if not (isfinite(u) and isfinite(v))]
    if bad:
        raise ValueError(f"non-finite position for robot(s) {', '.join(bad)}")
    for sid, row in zip(slot_ids, sxy, strict=True):
        if not (isfinite(row[0]) and isfinite(row[1])):
            raise ValueError(f"slot {sid}: non-finite position ({row[0]!r}, {row[1]!r})")


def _greedy_np(
    robot_ids: Sequence[str],
    rxy: Sequence[tuple[float, float]],
    slot_ids: Sequence[int],
    sxy: Sequence[Sequence[float]],
    k: int,
    incumbent: Mapping[str, int] | None,
    hyst: float,
    tol: float,
) -> dict[str, int]:
    """Vectorised greedy (large fleets): one cost matrix, then a masked argmin per slot."""
    _, cost = _costs(robot_ids, _as_array(rxy), slot_ids[:k], _as_array(sxy[:k]), incumbent, hyst)
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


def _cost_rows_py(
    robot_ids: Sequence[str],
    rxy: Sequence[tuple[float, float]],
    slot_ids: Sequence[int],
    sxy: Sequence[Sequence[float]],
    k: int,
    incumbent: Mapping[str, int] | None,
    hyst: float,
) -> list[list[float]]:
    """:func:`_costs`' adjusted cost (first ``k`` slots x robots, one list a slot) built in
    plain Python: for small fleets cheaper than cdist's call overhead, and the same numbers
    (sqrt(dx*dx + dy*dy))."""
    inc = _incumbent_slots(robot_ids, incumbent, hyst)
    cols = range(len(robot_ids))
    return [_slot_costs(sxy[j], slot_ids[j], rxy, cols, inc, hyst) for j in range(k)]


@functools.lru_cache(maxsize=32)
def _tie_break(n_r: int, k: int, tol: float) -> FloatArray:
    """The optimal rule's deterministic tie-break term, (k, n_r) in m (read-only, cached).

    Sum over the k chosen pairs < tol. Minimising sum(rank_r * weight_slot) pairs low ranks with
    high weights (rearrangement inequality): lower ids on higher-priority slots.
    """
    rank = np.arange(n_r, dtype=np.float64) / n_r
    weight = 1.0 - np.arange(k, dtype=np.float64) / k
    term: FloatArray = (tol / k) * weight[:, None] * rank[None, :]
    term.setflags(write=False)
    return term


def _optimal_kept(
    robot_ids: Sequence[str],
    slot_ids: Sequence[int],
    k: int,
    incumbent: Mapping[str, int] | None,
    cost: Sequence[list[float]] | FloatArray,
    tol: float,
) -> dict[str, int] | None:
    """The optimal rule's answer when it is provably the incumbent, else None (then the solver
    runs). ``cost``: the (k, n) adjusted costs (eq 6 less the incumbent's margin), rows in
    slot priority order, before the tie-break term.

    Each of the first ``k`` slots has an incumbent robot (a distinct one) whose cost is below
    every other robot's in that row by more than ``tol / k`` (the tie-break term lies in
    ``[0, tol / k)``) plus :data:`_KEPT_MARGIN_M`. Then the incumbents take every row's least
    cost (with the tie-break added), which no assignment undercuts, and any other assignment
    pays more in some row: the minimum is the incumbent, and it is the only one, so it is what
    the Hungarian solver returns.
    """
    if not incumbent or k == 0:
        return None
    cols = _kept_columns(robot_ids, slot_ids, k, incumbent)
    if cols is None:
        return None
    gap = (tol / k if tol > 0.0 else 0.0) + _KEPT_MARGIN_M
    if isinstance(cost, np.ndarray):
        if not math.isfinite(float(cost.sum())):
            return None
        at = np.arange(k)
        own = cost[at, cols]
        others = cost.copy()
        others[at, cols] = np.inf
        if not bool((others.min(axis=1) > own + gap).all()):
            return None
        return _in_id_order(robot_ids, slot_ids, cols)
    isfinite = math.isfinite
    for row, c in zip(cost, cols, strict=True):
        own_c = row[c]
        bound = own_c + gap
        if not isfinite(bound):
            return None
        for i, v in enumerate(row):
            if not (v > bound or i == c):  # (a NaN or a challenger: the solver decides)
                return None
            if not isfinite(v):
                return None
    return _in_id_order(robot_ids, slot_ids, cols)


def optimal_ordered(
    robot_ids: Sequence[str],
    rxy: Sequence[tuple[float, float]],
    slot_ids: Sequence[int],
    sxy: Sequence[Sequence[float]],
    incumbent: Mapping[str, int] | None,
    hyst: float,
    tol: float,
) -> dict[str, int]:
    """The Hungarian assignment on validated input (orders as in :func:`greedy_ordered`)."""
    n_r = len(robot_ids)
    k = min(n_r, len(slot_ids))
    if k == 0:
        return {}
    if n_r * k <= GREEDY_PY_MAX_PAIRS:
        cost_rows = _cost_rows_py(robot_ids, rxy, slot_ids, sxy, k, incumbent, hyst)
        kept = _optimal_kept(robot_ids, slot_ids, k, incumbent, cost_rows, tol)
        if kept is not None:
            return kept
        cost = np.array(cost_rows, dtype=np.float64).reshape(k, n_r)
    else:
        _, cost = _costs(
            robot_ids, _as_array(rxy), slot_ids[:k], _as_array(sxy[:k]), incumbent, hyst
        )
        kept = _optimal_kept(robot_ids, slot_ids, k, incumbent, cost, tol)
        if kept is not None:
            return kept
    if tol > 0.0:
        cost += _tie_break(n_r, k, tol)
    rows, cols = linear_sum_assignment(cost)
    pairs = sorted(zip(cols.tolist(), rows.tolist(), strict=True))
    return {robot_ids[i]: slot_ids[j] for i, j in pairs}


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
    tol = check_tolerance("tie_tol_m", tie_tol_m)
    hyst = check_tolerance("hysteresis_m", hysteresis_m)
    check_incumbent(incumbent)
    robot_ids, rxy = robots_xy(robots)
    slot_ids, sxy = slots_xy(slots)
    return greedy_ordered(robot_ids, rxy, slot_ids, sxy, incumbent, hyst, tol)


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
    tol = check_tolerance("tie_tol_m", tie_tol_m)
    hyst = check_tolerance("hysteresis_m", hysteresis_m)
    check_incumbent(incumbent)
    robot_ids, rxy = robots_xy(robots)
    slot_ids, sxy = slots_xy(slots)
    return optimal_ordered(robot_ids, rxy, slot_ids, sxy, incumbent, hyst, tol)


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
