"""The timer loop of an agent process (one robot or an agent host): control watchdog and status.

One loop, shared by ``formation agent`` and ``formation agent-host``: the realtime control tick
(``node.control_timer``, also where systemd's WATCHDOG is sent, since the control loop is what
must be alive), the status publication, and the stall detector's turn marks. The control tick
is a fixed grid of ``period_s`` unless ``control_timer`` returns the time it wants to run next
(an agent host: when its oldest robot falls due, or at once to go on after the loop served
what arrived); a time in the past means "after one turn of the event loop". Likewise
``publish_status`` may return when it wants to go on with a status round it does in pieces (an
agent host); the 5 Hz grid of rounds stays.
"""

from __future__ import annotations

import asyncio
import time
from typing import Final, Protocol

from runtime.sdnotify import Notifier
from runtime.stall import StallDetector

__all__ = ["STATUS_PERIOD_S", "TimedNode", "run_timers"]

STATUS_PERIOD_S: Final = 0.2
"""Status publication period (s): 5 Hz, the contract's minimum rate."""


class TimedNode(Protocol):
    """What :func:`run_timers` drives."""

    period_s: float
    lockstep: bool
    stall: StallDetector

    def check_resume(self, now_s: float) -> bool: ...
    def control_timer(self, now: float) -> float | None: ...
    def publish_status(self) -> float | None: ...


async def run_timers(node: TimedNode, stop: asyncio.Event, notifier: Notifier | None) -> None:
    """The timers of an agent process until ``stop``: the realtime control/watchdog tick and the
    5 Hz status. Marks each loop turn on ``node.stall`` (hang detection)."""
    period = node.period_s
    wd_period = notifier.watchdog_interval_s() if notifier is not None else None
    now = time.monotonic()
    next_ctrl = now + period
    next_status = now
    status_more: float | None = None  # a status round in pieces: when to go on with it
    next_wd = now
    while not stop.is_set():
        now = time.monotonic()
        node.check_resume(now)
        if now >= next_ctrl:
            want = None if node.lockstep else node.control_timer(now)
            next_ctrl += period
            if next_ctrl <= now:  # fell behind (loop stalled): resynchronise
                next_ctrl = now + period
            if want is not None:  # the node's own schedule (an agent host's watchdog)
                next_ctrl = want
            if notifier is not None and wd_period is not None and now >= next_wd:
                notifier.watchdog()  # the control loop is alive
                next_wd = now + wd_period
        if now >= next_status or (status_more is not None and now >= status_more):
            status_more = node.publish_status()
            if now >= next_status:
                next_status += STATUS_PERIOD_S
                if next_status <= now:
                    next_status = now + STATUS_PERIOD_S
        turned = time.monotonic()
        node.stall.turned(turned)
        wake = min(next_ctrl, next_status)
        if status_more is not None:
            wake = min(wake, status_more)
        await asyncio.sleep(max(0.0, wake - turned))
