"""The safety filter's small quadratic program: ``solve_qp`` returns the velocity closest to the
nominal one that satisfies every half-plane constraint ``ax*u_x + ay*u_y >= b`` and the speed
cap, exactly (the method is described in ``safety_filter.py``'s module docstring). Standard
library only.

Split out of safety_filter.py (issue 12) so the solver can be read and tested apart from the
constraint geometry; still importable from ``robot_agent.safety_filter``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

_sqrt = math.sqrt


_TOL = 1e-9  # feasibility tolerance of a constraint (m/s)


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
