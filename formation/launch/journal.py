"""What happened to a ``formation up`` run, as it happened: the failures (the run exits 1) and
the events (deaths, respawns, scripted faults: ``metrics.json`` ``meta.events``), each said on
the run's output as it is kept. :class:`RunJournal` is their one owner; every part of the
launcher writes to it."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable
from typing import Any

__all__ = ["RunJournal"]


class RunJournal:
    """The run's failures and events (``say``/``warn``: the run's display)."""

    def __init__(self, say: Callable[[str], None], warn: Callable[[str], None]) -> None:
        self.say = say
        self.warn = warn
        self.failures: list[str] = []
        self.events: list[dict[str, Any]] = []

    def fail(self, text: str) -> None:
        """A failure of the run, warned now."""
        self.failures.append(text)
        self.warn(text)

    def failed_already(self, texts: Iterable[str]) -> None:
        """Failures another part has warned about already."""
        self.failures.extend(texts)

    def event(self, text: str) -> None:
        """An event of the run (not a failure), stamped with this host's monotonic clock."""
        self.events.append({"t": time.monotonic(), "event": text})
        self.say(f"formation up: {text}")
