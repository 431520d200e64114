"""Runtime reshaping of a running formation (issue 28): a new shape's slot offsets reached by
an interpolation over a transition time, with a separation guarantee. Pure: no clock, no I/O.

Theory of operation
-------------------
Shapes (:data:`SHAPE_KINDS`) are slot trees (paper eqs 3-5) of the same number of slots as the
running formation. The new shape's slots are *relabelled* with the running slots' ids so that
every robot keeps its slot id (the assignment's hysteresis keeps it there: no role change from a
reshape) and travels the least: slot 0, the virtual leader, stays slot 0; the others by the
permutation of least summed squared displacement (the CAPT rule, Turpin et al. 2014: with
synchronised straight lines it keeps the start and goal separations for well-spaced slots), or,
for up to :data:`BRUTE_FORCE_MAX` slots, by trying every permutation.

Each slot's body-frame offset ``d_i`` (from the leader, leader heading +x) moves from the old
value to the new along a straight line with a smoothstep profile ``s = 3 u^2 - 2 u^3`` over its
window of the transition (``u`` the fraction of the window elapsed), so its velocity is
continuous at both ends. The slot in the world: ``p_i = p_L + R(theta) d_i``, ``v_i = v_L +
omega J R(theta) d_i + R(theta) d_i'`` (eqs 1-5 differentiated with a moving offset).

**Another number of slots** (``slots``). Fewer: the rearmost running slots (the least body x;
equal x: the highest id; never the leader's) are dropped; each moves during the transition to a
parking place behind the new shape (straight back, one spacing behind its rearmost slot; else,
if that is not safe, in a row across there) and leaves the formation at its end, so its robot,
which then has no slot and stops, is left behind by a formation driving on instead of standing
in its way. More: the running slots are matched to as many slots of the new shape (least
displacement, as above) and the others get fresh ids (above every running one: nobody's slot is
renamed); an added slot stands where it ends from the start, and a robot without a slot (a
spare) takes it on an approach point (coordinator.core.coordinator: spares never sprint). The
separation check covers every slot of the transition.

Schedules tried, first that keeps every pair of slots at least ``safety_m`` apart all along:
every slot at once, then one slot at a time (rear first, then front first). The least
separation of a plan is computed on :data:`CHECK_SAMPLES` instants of its transition (between
two samples a pair closes by at most ``2 * RESHAPE_SPEED_MPS * T / CHECK_SAMPLES``, under a mm).
A reshape no plan makes safe is refused. The transition time makes the fastest slot move at most
:data:`RESHAPE_SPEED_MPS` relative to the formation (peak of the smoothstep: 1.5 x the mean).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Final

import numpy as np
from scipy.optimize import linear_sum_assignment

from coordinator.core.formation import FormationSpec, SlotRow
from coordinator.core.shapes import Row, chevron_rows, lattice_rows
from coordinator.core.trajectory import LeaderState, wrap_angle

__all__ = [
    "BRUTE_FORCE_MAX",
    "CHECK_SAMPLES",
    "MAX_SLOTS",
    "MIN_TRANSITION_S",
    "RESHAPE_SPEED_MPS",
    "SHAPE_KINDS",
    "Transition",
    "plan_reshape",
    "shape_spec",
]

SHAPE_KINDS: Final = ("triangle", "column", "line", "chevron")
RESHAPE_SPEED_MPS: Final = 0.06
"""Fastest a slot moves relative to the formation during a reshape (m/s): with the paper's
leaders (<= 0.1 m/s) a slot stays under the firmware's 0.25 m/s reference clamp."""
MIN_TRANSITION_S: Final = 3.0
CHECK_SAMPLES: Final = 1000
BRUTE_FORCE_MAX: Final = 6
SPACING_RANGE_M: Final = (0.1, 5.0)
MAX_SLOTS: Final = 1024
"""Most slots a reshape may ask (the bus contract's bound on robots of a fleet)."""


