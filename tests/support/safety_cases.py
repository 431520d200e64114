"""The default robot of the safety filter's tests and its distances (:data:`CFG`, :data:`L`,
:data:`RB`, :data:`DS`, :data:`TOUCH`) and a point-to-segment distance (:func:`seg_dist`)."""

from __future__ import annotations

import math

from robot_agent.core.params import (
    AgentConfig,
    SegmentObstacle,
)

CFG = AgentConfig()

GEOM = CFG.geometry

L = GEOM.ref_offset_m

RB = GEOM.body_radius_m

DS = CFG.safety_distance_m

TOUCH = 2 * RB  # bodies touch at this centre distance


def seg_dist(px: float, py: float, s: SegmentObstacle) -> float:
    sx, sy = s.x2 - s.x1, s.y2 - s.y1
    n2 = sx * sx + sy * sy
    t = 0.0 if n2 == 0 else max(0.0, min(1.0, ((px - s.x1) * sx + (py - s.y1) * sy) / n2))
    return math.hypot(px - (s.x1 + t * sx), py - (s.y1 + t * sy))
