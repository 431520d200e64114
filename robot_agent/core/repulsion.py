"""Potential-field repulsion (Khatib 1986), the safety stage of the Cartesian controller.

Each neighbour (a point) or obstacle (a circle) closer than ``d0`` pushes with speed
``k_rep * (1/d - 1/d0) / d^2`` (m/s) along the unit vector pointing away from it; nothing at or
beyond ``d0``. For a circle ``d`` is the distance to its surface. The pushes add as vectors and
the sum is capped at ``max_speed_mps`` (direction kept). This is the negative gradient of the
usual potential ``0.5 * k_rep * (1/d - 1/d0)^2`` and is added to the commanded reference-point
velocity just before the wheel map (safety last, as in the Robotarium pipeline).

Robustness: a neighbour or obstacle with a non-finite coordinate (or a circle with a negative or
non-finite radius) is skipped. Below 1 nm (or inside a circle) the magnitude is evaluated at 1 nm,
which saturates the cap; the direction is still away from the point (straight out of the circle),
and a point exactly coincident (or the circle's exact centre) pushes along +x. The result
is never NaN for finite ``px, py``; non-finite ``px, py`` give ``(0.0, 0.0)``.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from typing import Any, Final

from robot_agent.core.params import RepulsionParams

__all__ = ["repulsion_velocity", "repulsion_velocity_counted"]

_EPS_M: Final = 1e-9  # distances (m) below this are evaluated at this (the push saturates anyway)
_M_MAX: Final = 1e100  # cap on one push (m/s) before summing; far above any real cap
_hypot: Final = math.hypot


def repulsion_velocity(
    px: float,
    py: float,
    neighbours: Iterable[Sequence[float]],
    obstacles: Iterable[tuple[float, float, float]],
    params: RepulsionParams,
) -> tuple[float, float]:
    """Summed repulsion velocity (m/s) at point ``(px, py)`` (m).

    Args:
        px, py: where the push is evaluated (m); the firmware uses the robot's axle centre.
        neighbours: other robots' positions ``(x, y)`` (m), or longer tuples whose first two
            fields are x, y (``safety_filter.Neighbour``).
        obstacles: circles ``(x, y, radius_m)`` (m).
        params: gain, influence distance ``d0_m``, cap ``max_speed_mps``, ``enabled``.

    Returns:
        ``(vx, vy)`` in m/s, norm <= ``params.max_speed_mps``; ``(0.0, 0.0)`` when disabled.
    """
    vx, vy, _ = repulsion_velocity_counted(px, py, neighbours, obstacles, params)
    return vx, vy


def repulsion_velocity_counted(
    px: float,
    py: float,
    neighbours: Iterable[Sequence[float]],
    obstacles: Iterable[tuple[float, float, float]],
    params: RepulsionParams,
) -> tuple[float, float, int]:
    """As ``repulsion_velocity``, plus the number of entries skipped as non-finite / invalid.

    Args:
        px, py: where the push is evaluated (m); the firmware uses the robot's axle centre.
        neighbours: other robots' positions ``(x, y)`` (m), or longer tuples whose first two
            fields are x, y (``safety_filter.Neighbour``).
        obstacles: circles ``(x, y, radius_m)`` (m).
        params: gain, influence distance ``d0_m``, cap ``max_speed_mps``, ``enabled``.

    Returns:
        ``(vx, vy, skipped)``: velocity in m/s (norm <= ``params.max_speed_mps``) and the count
        of neighbours / obstacles ignored because a coordinate or radius was not finite (or the
        radius negative). ``(0.0, 0.0, 0)`` when disabled or ``px, py`` are not finite.
    """
    if not params.enabled:
        return 0.0, 0.0, 0
    d0 = params.influence_m
    return repulsion_raw(px, py, neighbours, obstacles, params.k_rep, d0, 1.0 / d0,
                         params.max_speed_mps)  # fmt: skip


def repulsion_raw(
    px: float,
    py: float,
    neighbours: Iterable[Sequence[Any]],  # (x, y, ...): a Neighbour or a pair
    obstacles: Iterable[tuple[float, float, float]],
    k: float,
    d0: float,
    inv_d0: float,
    cap: float,
) -> tuple[float, float, int]:
    """``repulsion_velocity_counted`` with the parameters read once (the firmware's per-tick
    call): gain ``k``, influence ``d0`` (> 0), ``inv_d0 = 1.0 / d0``, cap ``cap``; repulsion
    enabled."""
    if (s := px + py) - s != 0.0:  # not finite (x - x is 0.0 for a finite x only)
        return 0.0, 0.0, 0
    # (a list or a tuple as it is: _pushes may read it twice; any other iterable once, here)
    nbs: Any = neighbours if isinstance(neighbours, (list, tuple)) else list(neighbours)
    try:
        sx, sy, skipped = _pushes(px, py, nbs, k, d0, inv_d0)
    except TypeError:
        # an entry that is not a tuple (a list, ...), which the compiled core refuses where
        # _pushes types its entries as tuples (pure Python takes any sequence there): the same
        # sums from the start over its first two fields as a tuple (_pushes has no effect but
        # its result; a bad field raises TypeError here again, as it did there)
        sx, sy, skipped = _pushes(px, py, [(nb[0], nb[1]) for nb in nbs], k, d0, inv_d0)
    if obstacles:  # (no iterator for the usual empty tuple)
        for ox, oy, r in obstacles:
            if not (0.0 <= r < math.inf):
                skipped += 1
                continue
            dx = px - ox
            dy = py - oy
            reach = d0 + r
            if not (-reach < dx < reach and -reach < dy < reach):
                if (chk := dx + dy) - chk != 0.0:  # not finite
                    skipped += 1
                continue
            dc = _hypot(dx, dy)
            d = dc - r  # distance to the surface
            if d >= d0:
                continue
            if dc > 0.0:
                ux = dx / dc
                uy = dy / dc
            else:  # at the centre: pick +x
                ux, uy = 1.0, 0.0
            if d < _EPS_M:
                d = _EPS_M
            m = k * (1.0 / d - inv_d0) / (d * d)
            if m > _M_MAX:  # absurd gains: keep every term (and so the sum) finite
                m = _M_MAX
            sx += m * ux
            sy += m * uy
    if sx == 0.0 and sy == 0.0:
        return 0.0, 0.0, skipped
    s = _hypot(sx, sy)  # finite: each term is at most _M_MAX
    if s <= cap:
        return sx, sy, skipped
    f = cap / s
    return sx * f, sy * f, skipped


def _pushes(
    px: float,
    py: float,
    neighbours: Sequence[tuple[Any, ...]],
    k: float,
    d0: float,
    inv_d0: float,
) -> tuple[float, float, int]:
    """The neighbours' pushes at ``(px, py)`` (finite), summed in their order: ``(sx, sy,
    skipped)``. Compiled, each entry is typed as a tuple, so its x and y are read in place
    (a generic item lookup cost ~100 instructions each) and an entry of another type raises
    TypeError (``repulsion_raw`` then reads every entry as a tuple); in pure Python any
    sequence passes."""
    skipped = 0
    sx = 0.0
    sy = 0.0
    nd0 = -d0
    # (float-typed locals: the compiled core unboxes each field once and does the arithmetic
    # natively; an int field is its float value, as Python's mixed arithmetic takes it)
    qx: float
    qy: float
    for nb in neighbours:  # (x, y) or a longer tuple starting with x, y (safety_filter)
        qx = nb[0]
        qy = nb[1]
        dx = px - qx
        dy = py - qy
        # Cheap box reject first (most neighbours are far); NaN/inf also fail these tests.
        # (-d0 < dx < d0 and ... written as four plain comparisons: fewer bytecodes)
        if not (dx < d0 and dx > nd0 and dy < d0 and dy > nd0):
            if (chk := dx + dy) - chk != 0.0:  # not finite
                skipped += 1
            continue
        # the push of eq. "k_rep (1/d - 1/d0) / d^2" (Khatib's potential field, which the
        # paper names for collision avoidance), away from the neighbour
        d = _hypot(dx, dy)
        if d >= d0:
            continue
        if d > 0.0:
            ux = dx / d
            uy = dy / d
            if d < _EPS_M:
                d = _EPS_M
        else:  # coincident: no direction to be had, pick +x
            ux, uy, d = 1.0, 0.0, _EPS_M
        m = k * (1.0 / d - inv_d0) / (d * d)
        if m > _M_MAX:  # absurd gains: keep every term (and so the sum) finite
            m = _M_MAX
        sx += m * ux
        sy += m * uy
    return sx, sy, skipped
