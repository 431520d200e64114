"""Route search for the virtual leader: a heading lattice on a grid, Dijkstra, shortcuts (pure).

The state is a grid cell of the leader's position and one of 8 headings (the formation is rigid
about the leader, so where it fits depends on the heading). A state is free when the footprint
(``Footprint``) fits there in at least one of its squeezes (nominal, shrunk, column). From a
state the leader moves one cell on to a neighbour in its heading or one of the two next ones
(45 degrees), and the footprint must fit at both headings and at the heading between them (the
formation rotates about the leader on a turn). The clearance of a slot's point is read from the
exact clearance of the nearest cell centre, less the half cell diagonal (the clearance is
1-Lipschitz, so the test is conservative).

The graph (at most :data:`MAX_CELLS` cells x 8 headings) is built with numpy and searched with
``scipy.sparse.csgraph.dijkstra`` (C speed, deterministic: ties are broken by node index). A
cost is the step length, plus ``TURN_COST_M`` per 45 degrees of turn, plus the step length again
where the nominal formation does not fit (prefer open space to a squeeze). The cell path is
then shortened by shortcuts (a straight segment along which the footprint fits at the
segment's heading, and a rotation at its start that fits), found by exponential then binary
search along the path.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Final

import numpy as np
import numpy.typing as npt
import scipy.sparse as sp
from scipy.ndimage import distance_transform_edt
from scipy.sparse.csgraph import dijkstra

from .footprint import Footprint
from .world import PlanWorld

__all__ = ["MAX_CELLS", "Grid", "NoPlan", "route"]

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]

MAX_CELLS: Final = 25_000
"""Most grid cells of one search; a larger area gets coarser cells (never more work)."""
MIN_CELL_M: Final = 0.03
"""Finest grid cell (m)."""
TURN_COST_M: Final = 0.05
"""Extra cost of a 45 degree turn, in metres of path."""
_DIRS: Final = np.array(
    [(1, 0), (2, 1), (1, 1), (1, 2), (0, 1), (-1, 2), (-1, 1), (-2, 1),
     (-1, 0), (-2, -1), (-1, -1), (-1, -2), (0, -1), (1, -2), (1, -1), (2, -1)],
    dtype=np.int64,
)  # fmt: skip
"""The 16 moves of the lattice: the 8 neighbours and the 8 knight's moves between them."""
N_HEAD: Final = 16
_HEADINGS: Final = np.arctan2(_DIRS[:, 1], _DIRS[:, 0])


class NoPlan(ValueError):
    """No path exists (or none was found within the work bound); the message says where."""


@dataclass(frozen=True)
class Grid:
    """A regular grid of cell centres ``x0 + i * res``, ``y0 + j * res`` with the exact
    clearance (m, capped) of each centre; ``need_m`` is the clearance a slot point needs."""

    x0: float
    y0: float
    res_m: float
    nx: int
    ny: int
    clear_m: FloatArray  # (nx, ny)
    need_m: float

    def cell_of(self, x: float, y: float) -> tuple[int, int] | None:
        i = round((x - self.x0) / self.res_m)
        j = round((y - self.y0) / self.res_m)
        if 0 <= i < self.nx and 0 <= j < self.ny:
            return int(i), int(j)
        return None

    def centre(self, i: int, j: int) -> tuple[float, float]:
        return self.x0 + i * self.res_m, self.y0 + j * self.res_m

    def fits(self, points: FloatArray) -> BoolArray:
        """(..., 2) slot points -> whether each point's disc is clear (conservative)."""
        ii = np.rint((points[..., 0] - self.x0) / self.res_m).astype(np.int64)
        jj = np.rint((points[..., 1] - self.y0) / self.res_m).astype(np.int64)
        inside = (ii >= 0) & (ii < self.nx) & (jj >= 0) & (jj < self.ny)
        c = self.clear_m[np.clip(ii, 0, self.nx - 1), np.clip(jj, 0, self.ny - 1)]
        ok: BoolArray = inside & (c >= self.need_m + 0.7072 * self.res_m)
        return ok


