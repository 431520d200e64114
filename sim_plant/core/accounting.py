"""Safety accounting on the ground truth: separation, collisions, arena bounds.

Like the Robotarium simulator, the plant side counts violations itself, from the truth, so a
controller cannot hide them. Both monitors are pure: time is passed in, nothing is read.

SeparationMonitor
-----------------
Robots are discs of radius ``radius_m``; two robots touch when their centres are closer than
``2 * radius_m``. A *collision event* is a pair entering contact: it is counted once, when it
starts, with the time and the ids, however many ticks the contact lasts; the pair must separate
(centre distance >= ``2 * radius_m``) before it can count again. The monitor also keeps the
minimum centre distance over all robot pairs, over all updates.

For up to ``brute_force_max_n`` robots the pairwise distances are computed directly (numpy,
O(N^2) but tiny); up to :data:`PY_MAX_N` robots that is done in plain Python, where numpy's
per-call overhead would cost more than the arithmetic (same formula as ``pdist``,
``sqrt(dx*dx + dy*dy)``, so the same bits). Above that a k-d tree (``scipy.spatial.cKDTree``)
gives the nearest neighbour of every robot and the pairs in contact in about O(N log N), so
N = 1000 stays cheap. :meth:`SeparationMonitor.update_many` accounts a whole run's ticks at once.

BoundsMonitor
-------------
An axis-aligned arena rectangle; a robot is *out* when its body (a disc of ``radius_m``, 0 for the
centre alone) is not entirely inside. Leaving counts one event; coming back in re-arms it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import numpy as np
import numpy.typing as npt

__all__ = [
    "PAIR_BLOCK_ELEMENTS",
    "BoundsMonitor",
    "CollisionEvent",
    "ExitEvent",
    "SeparationMonitor",
    "contacts_and_min_distance",
]

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]

#: Largest fleet whose pairs are checked in plain Python (n (n - 1) / 2 pairs; numpy's pdist
#: wins above about a dozen robots, see bench/bench_sim.py).
PY_MAX_N = 10


PAIR_BLOCK_ELEMENTS = 1 << 16
""":meth:`SeparationMonitor.update_many` takes ticks in blocks of about this many pair distances
(~0.5 MB an array: its few passes stay in the cache; 8 MB blocks took three times as long)."""


@dataclass(frozen=True, slots=True)
class CollisionEvent:
    """Robots ``i < j`` came into contact at ``t_s`` with centre distance ``distance_m``."""

    t_s: float
    i: int
    j: int
    distance_m: float


@dataclass(frozen=True, slots=True)
class ExitEvent:
    """Robot ``i`` left the arena at ``t_s``, centre at ``(x_m, y_m)``."""

    t_s: float
    i: int
    x_m: float
    y_m: float


def _positions(truth: npt.ArrayLike) -> FloatArray:
    arr = np.asarray(truth, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] < 2:
        raise ValueError(f"truth must have shape (n, 2) or (n, 3), got {arr.shape}")
    xy = np.ascontiguousarray(arr[:, :2])
    if not np.all(np.isfinite(xy)):
        raise ValueError("truth positions must be finite")
    return xy


@lru_cache(maxsize=1)
def _spatial() -> tuple[Any, Any]:
    """scipy's ``cKDTree`` and ``pdist``, imported on the first call and kept: a plant or a
    launcher of a few robots never needs them (up to :data:`PY_MAX_N` the pairs are plain
    Python), and their import is a quarter of a second of every such process's start."""
    from scipy.spatial import cKDTree
    from scipy.spatial.distance import pdist

    return cKDTree, pdist


@lru_cache(maxsize=8)
def _upper_pairs(n: int) -> IntArray:
    """``(n (n - 1) / 2, 2)`` index pairs ``i < j`` in the order of ``pdist``'s condensed form."""
    iu, ju = np.triu_indices(n, k=1)
    pairs = np.stack([iu, ju], axis=1).astype(np.int64)
    pairs.flags.writeable = False
    return pairs


