"""The formation's footprint and how it squeezes: one morph parameter ``q`` (pure).

The footprint is every slot's body disc with its margin, as ``coordinator.core.path_check`` models a
slot (a disc of ``body_radius_m + ref_offset_m`` around the slot's reference point, whatever the
robot's heading) plus the safety filter's ``margin_m`` and a planning ``clearance_m``: a slot
point kept ``slot_radius_m`` from every obstacle keeps the robot's body out of the filter's
barrier, so the filter (the second layer) has nothing to do on a planned path.

Slots are offsets ``o_i`` from the virtual leader in its body frame (heading +x; eqs 3-5 summed
down the tree, ``FormationSpec.body_offsets_m``). Where the nominal formation does not fit, it
morphs continuously with one parameter ``q`` (dimensionless):

* ``q`` in [0, 1]: the spacing shrinks, ``o_i = s(q) d_i`` with ``s`` from 1 down to
  ``s_min = min(1, min_separation_m / spacing)``, so no two slots come closer than
  ``min_separation_m`` (the safety distance between robots plus a slack);
* ``q`` in [1, 2]: the shrunk formation turns into a column behind the leader (slots ranked
  front to back by their nominal offset, ``min_separation_m`` apart) in two phases: for ``q``
  in [1, 1.5] the slots move along the heading to their column places (a pair keeps its
  lateral gap while its longitudinal gap moves between two values of the same sign), then for
  ``q`` in [1.5, 2] across to the centre line (a pair keeps a longitudinal gap of at least one
  column spacing). So no pair comes closer than ``min_separation_m``; it is checked anyway (on
  201 values of ``q``) and the column is only offered when it holds.

Both ramps use the smoothstep ``3u^2 - 2u^3``, so ``do/dq`` is continuous and zero at ``q`` = 0,
1 and 2: a slot's velocity has no jump where a squeeze starts or ends.
"""

from __future__ import annotations

import math
from typing import Final

import numpy as np
import numpy.typing as npt

__all__ = ["Footprint"]

FloatArray = npt.NDArray[np.float64]

_CHECK_LEVELS: Final = 201


