"""The agent host's neighbour queries: a spatial hash of the latest pose frame.

Stdlib only. :class:`robot_agent.node.host.HostNode` keeps every robot's latest pose in its
neighbour table (:attr:`NeighbourGrid.seen` reads it) and asks, per hosted robot and step, for the
robots near it, as the safety filter and the repulsion see them (``robot_agent.core.neighbours``).
Cells are as large as the larger of the repulsion's influence distance ``d0`` and the safety
filter's ``neighbour_range_m``, so a query costs the robots in the 3 x 3 cells around a robot,
not N; neighbours are passed in frame order (the order ``formation agent`` sees them), so the
firmware sums the same terms in the same order (docs/scale.md).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Final

from robot_agent.core.neighbours import is_current, mover, neighbour
from robot_agent.core.safety_filter import Neighbour

__all__ = ["REACH_MARGIN", "NeighbourGrid", "Seen"]

REACH_MARGIN: Final = 1.1
"""A robot's neighbours are the robots within this factor of the larger of the repulsion's
``d0`` and the safety filter's ``neighbour_range_m`` (a worst-case bound already) of its
measured pose; the 10 % cover the estimator's drift from that pose."""

_Entry = tuple[int, str, Neighbour, float, float]
_Grid = dict[tuple[int, int], list[_Entry]]
"""Spatial hash: cell -> (frame order, robot id, what the safety filter sees, x, y) of its
robots."""


@dataclass(slots=True)
class Seen:
    """Latest pose of a robot from the pose frames (for repulsion and the safety filter)."""

    x: float
    y: float
    theta: float
    capture_s: float  # capture time on this host's clock (robot_agent.core.clocksync)
    rx_s: float | None  # receive time; None while pending (lockstep, until the next clock)
    order: int  # first-seen order (= frame order): neighbours are passed in this order


class NeighbourGrid:
    """Every robot's latest pose (:attr:`seen`, filled by the host's pose handler) and the
    spatial hash built from it once per step time."""

    __slots__ = (
        "_cooperative",
        "_grid",
        "_grid_now",
        "_movers",
        "_near_cache",
        "_reach2",
        "cell_m",
        "seen",
    )

    def __init__(
        self,
        cell_m: float,
        cooperative: Callable[[str, float], bool],
        seen: dict[str, Seen] | None = None,
    ) -> None:
        """``cell_m``: the reach (see the module docstring); ``cooperative(rid, now_s)``: rule 3
        of ``robot_agent.core.neighbours`` for robot ``rid``; ``seen``: the latest poses to
        read (``robot_agent.core.neighbour_table.NeighbourTable.seen``; default: a new dict)."""
        self.cell_m = cell_m
        # a robot gets only those within REACH_MARGIN x the reach of its pose (about half of the
        # 3 x 3 cells' robots: the firmware's loops over them cost per neighbour)
        self._reach2 = (REACH_MARGIN * cell_m) ** 2
        self._cooperative = cooperative
        self.seen: dict[str, Seen] = {} if seen is None else seen
        self._grid: _Grid | None = None
        self._grid_now = -math.inf
        self._near_cache: dict[tuple[int, int], list[_Entry]] = {}
        self._movers: Mapping[str, tuple[float, float]] = {}

    def set_movers(self, movers: Mapping[str, tuple[float, float]]) -> None:
        """The coordinator's moving obstacles for the next steps, id -> velocity (m/s; rule 4
        of ``robot_agent.core.neighbours``). A mover's row reaches ``(|vx| + |vy|) / gamma``
        farther than a still robot's, within the cooperative row's worst case that sizes the
        cells for ``|vx| + |vy|`` up to ``max_ref_speed + (Ds + 2 l - Ds - l) gamma`` (0.75 m/s
        with the defaults)."""
        if movers != self._movers:
            self._movers = movers
            self._grid = None

    def invalidate(self) -> None:
        """A pose changed or a pending one became current: rebuild at the next query."""
        self._grid = None

    def clear(self) -> None:
        """Forget every robot (the host resumed from a stop: old poses must not count)."""
        self.seen.clear()
        self._grid = None

    def _build_grid(self, now_s: float) -> _Grid:
        """The spatial hash of the robots current at ``now_s``: cell -> (frame order, robot id,
        the safety filter's view of it at ``now_s``). Every neighbour is built once here, so a
        step of N robots costs N :func:`neighbour` calls, not N x neighbours; its cooperative
        flag is taken now, before any robot of this step changed its mode (rule 3 of
        ``robot_agent.core.neighbours``: the mode of the previous control tick)."""
        grid: _Grid = {}
        c = self.cell_m
        coop = self._cooperative
        floor = math.floor
        movers = self._movers
        for rid, e in self.seen.items():
            rx_s = e.rx_s
            if rx_s is None or not is_current(now_s, rx_s):
                continue
            cell = (floor(e.x / c), floor(e.y / c))
            nb = neighbour(e.x, e.y, e.theta, e.capture_s, now_s, coop(rid, now_s))
            if movers:
                v = movers.get(rid)
                if v is not None:
                    nb = mover(nb, v[0], v[1])
            entry = (e.order, rid, nb, e.x, e.y)
            bucket = grid.get(cell)
            if bucket is None:
                grid[cell] = [entry]
            else:
                bucket.append(entry)
        return grid

    def _near(self, cell: tuple[int, int]) -> list[_Entry]:
        """The entries of the 3 x 3 cells around ``cell``, in frame order (cached per grid: the
        robots of one cell share them)."""
        near = self._near_cache.get(cell)
        if near is None:
            grid = self._grid
            assert grid is not None
            cx, cy = cell
            near = []
            for dx in (-1, 0, 1):
                for dy in (-1, 0, 1):
                    bucket = grid.get((cx + dx, cy + dy))
                    if bucket:
                        near.extend(bucket)
            near.sort()  # by frame order (unique: the ids are never compared)
            self._near_cache[cell] = near
        return near

    def neighbours_of(self, rid: str, x: float, y: float, now_s: float) -> list[Neighbour]:
        """The robots other than ``rid`` within :data:`REACH_MARGIN` x :attr:`cell_m` of ``(x,
        y)`` (found in the 3 x 3 cells around it), in frame order, as the safety filter sees them
        at ``now_s`` (``robot_agent.core.neighbours``); the robots beyond contribute exactly zero.
        The
        grid is built once per ``now_s`` (a frame, a watchdog chunk) and after
        :meth:`invalidate`."""
        if self._grid is None or now_s != self._grid_now:
            self._grid = self._build_grid(now_s)
            self._grid_now = now_s
            self._near_cache = {}
        c = self.cell_m
        r2 = self._reach2
        near = self._near((math.floor(x / c), math.floor(y / c)))
        return [
            e[2]
            for e in near
            if (dx := e[3] - x) * dx + (dy := e[4] - y) * dy <= r2 and e[1] != rid
        ]
