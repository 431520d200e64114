"""Scenario ``[[mover]]`` entries (issue 30): bodies that move among the robots and are not
robots (a cart pushed along a path, a person walking through the formation), for tests and
demos; the in-process simulator moves them (formation/sim/simulate.py)::

    [[mover]]
    id = "cart"                # optional, default "mover<k>"
    radius_m = 0.075           # the body's radius
    path = [[1.5, 0.0], [-1.0, 0.0]]   # waypoints (m), at least two
    speed_mps = 0.2            # along the path
    t_s = 10.0                 # when it starts to move (default 0)
    visible = true             # tracked by the camera (false: an untracked person)

A :class:`MoverBody` is a circle of ``radius_m`` that starts at the first waypoint at ``t_s``
and moves along the polyline of its waypoints at ``speed_mps``; it stands at the first
waypoint before ``t_s`` and at the last one after it arrives. ``visible``: the camera tracks it
(the robots and the coordinator see it as a tracked non-fleet object); not visible: in the
world only (its distance to the robots is still measured). Stdlib only (the agents import
``scenario``), time passed in.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

__all__ = ["MOVER_KEYS", "MoverBody", "parse_movers"]


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


MOVER_KEYS = frozenset({"id", "radius_m", "path", "speed_mps", "t_s", "visible"})


class _Bad(ValueError):
    pass


def _number(d: dict[str, Any], key: str, where: str, default: float | None = None) -> float:
    v = d.get(key, default)
    if v is None:
        raise _Bad(f"{where}.{key}: required")
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(float(v)):
        raise _Bad(f"{where}.{key}: expected a finite number, got {v!r}")
    return float(v)


def parse_movers(
    raw: object, robot_ids: tuple[str, ...], duration_s: float
) -> tuple[MoverBody, ...]:
    """The ``[[mover]]`` array of a scenario, validated; ValueError names what is wrong."""
    if raw is None:
        return ()
    if not isinstance(raw, list):
        raise _Bad("mover: expected an array of tables [[mover]]")
    out: list[MoverBody] = []
    for k, d in enumerate(raw):
        where = f"mover[{k}]"
        if not isinstance(d, dict):
            raise _Bad(f"{where}: expected a table")
        extra = set(d) - MOVER_KEYS
        if extra:
            raise _Bad(f"{where}: unknown key(s) {sorted(extra)}")
        mid = d.get("id", f"mover{k + 1}")
        if not isinstance(mid, str) or not mid or mid in robot_ids:
            raise _Bad(f"{where}.id: expected a non-empty string that is not a robot id")
        path_raw = d.get("path")
        if not isinstance(path_raw, list) or len(path_raw) < 2:
            raise _Bad(f"{where}.path: expected at least two waypoints [x, y]")
        path: list[tuple[float, float]] = []
        for j, w in enumerate(path_raw):
            if not isinstance(w, list) or len(w) != 2:
                raise _Bad(f"{where}.path[{j}]: expected [x, y]")
            pt = {"x": w[0], "y": w[1]}
            path.append(
                (_number(pt, "x", f"{where}.path[{j}]"), _number(pt, "y", f"{where}.path[{j}]"))
            )
        visible = d.get("visible", True)
        if not isinstance(visible, bool):
            raise _Bad(f"{where}.visible: expected true or false")
        t_s = _number(d, "t_s", where, 0.0)
        if not 0.0 <= t_s <= duration_s:
            raise _Bad(f"{where}.t_s: expected 0..{duration_s}, got {t_s}")
        try:
            out.append(
                MoverBody(
                    id=mid,
                    radius_m=_number(d, "radius_m", where),
                    path=tuple(path),
                    speed_mps=_number(d, "speed_mps", where),
                    t_s=t_s,
                    visible=visible,
                )
            )
        except ValueError as exc:
            raise _Bad(f"{where}: {exc}") from None
    if len({m.id for m in out}) != len(out):
        raise _Bad("mover: duplicate id")
    return tuple(out)