def shape_rows(kind: str, n: int, spacing_m: float) -> list[Row]:
    """The slot tree of ``kind`` with ``n`` slots ``spacing_m`` apart: ``triangle`` (the
    triangular lattice; the paper's triangle for 3), ``column`` (one behind the other), ``line``
    (abreast: left, right, left, ...), ``chevron`` (a filled wedge)."""
    lo, hi = SPACING_RANGE_M
    if not (math.isfinite(spacing_m) and lo <= spacing_m <= hi):
        raise ValueError(f"shape: spacing must be in [{lo}, {hi}] m, got {spacing_m!r}")
    if n < 1:
        raise ValueError(f"shape: needs at least one slot, got {n}")
    b = float(spacing_m)
    if kind == "triangle":
        return lattice_rows(n, b)
    if kind == "chevron":
        return chevron_rows(n, b)
    if kind == "column":
        return [(0, None, 0.0, 0.0)] + [(k, k - 1, b, math.pi / 2.0) for k in range(1, n)]
    if kind == "line":
        rows: list[Row] = [(0, None, 0.0, 0.0)]
        for k in range(1, n):
            left = k % 2 == 1
            parent = k - 2 if k > 2 else 0
            rows.append((k, parent, b, 0.0 if left else math.pi))
        return rows
    raise ValueError(f"shape: unknown kind {kind!r}; expected one of {', '.join(SHAPE_KINDS)}")


def shape_spec(kind: str, n: int, spacing_m: float) -> FormationSpec:
    """:func:`shape_rows` as a formation."""
    return FormationSpec.from_tree(shape_rows(kind, n, spacing_m))


def _relabel(new: FormationSpec, to_id: dict[int, int]) -> FormationSpec:
    """``new`` with slot ``k`` renamed ``to_id[k]`` (same tree, same definition order)."""
    return FormationSpec.from_tree(
        (to_id[s.slot], None if s.parent is None else to_id[s.parent], s.b_m, s.phi_rad)
        for s in new.slots
    )


def _separation(d0: np.ndarray, d1: np.ndarray, windows: Sequence[tuple[float, float]]) -> float:
    """Least pairwise distance (m) of the offsets along the plan, on CHECK_SAMPLES instants."""
    n = len(d0)
    if n < 2:
        return math.inf
    u = np.linspace(0.0, 1.0, CHECK_SAMPLES + 1)[:, None]
    a = np.array([w[0] for w in windows])[None, :]
    b = np.array([w[1] for w in windows])[None, :]
    f = np.clip((u - a) / (b - a), 0.0, 1.0)
    s = f * f * (3.0 - 2.0 * f)  # (samples, n)
    pts = d0[None, :, :] + s[:, :, None] * (d1 - d0)[None, :, :]
    i, j = np.triu_indices(n, 1)
    gaps = np.hypot(pts[:, i, 0] - pts[:, j, 0], pts[:, i, 1] - pts[:, j, 1])
    return float(gaps.min())


@dataclass(frozen=True)
class Transition:
    """A planned reshape: offsets of every slot of the transition (rows in :attr:`spec`'s
    definition order) before and after, each slot's window of the transition, its duration and
    the least separation of the slots along it."""

    kind: str
    spacing_m: float
    target: FormationSpec
    """The new shape with the running slot ids (the formation once the transition is over)."""
    start: np.ndarray
    end: np.ndarray
    windows: tuple[tuple[float, float], ...]
    duration_s: float
    least_separation_m: float
    schedule: str
    spec: FormationSpec
    """The formation during the transition (its rows are those of ``start``, ``end``): the
    running one, or the target when slots are added (they are in the target only)."""
    dropped: tuple[int, ...] = ()
    """Slots of the running formation that are not in the target (fewer slots): they keep
    their offset during the transition and are dropped at its end."""
    added: tuple[int, ...] = ()
    """Slots of the target that were not running (more slots): each stays where it ends."""

    @property
    def slots(self) -> int:
        """Number of slots once the transition is over."""
        return len(self.target)

    def progress(self, elapsed_s: float) -> tuple[np.ndarray, np.ndarray, bool]:
        """Offsets (n, 2) and their rates (m/s) at ``elapsed_s`` into the transition, and
        whether it is over."""
        u = min(max(elapsed_s / self.duration_s, 0.0), 1.0)
        a = np.array([w[0] for w in self.windows])
        b = np.array([w[1] for w in self.windows])
        f = np.clip((u - a) / (b - a), 0.0, 1.0)
        s = f * f * (3.0 - 2.0 * f)
        inside = (u > a) & (u < b)
        ds = np.where(inside, 6.0 * f * (1.0 - f) / ((b - a) * self.duration_s), 0.0)
        delta = self.end - self.start
        return self.start + s[:, None] * delta, ds[:, None] * delta, u >= 1.0


