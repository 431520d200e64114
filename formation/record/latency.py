"""Pose-to-wheels latency of a fleet seen on the bus: :class:`LatencyTracker` pairs each wheel
command with the pose it was computed from. Used by the recorder and ``formation report``.

The bus tap itself (every key and liveliness token of a fleet, handed to one worker thread) is
:class:`runtime.tap.BusTap`, the worker-thread delivery of the one subscription bridge.
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Iterable
from dataclasses import dataclass

from bus_schemas import (
    Wheels,
)

# --------------------------------------------------------------------------------------------
# Latency of wheel commands
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class LatencySample:
    """One wheel command's latency (see :data:`LATENCY_SCHEMA`); times in seconds."""

    robot: str
    t: float
    pose_t: float
    rx_latency_s: float | None
    pose_age_s: float


class LatencyTracker:
    """Matches each robot's wheel command to the pose it was computed from (``pose_t``).

    Feed every pose and wheels sample with its receive time (seconds, one monotonic clock);
    :meth:`on_wheels` returns the command's latency. Remembers the last ``window`` poses per
    robot (a command uses a pose of the last few frames). Lockstep is detected from the
    ``clock`` key: then ``pose_age_s`` is sim time (wheels ``t`` - ``pose_t``), otherwise the
    wheels receive time minus ``pose_t`` (meaningful when the publisher's monotonic clock is this
    host's, i.e. a local run).
    """

    def __init__(self, window: int = 64) -> None:
        self.window = window
        self.lockstep = False
        self._pose_rx: dict[str, OrderedDict[float, float]] = {}

    def on_clock(self) -> None:
        """A ``clock`` message was seen: the run is lockstep."""
        self.lockstep = True

    def on_pose(self, robot: str, t: float, rx_s: float) -> None:
        """A pose of ``robot`` with ``t`` arrived at ``rx_s``."""
        seen = self._pose_rx.get(robot)
        if seen is None:
            seen = self._pose_rx[robot] = OrderedDict()
        seen.setdefault(t, rx_s)  # the first arrival counts
        while len(seen) > self.window:
            seen.popitem(last=False)

    def on_frame(self, robots: Iterable[str], t: float, rx_s: float) -> None:
        """A ``poses`` frame of ``robots`` captured at ``t`` arrived at ``rx_s``: each robot's
        pose in lockstep, where every node reads the frames (the plant puts each robot's own
        ``pose`` only while someone subscribes to it); ignored in realtime, where an agent's
        pose is its own key's (:meth:`on_pose`)."""
        if self.lockstep:
            for robot in robots:
                self.on_pose(robot, t, rx_s)

    def on_wheels(self, robot: str, msg: Wheels, rx_s: float) -> LatencySample | None:
        """The latency of a wheel command, or None if it used no pose."""
        if msg.pose_t is None:
            return None
        seen = self._pose_rx.get(robot)
        pose_rx = None if seen is None else seen.get(msg.pose_t)
        age = (msg.t - msg.pose_t) if self.lockstep else (rx_s - msg.pose_t)
        return LatencySample(
            robot=robot,
            t=msg.t,
            pose_t=msg.pose_t,
            rx_latency_s=None if pose_rx is None else rx_s - pose_rx,
            pose_age_s=age,
        )