def make_grid(
    world: PlanWorld, footprint: Footprint, need_m: float, extra: list[tuple[float, float]]
) -> Grid:
    """The search grid: the arena, or (no arena) the obstacles, start, via points and goal
    padded by the footprint's extent and 1 m; cells as fine as :data:`MAX_CELLS` allows."""
    a = world.arena
    if a is not None:
        box = (a.x_min, a.y_min, a.x_max, a.y_max)
    else:
        xs = [p[0] for p in extra]
        ys = [p[1] for p in extra]
        b = world.bounds()
        if b is not None:
            xs += [b[0], b[2]]
            ys += [b[1], b[3]]
        pad = footprint.extent_m() + 1.0
        box = (min(xs) - pad, min(ys) - pad, max(xs) + pad, max(ys) + pad)
    w, h = box[2] - box[0], box[3] - box[1]
    res = max(MIN_CELL_M, math.sqrt(w * h / MAX_CELLS))
    nx = max(2, math.floor(w / res) + 1)
    ny = max(2, math.floor(h / res) + 1)
    while nx * ny > MAX_CELLS:
        res *= 1.05
        nx, ny = max(2, math.floor(w / res) + 1), max(2, math.floor(h / res) + 1)
    x0 = box[0] + 0.5 * (w - (nx - 1) * res)
    y0 = box[1] + 0.5 * (h - (ny - 1) * res)
    gx, gy = np.meshgrid(x0 + res * np.arange(nx), y0 + res * np.arange(ny), indexing="ij")
    cap = need_m + 2.0 * res
    clear = world.clearance(np.stack([gx.ravel(), gy.ravel()], axis=1), cap).reshape(nx, ny)
    return Grid(x0, y0, res, nx, ny, clear, need_m)


def _levels(fp: Footprint) -> list[float]:
    """The squeezes the search tries: nominal, shrunk, column (those the footprint offers)."""
    return [0.0] + [q for q in (1.0, 2.0) if q <= fp.q_max]


def _level_masks(grid: Grid, fp: Footprint) -> npt.NDArray[np.int8]:
    """(16, nx, ny): the least squeeze level (index into :func:`_levels`) at which the
    footprint fits with the leader on each cell at each of the 16 move headings;
    ``len(levels)`` if none."""
    levels = _levels(fp)
    out = np.full((N_HEAD, grid.nx, grid.ny), len(levels), dtype=np.int8)
    base = grid.clear_m >= grid.need_m + 0.7072 * grid.res_m
    for li in range(len(levels) - 1, -1, -1):
        o = fp.offsets(levels[li])[0]
        for k in range(N_HEAD):
            th = float(_HEADINGS[k])
            c, s = math.cos(th), math.sin(th)
            ok = base.copy()
            for dx, dy in o[1:]:
                ok &= _shifted(grid, ok, c * dx - s * dy, s * dx + c * dy)
            out[k][ok] = li
    return out


def _ramp_limit(
    grid: Grid,
    lvl: npt.NDArray[np.int8],
    n_levels: int,
    squeeze_from: tuple[float, float, Sequence[float]],
) -> None:
    """Mark not free (in place) the states of ``lvl`` that need a squeeze level nearer to the
    nominal start than its ramp allows (:func:`route`'s ``squeeze_from``)."""
    sx, sy, least_m = squeeze_from
    gx = grid.x0 + grid.res_m * np.arange(grid.nx) - sx
    gy = grid.y0 + grid.res_m * np.arange(grid.ny) - sy
    d = np.hypot(gx[:, None], gy[None, :])
    ramp = np.array([*least_m, 0.0])[np.minimum(lvl, n_levels)]
    lvl[(d[None, :, :] < ramp) & (d[None, :, :] > 2.0 * grid.res_m)] = n_levels


def _shifted(grid: Grid, ok: BoolArray, ox: float, oy: float) -> BoolArray:
    """For every cell, whether the point ``(ox, oy)`` (m) away from its centre is clear."""
    di, dj = round(ox / grid.res_m), round(oy / grid.res_m)
    # the nearest cell's centre is within (|ox - di res|, |oy - dj res|) of the true point
    err = math.hypot(ox - di * grid.res_m, oy - dj * grid.res_m)
    good = grid.clear_m >= grid.need_m + err
    out = np.zeros_like(ok)
    nx, ny = grid.nx, grid.ny
    src_i = slice(max(0, di), min(nx, nx + di))
    dst_i = slice(max(0, -di), min(nx, nx - di))
    src_j = slice(max(0, dj), min(ny, ny + dj))
    dst_j = slice(max(0, -dj), min(ny, ny - dj))
    if src_i.start < src_i.stop and src_j.start < src_j.stop:
        out[dst_i, dst_j] = good[src_i, src_j]
    return out