def _kept_rows(d0: np.ndarray, ids: Sequence[int], n_new: int) -> list[int]:
    """Rows of the running formation that keep a slot when it goes to ``n_new`` slots: all of
    them, or, fewer, all but the rearmost (the least body x; equal x: the highest slot id), the
    leader's row 0 always kept. A robot dropped at the rear is left behind by a formation that
    drives forward instead of being driven through."""
    n = len(ids)
    if n_new >= n:
        return list(range(n))
    rear_first = sorted(range(1, n), key=lambda r: (round(float(d0[r, 0]), 9), -ids[r]))
    drop = set(rear_first[: n - n_new])
    return [r for r in range(n) if r not in drop]


def _matchings(kept: Sequence[int], d0: np.ndarray, new_off: np.ndarray) -> list[dict[int, int]]:
    """Candidate matchings running row -> new row (row 0 -> 0) of the ``kept`` rows, least
    summed squared displacement first: every one for up to BRUTE_FORCE_MAX slots, else the
    optimal one (the CAPT rule, module docstring)."""
    rest = [r for r in kept if r != 0]
    n_new = len(new_off)
    if len(rest) == 0:
        return [{0: 0}]
    if n_new - 1 <= BRUTE_FORCE_MAX:
        cands = [
            {0: 0, **dict(zip(rest, cols, strict=True))}
            for cols in itertools.permutations(range(1, n_new), len(rest))
        ]
        cost = [sum(float(((new_off[m[r]] - d0[r]) ** 2).sum()) for r in rest) for m in cands]
        return [m for _, m in sorted(zip(cost, cands, strict=True), key=lambda cm: cm[0])]
    c = ((d0[rest][:, None, :] - new_off[None, 1:, :]) ** 2).sum(axis=2)
    rows, cols = linear_sum_assignment(c)
    return [{0: 0, **{rest[int(i)]: int(k) + 1 for i, k in zip(rows, cols, strict=True)}}]


def _rows_of_plan(
    running: FormationSpec,
    new: FormationSpec,
    d0: np.ndarray,
    match: dict[int, int],
    spacing_m: float,
    park: str,
) -> tuple[FormationSpec, FormationSpec, np.ndarray, np.ndarray, tuple[int, ...], tuple[int, ...]]:
    """For one matching: the target (``new`` relabelled), the formation during the transition,
    its start and end offsets, the dropped and the added slot ids. A dropped slot ends parked
    behind the new shape (:func:`_parking`, ``park``), so its robot, which stops there, is left
    behind by the formation."""
    ids = list(running.slot_ids)
    new_off = np.array(new.body_offsets_m)
    to_id: dict[int, int] = {}
    for r, j in match.items():
        to_id[new.slots[j].slot] = ids[r]
    fresh = max(ids) + 1
    added: list[int] = []
    for s in new.slots:
        if s.slot not in to_id:
            to_id[s.slot] = fresh
            added.append(fresh)
            fresh += 1
    target = _relabel(new, to_id)
    dropped = tuple(ids[r] for r in range(len(ids)) if r not in match)
    if added:  # the rows of the target; an added slot starts where it ends
        row_from = {j: r for r, j in match.items()}
        start = np.array(
            [d0[row_from[j]] if j in row_from else new_off[j] for j in range(len(new))]
        )
        return target, target, start, new_off.copy(), dropped, tuple(added)
    end = np.array([new_off[match[r]] if r in match else d0[r] for r in range(len(ids))])
    gone = [r for r in range(len(ids)) if r not in match]
    for r, xy in _parking(d0, gone, float(new_off[:, 0].min()) - spacing_m, spacing_m, park):
        end[r] = xy
    return target, running, d0.copy(), end, dropped, ()


PARKINGS: Final = ("behind", "abreast")
"""Where dropped slots go (:func:`_parking`), tried in this order."""


