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
    """A planned reshape: offsets of every slot (rows in the running formation's definition
    order) before and after, each slot's window of the transition, its duration and the least
    separation of the slots along it."""

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


def plan_reshape(
    running: FormationSpec,
    kind: str,
    spacing_m: float,
    safety_m: float,
    current: np.ndarray | None = None,
) -> Transition | str:
    """Plan the reshape of ``running`` into ``kind`` (module docstring), starting from the
    offsets ``current`` (default: the running formation's); the refusal reason instead when no
    plan keeps every pair at least ``safety_m`` (m) apart (``unsafe``) or the input is bad."""
    try:
        new = shape_spec(kind, len(running), spacing_m)
    except ValueError:
        return "bad_shape"
    d0 = np.array(running.body_offsets_m if current is None else current, dtype=np.float64)
    ids = list(running.slot_ids)
    new_off = np.array(new.body_offsets_m)
    n = len(ids)
    perms: list[list[int]] = []  # perm[r] = row of `new` for running row r
    if n - 1 <= BRUTE_FORCE_MAX:
        for rest in itertools.permutations(range(1, n)):
            perms.append([0, *rest])
        cost = [float(((new_off[p] - d0) ** 2).sum()) for p in perms]
        perms = [p for _, p in sorted(zip(cost, perms, strict=True), key=lambda cp: cp[0])]
    else:
        c = ((d0[1:, None, :] - new_off[None, 1:, :]) ** 2).sum(axis=2)
        _, cols = linear_sum_assignment(c)
        perms.append([0, *(int(k) + 1 for k in cols)])
    best: Transition | None = None
    for perm in perms[:24]:  # the least-displacement permutations first
        d1 = new_off[perm]
        dist = np.hypot(*(d1 - d0).T)
        moving = [r for r in range(n) if dist[r] > 1e-9]
        rear_first = sorted(moving, key=lambda r: (d0[r, 0], r))
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
            least = _separation(d0, d1, win)
            span = min(
                (w[1] - w[0] for w, dd in zip(win, dist, strict=True) if dd > 1e-9), default=1.0
            )
            duration = max(
                MIN_TRANSITION_S, 1.5 * float(dist.max(initial=0.0)) / RESHAPE_SPEED_MPS / span
            )
            to_id = {
                s.slot: ids[r] for r, s in zip(range(n), (new.slots[p] for p in perm), strict=True)
            }
            plan = Transition(
                kind,
                float(spacing_m),
                _relabel(new, to_id),
                d0,
                d1,
                tuple(win),
                duration,
                least,
                name,
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
