"""The safety filter's small quadratic program: ``solve_qp`` returns the velocity closest to the
nominal one that satisfies every half-plane constraint ``ax*u_x + ay*u_y >= b`` and the speed
cap, exactly (the method is described in ``safety_filter.py``'s module docstring). Standard
library only.

Split out of safety_filter.py (issue 12) so the solver can be read and tested apart from the
constraint geometry; still importable from ``robot_agent.core.safety_filter``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Final

_sqrt: Final = math.sqrt


_TOL: Final = 1e-9  # feasibility tolerance of a constraint (m/s)


def solve_qp(
    ux: float, uy: float, cons: Sequence[tuple[float, float, float]], cap: float
) -> tuple[float, float, bool]:
    """``argmin |u - (ux, uy)|^2`` s.t. ``ax*u_x + ay*u_y >= b`` for each ``(ax, ay, b)`` in
    ``cons`` (``(ax, ay)`` unit vectors) and ``|u| <= cap``; exact (see the module docstring).

    Returns ``(u_x, u_y, feasible)``; ``(0.0, 0.0, False)`` when no candidate is feasible.
    """
    cap2 = cap * cap * (1.0 + 1e-12) + 1e-18

    def ok(x: float, y: float) -> bool:
        if x * x + y * y > cap2:
            return False
        for ax, ay, b in cons:  # noqa: SIM110 (a plain loop: no generator on the hot path)
            if ax * x + ay * y < b - _TOL:
                return False
        return True

    if ok(ux, uy):
        return ux, uy, True
    best_x = best_y = 0.0
    best = math.inf
    m = len(cons)
    for i in range(m):
        ax, ay, b = cons[i]
        # projection of u_nom onto the line a . u = b
        t = b - (ax * ux + ay * uy)
        x = ux + t * ax
        y = uy + t * ay
        d = (x - ux) * (x - ux) + (y - uy) * (y - uy)
        if d < best and ok(x, y):
            best, best_x, best_y = d, x, y
        # the line's intersections with the speed circle |u| = cap
        r2 = cap * cap - b * b
        if r2 >= 0.0:
            r = _sqrt(r2)
            for sgn in (1.0, -1.0):
                x = b * ax - sgn * r * ay
                y = b * ay + sgn * r * ax
                d = (x - ux) * (x - ux) + (y - uy) * (y - uy)
                if d < best and ok(x, y):
                    best, best_x, best_y = d, x, y
        # intersections with the other lines
        for j in range(i + 1, m):
            bx, by, c = cons[j]
            det = ax * by - ay * bx
            if -1e-12 < det < 1e-12:
                continue
            x = (b * by - ay * c) / det
            y = (ax * c - b * bx) / det
            d = (x - ux) * (x - ux) + (y - uy) * (y - uy)
            if d < best and ok(x, y):
                best, best_x, best_y = d, x, y
    if best == math.inf:
        return 0.0, 0.0, False
    return best_x, best_y, True


def solve_qp_relaxed(
    ux: float, uy: float, cons: Sequence[tuple[float, float, float]], cap: float
) -> tuple[float, float, float, list[tuple[float, float, float]]]:
    """The least-violation fallback of an infeasible ``solve_qp`` (``safety_filter.py``'s module
    docstring, "Leaving a barrier"): every constraint with ``b <= 0`` is kept exactly, every
    "get out" demand ``b > 0`` is scaled by ONE factor ``s in [0, 1]``, the largest for which
    the set is feasible (found by bisection: feasibility is monotone in ``s``, as ``u`` feasible
    at ``s1`` gives ``(s / s1) u`` feasible at ``s <= s1``), and the QP is solved on that set.

    ``s = 0`` is always feasible (``u = 0``), so this never fails; the result satisfies
    ``n . u >= s b > 0`` for every ``b > 0`` when ``s > 0`` and ``n . u >= 0`` when ``s = 0``:
    at least what the old stop fallback (``u = 0``) gave on every constraint.

    Returns ``(u_x, u_y, s, relaxed_cons)``.
    """
    if len(cons) == 1:  # in closed form: b > cap (else feasible), s = cap / b, u = cap n
        ax, ay, b = cons[0]
        if b > cap > 0.0:
            return cap * ax, cap * ay, cap / b, [(ax, ay, cap)]
    lo = 0.0
    hi = 1.0
    relaxed = _scaled(cons, lo)
    bx, by, ok = solve_qp(ux, uy, relaxed, cap)
    if not ok:  # (rounding: u = 0 meets every constraint at s = 0)
        bx = by = 0.0
    # s to 1e-6 (20 steps): the demands met to 1e-6 b, far below the filter's other errors
    while hi - lo > 1e-6:
        mid = 0.5 * (lo + hi)
        trial = _scaled(cons, mid)
        x, y, ok = solve_qp(ux, uy, trial, cap)
        if ok:
            lo, relaxed, bx, by = mid, trial, x, y
        else:
            hi = mid
    return bx, by, lo, relaxed


def _scaled(
    cons: Sequence[tuple[float, float, float]], s: float
) -> list[tuple[float, float, float]]:
    """``cons`` with every ``b > 0`` multiplied by ``s`` (the ``b <= 0`` ones unchanged)."""
    out: list[tuple[float, float, float]] = []
    for ax, ay, b in cons:
        out.append((ax, ay, b * s) if b > 0.0 else (ax, ay, b))
    return out