def _pair_squares(truth: FloatArray, dx: FloatArray, dy: FloatArray) -> FloatArray:
    """``(n (n - 1) / 2, T)`` squared centre distances ``dx*dx + dy*dy`` (``dx = x_i - x_j``) of
    the poses ``truth[t, i, (x, y, ...)]``, pairs ``i < j`` in pdist's order, pair-major, written
    into ``dx`` (returned); ``dx`` and ``dy`` are buffers of that shape, reused block after block
    (fresh ones cost a page fault per 4 KiB at every block).

    Robot ``i``'s pairs are the rows ``j = i + 1 .. n - 1`` of one block, each a subtraction of
    two contiguous time series, not a gather by index per element (the same operations on the
    same operands as pdist's ``sqrt(dx*dx + dy*dy)`` before its root: the same bits).
    """
    x = np.ascontiguousarray(truth[:, :, 0].T)  # (n, T)
    y = np.ascontiguousarray(truth[:, :, 1].T)
    n = x.shape[0]
    row = 0
    for i in range(n - 1):
        end = row + n - 1 - i
        np.subtract(x[i], x[i + 1 :], out=dx[row:end])
        np.subtract(y[i], y[i + 1 :], out=dy[row:end])
        row = end
    np.multiply(dx, dx, out=dx)
    np.multiply(dy, dy, out=dy)
    return np.add(dx, dy, out=dx)


def contacts_and_min_distance(
    xy: FloatArray, contact_dist_m: float, brute_force_max_n: int = 64
) -> tuple[IntArray, FloatArray, float]:
    """Pairs closer than ``contact_dist_m`` and the minimum pairwise centre distance.

    ``xy`` is ``(n, 2)`` in metres. Returns ``(pairs, distances, min_dist)`` where ``pairs`` is
    ``(k, 2)`` with ``i < j`` sorted lexicographically, ``distances`` is ``(k,)`` metres and
    ``min_dist`` is ``inf`` for fewer than two robots.
    """
    n = xy.shape[0]
    if n < 2:
        return np.zeros((0, 2), dtype=np.int64), np.zeros(0), math.inf
    cKDTree, pdist = _spatial()
    if n <= brute_force_max_n:
        d = pdist(xy)  # condensed: pairs (0,1), (0,2), ..., (1,2), ... = upper triangle order
        close = d < contact_dist_m
        pairs = _upper_pairs(n)[close]
        return pairs, d[close], float(d.min())
    # An unbalanced, non-compact tree builds faster; it is rebuilt every update anyway.
    tree = cKDTree(xy, balanced_tree=False, compact_nodes=False)
    nn_dist, _ = tree.query(xy, k=2)
    min_dist = float(nn_dist[:, 1].min())
    if min_dist >= contact_dist_m:
        return np.zeros((0, 2), dtype=np.int64), np.zeros(0), min_dist
    raw = tree.query_pairs(contact_dist_m, output_type="ndarray").astype(np.int64)
    raw.sort(axis=1)
    delta = xy[raw[:, 0]] - xy[raw[:, 1]]
    d = np.hypot(delta[:, 0], delta[:, 1])
    close = d < contact_dist_m  # query_pairs includes d == r; contact is strict
    raw, d = raw[close], d[close]
    order = np.lexsort((raw[:, 1], raw[:, 0]))
    return raw[order], d[order], min_dist


