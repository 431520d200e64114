"""The estimator's arithmetic: the exact arc integration of the unicycle (``propagate_pose``,
paper eq 9 over constant ``(v, omega)``) and the history internals of ``Estimator`` (anchors of
fused camera poses, odometry/command segments, the fusion of one pose and the replay of later
ones), as the base class ``_EstimatorMath``.

Split out of estimator.py (issue 12) so estimator.py reads as the public inputs (commands,
odometry, measurements), ``tick`` and ``estimate``; the methods here moved verbatim and
``propagate_pose`` is still importable from ``robot_agent.estimator``.
"""

from __future__ import annotations

import math
from bisect import bisect_right

from .params import EstimatorParams

_isfinite = math.isfinite


_sin = math.sin


_cos = math.cos


_sqrt = math.sqrt


_PI = math.pi


# Pieces of constant twist shorter than this are skipped (a segment boundary and a capture time
# a few ulps apart, both computed as float sums of ticks): at most nanometres of motion.
_TINY_S = 1e-9


_TWO_PI = 2.0 * math.pi


# anchor tuple fields: (t, x, y, theta, P, Pth, zx, zy, zth)
_Anchor = tuple[float, float, float, float, float, float, float, float, float]


# segment tuple fields: (t_start, v, omega, measured, position variance per m, per s)
_Segment = tuple[float, float, float, bool, float, float]


def _wrap(a: float) -> float:
    """Angle to (-pi, pi] (finite input)."""
    r = (_PI - a) % _TWO_PI
    if not r < _TWO_PI:
        r = 0.0
    return _PI - r


def _sinc(h: float) -> float:
    """sin(h) / h, 1 at 0 (a series below |h| = 0.1: relative error < 3e-10)."""
    if -0.1 < h < 0.1:
        h2 = h * h
        return 1.0 - h2 * (1.0 / 6.0 - h2 * (1.0 / 120.0))
    return _sin(h) / h


def propagate_pose(
    x: float, y: float, theta: float, v: float, omega: float, dt: float
) -> tuple[float, float, float]:
    """Exact unicycle integration (eq 9) of a constant twist over ``dt`` s; theta not wrapped."""
    h = omega * dt * 0.5
    chord = v * dt * _sinc(h)
    mid = theta + h
    return x + chord * _cos(mid), y + chord * _sin(mid), mid + h


