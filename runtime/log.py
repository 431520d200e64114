"""``NodeLog``: the one way a process shell writes to stderr, rate-limited per topic.

A flood of bad input must not turn into a flood of log lines, so :meth:`NodeLog.limited` writes
at most one line per ``min_interval_s`` per topic and counts what it suppressed.
"""

from __future__ import annotations

import contextlib
import sys
import time

__all__ = ["NodeLog"]


class NodeLog:
    """Lines to stderr prefixed with the node's name; at most one line per second per ``topic``
    for :meth:`limited` (a flood of bad input must not turn into a flood of log lines)."""

    def __init__(self, prefix: str, min_interval_s: float = 1.0) -> None:
        self.prefix = prefix
        self._min_interval_s = min_interval_s
        self._last: dict[str, float] = {}
        self._suppressed: dict[str, int] = {}

    def info(self, text: str) -> None:
        """Write one line now."""
        with contextlib.suppress(OSError, ValueError):  # stderr closed: nothing to do
            print(f"{self.prefix}: {text}", file=sys.stderr, flush=True)

    def limited(self, topic: str, text: str) -> None:
        """Write one line unless ``topic`` was logged less than ``min_interval_s`` ago."""
        now = time.monotonic()
        last = self._last.get(topic)
        if last is not None and now - last < self._min_interval_s:
            self._suppressed[topic] = self._suppressed.get(topic, 0) + 1
            return
        self._last[topic] = now
        more = self._suppressed.pop(topic, 0)
        self.info(text + (f" (+{more} similar)" if more else ""))
