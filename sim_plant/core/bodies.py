"""Bodies that move among the robots and are not robots (issue 30, scenario ``[[mover]]``): a
cart pushed along a path, a person walking through the formation.

A :class:`MoverBody` is a circle of ``radius_m`` that starts at the first waypoint at ``t_s``
and moves along the polyline of its waypoints at ``speed_mps``; it stands at the first
waypoint before ``t_s`` and at the last one after it arrives. ``visible``: the camera tracks it
(the robots and the coordinator see it as a tracked non-fleet object); not visible: an
untracked person, in the world only (its distance to the robots is still measured).

Pure, stdlib only; time is passed in.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["MoverBody"]


@dataclass(frozen=True, slots=True)
class MoverBody:
    """One body moving along waypoints (see the module docstring).

    Attributes:
        id: a name for logs and metrics (not a robot id).
        radius_m: the body's radius (m).
        path: waypoints ``(x, y)`` (m), at least two.
        speed_mps: its speed along the path (m/s).
        t_s: when it starts to move (s, sim time).
        visible: the camera tracks it.
    """

    id: str
    radius_m: float
    path: tuple[tuple[float, float], ...]
    speed_mps: float
    t_s: float = 0.0
    visible: bool = True

    def __post_init__(self) -> None:
        if not self.id:
            raise ValueError("MoverBody.id: empty")
        for name in ("radius_m", "speed_mps"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0.0):
                raise ValueError(f"MoverBody.{name}: expected a positive finite number, got {v!r}")
        if not (math.isfinite(self.t_s) and self.t_s >= 0.0):
            raise ValueError(f"MoverBody.t_s: expected a finite number >= 0, got {self.t_s!r}")
        if len(self.path) < 2:
            raise ValueError("MoverBody.path: expected at least two waypoints")
        for x, y in self.path:
            if not (math.isfinite(x) and math.isfinite(y)):
                raise ValueError("MoverBody.path: non-finite waypoint")

    @property
    def length_m(self) -> float:
        """Length of the path (m)."""
        return sum(
            math.hypot(b[0] - a[0], b[1] - a[1])
            for a, b in zip(self.path, self.path[1:], strict=False)
        )

    def state(self, t_s: float) -> tuple[float, float, float, float]:
        """``(x, y, vx, vy)`` of the body's centre at sim time ``t_s`` (m, m/s)."""
        s = (t_s - self.t_s) * self.speed_mps
        if not s > 0.0:
            x, y = self.path[0]
            return x, y, 0.0, 0.0
        for a, b in zip(self.path, self.path[1:], strict=False):
            seg = math.hypot(b[0] - a[0], b[1] - a[1])
            if s < seg:
                ux, uy = (b[0] - a[0]) / seg, (b[1] - a[1]) / seg
                return a[0] + ux * s, a[1] + uy * s, ux * self.speed_mps, uy * self.speed_mps
            s -= seg
        x, y = self.path[-1]
        return x, y, 0.0, 0.0