def _smooth(u: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Smoothstep of ``u`` clipped to [0, 1] and its derivative."""
    c = np.clip(u, 0.0, 1.0)
    return c * c * (3.0 - 2.0 * c), 6.0 * c * (1.0 - c)


class Footprint:
    """Slot offsets as a function of the morph parameter ``q`` (module docstring).

    Args:
        offsets_m: (n, 2) nominal body-frame offsets of the slots (row 0: the leader, (0, 0)).
        slot_radius_m: radius of one slot's disc that must stay clear of obstacles (m).
        min_separation_m: least distance between two slots in any squeeze (m).
        allow_shrink, allow_column: offer the shrink (q <= 1) and the column (q <= 2).
    """

    __slots__ = (
        "_cache",
        "column_gaps_m",
        "column_m",
        "n",
        "nominal_m",
        "q_max",
        "s_min",
        "slot_radius_m",
        "spacing_m",
    )

    def __init__(
        self,
        offsets_m: FloatArray,
        slot_radius_m: float,
        min_separation_m: float,
        *,
        allow_shrink: bool = True,
        allow_column: bool = True,
    ) -> None:
        d = np.array(offsets_m, dtype=np.float64).reshape(-1, 2)
        if not (np.all(np.isfinite(d)) and len(d) >= 1 and np.all(d[0] == 0.0)):
            raise ValueError("Footprint: offsets_m must be finite (n, 2) with row 0 at (0, 0)")
        if not (math.isfinite(slot_radius_m) and slot_radius_m > 0.0):
            raise ValueError(f"Footprint: slot_radius_m must be > 0, got {slot_radius_m!r}")
        if not (math.isfinite(min_separation_m) and min_separation_m > 0.0):
            raise ValueError(f"Footprint: min_separation_m must be > 0, got {min_separation_m!r}")
        self.n = len(d)
        self._cache: dict[float, FloatArray] = {}
        self.nominal_m = d
        self.slot_radius_m = float(slot_radius_m)
        spacing = _min_pair_distance(d)
        self.spacing_m = spacing
        s_min = min(1.0, min_separation_m / spacing) if math.isfinite(spacing) else 1.0
        self.s_min = s_min if allow_shrink else 1.0
        # column: rank the non-leader slots front to back (x descending, then left to right)
        order = sorted(range(1, self.n), key=lambda i: (-d[i, 0], -d[i, 1], i))
        col = np.zeros_like(d)
        sep = max(min_separation_m, 0.0)
        if math.isfinite(spacing):
            sep = max(sep, min(spacing * self.s_min, spacing))
        gaps = np.zeros(self.n)
        for rank, i in enumerate(order, start=1):
            col[i, 0] = -rank * sep
            gaps[i] = rank * sep
        self.column_m = col
        self.column_gaps_m = gaps
        q_max = 1.0 if self.s_min < 1.0 else 0.0
        self.q_max = 2.0  # provisional, for the check below
        if allow_column and self.n > 2:
            qs = np.linspace(1.0, 2.0, _CHECK_LEVELS)
            ok = all(
                _min_pair_distance(self.offsets(float(q))[0]) >= min_separation_m - 1e-9 for q in qs
            )
            if ok:
                q_max = 2.0
        self.q_max = q_max

    def _rigid(self, q: float) -> FloatArray:
        """The offsets at ``q`` with the rigid column, cached (the searches ask for a few
        levels thousands of times)."""
        got = self._cache.get(q)
        if got is None:
            got = self.offsets_many(np.array([q]))[0][0]
            got.setflags(write=False)
            if len(self._cache) < 64:
                self._cache[q] = got
        return got

    def offsets(self, q: float) -> tuple[FloatArray, FloatArray]:
        """(offsets (n, 2) in m, their derivative d/dq (n, 2) in m) at morph ``q``, with the
        rigid column."""
        o, do, _ = self.offsets_many(np.array([q], dtype=np.float64))
        return o[0], do[0]

    def offsets_many(
        self, q: FloatArray, column: FloatArray | None = None
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Offsets at each morph value of ``q`` (m,): ``(o, do/dq, w)``, each (m, n, 2).

        ``column`` (m, n, 2): the column's offsets at each sample (the path-following column
        of a planned path: each slot where the leader was ``column_gaps_m`` earlier, in the
        leader's frame); None: the rigid column ``column_m``. ``w`` is ``do/dcolumn`` (the
        column's weight in each component), for the rate of a moving column.
        """
        qa = np.clip(np.asarray(q, dtype=np.float64), 0.0, self.q_max)
        ss, dss = _smooth(qa)
        s = 1.0 - (1.0 - self.s_min) * ss
        ds = -(1.0 - self.s_min) * dss
        # the column in two phases: first along the heading (x), then across (y)
        lx, dlx = _smooth(2.0 * (qa - 1.0))
        ly, dly = _smooth(2.0 * (qa - 1.5))
        dlx, dly = 2.0 * dlx, 2.0 * dly
        d = self.nominal_m[None, :, :]
        c = self.column_m[None, :, :] if column is None else np.asarray(column)
        s3, ds3 = s[:, None], ds[:, None]
        lx3, dlx3, ly3, dly3 = lx[:, None], dlx[:, None], ly[:, None], dly[:, None]
        o = np.empty((len(qa), self.n, 2))
        do = np.empty_like(o)
        w = np.empty_like(o)
        o[..., 0] = (1.0 - lx3) * s3 * d[..., 0] + lx3 * c[..., 0]
        do[..., 0] = -dlx3 * s3 * d[..., 0] + (1.0 - lx3) * ds3 * d[..., 0] + dlx3 * c[..., 0]
        o[..., 1] = (1.0 - ly3) * s3 * d[..., 1] + ly3 * c[..., 1]
        do[..., 1] = -dly3 * s3 * d[..., 1] + (1.0 - ly3) * ds3 * d[..., 1] + dly3 * c[..., 1]
        w[..., 0] = lx3
        w[..., 1] = ly3
        return o, do, w

    def slot_points(
        self, poses: FloatArray, q: FloatArray, column: FloatArray | None = None
    ) -> FloatArray:
        """World positions (m, n, 2) of every slot for leader poses (m, 3) ``(x, y, theta)`` and
        morph values ``q`` (m,): ``p_i = p_L + R(theta) o_i(q)`` (eqs 3-5)."""
        p = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
        qa = np.asarray(q, dtype=np.float64)
        if column is None and len(qa) and np.all(qa == qa[0]):  # one squeeze: computed once
            o = np.broadcast_to(self._rigid(float(qa[0])), (len(qa), self.n, 2))
        else:
            o, _, _ = self.offsets_many(qa, column)
        c, s = np.cos(p[:, 2])[:, None], np.sin(p[:, 2])[:, None]
        out = np.empty_like(o)
        out[..., 0] = p[:, 0:1] + c * o[..., 0] - s * o[..., 1]
        out[..., 1] = p[:, 1:2] + s * o[..., 0] + c * o[..., 1]
        return out

    def extent_m(self) -> float:
        """The farthest any slot's disc reaches from the leader in any squeeze (m)."""
        qs = np.linspace(0.0, self.q_max, 21) if self.q_max > 0 else np.zeros(1)
        o, _, _ = self.offsets_many(qs)
        return float(np.hypot(o[..., 0], o[..., 1]).max()) + self.slot_radius_m


def _min_pair_distance(d: FloatArray) -> float:
    if len(d) < 2:
        return math.inf
    diff = d[:, None, :] - d[None, :, :]
    dist = np.hypot(diff[..., 0], diff[..., 1])
    np.fill_diagonal(dist, np.inf)
    return float(dist.min())
