"""The safety filter's static barriers: circle and segment obstacles and the arena walls.

Stdlib only, pure. The barriers (``h >= 0`` is safe; notation of
``robot_agent.core.safety_filter``'s
module docstring, where the proof is)::

    obstacle (circle centre o, radius r):  h = |p - o| - (r + r_b + margin + l + rho)
    segment (closest point q on it):       h = |p - q| - (r_seg + r_b + margin + l + rho)
    arena wall (x >= x_min, ...):          h = p_x - (x_min + r_b + margin + l + rho), ...

each with the constraint ``n . u >= -gamma h`` (the robot alone takes the responsibility).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Final

from robot_agent.core.params import AgentConfig, CircleObstacle, SegmentObstacle
from robot_agent.core.qp import _sqrt

__all__ = ["WorldBarriers"]

_hypot: Final = math.hypot


class WorldBarriers:
    """The configured world (``AgentConfig.world``) of one robot, as barrier data: circles and
    segments grown by ``clear_m`` (body radius + margin + reference offset), the arena shrunk by
    it."""

    __slots__ = ("_arena", "_circles", "_obs_clear", "_segments", "present")

    def __init__(self, config: AgentConfig, clear_m: float) -> None:
        self._obs_clear = clear_m
        circles: list[tuple[float, float, float]] = []
        segments: list[tuple[float, float, float, float, float, float]] = []
        for o in config.world.obstacles:
            if isinstance(o, CircleObstacle):
                circles.append((o.x, o.y, o.radius_m + clear_m))
            elif isinstance(o, SegmentObstacle):
                dx = o.x2 - o.x1
                dy = o.y2 - o.y1
                segments.append((o.x1, o.y1, dx, dy, dx * dx + dy * dy, o.radius_m + clear_m))
        self._circles = tuple(circles)
        self._segments = tuple(segments)
        a = config.world.arena
        self._arena = (
            None
            if a is None
            else (a.x_min + clear_m, a.y_min + clear_m, a.x_max - clear_m, a.y_max - clear_m)
        )
        self.present = bool(circles or segments or a is not None)
        """Some obstacle or an arena is configured."""

    def append(
        self,
        px: float,
        py: float,
        reach: float,
        gamma: float,
        rho: float,
        obstacles: Sequence[tuple[float, float, float]],
        cons: list[tuple[float, float, float]],
        min_h: float,
    ) -> tuple[float, int]:
        """Append the obstacle / wall constraints in range (``obstacles``: circles ``(x, y,
        radius_m)`` given for this tick, on top of the configured world); returns the least
        barrier value (``min_h`` if none is lower) and how many given obstacles were rejected
        (a radius that is negative or not finite)."""
        rejected = 0
        for ox, oy, r in obstacles:  # (x, y, radius_m) circles given per tick
            if not (0.0 <= r < math.inf):
                rejected += 1
                continue
            h = _circle(px, py, ox, oy, r + self._obs_clear + rho, reach, gamma, cons)
            if h < min_h:
                min_h = h
        for ox, oy, rr in self._circles:
            h = _circle(px, py, ox, oy, rr + rho, reach, gamma, cons)
            if h < min_h:
                min_h = h
        for x1, y1, sx, sy, len2, rr in self._segments:
            t = ((px - x1) * sx + (py - y1) * sy) / len2 if len2 > 0.0 else 0.0
            t = 0.0 if t < 0.0 else (1.0 if t > 1.0 else t)
            dx = px - (x1 + t * sx)
            dy = py - (y1 + t * sy)
            d = _hypot(dx, dy)
            h = d - rr - rho
            if h < min_h:
                min_h = h
            if h < reach:
                if d > 0.0:
                    cons.append((dx / d, dy / d, -gamma * h))
                elif len2 > 0.0:  # on the wall itself: push along its (left) normal
                    nrm = _sqrt(len2)
                    cons.append((-sy / nrm, sx / nrm, -gamma * h))
                else:
                    cons.append((1.0, 0.0, -gamma * h))
        arena = self._arena
        if arena is not None:
            x0, y0, x1, y1 = arena
            for h, ax, ay in (
                (px - x0 - rho, 1.0, 0.0),
                (x1 - px - rho, -1.0, 0.0),
                (py - y0 - rho, 0.0, 1.0),
                (y1 - py - rho, 0.0, -1.0),
            ):
                if h < min_h:
                    min_h = h
                if h < reach:
                    cons.append((ax, ay, -gamma * h))
        return min_h, rejected


def _circle(
    px: float,
    py: float,
    ox: float,
    oy: float,
    rr: float,
    reach: float,
    gamma: float,
    cons: list[tuple[float, float, float]],
) -> float:
    dx = px - ox
    dy = py - oy
    lim = rr + reach
    if not (-lim < dx < lim and -lim < dy < lim):
        return math.inf
    d = _hypot(dx, dy)
    h = d - rr
    if h < reach:
        if d > 0.0:
            cons.append((dx / d, dy / d, -gamma * h))
        else:
            cons.append((1.0, 0.0, -gamma * h))
    return h
