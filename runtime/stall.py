"""Stall/resume detection of a realtime event loop: a pure core, time passed in.

A process that is stopped (SIGSTOP, a swapped-out VM) and resumed finds its event loop turning
again long after the last turn. Such a gap means two things for a node of this system:

* its liveliness token may have expired meanwhile (others gave its slot or its role away), so an
  active coordinator steps down instead of ticking;
* what it receives first is the backlog queued while it was stopped, stamped with fresh receive
  times on delivery, so an agent drops its inputs for a short quarantine and holds until fresh
  data arrives (a resumed robot must not fight the one that took its slot).

The gap is :data:`HANG_GAP_S` by default. With a Zenoh lease the others only notice a stop
after the whole lease, so :func:`hang_gap_for` uses 0.9 lease (0.1 margin for the lease timer):
a shorter stop cannot have cost the process its token. Lockstep nodes never use this (their
time is the plant's clock, not the wall clock).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Final

__all__ = [
    "HANG_GAP_MIN_S",
    "HANG_GAP_NO_LEASE_S",
    "HANG_GAP_S",
    "RESUME_QUARANTINE_S",
    "StallDetector",
    "hang_gap_for",
]

HANG_GAP_S: Final = 0.5
"""An event loop idle for longer than this (s) was stopped. Loops turn at least every control
period (20 ms at 50 Hz); 0.5 s leaves room for scheduling delay on a loaded 2-core machine."""
HANG_GAP_MIN_S: Final = 0.3
"""Lower bound of the gap derived from a short lease (s)."""
HANG_GAP_NO_LEASE_S: Final = 5.0
"""The gap for a role that matters only once the lease expired, when no lease is configured
(Zenoh's default lease is 10 s): an active coordinator."""
RESUME_QUARANTINE_S: Final = 0.25
"""After a stop, inputs received during this long (s) are dropped as backlog."""


def hang_gap_for(lease_ms: int | None, default_s: float = HANG_GAP_S) -> float:
    """The hang gap (s) of a process whose session announces ``lease_ms`` (None: ``default_s``)."""
    if lease_ms is None:
        return default_s
    return max(HANG_GAP_MIN_S, 0.9 * lease_ms / 1000.0)


@dataclass
class StallDetector:
    """Detects that the loop of this process was stopped, and the quarantine that follows.

    Call :meth:`turned` at the end of every loop turn; :meth:`stalled_for` tells how long the
    loop has been idle if that is longer than ``gap_s``; :meth:`resume` records a resume (and
    starts the quarantine) when the gap is exceeded; :meth:`quarantined` says whether inputs
    received at ``now_s`` are still backlog. All times are one host's monotonic clock, in s.
    """

    gap_s: float = HANG_GAP_S
    quarantine_s: float = RESUME_QUARANTINE_S
    last_turn_s: float | None = None
    quarantine_until_s: float = -math.inf
    resumes: int = 0

    def turned(self, now_s: float) -> None:
        """The loop completed a turn at ``now_s``."""
        self.last_turn_s = now_s

    def stalled_for(self, now_s: float) -> float | None:
        """Seconds since the last turn if more than ``gap_s``, else None (no side effect)."""
        last = self.last_turn_s
        if last is not None and now_s - last > self.gap_s:
            return now_s - last
        return None

    def resume(self, now_s: float) -> float | None:
        """If the loop was stopped, record the resume at ``now_s``, start the quarantine and
        return how long it was stopped (s); else None."""
        stopped = self.stalled_for(now_s)
        if stopped is None:
            return None
        self.last_turn_s = now_s
        self.quarantine_until_s = now_s + self.quarantine_s
        self.resumes += 1
        return stopped

    def quarantined(self, now_s: float) -> bool:
        """Inputs received at ``now_s`` are backlog of a stop (drop them)."""
        return now_s < self.quarantine_until_s