class _EstimatorMath:
    """The history internals of :class:`robot_agent.estimator.Estimator` (its base class): the
    methods below moved here verbatim; the state they use is declared and set by ``Estimator``
    (its ``__slots__`` and ``__init__``)."""

    __slots__ = (
        "_anch",
        "_anch_t",
        "_ck",
        "_ck_anchor",
        "_cmd_q",
        "_first_is_init",
        "_gated_run",
        "_p",
        "_q_rad",
        "_q_thm",
        "_q_ths",
        "_r_pos",
        "_r_th",
        "_seg",
        "_seg_t",
        "replayed",
    )
    _p: EstimatorParams
    _r_pos: float
    _r_th: float
    _cmd_q: tuple[float, float]
    _q_rad: float
    _q_thm: float
    _q_ths: float
    _seg: list[_Segment]
    _seg_t: list[float]
    _anch: list[_Anchor]
    _anch_t: list[float]
    _gated_run: int
    _first_is_init: bool
    _ck: list[tuple[float, float, float, float, float, float, float, float]]
    _ck_anchor: _Anchor | None
    replayed: int

    # ------------------------------------------------------------------ internals

    def _init(self, t_s: float, x: float, y: float, theta: float) -> None:
        self._anch.append((t_s, x, y, theta, self._r_pos, self._r_th, x, y, theta))
        self._anch_t.append(t_s)
        self._gated_run = 0
        self._first_is_init = True

    def _truncate(self, t_s: float) -> None:
        """Drop every segment starting at or after ``t_s``."""
        seg = self._seg
        seg_t = self._seg_t
        while seg_t and seg_t[-1] >= t_s:
            seg_t.pop()
            seg.pop()
        ck = self._ck
        while ck and ck[-1][0] > t_s:
            ck.pop()

    def _fuse(
        self,
        t_s: float,
        px: float,
        py: float,
        pth: float,
        pp: float,
        ppth: float,
        zx: float,
        zy: float,
        zth: float,
    ) -> _Anchor:
        """Kalman update of the prior at ``t_s`` with a measurement: the new anchor."""
        s = pp + self._r_pos
        k = pp / s if s > 0.0 else 1.0
        s = ppth + self._r_th
        kt = ppth / s if s > 0.0 else 1.0
        d = zth - pth
        if not -_PI < d <= _PI:
            d = _wrap(d)
        th = pth + kt * d
        if not -_PI < th <= _PI:
            th = _wrap(th)
        return (t_s, px + k * (zx - px), py + k * (zy - py), th, (1.0 - k) * pp,
                (1.0 - kt) * ppth, zx, zy, zth)  # fmt: skip

    def _refuse(self, later: list[_Anchor]) -> None:
        """Fuse the measurements of ``later`` again, in order, after the newest anchor."""
        anch = self._anch
        anch_t = self._anch_t
        for b in later:
            t = b[0]
            px, py, pth, pp, ppth = self._propagate(anch[-1], t)
            anch.append(self._fuse(t, px, py, pth, pp, ppth, b[6], b[7], b[8]))
            anch_t.append(t)

    def _replay_after(self, t_s: float) -> None:
        """Segments from ``t_s`` on changed: re-fuse every anchor captured after ``t_s``."""
        anch_t = self._anch_t
        i = bisect_right(anch_t, t_s)
        if i >= len(anch_t):
            return
        if i == 0:  # the first anchor is an initialisation: keep it, replay the rest
            i = 1
            if i >= len(anch_t):
                return
        later = self._anch[i:]
        del self._anch[i:]
        del anch_t[i:]
        self.replayed += 1
        self._refuse(later)

    def _trim(self, now_s: float) -> None:
        """Bound the history: anchors older than ``history_s`` (keeping the newest) and the
        segments before the oldest anchor kept."""
        cutoff = now_s - self._p.history_s
        anch_t = self._anch_t
        n = bisect_right(anch_t, cutoff)
        if n >= len(anch_t):
            n = len(anch_t) - 1
        if n > 0:
            del anch_t[:n]
            del self._anch[:n]
            self._first_is_init = False
        if anch_t:
            j = bisect_right(self._seg_t, min(cutoff, anch_t[0])) - 1
            if j > 0:
                del self._seg_t[:j]
                del self._seg[:j]

    def _propagate(
        self, a: _Anchor, t_end: float, record: bool = False
    ) -> tuple[float, float, float, float, float]:
        """Anchor ``a`` propagated through the segments to ``t_end``: (x, y, theta, P, Pth).

        Checkpoints: with ``record`` the state at every segment boundary passed is kept (for the
        newest anchor); a later call from the same anchor resumes from the last checkpoint at
        or before ``t_end`` (up to ``_TINY_S`` after it: float tick sums), which is the same
        arithmetic in the same order as starting from the anchor (so the same bits, but for
        that nanosecond). Segment changes drop the checkpoints after them.
        """
        t, x, y, th, pp, ppth = a[0], a[1], a[2], a[3], a[4], a[5]
        if t_end <= t:
            return x, y, th, pp, ppth
        t0 = t
        seg = self._seg
        seg_t = self._seg_t
        n = len(seg_t)
        ck = self._ck
        start = None
        if a is self._ck_anchor:
            j = len(ck) - 1
            while j >= 0 and ck[j][0] > t_end + _TINY_S:
                j -= 1
            if j >= 0:
                start = ck[j]
        elif record:
            self._ck_anchor = a
            ck.clear()
        if start is not None:
            t, x, y, th, dist, turn, qd, qt = start
            i = bisect_right(seg_t, t) - 1
        else:
            i = n - 1 if n and seg_t[-1] <= t else bisect_right(seg_t, t) - 1
            dist = turn = qd = qt = 0.0
        record = record and a is self._ck_anchor
        # Invariant: seg_t[i] <= t < seg_t[i + 1] (i = -1: before the first segment); the
        # last segment's twist holds up to t_end.
        while t < t_end:
            if i >= 0:
                _, v, w, _, qm, qs = seg[i]
            else:  # before any known twist: assume standing still
                v = w = 0.0
                qm, qs = self._cmd_q
            nxt = seg_t[i + 1] if i + 1 < n else t_end
            if nxt > t_end:
                nxt = t_end
            dt = nxt - t
            if dt < _TINY_S:  # a boundary a rounding error away (ticks as float sums)
                t = nxt
                i += 1
                continue
            h = w * dt * 0.5
            if -0.1 < h < 0.1:  # _sinc inlined
                h2 = h * h
                chord = v * dt * (1.0 - h2 * (1.0 / 6.0 - h2 * (1.0 / 120.0)))
            else:
                chord = v * dt * (_sin(h) / h)
            mid = th + h
            x += chord * _cos(mid)
            y += chord * _sin(mid)
            th = mid + h
            d = v * dt if v >= 0.0 else -v * dt
            dist += d
            turn += h if h >= 0.0 else -h
            qd += qm * d
            qt += qs * dt
            t = nxt
            i += 1
            if record and t < t_end and (not ck or ck[-1][0] < t):
                ck.append((t, x, y, th, dist, turn, qd, qt))
        # variances over the whole interval (the heading variance at its start swings the
        # whole distance sideways)
        pp += qd + qt + ppth * dist * dist
        ppth += self._q_rad * 2.0 * turn + self._q_thm * dist + self._q_ths * (t_end - t0)
        return x, y, th, pp, ppth
