"""The planner's view of the world: obstacles as exact geometry and a clearance query (pure).

Obstacles are the scenario's ``[[obstacle]]`` tables (``robot_agent.core.robot_config`` rules):
``circle`` (a disc), ``segment`` (a wall ``radius_m`` thick on each side) and ``polygon`` (for
the planner a FILLED polygon, ``radius_m`` thick: the firmware sees its outline as segments, the
planner does not route through its inside, which only a path starting inside could reach). The
arena is a rectangle whose walls are obstacles too.

:meth:`PlanWorld.clearance` gives, for many points at once, the distance (m) from each point to
the nearest obstacle surface or arena wall, capped at ``cap_m`` (< 0: the point is inside an
obstacle). It is exact (shapely's GEOS distances to the obstacles' cores, minus their radii),
and it only measures obstacles within ``cap_m`` of a point (an STRtree ``dwithin`` query), so a
map of thousands of obstacles costs what the obstacles near the points cost.

Refused with ``ValueError`` (a message naming ``obstacle[k]``): a polygon with fewer than three
distinct points, zero area or a self-intersection; more than :data:`MAX_OBSTACLES` obstacles.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Final

import numpy as np
import numpy.typing as npt
import shapely

__all__ = ["MAX_OBSTACLES", "ArenaBox", "PlanWorld"]

FloatArray = npt.NDArray[np.float64]

MAX_OBSTACLES: Final = 20_000
"""Most obstacles a map may have: a larger map is refused, never planned for unbounded time."""

MAX_PAIRS: Final = 20_000_000
"""Most (point, obstacle) pairs one clearance query may measure; beyond it the query raises
``ValueError`` (the planner turns it into "no plan: map too dense")."""


@dataclass(frozen=True, slots=True)
class ArenaBox:
    """The arena rectangle (m)."""

    x_min: float
    y_min: float
    x_max: float
    y_max: float


def _num(where: str, value: object) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise ValueError(f"{where}: expected a finite number, got {value!r}")
    return float(value)


def _xy(where: str, value: object) -> tuple[float, float]:
    if isinstance(value, str | bytes) or not isinstance(value, Sequence) or len(value) != 2:
        raise ValueError(f"{where}: expected an [x, y] pair, got {value!r}")
    return _num(f"{where}[0]", value[0]), _num(f"{where}[1]", value[1])


def _obstacle(k: int, table: Mapping[str, Any]) -> tuple[Any, float]:
    """(shapely core geometry, radius_m) of ``obstacle[k]``."""
    where = f"obstacle[{k}]"
    if not isinstance(table, Mapping):
        raise ValueError(f"{where}: expected a table, got {table!r}")
    kind = table.get("kind")
    radius = _num(f"{where}.radius_m", table.get("radius_m", 0.0))
    if radius < 0.0:
        raise ValueError(f"{where}.radius_m: must be >= 0, got {radius}")
    if kind == "circle":
        return shapely.Point(
            _num(f"{where}.x", table.get("x")), _num(f"{where}.y", table.get("y"))
        ), radius
    if kind == "segment":
        a = (_num(f"{where}.x1", table.get("x1")), _num(f"{where}.y1", table.get("y1")))
        b = (_num(f"{where}.x2", table.get("x2")), _num(f"{where}.y2", table.get("y2")))
        if a == b:
            return shapely.Point(*a), radius
        return shapely.LineString([a, b]), radius
    if kind == "polygon":
        raw = table.get("points")
        if isinstance(raw, str | bytes) or not isinstance(raw, Sequence):
            raise ValueError(f"{where}.points: expected a list of [x, y] pairs, got {raw!r}")
        pts = [_xy(f"{where}.points[{i}]", p) for i, p in enumerate(raw)]
        if len(set(pts)) < 3:
            raise ValueError(f"{where}.points: a polygon needs >= 3 distinct points, got {pts!r}")
        poly = shapely.Polygon(pts)
        if not poly.is_valid:
            why = shapely.is_valid_reason(poly)
            raise ValueError(f"{where}.points: degenerate polygon ({why})")
        if not poly.area > 1e-12:
            raise ValueError(f"{where}.points: degenerate polygon (zero area)")
        return poly, radius
    raise ValueError(f"{where}.kind: must be circle, segment or polygon, got {kind!r}")


class PlanWorld:
    """Obstacles and arena of a map, with an exact, capped clearance query (module docstring)."""

    __slots__ = ("_cores", "_r_max", "_radii", "_tree", "arena", "n_obstacles")

    def __init__(
        self, obstacles: Sequence[Mapping[str, Any]], arena: Mapping[str, Any] | None
    ) -> None:
        if isinstance(obstacles, str | bytes) or not isinstance(obstacles, Sequence):
            raise ValueError(f"obstacle: expected a list of tables, got {obstacles!r}")
        if len(obstacles) > MAX_OBSTACLES:
            raise ValueError(
                f"obstacle: {len(obstacles)} obstacles, the planner takes at most {MAX_OBSTACLES}"
            )
        cores: list[Any] = []
        radii: list[float] = []
        for k, table in enumerate(obstacles):
            core, radius = _obstacle(k, table)
            cores.append(core)
            radii.append(radius)
        self.n_obstacles = len(cores)
        self._cores = np.array(cores, dtype=object)
        self._radii = np.array(radii, dtype=np.float64)
        self._r_max = float(self._radii.max()) if radii else 0.0
        self._tree = shapely.STRtree(self._cores) if cores else None
        self.arena: ArenaBox | None = None
        if arena is not None:
            box = ArenaBox(
                *(_num(f"arena.{k}", arena.get(k)) for k in ("x_min", "y_min", "x_max", "y_max"))
            )
            if not (box.x_min < box.x_max and box.y_min < box.y_max):
                raise ValueError(f"arena: x_min < x_max and y_min < y_max needed, got {box}")
            self.arena = box

    def bounds(self) -> tuple[float, float, float, float] | None:
        """``(x_min, y_min, x_max, y_max)`` of the obstacles (with their radii), None if none."""
        if self._tree is None:
            return None
        b = shapely.bounds(self._cores)
        r = self._radii
        return (
            float((b[:, 0] - r).min()),
            float((b[:, 1] - r).min()),
            float((b[:, 2] + r).max()),
            float((b[:, 3] + r).max()),
        )

    def clearance(self, xy: FloatArray, cap_m: float) -> FloatArray:
        """Distance (m) from each row of ``xy`` (m, shape (m, 2)) to the nearest obstacle surface
        or arena wall, at most ``cap_m``; < 0 inside an obstacle or outside the arena; -inf for
        a row that is not finite."""
        pts = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        out = np.full(len(pts), float(cap_m), dtype=np.float64)
        a = self.arena
        if a is not None:
            gap = np.minimum(
                np.minimum(pts[:, 0] - a.x_min, a.x_max - pts[:, 0]),
                np.minimum(pts[:, 1] - a.y_min, a.y_max - pts[:, 1]),
            )
            np.minimum(out, gap, out=out)
        finite = np.isfinite(pts).all(axis=1)
        out[~finite] = -np.inf  # a point that is not a point is nowhere safe
        if self._tree is None or not finite.any():
            return out
        where = np.flatnonzero(finite)
        geoms = shapely.points(pts[where])
        pairs = self._tree.query(geoms, predicate="dwithin", distance=cap_m + self._r_max)
        if pairs.shape[1] > MAX_PAIRS:
            raise ValueError(
                f"the map is too dense for the planner: {pairs.shape[1]} point-obstacle pairs "
                f"(at most {MAX_PAIRS})"
            )
        if pairs.shape[1]:
            pi, oi = pairs[0], pairs[1]
            d = shapely.distance(geoms[pi], self._cores[oi]) - self._radii[oi]
            np.minimum.at(out, where[pi], d)
        return out
