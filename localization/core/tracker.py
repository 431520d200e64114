"""Per-robot plausibility and bookkeeping between detection and publication (pure, no clock).

For each frame (``update(t_s, measurements)``) the tracker decides which measurements are
published:

* **jump rejection**: a measurement farther from the robot's last accepted pose than
  ``max_speed_mps * dt + jump_slack_m`` (or turned more than ``max_turn_radps * dt +
  turn_slack_rad``) is rejected and counted. After ``reacquire_after`` consecutive rejections
  that agree with each other (a robot picked up and put down elsewhere), or once the track is
  older than ``lost_after_s``, the next measurement starts a new track (counted as reacquired);
* **scale check**: a tag whose floor edge differs from ``tag_size_m`` by more than 25 % is a
  false detection (a tag lying elsewhere, or a wrong homography) and is rejected;
* **misses**: a known robot not measured in a frame is counted as a miss;
* a robot not measured is simply not published (no hold-last-value): its firmware's staleness
  rule (SafetyParams.stale_pose_s) handles it.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

from localization.core.calibration import TrackerParams
from localization.core.pose import Measurement
from robot_agent.core.kinematics import wrap_angle

__all__ = ["Track", "Tracker"]

SIZE_TOLERANCE = 0.25


@dataclass
class Track:
    """The state and counters of one robot."""

    t: float = math.nan
    x: float = math.nan
    y: float = math.nan
    theta: float = math.nan
    detections: int = 0
    published: int = 0
    misses: int = 0
    jumps: int = 0
    bad_size: int = 0
    reacquired: int = 0
    pending: list[Measurement] = field(default_factory=list)

    @property
    def valid(self) -> bool:
        return not math.isnan(self.t)


class Tracker:
    """Jump rejection, miss counting and stats for the robots ``robots``."""

    def __init__(
        self,
        robots: Iterable[str],
        params: TrackerParams | None = None,
        *,
        tag_size_m: float | None = None,
    ) -> None:
        self.params = params if params is not None else TrackerParams()
        self.tag_size_m = tag_size_m
        self.tracks: dict[str, Track] = {rid: Track() for rid in robots}
        self.frames = 0

    def seed(self, robot: str, x: float, y: float, t_s: float) -> None:
        """Give ``robot`` a starting position (patches mode: identity by proximity)."""
        tr = self.tracks[robot]
        tr.t, tr.x, tr.y, tr.theta = t_s, x, y, math.nan

    def positions(self) -> dict[str, tuple[float, float]]:
        """Last accepted (x, y) of every robot that has one."""
        return {r: (t.x, t.y) for r, t in self.tracks.items() if not math.isnan(t.x)}

    def _plausible(self, tr: Track, m: Measurement, dt: float) -> bool:
        p = self.params
        if math.hypot(m.x - tr.x, m.y - tr.y) > p.max_speed_mps * dt + p.jump_slack_m:
            return False
        if math.isnan(tr.theta):
            return True
        return abs(wrap_angle(m.theta - tr.theta)) <= p.max_turn_radps * dt + p.turn_slack_rad

    def update(self, t_s: float, measurements: Sequence[Measurement]) -> list[Measurement]:
        """Process one frame taken at ``t_s``; return the measurements to publish."""
        self.frames += 1
        p = self.params
        seen: set[str] = set()
        out: list[Measurement] = []
        for m in measurements:
            tr = self.tracks.get(m.robot)
            if tr is None or m.robot in seen:
                continue
            seen.add(m.robot)
            tr.detections += 1
            if (
                self.tag_size_m is not None
                and not math.isnan(m.size_m)
                and abs(m.size_m / self.tag_size_m - 1.0) > SIZE_TOLERANCE
            ):
                tr.bad_size += 1
                continue
            fresh = tr.valid and t_s - tr.t <= p.lost_after_s
            if fresh and not self._plausible(tr, m, max(t_s - tr.t, 0.0)):
                tr.pending.append(m)
                if len(tr.pending) < p.reacquire_after or not self._consistent(tr.pending):
                    tr.jumps += 1  # rejected
                    if len(tr.pending) >= p.reacquire_after:
                        tr.pending = tr.pending[-(p.reacquire_after - 1) :]
                    continue
                tr.reacquired += 1  # the robot really is there now
            elif not fresh and tr.valid and tr.published:
                tr.reacquired += 1
            tr.pending.clear()
            tr.t, tr.x, tr.y, tr.theta = t_s, m.x, m.y, m.theta
            tr.published += 1
            out.append(m)
        for rid, tr in self.tracks.items():
            if rid not in seen:
                tr.misses += 1
        return out

    def _consistent(self, pending: list[Measurement]) -> bool:
        """The last rejected measurements agree with each other (not a flicker)."""
        ref = pending[-1]
        return all(
            math.hypot(m.x - ref.x, m.y - ref.y) <= self.params.jump_slack_m * 2 for m in pending
        )

    def stats(self) -> dict[str, Any]:
        """Counters per robot and totals (for the status key)."""
        tracks = self.tracks
        return {
            "frames": self.frames,
            "detections": {r: t.detections for r, t in tracks.items()},
            "published": {r: t.published for r, t in tracks.items()},
            "misses": {r: t.misses for r, t in tracks.items()},
            "jumps": sum(t.jumps for t in tracks.values()),
            "bad_size": sum(t.bad_size for t in tracks.values()),
            "reacquired": sum(t.reacquired for t in tracks.values()),
        }
