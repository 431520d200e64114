"""What a :class:`formation.record.collector.RunCollector` knows of each robot *now*: its latest
truth pose, its latest status, the safety filter counters of its newest status (by ``t``), the
fleet's liveliness tokens and the plant's latest clock. :class:`RobotStates` owns them; the
live view and the end of a lockstep run read them, the run's log takes the filter counters."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

from bus_schemas import Clock, Status, keys

__all__ = ["RobotStates"]

Pose = tuple[float, float, float]


class RobotStates:
    """The latest state of the robots ``robot_ids`` (by index) and of ``fleet``'s tokens."""

    def __init__(self, robot_ids: Sequence[str], fleet: str) -> None:
        self.robot_ids = list(robot_ids)
        self.fleet = fleet
        n = len(self.robot_ids)
        self.latest_truth: list[Pose | None] = [None] * n
        self.status: list[Status | None] = [None] * n
        # the safety filter counters of each robot's newest status (by t), None before any
        self._filter: list[dict[str, Any] | None] = [None] * n
        self._filter_t: list[float] = [-math.inf] * n
        self.tokens: dict[str, bool] = {}  # "kind/ident" (or "kind") -> present
        self.last_clock: Clock | None = None

    def pose(self, i: int, pose: Pose) -> None:
        self.latest_truth[i] = pose

    def filter_counters(self, i: int, t: float, counts: dict[str, Any]) -> None:
        """Robot ``i``'s safety filter counters as of its status at ``t`` (the newest kept: the
        counters only grow, and a status may arrive after a newer one)."""
        if t >= self._filter_t[i]:
            self._filter[i], self._filter_t[i] = counts, t

    def filter_counts(self) -> dict[str, dict[str, Any]]:
        """Robot id -> its newest filter counters (robots without any left out)."""
        return {
            rid: dict(counts)
            for rid, counts in zip(self.robot_ids, self._filter, strict=True)
            if counts is not None
        }

    def feed_alive(self, key: str, alive: bool) -> None:
        """A liveliness token of this fleet appeared (``alive``) or vanished."""
        parsed = keys.parse_alive_key(key)
        if parsed is None or parsed[0] != self.fleet:
            return
        _, kind, ident = parsed
        self.tokens[f"{kind}/{ident}" if ident is not None else kind] = alive

    def alive(self, kind: str, ident: str | None = None) -> bool | None:
        """Whether the token ``alive/<kind>[/<ident>]`` is present (None: never seen)."""
        return self.tokens.get(f"{kind}/{ident}" if ident is not None else kind)
