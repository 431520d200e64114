"""The e-stop parts an agent and an agent host each own (docs/faults.md): the query of the latched
state (:class:`EstopQuery`) and the witness of every engagement seen (:class:`EstopWitness`).
``robot_agent.node.agent_estop.attach_estop`` connects both to the bus.

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

from bus_schemas import encode_estop_entries
from robot_agent.core.estop import ESTOP_REFRESH_S, Entry, EstopLatch
from runtime.faults import Internal

__all__ = ["EstopQuery", "EstopWitness"]


class EstopQuery:
    """Asks the latched e-stop state: :attr:`ask` (set by ``attach_estop``; None: not on a bus)
    sends both queries, :meth:`request` calls it, :meth:`due` says when to ask again.

    Args:
        internal: the node's internal-error counter (an exception of :attr:`ask`).
    """

    __slots__ = ("_internal", "ask", "asked_s")

    def __init__(self, internal: Internal) -> None:
        self._internal = internal
        self.ask: Callable[[], None] | None = None
        self.asked_s = -math.inf
        """When the state was last asked (this node's clock)."""

    def due(self, now_s: float) -> bool:
        """Realtime: the state was last asked ``ESTOP_REFRESH_S`` or more before ``now_s``."""
        return now_s - self.asked_s >= ESTOP_REFRESH_S

    def request(self, now_s: float) -> None:
        """Ask for the latched e-stop state now (never raises)."""
        self.asked_s = now_s
        if self.ask is not None:
            try:
                self.ask()
            except Exception as exc:
                self._internal("estop_query", exc)


class EstopWitness:
    """Every e-stop engagement this process saw, any robot's (:attr:`latch`, by the same rules as
    a robot's own latch), offered to :attr:`offer` on each change: a robot restarted under its
    own e-stop learns it from the others even when no coordinator remembers it.

    :attr:`offer` (set by ``attach_estop``) answers ``estop/held/<name>`` from then on with the
    payloads it is given (none: nothing held, no queryable). While it is None nothing is kept
    (the robots inside an agent host: the host witnesses for them).

    Args:
        internal: the node's internal-error counter (an exception of :attr:`offer`).
    """

    __slots__ = ("_internal", "_offered", "latch", "offer")

    def __init__(self, internal: Internal) -> None:
        self._internal = internal
        self.offer: Callable[[tuple[bytes, ...]], None] | None = None
        self.latch = EstopLatch()
        self._offered: list[Entry] = []

    def message(self, engage: bool, robot: str | None, eid: int | None) -> None:
        """An ``estop`` message of any scope (``EstopLatch.apply``)."""
        if self.offer is not None:
            self.latch.apply(engage, robot, eid)
            self._offer_held()

    def answer(self, answers: Iterable[Entry]) -> None:
        """A query's decoded answer, every robot's entries (``EstopLatch.merge_answer``)."""
        if self.offer is not None:
            self.latch.merge_answer(answers)
            self._offer_held()

    def _offer_held(self) -> None:
        held = self.latch.engagements()
        if self.offer is None or held == self._offered:
            return
        self._offered = held
        try:
            self.offer(encode_estop_entries(held, time.monotonic()))
        except Exception as exc:
            self._internal("estop_held", exc)
