"""Stall/resume detection of a realtime event loop: a pure core, time passed in.

A process that is stopped (SIGSTOP, a swapped-out VM) and resumed finds its event loop turning
again long after the last turn. Such a gap means two things for a node of this system:

* its liveliness token may have expired meanwhile (others gave its slot or its role away), so an
  active coordinator steps down instead of ticking;
* what it receives first is the backlog queued while it was stopped, stamped with fresh receive
  times on delivery, so an agent drops its inputs for a short quarantine and holds until fresh
  data arrives (a resumed robot must not fight the one that took its slot).

Scheduling delay is not a stop (issue 13 item 7: on a machine at load 50-100 the coordinator's
loop was idle 0.64 s and it stepped down for nothing). A SIGSTOP/SIGCONT pair is told apart by
the SIGCONT itself: with :meth:`StallDetector.watch_sigcont` (every realtime node) a gap counts
as a stop only if a SIGCONT arrived during it, or if it is longer than ``unsignalled_gap_s``
(a stop that sends no SIGCONT, e.g. a suspended VM; default :data:`HANG_GAP_NO_LEASE_S`).

The gap is :data:`HANG_GAP_S` by default. With a Zenoh lease the others only notice a stop
after the whole lease, so :func:`hang_gap_for` uses 0.9 lease (0.1 margin for the lease timer):
a shorter stop cannot have cost the process its token. Lockstep nodes never use this (their
time is the plant's clock, not the wall clock).
"""

from __future__ import annotations

import contextlib
import math
import signal
from dataclasses import dataclass
from types import FrameType
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
    require_continue: bool = False
    """A gap is a stop only with a SIGCONT during it (or longer than ``unsignalled_gap_s``)."""
    unsignalled_gap_s: float = HANG_GAP_NO_LEASE_S
    continued: int = 0
    """SIGCONTs received (:meth:`watch_sigcont`); ``_seen`` is the count at the last turn."""
    _seen: int = 0
    ignored_gaps: int = 0
    """Gaps longer than ``gap_s`` not counted as stops (scheduling delay: no SIGCONT)."""

    def watch_sigcont(self) -> bool:
        """Count SIGCONTs (chaining any previous Python handler) and require one for a stop;
        False (and nothing changes) off the main thread or where signals are unavailable."""
        sigcont = getattr(signal, "SIGCONT", None)
        if sigcont is None:
            return False
        previous = signal.getsignal(sigcont)

        def on_cont(signum: int, frame: FrameType | None) -> None:
            self.continued += 1
            if callable(previous):
                with contextlib.suppress(Exception):
                    previous(signum, frame)

        try:
            signal.signal(sigcont, on_cont)
        except (ValueError, OSError):  # not the main thread
            return False
        self.require_continue = True
        return True

    def note_continue(self) -> None:
        """A SIGCONT arrived (what the handler of :meth:`watch_sigcont` does; for tests)."""
        self.continued += 1

    def turned(self, now_s: float) -> None:
        """The loop completed a turn at ``now_s``."""
        last = self.last_turn_s
        if last is not None and now_s - last > self.gap_s and self._seen == self.continued:
            self.ignored_gaps += 1  # a long turn that was no stop (scheduling delay)
        self.last_turn_s = now_s
        self._seen = self.continued

    def stalled_for(self, now_s: float) -> float | None:
        """Seconds since the last turn if more than ``gap_s`` and it was a stop (module
        docstring), else None (no side effect)."""
        last = self.last_turn_s
        if last is None or now_s - last <= self.gap_s:
            return None
        gap = now_s - last
        if self.require_continue and self.continued == self._seen and gap <= self.unsignalled_gap_s:
            return None  # no SIGCONT: the loop was only late
        return gap

    def resume(self, now_s: float) -> float | None:
        """If the loop was stopped, record the resume at ``now_s``, start the quarantine and
        return how long it was stopped (s); else None."""
        stopped = self.stalled_for(now_s)
        if stopped is None:
            return None
        self.last_turn_s = now_s
        self._seen = self.continued
        self.quarantine_until_s = now_s + self.quarantine_s
        self.resumes += 1
        return stopped

    def quarantined(self, now_s: float) -> bool:
        """Inputs received at ``now_s`` are backlog of a stop (drop them)."""
        return now_s < self.quarantine_until_s