class SeparationMonitor:
    """Minimum pairwise separation and collision events of discs of ``radius_m``.

    Pairs are keyed by robot index; if the number of robots changes between updates, contacts
    involving indices that no longer exist are forgotten.
    """

    def __init__(self, radius_m: float, brute_force_max_n: int = 64) -> None:
        r = float(radius_m)
        if not math.isfinite(r) or r < 0.0:
            raise ValueError(f"radius_m must be finite and >= 0, got {radius_m!r}")
        self.radius_m = r
        self.contact_dist_m = 2.0 * r
        self.brute_force_max_n = int(brute_force_max_n)
        self._min_sep_m = math.inf
        self._min_sep_t_s = math.nan
        self._last_min_sep_m = math.inf
        self._in_contact: set[tuple[int, int]] = set()
        self._events: list[CollisionEvent] = []
        self.updates = 0

    @property
    def min_separation_m(self) -> float:
        """Smallest centre-to-centre distance of any pair seen so far, metres (inf if none)."""
        return self._min_sep_m

    @property
    def min_separation_t_s(self) -> float:
        """Time of :attr:`min_separation_m`, seconds (nan before the first pair)."""
        return self._min_sep_t_s

    @property
    def min_clearance_m(self) -> float:
        """Smallest body gap so far, ``min_separation_m - 2 radius_m``, metres (< 0: overlap)."""
        return self._min_sep_m - self.contact_dist_m

    @property
    def last_min_separation_m(self) -> float:
        """Minimum centre distance at the latest update, metres."""
        return self._last_min_sep_m

    @property
    def collisions(self) -> list[CollisionEvent]:
        """Collision events so far, in time order (a copy)."""
        return list(self._events)

    @property
    def collision_count(self) -> int:
        """Number of collision events so far."""
        return len(self._events)

    @property
    def in_contact(self) -> frozenset[tuple[int, int]]:
        """Pairs ``(i, j)``, ``i < j``, in contact at the latest update."""
        return frozenset(self._in_contact)

    def update(self, t_s: float, truth: npt.ArrayLike) -> list[CollisionEvent]:
        """Account the poses ``truth`` (``(n, 3)`` or ``(n, 2)``) at ``t_s``; returns new events."""
        if (
            isinstance(truth, np.ndarray)
            and truth.ndim == 2
            and 2 <= truth.shape[0] <= PY_MAX_N
            and truth.shape[1] >= 2
            and truth.dtype == np.float64
        ):
            truth = truth.tolist()  # a few robots: plain Python (the plant node's truth, a tick)
        if isinstance(truth, list | tuple) and 2 <= len(truth) <= PY_MAX_N:
            small = self._update_rows(t_s, truth)
            if small is not None:
                return small
        xy = _positions(truth)
        self.updates += 1
        pairs, dists, min_dist = contacts_and_min_distance(
            xy, self.contact_dist_m, self.brute_force_max_n
        )
        self._last_min_sep_m = min_dist
        if min_dist < self._min_sep_m:
            self._min_sep_m = min_dist
            self._min_sep_t_s = float(t_s)
        new: list[CollisionEvent] = []
        if pairs.shape[0] == 0:
            self._in_contact = set()
            return new
        pair_list = pairs.tolist()
        for (a, b), d in zip(pair_list, dists.tolist(), strict=True):
            if (a, b) not in self._in_contact:
                new.append(CollisionEvent(float(t_s), a, b, d))
        self._in_contact = {(a, b) for a, b in pair_list}
        self._events.extend(new)
        return new

    def _update_rows(
        self, t_s: float, rows: Sequence[Sequence[float]]
    ) -> list[CollisionEvent] | None:
        """:meth:`update` for 2..PY_MAX_N robots given as rows ``(x, y, ...)`` in plain Python.

        Returns None, having changed nothing, for input the array path must judge: a distance
        that is not finite (so a non-finite position; that path raises) or entries that are not
        numbers. Only the first two entries of each row are read.
        """
        sqrt = math.sqrt
        inf = math.inf
        contact = self.contact_dist_m
        min_dist = inf
        close: list[tuple[int, int, float]] = []
        n = len(rows)
        try:
            for i in range(n - 1):
                ri = rows[i]
                xi = ri[0]
                yi = ri[1]
                for j in range(i + 1, n):
                    rj = rows[j]
                    dx = xi - rj[0]
                    dy = yi - rj[1]
                    d = sqrt(dx * dx + dy * dy)  # pdist's euclidean, bit for bit
                    if not d < inf:  # a NaN or inf coordinate (or an overflow): array path
                        return None
                    if d < min_dist:
                        min_dist = d
                    if d < contact:
                        close.append((i, j, d))
        except (TypeError, IndexError):
            return None
        self.updates += 1
        self._last_min_sep_m = min_dist
        if min_dist < self._min_sep_m:
            self._min_sep_m = min_dist
            self._min_sep_t_s = float(t_s)
        new: list[CollisionEvent] = []
        if not close:
            if self._in_contact:
                self._in_contact = set()
            return new
        for a, b, d in close:
            if (a, b) not in self._in_contact:
                new.append(CollisionEvent(float(t_s), a, b, d))
        self._in_contact = {(a, b) for a, b, _ in close}
        self._events.extend(new)
        return new

    def update_many(self, t_s: npt.ArrayLike, truth: npt.ArrayLike) -> list[CollisionEvent]:
        """Account a whole sequence of ticks: the same as ``update(t_s[k], truth[k])`` for
        k = 0, 1, ... in turn (same events, minimum, state and counters afterwards).

        ``t_s`` is ``(T,)`` seconds, ``truth`` ``(T, n, 3)`` or ``(T, n, 2)``. Up to
        ``brute_force_max_n`` robots this is vectorised over ticks (the distances are pdist's,
        ``sqrt(dx*dx + dy*dy)``, bit for bit), in blocks of ticks to bound memory; above that,
        and for input that the per-tick path would reject part-way, it is a loop of
        :meth:`update`. Returns the new events in time order.
        """
        times = np.asarray(t_s, dtype=np.float64)
        arr = np.asarray(truth, dtype=np.float64)
        if arr.ndim != 3 or arr.shape[2] < 2 or times.shape != arr.shape[:1]:
            raise ValueError(
                f"update_many: need t_s (T,) and truth (T, n, 2 or 3), got {times.shape} and "
                f"{arr.shape}"
            )
        ticks, n = arr.shape[0], arr.shape[1]
        if n < 2 or n > self.brute_force_max_n or not np.isfinite(arr[:, :, :2]).all():
            out: list[CollisionEvent] = []
            for k in range(ticks):
                out.extend(self.update(float(times[k]), arr[k]))
            return out
        pairs = _upper_pairs(n)
        ii, jj = pairs[:, 0], pairs[:, 1]
        contact = self.contact_dist_m
        block = max(1, PAIR_BLOCK_ELEMENTS // len(pairs))
        dx_buf = np.empty((len(pairs), min(block, ticks)))
        dy_buf = np.empty_like(dx_buf)
        new: list[CollisionEvent] = []
        in_contact = self._in_contact
        for k0 in range(0, ticks, block):
            chunk = arr[k0 : k0 + block]
            width = chunk.shape[0]
            sq = _pair_squares(chunk, dx_buf[:, :width], dy_buf[:, :width])  # (pairs, ticks)
            # Each tick's minimum distance is the root of its minimum square: the root is
            # correctly rounded, hence monotone, so sqrt(min(s)) == min(sqrt(s)) bit for bit;
            # the roots of all the pairs are taken only for a block where some pair touches.
            dmin = np.sqrt(sq.min(axis=0))
            kmin = int(np.argmin(dmin))  # the first tick that reaches the block's minimum
            if dmin[kmin] < self._min_sep_m:
                self._min_sep_m = float(dmin[kmin])
                self._min_sep_t_s = float(times[k0 + kmin])
            self._last_min_sep_m = float(dmin[-1])
            if not dmin[kmin] < contact:  # no pair touches in the block: no event, none after
                in_contact = set()
                continue
            d = np.sqrt(sq, out=sq).T  # (ticks, pairs): pdist's distances, in pdist's order
            touching = d < contact
            prev = np.zeros((1, len(pairs)), dtype=np.bool_)
            for a, b in in_contact:
                if b < n:
                    prev[0, a * n - a * (a + 1) // 2 + (b - a - 1)] = True  # condensed index
            starts = touching & ~np.concatenate([prev, touching[:-1]], axis=0)
            for k, p in zip(*(x.tolist() for x in np.nonzero(starts)), strict=True):
                new.append(
                    CollisionEvent(float(times[k0 + k]), int(ii[p]), int(jj[p]), float(d[k, p]))
                )
            in_contact = {(int(ii[p]), int(jj[p])) for p in np.flatnonzero(touching[-1])}
        self.updates += ticks
        self._in_contact = in_contact
        self._events.extend(new)
        return new


class BoundsMonitor:
    """Counts robots leaving the arena rectangle ``[x_min, x_max] x [y_min, y_max]`` (metres).

    ``radius_m`` shrinks the allowed region for the centre so the whole body must stay inside.
    """

    def __init__(
        self, x_min: float, x_max: float, y_min: float, y_max: float, radius_m: float = 0.0
    ) -> None:
        vals = [float(x_min), float(x_max), float(y_min), float(y_max), float(radius_m)]
        if not all(math.isfinite(v) for v in vals):
            raise ValueError("bounds and radius must be finite")
        if radius_m < 0.0:
            raise ValueError(f"radius_m must be >= 0, got {radius_m}")
        if x_max - x_min < 2.0 * radius_m or y_max - y_min < 2.0 * radius_m:
            raise ValueError("arena smaller than one robot")
        self.x_min, self.x_max, self.y_min, self.y_max, self.radius_m = vals
        self._outside: npt.NDArray[np.bool_] = np.zeros(0, dtype=np.bool_)
        self._events: list[ExitEvent] = []

    @property
    def outside(self) -> npt.NDArray[np.bool_]:
        """Mask of robots outside at the latest update (a copy)."""
        return self._outside.copy()

    @property
    def exits(self) -> list[ExitEvent]:
        """Exit events so far, in time order (a copy)."""
        return list(self._events)

    @property
    def exit_count(self) -> int:
        """Number of exit events so far."""
        return len(self._events)

    def update(self, t_s: float, truth: npt.ArrayLike) -> list[ExitEvent]:
        """Account the poses ``truth`` at ``t_s``; returns the new exit events."""
        xy = _positions(truth)
        r = self.radius_m
        x = xy[:, 0]
        y = xy[:, 1]
        out = (
            (x < self.x_min + r)
            | (x > self.x_max - r)
            | (y < self.y_min + r)
            | (y > self.y_max - r)
        )
        prev = self._outside
        n = out.shape[0]
        was = np.zeros(n, dtype=np.bool_)
        m = min(n, prev.shape[0])
        was[:m] = prev[:m]
        leaving = np.flatnonzero(out & ~was)
        new = [ExitEvent(float(t_s), int(i), float(x[i]), float(y[i])) for i in leaving.tolist()]
        self._outside = out
        self._events.extend(new)
        return new
