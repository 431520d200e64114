"""The e-stop as latched fleet state: a pure core (stdlib only), shared by agents and coordinators.

An e-stop has a *scope*: the fleet (``robot`` nil) or one robot. Each scope is latched on its own
and released only by a release of the same scope (issue 13 item 4): a release of r1 does not clear
a fleet e-stop for r1, and a fleet release does not clear an e-stop of r2 alone. A robot is
stopped while the fleet scope or its own scope is latched.

Who holds it: every coordinator instance (active and standby) keeps an :class:`EstopLatch` from
the ``estop`` messages it receives and answers queries on the ``estop`` key with
:meth:`EstopLatch.answer` (the durable source); an agent keeps its own latch, queries it when it
starts, when it resumes from a stop and every :data:`ESTOP_REFRESH_S` (realtime), and merges the
answers with :meth:`EstopLatch.merge_answer`. An agent holding an engagement answers too, on its
own key ``estop/held/<name>``, with the :meth:`EstopLatch.engagements` of a witness latch (every
engagement it saw, another robot's too; never a release): an
agent or coordinator that starts with nothing learns there what the robots still obey
(robot_agent.node.estop_shell).

Engagement identity (docs/faults.md): every engage carries a fresh random ``id``
(``bus_schemas.new_estop_id``); a latched scope remembers the ids of the engagements holding it,
and a release remembers the ids it released (a bounded record, :data:`MAX_RELEASED`). A query
answer may always *add* engagements, but it releases a scope an agent holds only if it proves
that it saw *that* engagement released (the agent's id is in the answer's release record): an
answer "nothing latched" from a coordinator that never received the e-stop (partitioned, or
respawned alone after it) no longer releases an e-stopped robot. An engagement without an id
(an older sender) is held until a release message of its scope arrives.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Final

__all__ = [
    "ESTOP_QUERY_TIMEOUT_S",
    "ESTOP_REFRESH_S",
    "MAX_IDS",
    "MAX_LATCHED",
    "MAX_RELEASED",
    "NO_ID",
    "Entry",
    "EstopLatch",
]

MAX_LATCHED: Final = 4096
"""Robots latched at most (made-up ids cannot grow memory; beyond it the fleet scope latches,
the safe side)."""
MAX_IDS: Final = 8
"""Engagement ids remembered per latched scope; one more pins the scope (:data:`NO_ID`): only a
release message clears it then (made-up ids cannot grow memory, the safe side)."""
MAX_RELEASED: Final = 64
"""Released engagements remembered (the whole latch, oldest forgotten first): what an answer
can prove released. A forgotten one only costs liveness (an agent that missed that release
stays stopped until the next release message), never safety."""
NO_ID: Final = 0
"""The id of an engagement without one (an older sender, or a scope pinned past
:data:`MAX_IDS`): never in a release record (ids are >= 1), so no answer releases it."""
ESTOP_REFRESH_S: Final = 1.0
"""Realtime agents re-query the latched state this often (s): a lost e-stop message, or an agent
started before any coordinator, is stopped within this long."""
ESTOP_QUERY_TIMEOUT_S: Final = 0.5
"""Timeout of one query of the latched state (s)."""

Scope = str | None
Entry = tuple[bool, str | None, int | None]
"""One ``Estop`` of an answer as ``(engage, robot, id)``."""


class EstopLatch:
    """Latched e-stops: for each latched scope (None: the fleet) the ids of the engagements
    holding it, and the record of released engagements."""

    __slots__ = ("held", "released")

    def __init__(self) -> None:
        self.held: dict[Scope, set[int]] = {}
        """Latched scope -> ids of the engagements holding it (:data:`NO_ID`: one without)."""
        self.released: dict[tuple[Scope, int], None] = {}
        """``(scope, id)`` of released engagements, oldest first, at most :data:`MAX_RELEASED`."""

    @property
    def fleet(self) -> bool:
        """The fleet scope is latched."""
        return None in self.held

    @property
    def robots(self) -> set[str]:
        """The robots latched on their own."""
        return {r for r in self.held if r is not None}

    def _engage(self, scope: Scope, eid: int) -> bool:
        ids = self.held.get(scope)
        if ids is None:
            if scope is not None and len(self.held) - self.fleet >= MAX_LATCHED:
                scope, eid = None, NO_ID  # cannot remember one more robot: stop them all
                ids = self.held.get(None)
            if ids is None:
                self.held[scope] = {eid}
                return True
        if eid not in ids and len(ids) >= MAX_IDS:
            eid = NO_ID  # pinned: only a release message clears it
        if eid in ids:
            return False
        ids.add(eid)
        return True

    def _record(self, scope: Scope, ids: Iterable[int]) -> None:
        for eid in ids:
            if eid == NO_ID:
                continue
            self.released.pop((scope, eid), None)
            self.released[(scope, eid)] = None
        while len(self.released) > MAX_RELEASED:
            del self.released[next(iter(self.released))]

    def apply(self, engage: bool, robot: str | None, eid: int | None = None) -> bool:
        """An ``estop`` message of scope ``robot`` (None: the fleet) and engagement id ``eid``
        (None: none); True if the latched state changed. A release releases every engagement
        of the scope (and records their ids); its own ``eid`` is not used."""
        if engage:
            key = NO_ID if eid is None else eid
            self.released.pop((robot, key), None)  # engaged again (a copy, a replay): held
            return self._engage(robot, key)
        ids = self.held.pop(robot, None)
        if ids is None:
            return False
        self._record(robot, ids)
        return True

    def stopped(self, robot: str) -> bool:
        """Robot ``robot`` must stand still (its scope or the fleet's is latched)."""
        return None in self.held or robot in self.held

    def engagements(self) -> list[Entry]:
        """Every engagement held, as ``(True, robot, id)``: the fleet scope's first, then each
        latched robot's (an agent's answer on ``estop/held/<name>``: engagements only)."""
        out: list[Entry] = [(True, None, i or None) for i in sorted(self.held.get(None, ()))]
        for robot in sorted(r for r in self.held if r is not None):
            out.extend((True, robot, i or None) for i in sorted(self.held[robot]))
        return out

    def answer(self) -> list[Entry]:
        """The full state as ``(engage, robot, id)`` messages: the fleet scope first (always,
        engaged or not, so an empty answer is told apart from no answer: one entry per
        engagement, or ``(False, None, None)``), then every engagement of every latched robot,
        then the release record as ``(False, scope, id)``, oldest first."""
        out = self.engagements()
        if not self.fleet:
            out.insert(0, (False, None, None))
        out.extend((False, scope, eid) for scope, eid in self.released)
        return out

    def merge_answer(self, answers: Iterable[Entry], *, release: bool = True) -> bool:
        """Merge a query's answer (the union of every responder's :meth:`answer`); True if the
        state changed. Its engagements are added unless it or this latch saw them released;
        ``release`` (an agent): an engagement held here is released if the answer's record has
        it, and only then (never for lack of an engagement in the answer, never one without an
        id); otherwise (a coordinator learning from the others) nothing held is released. The
        answer's release record is merged either way (what a later answer can prove), except
        for engagements still held here. Independent of the order of the entries and of
        ``estop`` messages received meanwhile (an id released once stays released)."""
        engaged: dict[Scope, set[int]] = {}
        proven: dict[tuple[Scope, int], None] = {}  # in the answer's order (oldest first)
        for engage, robot, eid in answers:
            if engage:
                engaged.setdefault(robot, set()).add(NO_ID if eid is None else eid)
            elif eid is not None and eid != NO_ID:
                proven[(robot, eid)] = None
            # (False, scope, None): "not latched" says nothing about any engagement
        changed = False
        if release:
            for scope in list(self.held):
                ids = self.held[scope]
                gone = {i for i in ids if (scope, i) in proven}
                if gone:
                    ids -= gone
                    if not ids:
                        del self.held[scope]
                    self._record(scope, sorted(gone))
                    changed = True
        for scope, ids in engaged.items():
            for eid in sorted(ids):
                if (scope, eid) not in proven and (scope, eid) not in self.released:
                    changed = self._engage(scope, eid) or changed
        for scope, eid in proven:
            if (scope, eid) not in self.released and eid not in self.held.get(scope, ()):
                self._record(scope, (eid,))
        return changed
