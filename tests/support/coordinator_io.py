"""Driving a ``formation coordinator`` from a test: paper-exp2's robots at their start poses
(:data:`SCENARIO`, :data:`START`) published as poses from a thread (:class:`PoseFeeder`) on
fleet :data:`FLEET`."""

from __future__ import annotations

import threading
import time

import runtime as rt
from bus_schemas import Pose, encode, keys
from scenario import load

FLEET = "demo"

SCENARIO = load("paper-exp2")  # r1 ahead at (0.40, 0.02), r2 left-behind, r3 right-behind

START = dict(zip(SCENARIO.robot_ids, SCENARIO.initial, strict=True))


class PoseFeeder:
    """Publishes ``robot/<id>/pose`` for the robots in :attr:`robots` every ``period_s``
    (``t`` = monotonic, or a fixed ``t``), from a thread."""

    def __init__(self, pubs: rt.Publishers, robots: set[str], period_s: float = 0.02) -> None:
        self.pubs = pubs
        self.robots = robots
        self.period_s = period_s
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def __enter__(self) -> PoseFeeder:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(2.0)

    def _run(self) -> None:
        seq = 0
        while not self._stop.is_set():
            seq += 1
            for rid in sorted(self.robots):
                x, y, th = START[rid]
                msg = Pose(t=time.monotonic(), seq=seq, x=x, y=y, theta=th, robot=rid)
                self.pubs.put(keys.pose_key(FLEET, rid), encode(msg), rt.QOS_CRITICAL)
            self._stop.wait(self.period_s)
