"""The safety filter's barriers against the other robots (the neighbour rows).

Stdlib only, pure. The barriers (``h >= 0`` is safe; notation of
``robot_agent.core.safety_filter``'s
module docstring, where the proof is)::

    neighbour j, not cooperative:  h = |p - c_j| - (Ds + l + rho + V a_j + rho_j)
    neighbour j, cooperative:      h = |p - p_j| - (Ds + 2 l + rho + V a_j + rho_j)

with the constraint ``n . u >= -gamma h + n . v_j`` (not cooperative: the robot takes the full
responsibility, plus the neighbour's known velocity ``v_j``) or ``n . u >= -gamma h / 2``
(cooperative: the reciprocal half). For a cooperative neighbour measured in this robot's own
camera frame, with ``shared_frame``, the plane of ``robot_agent.core.safety_plane`` replaces the
``V a_j`` inflation; for a neighbour whose entry carries a motion claim's view (a ninth field,
``Neighbour.motion``), the claimed row of ``robot_agent.core.neighbour_motion`` does (its
reference point extrapolated with the claimed velocity, inflated by what its enforced bound lets
it deviate; full responsibility). A neighbour entry is an ``(x, y)`` tuple (a fresh position of
a robot treated as an obstacle: the fast path) or a ``Neighbour``
(``robot_agent.core.safety_types``); a non-finite or absurd field is counted (``rejected``) and
the position kept, as old as allowed and not moving.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any, Final

from .kinematics import reference_point
from .neighbour_motion import append_claimed, view_is_sane
from .params import AgentConfig
from .qp import _TOL
from .safety_plane import SharedFramePlane
from .safety_types import _isfinite

__all__ = ["NeighbourBarriers"]

_hypot: Final = math.hypot
_INF: Final = math.inf
_SHIFT_BOUND_M: Final = 1.0e6
"""Coordinates within +-this (m) let ``append`` reject a cooperative entry before its shift by
``l`` (eqs 10-11): every difference and sum it would compute is then exact to ~1e-9 m."""
_SHIFT_PAD_M: Final = 1.0e-6
"""How far (m) beyond ``l`` that early reject stays from the shifted box: far more than that
rounding."""


def _as_tuple(entry: object) -> tuple[Any, ...]:
    """A neighbour entry that is not a tuple (a list, ...) as its tuple; one without a length
    raises TypeError, as ``len`` does."""
    seq: Any = entry
    len(seq)
    return tuple(seq)


class NeighbourBarriers:
    """One robot's barrier data against its neighbours (``AgentConfig.safety_filter``) and the
    counters of what it did with them."""

    __slots__ = (
        "_budget",
        "_d_coop",
        "_d_plain",
        "_frame_age",
        "_gap",
        "_gmax_slow",
        "_l",
        "_max_age",
        "_plane",
        "_shift_m",
        "_vbad",
        "_vnb",
        "other_frame",
        "plane_pairs",
        "rejected",
    )

    def __init__(self, config: AgentConfig) -> None:
        g = config.geometry
        p = config.safety_filter
        l_m = g.ref_offset_m
        self._l = l_m
        self._shift_m = abs(l_m) + _SHIFT_PAD_M  # (how far a shift by l moves a point, at most)
        ds = 2.0 * g.body_radius_m + p.margin_m
        self._d_plain = ds + l_m  # p_i to c_j
        self._d_coop = ds + 2.0 * l_m  # p_i to p_j
        self._gmax_slow = 1.0 / config.safety.max_dt_s
        self._vnb = p.neighbour_speed_mps if p.neighbour_speed_mps > 0.0 else g.max_speed_mps
        self._vbad = 10.0 * self._vnb  # a neighbour velocity beyond this is absurd: rejected
        self._max_age = p.max_age_s
        self._budget = p.noise_budget_m
        self._plane = SharedFramePlane(config)
        self._gap = p.convoy_gap_m
        self._frame_age = p.frame_max_age_s
        self.rejected = 0
        """Entries with a non-finite or absurd field."""
        self.plane_pairs = 0
        """Cooperative neighbours in range that the shared-frame plane handled."""
        self.other_frame = 0
        """Cooperative neighbours in range measured in another frame than this robot's own."""

    @property
    def plane_bound(self) -> int:
        """Plane constraints that could bind (in reach: appended)."""
        return self._plane.bound

    def range_m(self, vcap: float, gamma_slow: float, shared: bool) -> float:
        """``SafetyFilter.neighbour_range_m`` (``vcap``: ``max_ref_speed_mps``; ``gamma_slow``:
        the least gamma; ``shared``: ``shared_frame``)."""
        far = self._d_coop + self._l + self._vnb * self._max_age + 0.1 + vcap / (0.5 * gamma_slow)
        if shared:  # a plane binds only within G < reach (append(): q2), with the own
            # camera pose at most max_ref_speed x frame_max_age + 2 noise budgets away
            off = vcap * self._frame_age + 2.0 * self._budget
            plane = self._d_coop + self._l + self._gap + 2.0 * vcap / gamma_slow
            far = max(far, plane + 3.0 * off)
        return far

    def quick_m(self, rho: float, reach: float) -> float:
        """The quick-reject half-width (m) of ``append`` for an entry of eight fields with no
        radius and no velocity, without the shared-frame plane: a box around the reference
        point outside which such an entry can bind nothing, whatever its share, age or heading
        (``rho``, ``reach``: as in ``append``). One formula for ``append`` and
        ``robot_agent.core.neighbour_select`` (``SafetyFilter.reach_box_m``)."""
        quick = self._d_coop + self._l + self._vnb * self._max_age
        return quick + rho + 2.0 * reach + _TOL

    def append(  # noqa: PLR0915 (per-neighbour constraints, inlined on the compiled hot path)
        self,
        px: float,
        py: float,
        cap: float,
        reach: float,
        gamma: float,
        rho: float,
        dt_s: float,
        frame: tuple[float, float, float, float] | None,
        neighbours: Sequence[Any],
        cons: list[tuple[float, float, float]],
        min_h: float,
    ) -> float:
        """Append the neighbour constraints ``(ax, ay, b)`` in range of a command of speed
        ``cap`` at reference point ``(px, py)`` (``reach``: ``(cap + tol) / gamma``; ``rho``:
        this robot's own uncertainty beyond the noise budget; ``dt_s``, ``frame``: as in
        ``SafetyFilter.constraints``); returns the least barrier value (``min_h`` if none is
        lower)."""
        d_plain = self._d_plain + rho
        lim_plain = d_plain + reach + _TOL
        nlim_plain = -lim_plain
        # the quick-reject bound of full Neighbour entries, computed at the first one (lazily:
        # (x, y) entries do not use it); q2_tol is the plane's bound when it is larger
        quick = -1.0
        q2_tol = 0.0  # (below any quick bound)
        pl = None  # own frame anchor (ref. point, heading, age): robot_agent.core.safety_plane
        gmax = 0.0  # (set with pl, which it goes with)
        if frame is not None:
            # the plane's largest gain: gamma dt <= 1 with this tick's dt (unknown: the longest)
            gmax = 1.0 / dt_s if dt_s > 0.0 else self._gmax_slow
            fx, fy, fth, fage = frame
            if fage < 0.0:  # the rule of neighbours.neighbour: a capture in the future is age 0
                fage = 0.0
            if _isfinite(fx + fy + fth) and fage <= self._frame_age:
                hix = math.cos(fth)
                hiy = math.sin(fth)
                qix, qiy = reference_point(fx, fy, fth, self._l)  # eqs 10-11
                off = _hypot(px - qix, py - qiy)
                if _isfinite(off):
                    pl = (qix, qiy, hix, hiy, fage)
                    # a plane constraint binds only if G < reach (see safety_plane)
                    q2 = self._d_coop + self._l + self._gap + 2.0 * (rho + reach) + 3.0 * off
                    q2_tol = q2 + _TOL
        # (float-typed locals: the compiled core unboxes each field of an entry once and does
        # the arithmetic natively; an int field is its float value, as Python's mixed
        # arithmetic takes it. "x - x == 0.0" is the finiteness test without a call: it holds
        # for a finite x only; a full entry's heading and age are held as read, oth and oage,
        # and unboxed past its quick reject, which does not use them: most entries are far)
        qx: float
        qy: float
        th: float
        age: float
        oth: Any
        oage: Any
        vx: float
        vy: float
        rad: float
        # (a list, as the firmware's neighbour selection answers: compiled, walked by index
        # instead of through an iterator object; any other sequence as its list)
        listed: list[Any] = neighbours if isinstance(neighbours, list) else list(neighbours)
        # (the early reject of a cooperative entry needs this robot's point within the bound)
        bound = _SHIFT_BOUND_M
        near_origin = -bound < px < bound and -bound < py < bound
        shift_m = self._shift_m
        for nb in listed:
            # (a tuple, as a Neighbour and an (x, y) pair are, typed so: compiled, its length
            # and fields are read in place instead of through generic calls; any other sequence
            # is read as its tuple)
            ent: tuple[Any, ...] = nb if isinstance(nb, tuple) else _as_tuple(nb)
            n = len(ent)
            if n == 8:  # a Neighbour (neighbours.neighbour's entries: the usual case)
                qx, qy, oth, oage, vx, vy, coop, rad = ent
                view = None
            elif n == 2:  # a fresh position of a robot treated as an obstacle (fast path)
                qx, qy = ent
                dx = px - qx
                dy = py - qy
                # (-lim < dx < lim and ... as four plain comparisons: fewer bytecodes)
                if not (dx < lim_plain and dx > nlim_plain and dy < lim_plain and dy > nlim_plain):
                    if (chk := dx + dy) - chk != 0.0:  # not finite
                        self.rejected += 1
                    continue
                d = _hypot(dx, dy)
                h = d - d_plain
                if h < min_h:
                    min_h = h
                if h < reach:
                    if d > 0.0:
                        cons.append((dx / d, dy / d, -gamma * h))
                    else:
                        cons.append((1.0, 0.0, -gamma * h))
                continue
            else:  # with a motion claim's view (robot_agent.core.neighbour_motion)
                qx, qy, oth, oage, vx, vy, coop, rad, view = ent
            if quick < 0.0:  # the first full entry of this call
                quick = self.quick_m(rho, reach)
                if q2_tol > quick:
                    quick = q2_tol
                nquick = -quick
                two_over_g = 2.0 / gamma
            # quick reject of a far neighbour (any share, age, shift by l); a non-finite
            # field makes the bound NaN and takes the full path below
            if rad > 0.0 or vx != 0.0 or vy != 0.0:
                lim = quick + (rad if rad > 0.0 else 0.0) + (abs(vx) + abs(vy)) * two_over_g
                nlim = -lim
            else:  # no radius, no velocity (neighbours.neighbour's entries): the same bits
                lim = quick
                nlim = nquick
            if view is not None:  # (a claimed shift: no quick reject)
                lim = _INF
            dx = px - qx
            dy = py - qy
            # (-lim < dx < lim and ... as four plain comparisons: fewer bytecodes)
            if not (dx < lim and dx > nlim and dy < lim and dy > nlim) and lim < _INF:
                if (chk := dx + dy) - chk != 0.0:  # not finite
                    self.rejected += 1
                continue
            th = oth
            age = oage
            if pl is not None and coop:
                if age == pl[4] and th - th == 0.0:  # finite th
                    # same frame as this robot's own pose, both cooperative: the plane
                    g = self._plane.constraint(px, py, qx, qy, th, pl, rho, gamma, gmax, cap, cons)
                    if g is not None:
                        self.plane_pairs += 1
                        if g < min_h:
                            min_h = g
                        continue
                elif age != pl[4]:
                    self.other_frame += 1
            if not (
                age - age == 0.0  # finite (x - x is 0.0 for a finite x only)
                and rad - rad == 0.0
                and -self._vbad < vx < self._vbad
                and -self._vbad < vy < self._vbad
            ):  # non-finite or absurd: keep the position, as old as allowed, not moving
                self.rejected += 1
                vx = vy = 0.0
                age = self._max_age
                rad = 0.0
                view = None
            if view is not None:
                if th - th == 0.0 and view_is_sane(view):  # finite th
                    # the claimed motion replaces the V a inflation (neighbour_motion)
                    qx, qy = reference_point(qx, qy, th, self._l)  # eqs 10-11
                    rad -= self._budget
                    dd = self._d_coop + (rad if rad > 0.0 else 0.0) + rho
                    held = dt_s if dt_s > 0.0 else 1.0 / self._gmax_slow
                    h = append_claimed(px, py, qx, qy, view, dd, gamma, held, cap, cons)
                    if h < min_h:
                        min_h = h
                    continue
                self.rejected += 1
            if age < 0.0:
                age = 0.0
            elif age > self._max_age:
                age = self._max_age
            rad -= self._budget
            infl = self._vnb * age + (rad if rad > 0.0 else 0.0) + rho
            if coop and th - th == 0.0:  # finite th: the reciprocal row at p_j
                share = 0.5
                dd = self._d_coop + infl
                vx = vy = 0.0
                lim = dd + (cap + abs(vx) + abs(vy)) / (share * gamma) + _TOL
                # a neighbour whose axle centre is beyond lim + |l| (+ pad) on an axis has its
                # reference point beyond lim there too (coordinates within the bound: the
                # rounding is ~1e-9 m): skipped below, finite, without its shift (cos, sin:
                # most cooperative entries in the quick box end here). A NaN or +inf lim
                # never takes this exit (a lim <= 0: the box below is empty too).
                dx = px - qx
                dy = py - qy
                far = lim + shift_m
                if (
                    (dx >= far or dx <= -far or dy >= far or dy <= -far)
                    and near_origin
                    and -bound < qx < bound
                    and -bound < qy < bound
                ):
                    continue
                qx, qy = reference_point(qx, qy, th, self._l)  # eqs 10-11
            else:
                share = 1.0
                dd = self._d_plain + infl
                lim = dd + (cap + abs(vx) + abs(vy)) / (share * gamma) + _TOL  # (as above)
            dx = px - qx
            dy = py - qy
            if not (-lim < dx < lim and -lim < dy < lim):
                if (chk := dx + dy) - chk != 0.0:  # not finite
                    self.rejected += 1
                continue
            d = _hypot(dx, dy)
            if d > 0.0:
                nx = dx / d
                ny = dy / d
            else:
                nx, ny = 1.0, 0.0
            h = d - dd
            if h < min_h:
                min_h = h
            b = -share * gamma * h + nx * vx + ny * vy
            if b > -cap - _TOL:
                cons.append((nx, ny, b))
        return min_h