def _parking(
    d0: np.ndarray, gone: Sequence[int], back_m: float, spacing_m: float, park: str
) -> list[tuple[int, tuple[float, float]]]:
    """Parking places (body frame) of the dropped rows ``gone``: ``behind``: straight back from
    where each is to ``back_m`` (one spacing behind the new shape; never forward), one more
    spacing back for each one already parked in its lane; ``abreast``: a row across at
    ``back_m``, ``spacing_m`` apart, in the order they stand across (right to left)."""
    out: list[tuple[int, tuple[float, float]]] = []
    if park == "abreast":
        across = sorted(gone, key=lambda r: (float(d0[r, 1]), r))
        for j, r in enumerate(across):
            out.append((r, (back_m, (j - 0.5 * (len(across) - 1)) * spacing_m)))
        return out
    for r in sorted(gone, key=lambda r: (-float(d0[r, 0]), r)):  # the front one first
        x, y = min(back_m, float(d0[r, 0])), float(d0[r, 1])
        while any(abs(px - x) < spacing_m and abs(py - y) < spacing_m for _, (px, py) in out):
            x -= spacing_m
        out.append((r, (x, y)))
    return out


def plan_reshape(
    running: FormationSpec,
    kind: str,
    spacing_m: float,
    safety_m: float,
    current: np.ndarray | None = None,
    slots: int | None = None,
) -> Transition | str:
    """Plan the reshape of ``running`` into ``kind`` with ``slots`` slots (default: as many as
    running; module docstring), starting from the offsets ``current`` (default: the running
    formation's); the refusal reason instead when no plan keeps every pair at least
    ``safety_m`` (m) apart (``unsafe``) or the input is bad (``bad_shape``, ``bad_slots``)."""
    n_new = len(running) if slots is None else slots
    if isinstance(n_new, bool) or not isinstance(n_new, int) or not 1 <= n_new <= MAX_SLOTS:
        return "bad_slots"
    try:
        new = shape_spec(kind, n_new, spacing_m)
    except ValueError:
        return "bad_shape"
    d0 = np.array(running.body_offsets_m if current is None else current, dtype=np.float64)
    new_off = np.array(new.body_offsets_m)
    kept = _kept_rows(d0, running.slot_ids, n_new)
    best: Transition | None = None
    parkings = PARKINGS if len(kept) < len(running) else PARKINGS[:1]
    candidates = itertools.product(_matchings(kept, d0, new_off)[:24], parkings)
    for match, park in candidates:  # the least-displacement matchings first
        target, spec, start, end, dropped, added = _rows_of_plan(
            running, new, d0, match, spacing_m, park
        )
        n = len(start)
        dist = np.hypot(*(end - start).T)
        moving = [r for r in range(n) if dist[r] > 1e-9]
        rear_first = sorted(moving, key=lambda r: (start[r, 0], r))
        schedules: list[tuple[str, list[tuple[float, float]]]] = [
            ("together", [(0.0, 1.0)] * n),
        ]
        for name, order in (("rear first", rear_first), ("front first", rear_first[::-1])):
            k = max(len(order), 1)
            win = [(0.0, 1.0)] * n
            for j, r in enumerate(order):
                win[r] = (j / k, (j + 1) / k)
            schedules.append((name, win))
        for name, win in schedules:
            least = _separation(start, end, win)
            span = min(
                (w[1] - w[0] for w, dd in zip(win, dist, strict=True) if dd > 1e-9), default=1.0
            )
            duration = max(
                MIN_TRANSITION_S, 1.5 * float(dist.max(initial=0.0)) / RESHAPE_SPEED_MPS / span
            )
            plan = Transition(
                kind,
                float(spacing_m),
                target,
                start,
                end,
                tuple(win),
                duration,
                least,
                name,
                spec,
                dropped,
                added,
            )
            if least >= safety_m:
                return plan
            if best is None or least > best.least_separation_m:
                best = plan
    return "unsafe"


def blended_rows(
    leader: LeaderState, offsets: np.ndarray, rates: np.ndarray
) -> tuple[float, list[SlotRow]]:
    """``(theta, rows)`` of slots at body-frame ``offsets`` moving at ``rates`` (module
    docstring): positions and feed-forward velocities, rows in the offsets' order."""
    theta = wrap_angle(leader.theta)
    c, s = math.cos(theta), math.sin(theta)
    v, w = leader.v_mps, leader.omega_radps
    vx0, vy0 = v * c, v * s
    rows: list[SlotRow] = []
    for (dx, dy), (rx, ry) in zip(offsets.tolist(), rates.tolist(), strict=True):
        ox, oy = c * dx - s * dy, s * dx + c * dy  # R(theta) d
        rows.append(
            (
                leader.x + ox,
                leader.y + oy,
                vx0 - w * oy + c * rx - s * ry,  # v_L + omega J R d + R d'
                vy0 + w * ox + s * rx + c * ry,
            )
        )
    return theta, rows
