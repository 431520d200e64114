"""The e-stop as latched fleet state: a pure core (stdlib only), shared by agents and coordinators.

An e-stop has a *scope*: the fleet (``robot`` nil) or one robot. Each scope is latched on its own
and released only by a release of the same scope (issue 13 item 4): a release of r1 does not clear
a fleet e-stop for r1, and a fleet release does not clear an e-stop of r2 alone. A robot is
stopped while the fleet scope or its own scope is latched.

Who holds it: every coordinator instance (active and standby) keeps an :class:`EstopLatch` from
the ``estop`` messages it receives and answers queries on the ``estop`` key with
:meth:`EstopLatch.answer` (the durable source); an agent keeps its own latch, queries it when it
starts, when it resumes from a stop and every :data:`ESTOP_REFRESH_S` (realtime), and merges the
answers with :meth:`EstopLatch.merge_answer`.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Final

__all__ = ["ESTOP_QUERY_TIMEOUT_S", "ESTOP_REFRESH_S", "MAX_LATCHED", "EstopLatch"]

MAX_LATCHED: Final = 4096
"""Robots latched at most (made-up ids cannot grow memory; beyond it the fleet scope latches,
the safe side)."""
ESTOP_REFRESH_S: Final = 1.0
"""Realtime agents re-query the latched state this often (s): a lost e-stop message, or an agent
started before any coordinator, is stopped within this long."""
ESTOP_QUERY_TIMEOUT_S: Final = 0.5
"""Timeout of one query of the latched state (s)."""


class EstopLatch:
    """Latched e-stops: the fleet scope and the set of robots stopped on their own."""

    __slots__ = ("fleet", "robots")

    def __init__(self) -> None:
        self.fleet = False
        self.robots: set[str] = set()

    def apply(self, engage: bool, robot: str | None) -> bool:
        """An ``estop`` message of scope ``robot`` (None: the fleet); True if the state changed."""
        if robot is None:
            changed = self.fleet != engage
            self.fleet = engage
            return changed
        if engage:
            if robot in self.robots:
                return False
            if len(self.robots) >= MAX_LATCHED:
                changed = not self.fleet
                self.fleet = True  # cannot remember one more robot: stop them all
                return changed
            self.robots.add(robot)
            return True
        if robot not in self.robots:
            return False
        self.robots.discard(robot)
        return True

    def stopped(self, robot: str) -> bool:
        """Robot ``robot`` must stand still (its scope or the fleet's is latched)."""
        return self.fleet or robot in self.robots

    def answer(self) -> list[tuple[bool, str | None]]:
        """The full state as ``(engage, robot)`` messages: the fleet scope first (always, engaged
        or not, so an empty answer is told apart from no answer), then every latched robot."""
        return [(self.fleet, None), *((True, r) for r in sorted(self.robots))]

    def merge_answer(self, answers: Iterable[tuple[bool, str | None]], *, replace: bool) -> bool:
        """Merge a query's answer (the union of every responder's :meth:`answer`); True if the
        state changed. ``replace``: no ``estop`` message arrived since the query was sent, so
        the answer is the whole truth (releases missed meanwhile apply too); otherwise only its
        engagements are added (a message newer than the answer must not be undone)."""
        fleet = False
        robots: set[str] = set()
        for engage, robot in answers:
            if not engage:
                continue
            if robot is None:
                fleet = True
            elif len(robots) < MAX_LATCHED:
                robots.add(robot)
            else:
                fleet = True
        before = (self.fleet, frozenset(self.robots))
        if replace:
            self.fleet, self.robots = fleet, robots
        else:
            self.fleet = self.fleet or fleet
            for r in robots:
                self.apply(True, r)
        return before != (self.fleet, frozenset(self.robots))
