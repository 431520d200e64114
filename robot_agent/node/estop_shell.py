"""The e-stop hooks an agent and an agent host share with their process shell
(``robot_agent.node.agent_estop``, ``robot_agent.node.host_main``): asking the latched state and
offering
the engagements held (docs/faults.md).

An agent or agent host that holds an e-stop engagement (of any scope: the fleet's, its robots',
another robot's it received) answers queries on ``formation/<fleet>/estop/held/<name>`` with its
engagements (never a release): a coordinator that starts with nothing (restarted alone, without
its ``--estop-state`` file) learns them at start, and an agent that starts then learns them with
its first query, so a robot started while it is e-stopped comes up stopped even when no
coordinator remembers the e-stop.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterable
from typing import TYPE_CHECKING

from bus_schemas import encode_estop_entries
from robot_agent.core.estop import Entry, EstopLatch

__all__ = ["EstopHooks"]


class EstopHooks:
    """:attr:`estop_query` asks the latched state (set by the shell; :meth:`request_estop_state`
    calls it); :attr:`estop_held` answers ``estop/held/<name>`` from now on with the payloads it
    is given (none: nothing held, no queryable); :attr:`witness` is every engagement this
    process saw, any robot's, and what it answers (:meth:`witness_message`,
    :meth:`witness_answer` keep it and offer it on a change)."""

    def _init_estop_hooks(self) -> None:
        self.estop_query: Callable[[], None] | None = None
        self.estop_queried_s = -math.inf
        self.estop_held: Callable[[tuple[bytes, ...]], None] | None = None
        self.witness = EstopLatch()
        """Every scope's engagements seen here (messages and answers, another robot's too, by
        the same rules as a robot's own latch): a robot restarted under its own e-stop learns
        it from the others even when no coordinator remembers it."""
        self._held_offered: list[Entry] = []

    if TYPE_CHECKING:

        def _internal(self, where: str, exc: BaseException) -> None: ...

    def request_estop_state(self, now_s: float) -> None:
        """Ask for the latched e-stop state (through :attr:`estop_query`)."""
        self.estop_queried_s = now_s
        if self.estop_query is not None:
            try:
                self.estop_query()
            except Exception as exc:
                self._internal("estop_query", exc)

    def witness_message(self, engage: bool, robot: str | None, eid: int | None) -> None:
        """An ``estop`` message of any scope (``EstopLatch.apply``); kept only where something
        answers (:attr:`estop_held` set: not for the robots inside an agent host)."""
        if self.estop_held is not None:
            self.witness.apply(engage, robot, eid)
            self._offer_held()

    def witness_answer(self, answers: Iterable[Entry]) -> None:
        """A query's decoded answer, every robot's entries (``EstopLatch.merge_answer``)."""
        if self.estop_held is not None:
            self.witness.merge_answer(answers)
            self._offer_held()

    def _offer_held(self) -> None:
        held = self.witness.engagements()
        if self.estop_held is None or held == self._held_offered:
            return
        self._held_offered = held
        try:
            self.estop_held(encode_estop_entries(held, time.monotonic()))
        except Exception as exc:
            self._internal("estop_held", exc)
