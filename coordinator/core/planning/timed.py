"""A timed plan read at a time: the leader's state and the slots' squeeze offsets (pure).

:class:`TimedPlan` wraps a :class:`~coordinator.core.planning.planner.PlanResult` (arrays over the
arc length with the time of each sample) and samples it at a plan time ``tau`` (s, from the
plan's start): the leader's pose from the exact path geometry, its speed from the profile
(constant acceleration between two samples, so the arc length is exact for it), ``omega =
v kappa`` (eqs 1-2). Before the start it is at the start with the profile's first speed (0 for
a plan from rest, the join speed of a run-time plan), after the end at rest on the goal.

Used by ``kind = "plan"`` trajectories (``trajectory.PlannedTrajectory``) and by the run-time
plans the leader follows after a goal or a replan (``coordinator.core.leader``). Plain floats
per call: it is on the tick's path.
"""

from __future__ import annotations

import bisect
from collections.abc import Sequence

from .planner import PlanResult

__all__ = ["NOMINAL_Q", "TimedPlan"]

NOMINAL_Q = 0.05
"""A squeeze this small is the nominal formation for a replan: the shrink's smoothstep is 0.7 %
of the way at ``q`` = 0.05, under 2 mm of a slot's offset for a 0.4 m spacing."""


class TimedPlan:
    """Sample ``result`` at plan time (module docstring)."""

    __slots__ = ("_dq", "_morph", "_nominal", "_q", "_s", "_t", "_v", "_zeros", "result")

    def __init__(self, result: PlanResult) -> None:
        self.result = result
        self._t = tuple(float(v) for v in result.t_s)
        self._morph = any(float(v) > 0.0 for v in result.q)
        self._q = tuple(float(v) for v in result.q)
        self._v = tuple(float(v) for v in result.v_mps)
        self._dq = tuple(float(v) for v in result.dq_per_m)
        self._s = tuple(float(v) for v in result.s_m)
        fp = result.footprint
        self._nominal = tuple((float(a), float(b)) for a, b in fp.nominal_m)
        self._zeros = tuple((0.0, 0.0) for _ in range(fp.n))

    @property
    def duration_s(self) -> float:
        """Time from the start to the goal (s)."""
        return self._t[-1]

    @property
    def squeezes(self) -> bool:
        """The formation squeezes somewhere on this plan (:meth:`slot_offsets` is not None)."""
        return self._morph

    def where(self, tau_s: float) -> tuple[float, float, int, float]:
        """(arc length s_m, speed v_mps, sample index k, position u in [k, k+1]) at ``tau_s``."""
        if tau_s <= 0.0:
            return 0.0, self._v[0], 0, 0.0
        if tau_s >= self._t[-1]:
            return self._s[-1], 0.0, len(self._t) - 2, 1.0
        k = bisect.bisect_right(self._t, tau_s) - 1
        dt = self._t[k + 1] - self._t[k]
        v0, v1 = self._v[k], self._v[k + 1]
        a = (v1 - v0) / dt
        u = tau_s - self._t[k]
        ds = self._s[k + 1] - self._s[k]
        s_in = min(v0 * u + 0.5 * a * u * u, ds)
        return self._s[k] + s_in, v0 + a * u, k, s_in / ds if ds > 0 else 0.0

    def state(self, tau_s: float) -> tuple[float, float, float, float, float]:
        """``(x, y, theta, v_mps, omega_radps)`` at plan time ``tau_s`` (theta not wrapped)."""
        s, v, _, _ = self.where(tau_s)
        x, y, th, kappa = self.result.pose_at(s)
        return x, y, th, v, v * kappa

    def slot_offsets(self, tau_s: float) -> tuple[tuple[float, float, float, float], ...] | None:
        """The slots' body-frame offsets from the leader and their rates at ``tau_s``: per slot
        (definition order) ``(ox, oy, dox, doy)`` in m and m/s; None where the formation is not
        squeezed (the rigid offsets of the formation hold)."""
        if not self._morph:
            return None
        r = self.result
        s, v, k, u = self.where(float(tau_s))
        q0, q1 = self._q[k], self._q[k + 1]
        if q0 == 0.0 and q1 == 0.0:
            return None  # not squeezed here: the rigid formation (its exact arithmetic)
        q = q0 + (q1 - q0) * u
        dq_ds = self._dq[k] + (self._dq[k + 1] - self._dq[k]) * u
        fp = r.footprint
        # the squeeze of Footprint.offsets_many in plain floats (the per-tick path)
        qa = min(max(q, 0.0), fp.q_max)
        u1 = min(max(qa, 0.0), 1.0)
        sc = 1.0 - (1.0 - fp.s_min) * u1 * u1 * (3.0 - 2.0 * u1)
        dsc = -(1.0 - fp.s_min) * 6.0 * u1 * (1.0 - u1)
        ux = min(max(2.0 * (qa - 1.0), 0.0), 1.0)
        uy = min(max(2.0 * (qa - 1.5), 0.0), 1.0)
        lx, dlx = ux * ux * (3.0 - 2.0 * ux), 12.0 * ux * (1.0 - ux)
        ly, dly = uy * uy * (3.0 - 2.0 * uy), 12.0 * uy * (1.0 - uy)
        col: Sequence[tuple[float, float]] = self._zeros
        dcol: Sequence[tuple[float, float]] = self._zeros
        if lx > 0.0 or ly > 0.0 or dlx > 0.0 or dly > 0.0:
            col, dcol = r.column_at(s)
        out = []
        for (dx, dy), (cx, cy), (gx, gy) in zip(self._nominal, col, dcol, strict=True):
            ox = (1.0 - lx) * sc * dx + lx * cx
            oy = (1.0 - ly) * sc * dy + ly * cy
            dox = -dlx * sc * dx + (1.0 - lx) * dsc * dx + dlx * cx
            doy = -dly * sc * dy + (1.0 - ly) * dsc * dy + dly * cy
            # d/dt: the squeeze's rate and the column moving along the path
            out.append((ox, oy, (dox * dq_ds + lx * gx) * v, (doy * dq_ds + ly * gy) * v))
        return tuple(out)

    def squeezed_at(self, tau_s: float) -> bool:
        """The formation is squeezed at plan time ``tau_s``: ``q`` above
        :data:`NOMINAL_Q` (below it no slot is 2 mm off its nominal offset)."""
        if not self._morph:
            return False
        _, _, k, _ = self.where(tau_s)
        return max(self._q[k], self._q[k + 1]) > NOMINAL_Q
