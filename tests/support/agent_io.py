"""Driving one ``formation agent`` from a test (fleet :data:`FLEET`): start it
(:func:`start_agent`), feed it poses and setpoints from a thread (:class:`Feeder`,
:func:`setpoint_msg`), read its wheels (:func:`nonzero`)."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Any

import runtime as rt
from bus_schemas import Pose, Setpoint, Wheels, encode, keys
from support.routers import RouterHandle
from support.spawn import Spawner

FLEET = "demo"


class Feeder:
    """Publishes the agent's inputs every ``period_s`` from a thread: pose (t = monotonic) and
    setpoint (t = monotonic) built by callables, until stopped."""

    def __init__(
        self,
        pubs: rt.Publishers,
        robot: str,
        pose: Callable[[], tuple[float, float, float]] | None,
        setpoint: Callable[[], tuple[float, float]] | None,
        period_s: float = 0.02,
    ) -> None:
        self.pubs = pubs
        self.robot = robot
        self.pose = pose
        self.setpoint = setpoint
        self.period_s = period_s
        self.sent_pose_t: list[float] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def __enter__(self) -> Feeder:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(2.0)

    def _run(self) -> None:
        seq = 0
        while not self._stop.is_set():
            seq += 1
            now = time.monotonic()
            if self.setpoint is not None:
                x, y = self.setpoint()
                self.pubs.put(
                    keys.setpoint_key(FLEET, self.robot),
                    encode(setpoint_msg(self.robot, x, y, t=now, seq=seq)),
                    rt.QOS_CRITICAL,
                )
            if self.pose is not None:
                px, py, pth = self.pose()
                t = time.monotonic()
                self.pubs.put(
                    keys.pose_key(FLEET, self.robot),
                    encode(Pose(t=t, seq=seq, x=px, y=py, theta=pth, robot=self.robot)),
                    rt.QOS_CRITICAL,
                )
                self.sent_pose_t.append(t)
            self._stop.wait(self.period_s)


def setpoint_msg(
    robot: str, x: float, y: float, *, t: float, seq: int = 1, slot: int = 1
) -> Setpoint:
    """A follower setpoint: the reference point should be at (x, y), not moving."""
    return Setpoint(
        t=t,
        seq=seq,
        robot=robot,
        slot=slot,
        role="leader" if slot == 0 else "follower",
        stage=0 if slot == 0 else 1,
        parent=None if slot == 0 else 0,
        x=x,
        y=y,
        theta=0.0,
        vx=0.0,
        vy=0.0,
    )


def nonzero(w: Wheels) -> bool:
    return w.omega_r != 0.0 or w.omega_l != 0.0


def start_agent(spawn: Spawner, router: RouterHandle, *extra: str, robot: str = "r1") -> Any:
    return spawn("agent", "--id", robot, "--endpoint", router.endpoint, *extra, ready="agent")
