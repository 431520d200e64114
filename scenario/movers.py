"""Scenario ``[[mover]]`` entries (issue 30): bodies that move among the robots, for tests and
demos (``sim_plant.core.bodies.MoverBody``; the in-process simulator moves them)::

    [[mover]]
    id = "cart"                # optional, default "mover<k>"
    radius_m = 0.075           # the body's radius
    path = [[1.5, 0.0], [-1.0, 0.0]]   # waypoints (m), at least two
    speed_mps = 0.2            # along the path
    t_s = 10.0                 # when it starts to move (default 0)
    visible = true             # tracked by the camera (false: an untracked person)
"""

from __future__ import annotations

import math
from typing import Any

from sim_plant.core.bodies import MoverBody

__all__ = ["MOVER_KEYS", "parse_movers"]

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