def _move_ok(free: BoolArray, di: int, dj: int) -> BoolArray:
    """For every cell, whether a move by ``(di, dj)`` lands on a cell free in ``free`` and, for
    a knight's move, passes over free cells (the two cells beside its midpoint)."""
    out = _shift_bool(free, di, dj)
    if abs(di) == 2 or abs(dj) == 2:
        hi, hj = di / 2.0, dj / 2.0
        for mi, mj in {(math.floor(hi), math.floor(hj)), (math.ceil(hi), math.ceil(hj))}:
            out &= _shift_bool(free, mi, mj)
    return out


def _shift_bool(a: BoolArray, di: int, dj: int) -> BoolArray:
    """``out[i, j] = a[i + di, j + dj]`` (False off the grid)."""
    nx, ny = a.shape
    out = np.zeros_like(a)
    src_i = slice(max(0, di), min(nx, nx + di))
    dst_i = slice(max(0, -di), min(nx, nx - di))
    src_j = slice(max(0, dj), min(ny, ny + dj))
    dst_j = slice(max(0, -dj), min(ny, ny - dj))
    if src_i.start < src_i.stop and src_j.start < src_j.stop:
        out[dst_i, dst_j] = a[src_i, src_j]
    return out


def _graph(
    lvl: npt.NDArray[np.int8], n_levels: int, res_m: float, band: BoolArray
) -> sp.csr_matrix:
    """The heading lattice (module docstring) on the cells of ``band``."""
    free = (lvl < n_levels) & band[None, :, :]
    lvl_f = lvl.astype(np.float64)
    _, nx, ny = lvl.shape
    n_states = N_HEAD * nx * ny
    idx = np.arange(n_states, dtype=np.int64).reshape(N_HEAD, nx, ny)
    rows: list[npt.NDArray[np.int64]] = []
    cols: list[npt.NDArray[np.int64]] = []
    costs: list[FloatArray] = []
    for k in range(N_HEAD):
        for turn in (-1, 0, 1):
            k2 = (k + turn) % N_HEAD
            di, dj = (int(v) for v in _DIRS[k2])
            step = res_m * math.hypot(di, dj)
            ok = free[k] & free[k2] & _move_ok(free[k2], di, dj)
            src = idx[k][ok]
            ii, jj = np.nonzero(ok)
            dst = idx[k2][ii + di, jj + dj]
            penalty = 0.5 * step * lvl_f[k2][ii + di, jj + dj]
            turn_rad = abs(math.remainder(float(_HEADINGS[k2] - _HEADINGS[k]), 2.0 * math.pi))
            rows.append(src)
            cols.append(dst)
            costs.append(step + TURN_COST_M * turn_rad / (math.pi / 4.0) + penalty)
    r = np.concatenate(rows)
    c = np.concatenate(cols)
    w = np.concatenate(costs)
    return sp.csr_matrix((w, (r, c)), shape=(n_states, n_states))


def _cell_route(
    free_any: BoolArray, res_m: float, ca: tuple[int, int], cb: tuple[int, int]
) -> list[tuple[int, int]] | None:
    """The shortest 8-connected route of cells from ``ca`` to ``cb`` through cells where the
    footprint fits in some heading (a cheap first pass that bounds the lattice search)."""
    nx, ny = free_any.shape
    idx = np.arange(nx * ny, dtype=np.int64).reshape(nx, ny)
    rows, cols, costs = [], [], []
    for di, dj in ((1, 0), (0, 1), (1, 1), (1, -1)):
        ok = free_any & _shift_bool(free_any, di, dj)
        ii, jj = np.nonzero(ok)
        a_, b_ = idx[ii, jj], idx[ii + di, jj + dj]
        w = np.full(len(a_), res_m * math.hypot(di, dj))
        rows += [a_, b_]
        cols += [b_, a_]
        costs += [w, w]
    g = sp.csr_matrix(
        (np.concatenate(costs), (np.concatenate(rows), np.concatenate(cols))),
        shape=(nx * ny, nx * ny),
    )
    src, dst = int(idx[ca]), int(idx[cb])
    dist, pred = dijkstra(g, directed=True, indices=src, return_predecessors=True)
    if not math.isfinite(dist[dst]):
        return None
    out: list[tuple[int, int]] = []
    s = dst
    while s >= 0:
        i, j = divmod(int(s), ny)
        out.append((i, j))
        s = int(pred[s])
    return out[::-1]


