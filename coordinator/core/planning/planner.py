"""Plan the virtual leader to a goal: route, smooth, squeeze, time-parameterise (pure).

:func:`plan` is the planning core: a deterministic function of its inputs (no clock, no
randomness), so every process that plans from the same scenario gets the same bits.

1. **Route** (``search.route``): a heading lattice on a grid over the arena, searched with
   Dijkstra; a state is free when the formation's footprint fits there, nominal or squeezed.
2. **Shortcuts** (``search.shortcut``): straight segments that the footprint clears, joined at
   corners by circular arcs (radius up to :data:`CORNER_RADIUS_M`, less where the segments are
   short). The leader moves like the paper's unicycle (eqs 1-2): heading = direction of travel.
3. **Verify and squeeze**: the path is sampled every :data:`VERIFY_DS_M` and the footprint is
   tested with EXACT clearances (``PlanWorld.clearance``) at the least squeeze ``q`` that fits
   (``Footprint``). A sample where nothing fits halves the radius of the nearest corner and
   retries; without shortcuts as a last resort. The needed ``q`` is then widened ahead of and
   behind every squeeze (the formation is already squeezed when the passage starts and opens
   only after it) and smoothed, and the footprint is tested again at the final ``q``.
4. **Timing**: the leader's speed profile along the path keeps EVERY slot within the robots'
   limits (``SlotLimits``): a slot's velocity is ``v g_i(s)`` with ``g_i = t + kappa J R o_i +
   R o_i' q'`` (eqs 1-5 differentiated along the arc length ``s``, plus the squeeze), so the
   leader's speed is capped where ``|g_i|`` is large (outer slots on a turn), where
   ``v |kappa|`` would exceed the turn rate, where a slot's velocity would turn too fast, and
   by the slots' acceleration; then the usual forward/backward passes from rest to rest.

The result is a :class:`PlanResult`: arrays over the arc length that ``PlannedTrajectory``
samples in time. :class:`~coordinator.core.planning.search.NoPlan` (a ``ValueError``) says why
there is none.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Final

import numpy as np
import numpy.typing as npt
from scipy.interpolate import PchipInterpolator
from scipy.ndimage import uniform_filter1d

from .footprint import Footprint
from .limits import SlotLimits
from .search import Grid, NoPlan, make_grid, route, shortcut
from .world import PlanWorld

__all__ = ["CORNER_RADIUS_M", "PlanResult", "PlanStats", "plan"]

FloatArray = npt.NDArray[np.float64]

CORNER_RADIUS_M: Final = 0.3
"""Largest corner arc radius (m)."""
MIN_CORNER_RADIUS_M: Final = 0.01
VERIFY_DS_M: Final = 0.03
"""Arc-length step (m) of the exact footprint test."""
TIME_DS_M: Final = 0.005
"""Arc-length step (m) of the speed profile."""
SQUEEZE_RAMP_M: Final = 0.8
"""Travel (m) over which the formation goes from nominal to fully shrunk (and shrunk to column)."""
SQUEEZE_SMOOTH_M: Final = 0.3
"""Width (m) of each of the two moving averages that smooth the squeeze profile."""
_Q_STEP: Final = 0.1
_MIN_SEEN_RADIUS_M: Final = 0.05
"""A run-time plan's arc of a smaller radius must be long enough for the timing grid to see
it (two samples), or its turn rate would not be bounded."""
_CAP_M: Final = 0.01
"""Clearance cap beyond the need (m) where a test only asks whether the footprint fits."""


@dataclass(frozen=True)
class PlanStats:
    """Figures of a plan: ``length_m`` (path), ``straight_m`` (start to goal through the via
    points in straight lines), ``min_clearance_m`` (least distance of a slot point to an
    obstacle or wall on the final path, >= the footprint's ``slot_radius_m``), the grid
    ``cell_m``, the number of ``corners``, whether the formation squeezes and the time to
    the goal ``duration_s``."""

    length_m: float
    straight_m: float
    min_clearance_m: float
    cell_m: float
    corners: int
    squeezes: bool
    duration_s: float


@dataclass(frozen=True)
class PlanResult:
    """A timed plan: arrays over ``s_m`` (arc length, step ``ds_m``) of the leader's pose
    ``x_m, y_m, theta_rad``, curvature ``kappa_per_m``, squeeze ``q`` and the speed ``v_mps``
    of the timing profile; ``t_s`` the time at each sample (from 0, at rest at both ends)."""

    s_m: FloatArray
    x_m: FloatArray
    y_m: FloatArray
    theta_rad: FloatArray
    kappa_per_m: FloatArray
    q: FloatArray
    dq_per_m: FloatArray
    v_mps: FloatArray
    t_s: FloatArray
    footprint: Footprint
    stats: PlanStats
    waypoints: tuple[tuple[float, float], ...]
    pieces: tuple[_Piece, ...]

    def pose_at(self, s_m: float) -> tuple[float, float, float, float]:
        """Exact ``(x, y, theta, kappa)`` at arc length ``s_m`` (clipped to the path)."""
        return _pose_at(self.pieces, s_m)

    def column_at(self, s_m: float) -> tuple[list[tuple[float, float]], list[tuple[float, float]]]:
        """The path-following column at arc length ``s_m``: per slot its offset in the
        leader's frame and the offset's derivative along the path (see :func:`_columns`)."""
        x, y, th, ka = _pose_at(self.pieces, s_m)
        c, s = math.cos(th), math.sin(th)
        total = self.pieces[-1].s0 + self.pieces[-1].length
        col: list[tuple[float, float]] = []
        dcol: list[tuple[float, float]] = []
        for gap in self.footprint.column_gaps_m:
            sb = s_m - float(gap)
            xb, yb, thb, _ = _pose_at(self.pieces, sb)
            if sb < 0.0:
                xb, yb = xb + sb * math.cos(thb), yb + sb * math.sin(thb)
            elif sb > total:
                xb, yb = xb + (sb - total) * math.cos(thb), yb + (sb - total) * math.sin(thb)
            wx, wy = xb - x, yb - y
            cx, cy = c * wx + s * wy, -s * wx + c * wy
            tx, ty = math.cos(thb) - c, math.sin(thb) - s
            col.append((cx, cy))
            dcol.append((ka * cy + c * tx + s * ty, -ka * cx - s * tx + c * ty))
        return col, dcol


# -- path geometry: lines joined by arcs -------------------------------------------------------


@dataclass(frozen=True, slots=True)
class _Piece:
    s0: float
    length: float
    x0: float
    y0: float
    h0: float
    kappa: float  # 0 for a line


def _pieces(pts: Sequence[tuple[float, float]], radii: Sequence[float]) -> list[_Piece]:
    """Lines between ``pts`` with corner ``k`` (an interior point) rounded by an arc of radius
    ``radii[k - 1]`` (clipped so the tangent lengths fit in half of each segment)."""
    n = len(pts)
    seg = [(pts[i + 1][0] - pts[i][0], pts[i + 1][1] - pts[i][1]) for i in range(n - 1)]
    lens = [math.hypot(dx, dy) for dx, dy in seg]
    heads = [math.atan2(dy, dx) for dx, dy in seg]
    tang = [0.0] * n
    turn = [0.0] * n
    rad = [0.0] * n
    for k in range(1, n - 1):
        d = math.remainder(heads[k] - heads[k - 1], 2.0 * math.pi)
        if abs(d) < 1e-9:
            continue
        if abs(d) > math.pi - 1e-3:
            raise NoPlan(f"the path doubles back at {pts[k]} (a U-turn at a via point)")
        t_half = math.tan(abs(d) / 2.0)
        r = min(radii[k - 1], 0.5 * min(lens[k - 1], lens[k]) / t_half)
        r = max(r, 0.0)
        turn[k], rad[k], tang[k] = d, r, r * t_half
    out: list[_Piece] = []
    s = 0.0
    for i in range(n - 1):
        ux, uy = math.cos(heads[i]), math.sin(heads[i])
        a = tang[i]
        length = lens[i] - tang[i] - tang[i + 1]
        if length > 1e-12:
            out.append(_Piece(s, length, pts[i][0] + a * ux, pts[i][1] + a * uy, heads[i], 0.0))
            s += length
        k = i + 1
        if k < n - 1 and turn[k] != 0.0:
            if rad[k] > 1e-9:
                sign = 1.0 if turn[k] > 0 else -1.0
                ax, ay = pts[k][0] - tang[k] * ux, pts[k][1] - tang[k] * uy
                arc = rad[k] * abs(turn[k])
                out.append(_Piece(s, arc, ax, ay, heads[i], sign / rad[k]))
                s += arc
            else:
                raise NoPlan(f"a corner at {pts[k]} has no room for a turn")
    if not out:
        raise NoPlan("the path has zero length (the goal is the start)")
    return out


def _pose_at(pieces: Sequence[_Piece], s_m: float) -> tuple[float, float, float, float]:
    """Scalar :func:`_eval` (plain floats: the per-tick path)."""
    lo, hi = 0, len(pieces) - 1
    while lo < hi:  # last piece with s0 <= s_m
        mid = (lo + hi + 1) // 2
        if pieces[mid].s0 <= s_m:
            lo = mid
        else:
            hi = mid - 1
    p = pieces[lo]
    u = min(max(s_m - p.s0, 0.0), p.length)
    if p.kappa == 0.0:
        return p.x0 + u * math.cos(p.h0), p.y0 + u * math.sin(p.h0), p.h0, 0.0
    h = p.h0 + p.kappa * u
    r = 1.0 / p.kappa
    return (
        p.x0 + r * (math.sin(h) - math.sin(p.h0)),
        p.y0 - r * (math.cos(h) - math.cos(p.h0)),
        h,
        p.kappa,
    )


def _eval(pieces: list[_Piece], s: FloatArray) -> tuple[FloatArray, ...]:
    """(x, y, theta, kappa) at arc lengths ``s`` (clipped to the path)."""
    starts = np.array([p.s0 for p in pieces])
    total = pieces[-1].s0 + pieces[-1].length
    sc = np.clip(s, 0.0, total)
    idx = np.clip(np.searchsorted(starts, sc, side="right") - 1, 0, len(pieces) - 1)
    x = np.empty_like(sc)
    y = np.empty_like(sc)
    th = np.empty_like(sc)
    ka = np.empty_like(sc)
    for k, p in enumerate(pieces):
        m = idx == k
        if not m.any():
            continue
        u = np.minimum(sc[m] - p.s0, p.length)
        if p.kappa == 0.0:
            x[m] = p.x0 + u * math.cos(p.h0)
            y[m] = p.y0 + u * math.sin(p.h0)
            th[m] = p.h0
        else:
            h = p.h0 + p.kappa * u
            r = 1.0 / p.kappa
            x[m] = p.x0 + r * (np.sin(h) - math.sin(p.h0))
            y[m] = p.y0 - r * (np.cos(h) - math.cos(p.h0))
            th[m] = h
        ka[m] = p.kappa
    return x, y, th, ka


def _eval_ext(pieces: list[_Piece], s: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """(x, y, theta) at arc lengths ``s``, extended by straight lines before the start and after
    the end (where a column's tail is before the leader has moved)."""
    total = pieces[-1].s0 + pieces[-1].length
    x, y, th, _ = _eval(pieces, s)
    before = s < 0.0
    after = s > total
    x = np.where(before, x + s * np.cos(th), x)
    y = np.where(before, y + s * np.sin(th), y)
    x = np.where(after, x + (s - total) * np.cos(th), x)
    y = np.where(after, y + (s - total) * np.sin(th), y)
    return x, y, th


def _columns(pieces: list[_Piece], s: FloatArray, fp: Footprint) -> tuple[FloatArray, FloatArray]:
    """The path-following column at arc lengths ``s`` (m,): each slot where the leader was
    ``column_gaps_m`` earlier on the path, in the leader's frame, ``(c, dc/ds)`` each (m, n, 2).

    ``c_i = R(theta)^T (p(s - g_i) - p(s))``, so ``dc_i/ds = kappa J^T c_i + R(theta)^T
    (t(s - g_i) - t(s))`` (``t`` the unit tangent, ``J`` the rotation by +pi/2)."""
    x, y, th, ka = _eval(pieces, s)
    cth, sth = np.cos(th), np.sin(th)
    m, n = len(s), fp.n
    col = np.zeros((m, n, 2))
    dcol = np.zeros((m, n, 2))
    for i in range(1, n):
        xb, yb, thb = _eval_ext(pieces, s - fp.column_gaps_m[i])
        wx, wy = xb - x, yb - y
        cx, cy = cth * wx + sth * wy, -sth * wx + cth * wy
        tx, ty = np.cos(thb) - cth, np.sin(thb) - sth
        col[:, i, 0], col[:, i, 1] = cx, cy
        dcol[:, i, 0] = ka * cy + cth * tx + sth * ty
        dcol[:, i, 1] = -ka * cx - sth * tx + cth * ty
    return col, dcol


# -- squeeze -----------------------------------------------------------------------------------


def _needed_q(
    world: PlanWorld, fp: Footprint, poses: FloatArray, col: FloatArray, need_m: float
) -> tuple[FloatArray, FloatArray]:
    """Least squeeze (a multiple of ``_Q_STEP``, or inf) at which each pose fits; its least
    clearance."""
    m = len(poses)
    q_req = np.full(m, np.inf)
    clear = np.full(m, -np.inf)
    todo = np.arange(m)
    levels = np.arange(0.0, fp.q_max + 1e-9, _Q_STEP) if fp.q_max > 0 else np.zeros(1)
    for q in levels:
        if len(todo) == 0:
            break
        pts = fp.slot_points(poses[todo], np.full(len(todo), q), col[todo])
        # only "fits or not" matters here: a tight cap keeps the obstacle query small
        c = world.clearance(pts.reshape(-1, 2), need_m + _CAP_M).reshape(len(todo), -1).min(axis=1)
        ok = c >= need_m
        q_req[todo[ok]] = q
        clear[todo[ok]] = c[ok]
        todo = todo[~ok]
    return q_req, clear


def _feasible(
    world: PlanWorld,
    fp: Footprint,
    poses: FloatArray,
    col: FloatArray,
    q_req: FloatArray,
    min_pair_m: float,
    soft_pair_m: float,
) -> tuple[npt.NDArray[np.bool_], npt.NDArray[np.bool_]]:
    """(m, levels) whether the footprint fits at each pose at each squeeze level (exact test,
    slots at least ``min_pair_m`` apart; only computed near where the formation must squeeze:
    elsewhere the nominal one fits and the search stays nominal), and whether its slots are
    also ``soft_pair_m`` apart (preferred)."""
    levels = _q_levels(fp)
    m = len(poses)
    feas = np.zeros((m, len(levels)), dtype=bool)
    feas[:, 0] = q_req == 0.0
    soft = np.ones((m, len(levels)), dtype=bool)
    near = np.flatnonzero(q_req > 0.0)
    if len(near) == 0:
        return feas, soft
    # every pose within one full ramp (0 to q_max) of a squeezed one: q > 0 nowhere else
    reach = math.ceil(1.1 * SQUEEZE_RAMP_M * fp.q_max / VERIFY_DS_M) + 2
    mark = np.zeros(m, dtype=bool)
    for k in near:
        mark[max(0, k - reach - 1) : k + reach + 2] = True
    mark_all = mark.copy()
    # every other sample (6 cm): a sample between two is feasible where both are (the final
    # profile is tested exactly at every sample anyway)
    mark[1::2] = False
    mark[m - 1] = mark_all[m - 1]
    idx = np.flatnonzero(mark)
    for li, q in enumerate(levels):
        pts = fp.slot_points(poses[idx], np.full(len(idx), q), col[idx])
        c = world.clearance(pts.reshape(-1, 2), fp.slot_radius_m + _CAP_M)
        pair = _pair_min(pts)
        feas[idx, li] = (c.reshape(len(idx), -1).min(axis=1) >= fp.slot_radius_m) & (
            pair >= min_pair_m
        )
        soft[idx, li] = pair >= soft_pair_m
    odd = np.arange(1, m - 1, 2)
    odd = odd[mark_all[odd]]
    feas[odd] = feas[odd - 1] & feas[odd + 1]
    soft[odd] = soft[odd - 1] & soft[odd + 1]
    return feas, soft


def _q_levels(fp: Footprint) -> FloatArray:
    if fp.q_max <= 0.0:
        return np.zeros(1)
    out: FloatArray = np.round(np.arange(0.0, fp.q_max + 1e-9, _Q_STEP), 10)
    return out


def _squeeze_dp(
    feas: npt.NDArray[np.bool_],
    soft: npt.NDArray[np.bool_],
    stride: int,
    start_nominal: bool = False,
) -> FloatArray | None:
    """The least squeeze path through ``feas`` (m, L): one level step at most per ``stride``
    samples, every sample of a stage feasible at the levels on both its ends, levels outside
    ``soft`` only where there is no other way (a cost of 1000 per sample), from level 0 at the
    start when ``start_nominal``; the level at each sample (linear inside a stage), or None if
    there is none."""
    m, n_lv = feas.shape
    stages = [*range(0, m - 1, stride), m - 1]
    n_st = len(stages)
    inf = math.inf
    cost = np.full((n_st, n_lv), inf)
    back = np.zeros((n_st, n_lv), dtype=np.int64)
    first = feas[0].copy()
    if start_nominal:
        first[1:] = False
    cost[0, first] = np.nonzero(first)[0].astype(float)
    for j in range(1, n_st):
        a, b = stages[j - 1], stages[j]
        span = np.asarray(feas[a : b + 1].all(axis=0))  # level feasible on the whole stage
        hard = np.asarray((~soft[a : b + 1]).sum(axis=0)) * 1000.0
        for lv in range(n_lv):
            if not span[lv]:
                continue
            best, arg = inf, -1
            for lp in (lv - 1, lv, lv + 1):  # ties: the smaller level first
                if 0 <= lp < n_lv and span[lp] and cost[j - 1, lp] < best:
                    best, arg = cost[j - 1, lp], lp
            if arg >= 0:
                cost[j, lv] = best + lv * (b - a) + hard[lv] + (0.01 if arg != lv else 0.0)
                back[j, lv] = arg
    if not np.isfinite(cost[-1]).any():
        return None
    lv = int(np.argmin(cost[-1]))
    path = [lv]
    for j in range(n_st - 1, 0, -1):
        lv = int(back[j, lv])
        path.append(lv)
    path.reverse()
    q: FloatArray = np.interp(np.arange(m), stages, np.array(path, dtype=float) * _Q_STEP)
    return q


def _fit_squeeze(
    world: PlanWorld,
    fp: Footprint,
    poses: FloatArray,
    col: FloatArray,
    q_req: FloatArray,
    ds: float,
    min_pair_m: float,
    soft_pair_m: float,
    start_nominal: bool = False,
) -> tuple[FloatArray, FloatArray]:
    """The squeeze profile (at each pose) and each pose's least clearance: the least squeeze
    through the feasible levels (dynamic programming, at most one level of ``_Q_STEP`` per
    ``SQUEEZE_RAMP_M * _Q_STEP`` of travel; from the nominal formation when
    ``start_nominal``), smoothed by two moving averages of ``SQUEEZE_SMOOTH_M`` when that
    still fits, then tested exactly."""
    need = fp.slot_radius_m
    if not np.any(q_req > 0.0):
        q0 = np.zeros(len(poses))
        pts = fp.slot_points(poses, q0, col)
        c = world.clearance(pts.reshape(-1, 2), need + 1.0).reshape(len(q0), -1).min(axis=1)
        return q0, c
    feas, soft = _feasible(world, fp, poses, col, q_req, min_pair_m, soft_pair_m)
    stride = max(1, round(_Q_STEP * SQUEEZE_RAMP_M / ds))
    q_lin = _squeeze_dp(feas, soft, stride, start_nominal)
    if q_lin is None:
        raise NoPlan("the formation cannot squeeze in time for a passage on the route")
    w = max(1, round(SQUEEZE_SMOOTH_M / ds))
    q_smooth = uniform_filter1d(uniform_filter1d(q_lin, size=w, mode="nearest"), w, mode="nearest")
    q_smooth = np.clip(q_smooth, 0.0, fp.q_max)
    if start_nominal:  # the averages reach back to the start: fade them in (C1, 0 at the start)
        u = np.clip(np.arange(len(q_smooth)) * ds / SQUEEZE_SMOOTH_M, 0.0, 1.0)
        q_smooth = q_smooth * (u * u * (3.0 - 2.0 * u))
    for q in (q_smooth, q_lin):
        pts = fp.slot_points(poses, q, col)
        c = world.clearance(pts.reshape(-1, 2), need + 1.0).reshape(len(q), -1).min(axis=1)
        if np.all(c >= need) and _min_pair(pts) >= min_pair_m:
            return q, c
    raise NoPlan("the formation cannot squeeze in time for a passage on the route")


def _pair_min(pts: FloatArray) -> FloatArray:
    """Least distance (m) between two slots at each sample of ``pts`` (m, n, 2)."""
    m, n = pts.shape[:2]
    if n < 2:
        return np.full(m, np.inf)
    iu = np.triu_indices(n, 1)
    d = pts[:, iu[0], :] - pts[:, iu[1], :]
    out: FloatArray = np.hypot(d[..., 0], d[..., 1]).min(axis=1)
    return out


def _min_pair(pts: FloatArray) -> float:
    """Least distance (m) between two slots at any sample of ``pts`` (m, n, 2)."""
    return float(_pair_min(pts).min()) if len(pts) else math.inf


# -- timing ------------------------------------------------------------------------------------


def _speed_profile(
    fp: Footprint,
    theta: FloatArray,
    kappa: FloatArray,
    q: FloatArray,
    dq: FloatArray,
    col: FloatArray,
    dcol: FloatArray,
    ds: float,
    cruise_mps: float,
    lim: SlotLimits,
    accel_share: float = 0.4,
    turn_share: float = 0.95,
    speed_share: float = 0.93,
    v_start_mps: float = 0.0,
) -> tuple[FloatArray, FloatArray]:
    """Leader speed at each sample, every slot within ``lim`` (module docstring, step 4), and
    every slot's velocity per unit leader speed in the world frame (m, n, 2).
    ``accel_share``: the share of the acceleration limit given to each of the leader's own
    acceleration and the slots' turning."""
    o, do, w = fp.offsets_many(q, col)  # (m, n, 2) body frame
    rate = do * dq[:, None, None] + w * dcol  # do/ds: the squeeze and the moving column
    # g_i in the body frame: (1, 0) + kappa J o_i + do_i/ds  (rotation does not change norms)
    gx = 1.0 - kappa[:, None] * o[..., 1] + rate[..., 0]
    gy = kappa[:, None] * o[..., 0] + rate[..., 1]
    # world frame, for the derivative along s
    c, s = np.cos(theta)[:, None], np.sin(theta)[:, None]
    wx, wy = c * gx - s * gy, s * gx + c * gy
    gnorm = np.hypot(gx, gy)
    dgx = np.gradient(wx, ds, axis=0)
    dgy = np.gradient(wy, ds, axis=0)
    dg = np.hypot(dgx, dgy)
    big = gnorm > 0.5  # direction rate counts where the slot moves at >= half the leader speed
    dpsi = np.where(big, np.abs(wx * dgy - wy * dgx) / np.maximum(gnorm, 1e-9) ** 2, 0.0)
    gmax = gnorm.max(axis=1)
    v = np.full(len(q), cruise_mps)
    v = np.minimum(v, speed_share * lim.speed_mps / np.maximum(gmax, 1e-9))
    v = np.minimum(v, turn_share * lim.turn_radps / np.maximum(np.abs(kappa), 1e-9))
    v = np.minimum(v, turn_share * lim.turn_radps / np.maximum(dpsi.max(axis=1), 1e-9))
    v = np.minimum(v, np.sqrt(accel_share * lim.accel_mps2 / np.maximum(dg.max(axis=1), 1e-9)))
    a_lead = accel_share * lim.accel_mps2 / np.maximum(gmax, 1.0)
    if v_start_mps > v[0] + 1e-12:
        raise NoPlan(
            f"the leader's speed {v_start_mps:.3f} m/s is beyond what the slots allow at the start"
        )
    v[0] = v_start_mps  # from rest, or the join speed of a run-time plan (replan.py)
    v[-1] = 0.0
    for k in range(1, len(v)):
        v[k] = min(v[k], math.sqrt(v[k - 1] ** 2 + 2.0 * a_lead[k - 1] * ds))
    for k in range(len(v) - 2, -1, -1):
        v[k] = min(v[k], math.sqrt(v[k + 1] ** 2 + 2.0 * a_lead[k] * ds))
    if v[0] < v_start_mps - 1e-12:
        raise NoPlan("the leader cannot slow down in time from its speed for the plan's first turn")
    return v, np.stack([wx, wy], axis=-1)


def _within_limits(
    s: FloatArray, v: FloatArray, t: FloatArray, g: FloatArray, lim: SlotLimits
) -> tuple[float, float, float]:
    """The largest ratio to its limit of every slot's speed, turn rate and acceleration (over
    ``feasibility.ACCEL_WINDOW_S``), as the feasibility check measures them on a 0.02 s
    grid."""
    from .feasibility import ACCEL_WINDOW_S

    step = 0.02
    tu = np.arange(0.0, float(t[-1]) + step, step)
    su = np.interp(tu, t, s)
    vu = np.interp(tu, t, v)
    n = g.shape[1]
    vel = np.empty((len(tu), n, 2))
    for i in range(n):
        vel[:, i, 0] = vu * np.interp(su, s, g[:, i, 0])
        vel[:, i, 1] = vu * np.interp(su, s, g[:, i, 1])
    speed = np.hypot(vel[..., 0], vel[..., 1])
    moving = speed > 0.5 * lim.speed_mps
    heading = np.unwrap(np.arctan2(vel[..., 1], vel[..., 0]), axis=0)
    rate = np.abs(np.diff(heading, axis=0)) / step
    turn = float(np.where(moving[1:] & moving[:-1], rate, 0.0).max(initial=0.0))
    w = max(1, round(ACCEL_WINDOW_S / step))
    accel = 0.0
    if len(tu) > w:
        dv = vel[w:] - vel[:-w]
        accel = float(np.hypot(dv[..., 0], dv[..., 1]).max()) / (w * step)
    return (
        float(speed.max()) / lim.speed_mps,
        turn / lim.turn_radps,
        accel / lim.accel_mps2,
    )


def _times(v: FloatArray, ds: float) -> FloatArray:
    vsum = v[:-1] + v[1:]
    if np.any(vsum <= 0.0):
        raise NoPlan("the speed profile stops inside the path (a limit is zero)")
    t: FloatArray = np.concatenate([[0.0], np.cumsum(2.0 * ds / vsum)])
    return t


# -- the planner -------------------------------------------------------------------------------


def _verify(
    world: PlanWorld, fp: Footprint, pts: list[tuple[float, float]], radii: list[float]
) -> tuple[list[_Piece], FloatArray, FloatArray, FloatArray, FloatArray, FloatArray] | int:
    """Pieces and exact samples of the path, or the index of the corner to tighten (or -1)."""
    pieces = _pieces(pts, radii)
    total = pieces[-1].s0 + pieces[-1].length
    n = max(2, math.ceil(total / VERIFY_DS_M) + 1)
    s = np.linspace(0.0, total, n)
    x, y, th, _ = _eval(pieces, s)
    poses = np.stack([x, y, th], axis=1)
    col, _ = _columns(pieces, s, fp)
    q_req, _ = _needed_q(world, fp, poses, col, fp.slot_radius_m)
    bad = ~np.isfinite(q_req)
    if bad.any():
        # the corner nearest the first failing sample
        xb, yb = x[bad][0], y[bad][0]
        if len(pts) <= 2:
            return -1
        k = min(range(1, len(pts) - 1), key=lambda c: math.hypot(pts[c][0] - xb, pts[c][1] - yb))
        return k - 1
    return pieces, s, poses, col, q_req, np.array([total])


def _routed(
    world: PlanWorld,
    fp: Footprint,
    grid: Grid,
    pts_in: list[tuple[float, float]],
    goal_heading: float | None,
    names: list[str],
    ramp: tuple[float, float, list[float]] | None,
    straight_first: bool,
) -> tuple[list[_Piece], FloatArray, FloatArray, float, list[tuple[float, float]], FloatArray,
           FloatArray]:  # fmt: skip
    """The route (``search.route``, ``ramp`` its ``squeeze_from``; ``straight_first``: its
    first leg, start to departure, straight), shortcut and verified: ``(pieces, verify arc
    lengths, needed squeeze, length, corner points, poses, column)``."""
    legs = route(grid, fp, pts_in, goal_heading, names, ramp)
    if straight_first:  # a run-time plan leaves along the leader's heading:
        legs[0] = [legs[0][0], legs[0][-1]]  # the departure straight (tested exactly below)
    # shortcut each leg (the via points stay); fall back to the raw grid path
    h_prev: float | None = None  # the trajectory starts on its first segment's heading
    short: list[tuple[float, float]] = [pts_in[0]]
    for leg in legs:
        cut = shortcut(grid, fp, leg, h_prev)
        short.extend(cut[1:])
        h_prev = math.atan2(cut[-1][1] - cut[-2][1], cut[-1][0] - cut[-2][0])
    raw: list[tuple[float, float]] = [pts_in[0]]
    for leg in legs:
        raw.extend(_collinear_free(leg)[1:])
    keep = set(pts_in)
    for pts in (_drop_short(short, keep, 2.5 * grid.res_m), raw):
        pts = _drop_close(pts)
        radii = [CORNER_RADIUS_M] * max(0, len(pts) - 2)
        for _ in range(12):
            got = _verify(world, fp, pts, radii)
            if isinstance(got, int):
                if got < 0 or radii[got] <= MIN_CORNER_RADIUS_M:
                    break
                radii[got] *= 0.5
                continue
            pieces, s_v, poses_v, col_v, q_req, total_a = got
            if straight_first and any(
                p.length < 2.0 * TIME_DS_M and abs(p.kappa) > 1.0 / _MIN_SEEN_RADIUS_M
                for p in pieces
            ):
                break  # a sharp arc the timing grid would not see (its turn rate unbounded)
            return pieces, s_v, q_req, float(total_a[0]), pts, poses_v, col_v
    raise NoPlan("no smooth path was found along the route (the passages are too tight)")


def plan(  # noqa: PLR0915 (the planner's phases in order: search, shortcuts, squeeze, timing)
    world: PlanWorld,
    footprint: Footprint,
    start: tuple[float, float, float],
    goal: tuple[float, float],
    *,
    via: Sequence[tuple[float, float]] = (),
    goal_heading: float | None = None,
    cruise_mps: float,
    limits: SlotLimits,
    min_pair_m: float = 0.0,
    soft_pair_m: float = 0.0,
    v_start_mps: float = 0.0,
    start_nominal: bool = False,
    departure_m: float | None = None,
) -> PlanResult:
    """Plan the virtual leader from ``start`` ``(x, y, theta)`` through ``via`` to ``goal``
    (module docstring); no two slots closer than ``min_pair_m`` (m), closer than
    ``soft_pair_m`` only where there is no other way. ``v_start_mps`` (>= 0): the leader's
    speed at the start (a run-time plan joins a moving leader, going straight along ``theta``:
    the plan leaves along it at that speed). ``start_nominal``: the formation is nominal at
    the start (a run-time plan: the leader's formation there), so the squeeze starts at 0 and
    the route needs no more squeeze near the start than the ramp from it gives. Raises
    :class:`NoPlan` (clean, with the reason) when there is none. ``departure_m``: the length
    of the straight departure (m; default: 0.4, 0.2 or 0.1, the first with room)."""
    if not (math.isfinite(v_start_mps) and 0.0 <= v_start_mps <= cruise_mps + 1e-12):
        raise NoPlan(f"start speed {v_start_mps!r} m/s: must be in [0, the cruise speed]")
    fp = footprint
    need = fp.slot_radius_m
    sx, sy, sth = start
    pts_in = [(sx, sy), *[(float(a), float(b)) for a, b in via], (float(goal[0]), float(goal[1]))]
    names = ["start", *[f"via[{i}]" for i in range(len(via))], "goal"]
    # a point inside an obstacle or outside the arena is a clean refusal, named
    point_clear = world.clearance(np.array(pts_in), need + 1.0)
    for name, c in zip(names, point_clear, strict=True):
        if c < 0.0:
            where = (
                "outside the arena"
                if _outside(world, pts_in[names.index(name)])
                else ("inside an obstacle")
            )
            raise NoPlan(f"{name} {pts_in[names.index(name)]} is {where}")
    # leave along the start heading (the robots start in formation at that heading): a first
    # straight departure, when there is room for it
    aheads = (0.4, 0.2) if v_start_mps == 0.0 else (0.4, 0.2, 0.1)
    departures: list[tuple[float, float] | None] = []
    for ahead in aheads if departure_m is None else (departure_m,):
        p = (sx + ahead * math.cos(sth), sy + ahead * math.sin(sth))
        if (
            math.hypot(pts_in[1][0] - sx, pts_in[1][1] - sy) > 2.0 * ahead
            and world.clearance(np.array([p]), need + 1.0)[0] >= need
        ):
            departures.append(p)
            if not start_nominal:  # a run-time plan tries the shorter ones when one fails
                break
    if not departures:
        if v_start_mps > 0.0:
            raise NoPlan("no room ahead of the moving leader to leave along its heading")
        departures.append(None)
    if goal_heading is not None:
        # arrive along goal_heading: a last straight approach to the goal
        gx, gy = pts_in[-1]
        for back in (0.6, 0.4, 0.2):
            p = (gx - back * math.cos(goal_heading), gy - back * math.sin(goal_heading))
            if world.clearance(np.array([p]), need + 1.0)[0] >= need:
                pts_in.insert(len(pts_in) - 1, p)
                names.insert(len(names) - 1, "goal approach")
                break
    attempts: list[tuple[float, float, list[float]] | None] = [None]
    if start_nominal:  # the route again, with each squeeze no nearer the start than its ramp
        least = [0.0] + [min(q, 1.5) * SQUEEZE_RAMP_M for q in (1.0, 2.0) if q <= fp.q_max]
        attempts.append((sx, sy, least))
    tries = [(d, ramp) for d in departures for ramp in attempts]
    base_pts, base_names = pts_in, names
    for k, (dep, ramp) in enumerate(tries):
        pts_in, names = list(base_pts), list(base_names)
        if dep is not None:  # leave along the start heading: a first straight departure
            pts_in.insert(1, dep)
            names.insert(1, "start departure")
        try:
            grid = make_grid(world, fp, need, pts_in)
            first_straight = start_nominal and dep is not None
            routed = _routed(world, fp, grid, pts_in, goal_heading, names, ramp, first_straight)
            pieces, s_v, q_req, total, pts, _poses_v, col_v = routed
            if start_nominal and abs(math.remainder(pieces[0].h0 - sth, 2.0 * math.pi)) > 1e-6:
                # (a run-time plan from rest without a departure: the heading would jump)
                raise NoPlan("the plan cannot leave along the leader's heading")
            # squeeze profile on the verify grid, then re-verify at the final q
            q_v, c_f = _fit_squeeze(
                world,
                fp,
                _poses_v,
                col_v,
                q_req,
                float(s_v[1] - s_v[0]),
                min_pair_m,
                soft_pair_m,
                start_nominal,
            )
            break
        except NoPlan:
            if k == len(tries) - 1:
                raise
    # timing on a finer grid
    n_t = max(2, math.ceil(total / TIME_DS_M) + 1)
    s_t = np.linspace(0.0, total, n_t)
    ds = float(s_t[1] - s_t[0])
    x, y, th, ka = _eval(pieces, s_t)
    th = np.unwrap(th)
    # the squeeze on the timing grid: a monotone C1 interpolation (PCHIP, within [0, q_max]),
    # and its derivative along the path, so no slot's velocity steps where the grid does
    if np.any(q_v > 0.0):
        spline = PchipInterpolator(s_v, q_v)
        q_t = np.clip(spline(s_t), 0.0, fp.q_max)
        dq_t = spline.derivative()(s_t)
        dq_t[q_t == 0.0] = 0.0
    else:
        q_t, dq_t = np.zeros_like(s_t), np.zeros_like(s_t)
    col_t, dcol_t = _columns(pieces, s_t, fp)
    share, turn_share, speed_share = 0.4, 0.95, 0.93
    for _ in range(10):  # tighten the budgets until the slots' check passes
        v, g = _speed_profile(
            fp,
            th,
            ka,
            q_t,
            dq_t,
            col_t,
            dcol_t,
            ds,
            cruise_mps,
            limits,
            share,
            turn_share,
            speed_share,
            v_start_mps,
        )
        t = _times(v, ds)
        r_speed, r_turn, r_accel = _within_limits(s_t, v, t, g, limits)
        if max(r_speed, r_turn, r_accel) <= 0.95:  # 5 % to spare
            break
        # both budgets act about linearly on what they bound: scale them to 90 %
        if r_accel > 0.95:
            share *= max(0.3, 0.9 / r_accel)
        if r_turn > 0.95:
            turn_share *= max(0.3, 0.9 / r_turn)
        if r_speed > 0.95:
            speed_share *= max(0.3, 0.9 / r_speed)
    else:
        raise NoPlan("no speed profile keeps every slot within the robots' limits")
    straight = sum(math.hypot(b[0] - a[0], b[1] - a[1]) for a, b in itertools.pairwise(pts_in))
    stats = PlanStats(
        length_m=total,
        straight_m=straight,
        min_clearance_m=float(c_f.min()),
        cell_m=grid.res_m,
        corners=max(0, len(pts) - 2),
        squeezes=bool(np.any(q_v > 0.0)),
        duration_s=float(t[-1]),
    )
    return PlanResult(s_t, x, y, th, ka, q_t, dq_t, v, t, fp, stats, tuple(pts), tuple(pieces))


def _outside(world: PlanWorld, p: tuple[float, float]) -> bool:
    a = world.arena
    return a is not None and not (a.x_min <= p[0] <= a.x_max and a.y_min <= p[1] <= a.y_max)


def _drop_close(pts: list[tuple[float, float]]) -> list[tuple[float, float]]:
    out = [pts[0]]
    for p in pts[1:]:
        if math.hypot(p[0] - out[-1][0], p[1] - out[-1][1]) > 1e-6:
            out.append(p)
    if len(out) == 1:
        raise NoPlan("the path has zero length (the goal is the start)")
    return out


def _drop_short(
    pts: list[tuple[float, float]], keep: set[tuple[float, float]], min_m: float
) -> list[tuple[float, float]]:
    """``pts`` without the interior points (not in ``keep``) closer than ``min_m`` to the
    previous point or to a kept one after them: grid-sized jogs that would make tight corners
    (the result is verified like any path)."""
    out = [pts[0]]
    for k in range(1, len(pts) - 1):
        p = pts[k]
        nxt = pts[k + 1]
        if p not in keep and (
            math.hypot(p[0] - out[-1][0], p[1] - out[-1][1]) < min_m
            or (nxt in keep and math.hypot(nxt[0] - p[0], nxt[1] - p[1]) < min_m)
        ):
            continue
        out.append(p)
    out.append(pts[-1])
    return out


def _collinear_free(pts: list[tuple[float, float]]) -> list[tuple[float, float]]:
    """``pts`` without the interior points where the direction does not change."""
    if len(pts) < 3:
        return pts
    out = [pts[0]]
    for k in range(1, len(pts) - 1):
        a, b, c = out[-1], pts[k], pts[k + 1]
        cross = (b[0] - a[0]) * (c[1] - b[1]) - (b[1] - a[1]) * (c[0] - b[0])
        if abs(cross) > 1e-12:
            out.append(b)
    out.append(pts[-1])
    return out


def grid_of(world: PlanWorld, fp: Footprint, pts: list[tuple[float, float]]) -> Grid:
    """The search grid :func:`plan` uses (for figures and benchmarks)."""
    return make_grid(world, fp, fp.slot_radius_m, pts)
