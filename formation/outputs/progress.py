"""Progress with an ETA for long runs (``formation sim``, ``formation up``).

On a terminal the line is redrawn in place (``\\r``) at most every :data:`TTY_PERIOD_S`; otherwise
(a pipe, a log, a test) one line is printed every :data:`LINE_PERIOD_S`, so a run shorter than
that prints no progress at all and output-checking tests stay stable. ``--quiet`` passes
``enabled=False``. Progress goes to stderr: stdout keeps the run's results only.
"""

from __future__ import annotations

import math
import sys
import time
from typing import Final, TextIO

__all__ = ["LINE_PERIOD_S", "TTY_PERIOD_S", "Progress", "eta_text"]

TTY_PERIOD_S: Final = 0.5
LINE_PERIOD_S: Final = 10.0


def _clock(s: float) -> str:
    s = max(0.0, s)
    if s < 60:
        return f"{s:.0f} s"
    if s < 3600:
        return f"{int(s // 60)} min {int(s % 60):02d} s"
    return f"{int(s // 3600)} h {int(s % 3600 // 60):02d} min"


def eta_text(done_s: float, total_s: float, rate: float | None) -> str:
    """``"37% of 110 s, ETA 1 min 09 s"``: ``rate`` is run seconds per wall second (None: 1)."""
    if not (math.isfinite(total_s) and total_s > 0):
        return ""
    frac = min(1.0, max(0.0, done_s / total_s))
    text = f"{frac * 100:3.0f}% of {total_s:g} s"
    r = 1.0 if rate is None else rate
    if math.isfinite(r) and r > 0:
        text += f", ETA {_clock((total_s - done_s) / r)}"
    return text


class Progress:
    """Call ``update(done_s, total_s)`` as a run goes; ``close()`` at the end."""

    def __init__(self, label: str, *, enabled: bool = True, stream: TextIO | None = None) -> None:
        self.label = label
        self.stream = stream if stream is not None else sys.stderr
        self.enabled = enabled
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.period = TTY_PERIOD_S if self.tty else LINE_PERIOD_S
        self.start = time.monotonic()
        self.last = self.start
        self.printed = False

    def update(self, done_s: float, total_s: float) -> None:
        if not self.enabled:
            return
        now = time.monotonic()
        if now - self.last < self.period:
            return
        self.last = now
        wall = now - self.start
        rate = done_s / wall if wall > 0 and done_s > 0 else math.nan
        text = f"{self.label}: t {done_s:.1f} s, {eta_text(done_s, total_s, rate)}"
        if math.isfinite(rate):
            text += f" ({rate:.0f}x real time)" if rate >= 10 else f" ({rate:.1f}x real time)"
        if self.tty:
            self.stream.write("\r\x1b[K" + text)
        else:
            self.stream.write(text + "\n")
        self.stream.flush()
        self.printed = True

    def close(self) -> None:
        if self.enabled and self.tty and self.printed:
            self.stream.write("\r\x1b[K")
            self.stream.flush()