BANDS_M: Final = (0.8, 2.0, math.inf)
"""Widths (m, each side) of the band round the cell route in which the lattice is searched,
tried in turn: the narrow band almost always holds the answer; inf is the whole map."""


def _heading_index(theta: float) -> int:
    """The lattice heading nearest ``theta`` (rad)."""
    d = np.abs(np.remainder(_HEADINGS - theta + math.pi, 2.0 * math.pi) - math.pi)
    return int(np.argmin(d))


def route(
    grid: Grid,
    fp: Footprint,
    points: list[tuple[float, float]],
    goal_heading: float | None,
    names: list[str],
    squeeze_from: tuple[float, float, Sequence[float]] | None = None,
) -> list[list[tuple[float, float]]]:
    """Polylines of leader positions, one per leg between consecutive ``points`` (start,
    via..., goal; ``names`` name them in messages), along which the footprint fits (grid
    test); raises :class:`NoPlan`.

    Each leg first finds a route of cells (8-connected, footprint fits in some heading), then
    searches the heading lattice in a band of :data:`BANDS_M` round it, widening the band when
    the lattice finds no way in it (same answer as the whole map when the band is wide enough,
    a fraction of the work).

    ``squeeze_from`` ``(x, y, least_m)``: the formation is nominal at ``(x, y)`` (a run-time
    plan's start) and squeezes to level ``k`` (:func:`_levels`) no nearer than ``least_m[k]``
    to it (the squeeze's ramp); a state nearer that needs more is not free (the cells next to
    the start excepted: the exact test decides there)."""
    lvl = _level_masks(grid, fp)
    n_levels = len(_levels(fp))
    if squeeze_from is not None:
        _ramp_limit(grid, lvl, n_levels, squeeze_from)
    free8 = lvl < n_levels
    free_any: BoolArray = np.asarray(free8.any(axis=0))
    nx, ny = grid.nx, grid.ny
    legs: list[list[tuple[float, float]]] = []
    for leg in range(len(points) - 1):
        a, b = points[leg], points[leg + 1]
        ca, cb = grid.cell_of(*a), grid.cell_of(*b)
        if ca is None or cb is None:
            raise NoPlan(f"{names[leg] if ca is None else names[leg + 1]} is off the map")
        starts = [k * nx * ny + ca[0] * ny + ca[1] for k in range(N_HEAD) if free8[k, ca[0], ca[1]]]
        if not starts:
            raise NoPlan(f"the formation does not fit at {names[leg]} {a} in any heading")
        ends = [k for k in range(N_HEAD) if free8[k, cb[0], cb[1]]]
        if leg == len(points) - 2 and goal_heading is not None:
            kg = _heading_index(goal_heading)
            ends = [kg] if kg in ends else []
        if not ends:
            raise NoPlan(f"the formation does not fit at {names[leg + 1]} {b}")
        no_way = NoPlan(
            f"no collision-free way for the formation from {names[leg]} {a} to {names[leg + 1]} {b}"
        )
        cells = _cell_route(free_any, grid.res_m, ca, cb)
        if cells is None:
            raise no_way
        goals = [k * nx * ny + cb[0] * ny + cb[1] for k in ends]
        along = np.ones((nx, ny), dtype=bool)
        ci, cj = zip(*cells, strict=True)
        along[list(ci), list(cj)] = False
        gap_m = distance_transform_edt(along) * grid.res_m
        found = None
        for band_m in BANDS_M:
            graph = _graph(lvl, n_levels, grid.res_m, gap_m <= band_m)
            dist, pred, _ = dijkstra(
                graph, directed=True, indices=starts, return_predecessors=True, min_only=True
            )
            best = min(goals, key=lambda s: (dist[s], s))
            if math.isfinite(dist[best]):
                found = (best, pred)
                break
        if found is None:
            raise no_way
        best, pred = found
        chain: list[int] = []
        s = best
        while s >= 0:
            chain.append(int(s))
            s = int(pred[s])
        chain.reverse()
        poly = [a]
        for st in chain[1:-1]:  # the last cell's centre is b's cell: b itself ends the leg
            rem = st % (nx * ny)
            i, j = divmod(rem, ny)
            poly.append(grid.centre(i, j))
        poly.append(b)
        legs.append(_dedupe(poly))
    return legs


