"""The cyclic garbage collector paused over the in-process simulator's loop.

CPython frees almost every object of the loop by reference counting the moment it is dropped;
the cyclic collector only looks for reference cycles. Left automatic, it runs every few hundred
allocations of container objects and walks the objects that survived: the run's growing log
(tens of thousands of tuples and commands at 30 robots) again at each of its middle-generation
collections and, at its full collections, every object the process holds (the imports' too).
That is work whose result is not used: the loop makes (almost) no cycles (a 60 s, 30-robot run
leaves none). Measured on that run: about 14 % of its process CPU (docs/benchmarks.md).

:class:`CollectorPause` turns the automatic runs off for the loop and back on (only if they were
on: a caller who had turned them off keeps them off), and :meth:`CollectorPause.collect_young`,
called every :data:`YOUNG_EVERY_TICKS` ticks, collects the youngest generation: a cycle made and
dropped since the previous call is freed then, so a long run cannot grow on cycles while paused,
and each object that survives is walked once more, not at every full collection. Which objects
are freed, and when, changes no result of the run (nothing in the loop reads the collector).

The switch is the process's (``gc.disable``): another thread's allocations in the same process
are not collected automatically while a run is in progress either (their cycles wait until the
run ends; reference counting still frees the rest).
"""

from __future__ import annotations

import gc

__all__ = ["YOUNG_EVERY_TICKS", "CollectorPause"]

YOUNG_EVERY_TICKS = 500
"""How often (ticks) the loop collects the youngest generation while the collector is paused."""


class CollectorPause:
    """Pauses the automatic cyclic collection from construction until :meth:`resume`."""

    __slots__ = ("_was_enabled",)

    def __init__(self) -> None:
        self._was_enabled = gc.isenabled()
        gc.disable()

    def collect_young(self) -> int:
        """Collect the youngest generation now; the number of unreachable objects found."""
        return gc.collect(0)

    def resume(self) -> None:
        """Turn automatic collection back on if it was on at construction (idempotent)."""
        if self._was_enabled:
            gc.enable()