def _dedupe(path: list[tuple[float, float]]) -> list[tuple[float, float]]:
    out = [path[0]]
    for p in path[1:]:
        if math.hypot(p[0] - out[-1][0], p[1] - out[-1][1]) > 1e-9:
            out.append(p)
    return out


def _fit_level(grid: Grid, fp: Footprint, poses: FloatArray) -> npt.NDArray[np.int64]:
    """Least squeeze level at which the footprint fits (grid test) at each pose (m, 3)."""
    levels = _levels(fp)
    out = np.full(len(poses), len(levels), dtype=np.int64)
    for li in range(len(levels) - 1, -1, -1):
        pts = fp.slot_points(poses, np.full(len(poses), levels[li]))
        out[grid.fits(pts).all(axis=1)] = li
    return out


def segment_fits(
    grid: Grid,
    fp: Footprint,
    a: tuple[float, float],
    b: tuple[float, float],
    h_prev: float | None,
    max_level: int,
) -> bool:
    """The footprint fits (grid test, squeezed at most to ``max_level``) along ``a -> b`` at its
    heading, and while rotating at ``a`` from ``h_prev`` to it."""
    L = math.hypot(b[0] - a[0], b[1] - a[1])
    if L < 1e-12:
        return True
    th = math.atan2(b[1] - a[1], b[0] - a[0])
    n = max(2, math.ceil(L / (0.5 * grid.res_m)) + 1)
    u = np.linspace(0.0, 1.0, n)
    poses = np.stack([a[0] + u * (b[0] - a[0]), a[1] + u * (b[1] - a[1]), np.full(n, th)], axis=1)
    if h_prev is not None:
        dh = math.remainder(th - h_prev, 2.0 * math.pi)
        m = max(2, math.ceil(abs(dh) / (math.pi / 16.0)) + 1)
        rot = np.stack(
            [np.full(m, a[0]), np.full(m, a[1]), h_prev + np.linspace(0.0, dh, m)], axis=1
        )
        poses = np.concatenate([rot, poses])
    return bool(np.all(_fit_level(grid, fp, poses) <= max_level))


def shortcut(
    grid: Grid, fp: Footprint, path: list[tuple[float, float]], h_prev: float | None
) -> list[tuple[float, float]]:
    """Greedy shortcuts along ``path`` (its first and last points stay; ``h_prev``: the heading
    on arrival at the first); exponential then binary search for the farthest point reachable
    in a straight line with the formation squeezed no more than on the path it replaces."""
    n = len(path)
    if n < 3:
        return list(path)
    pa = np.array(path)
    head = np.arctan2(np.diff(pa[:, 1]), np.diff(pa[:, 0]))
    head = np.concatenate([head, head[-1:]])
    need = _fit_level(grid, fp, np.concatenate([pa, head[:, None]], axis=1))
    need = np.minimum(need, len(_levels(fp)) - 1)
    out = [path[0]]
    i = 0

    def ok(i: int, j: int) -> bool:
        return segment_fits(grid, fp, path[i], path[j], h_prev, int(need[i : j + 1].max()))

    while i < n - 1:
        good = i + 1
        step = 1
        while good + step < n and ok(i, good + step):
            good += step
            step *= 2
        lo, hi = good, min(n - 1, good + step)
        while hi - lo > 1:
            mid = (lo + hi) // 2
            if ok(i, mid):
                lo = mid
            else:
                hi = mid
        if hi != lo and ok(i, hi):
            lo = hi
        j = lo
        h_prev = math.atan2(path[j][1] - path[i][1], path[j][0] - path[i][0])
        out.append(path[j])
        i = j
    return out
