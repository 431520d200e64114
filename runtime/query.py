"""Queries of latched state: a queryable that answers from a snapshot, and a query off the loop.

Used for the e-stop as latched fleet state (``robot_agent.core.estop``): every coordinator answers
queries on ``formation/<fleet>/estop`` with its latched state, every agent holding an engagement
answers on ``formation/<fleet>/estop/held/<name>`` with its engagements, and an agent asks both
when it starts, when it resumes from a stop and periodically (docs/faults.md).

* :class:`Answerer`: a queryable whose callback (a Zenoh thread) replies with the payloads of
  the current snapshot; the loop replaces the snapshot (one reference assignment, so the Zenoh
  thread never sees a half-built answer) and never blocks on Zenoh.
* :class:`Querier`: one ``get`` (:func:`get_all`) run on a worker thread (it blocks until every
  reply came or the timeout), the payloads handed to a callback on the loop: every reply of
  every queryable (no consolidation, target all), an answer being many replies on one key per
  responder. At most one query is in flight per :class:`Querier`; a request while one runs is
  merged into it.
* :class:`LazyAnswerer`: an :class:`Answerer` declared only while it has something to answer.
"""

from __future__ import annotations

import asyncio
import contextlib
import threading
from collections.abc import Callable, Sequence

import zenoh

from runtime.bridge import _post

__all__ = ["Answerer", "LazyAnswerer", "Querier", "get_all", "get_all_now"]


def get_all(
    session: zenoh.Session, key: str, timeout_s: float, max_replies: int = 4096
) -> list[bytes]:
    """The payloads of every reply of every queryable on ``key`` (blocks until all replied or
    the timeout; at most ``max_replies``). Zenoh's default query (target BEST_MATCHING,
    consolidation AUTO = the latest reply per key) kept one reply of one responder, while an
    answer is many replies on the same key from each coordinator: an agent saw only the last
    entry of one coordinator's e-stop state (tests/fleet/test_estop_identity.py)."""
    out: list[bytes] = []
    replies = session.get(
        key,
        target=zenoh.QueryTarget.ALL,
        consolidation=zenoh.ConsolidationMode.NONE,
        timeout=timeout_s,
    )
    for reply in replies:
        ok = reply.ok
        if ok is not None and len(out) < max_replies:
            out.append(ok.payload.to_bytes())
    return out


async def get_all_now(
    loop: asyncio.AbstractEventLoop,
    session: zenoh.Session,
    keys: Sequence[str],
    timeout_s: float,
    on_error: Callable[[BaseException], object],
) -> list[list[bytes]]:
    """:func:`get_all` of every key at once, off the loop; the payloads per key, in order (a
    query that raised is handed to ``on_error`` and answers nothing)."""
    got = await asyncio.gather(
        *(loop.run_in_executor(None, get_all, session, key, timeout_s) for key in keys),
        return_exceptions=True,
    )
    out: list[list[bytes]] = []
    for result in got:
        if isinstance(result, BaseException):
            on_error(result)
            out.append([])
        else:
            out.append(result)
    return out


class Answerer:
    """A queryable on ``key`` answering every query with the payloads of :attr:`snapshot`."""

    def __init__(self, session: zenoh.Session, key: str) -> None:
        self.key = key
        self.snapshot: tuple[bytes, ...] = ()
        self.answered = 0
        self._queryable = session.declare_queryable(key, self._on_query)

    def _on_query(self, query: zenoh.Query) -> None:  # Zenoh thread
        payloads = self.snapshot
        with contextlib.suppress(Exception):  # a closed session at shutdown
            for payload in payloads:
                query.reply(self.key, payload)
            self.answered += 1

    def close(self) -> None:
        with contextlib.suppress(Exception):
            self._queryable.undeclare()


class LazyAnswerer:
    """An :class:`Answerer` on ``key`` declared only while there is something to answer (an
    agent's held e-stop engagements, ``estop/held/<name>``): while it has nothing, no queryable
    exists and queries on the key cost the fleet nothing. :meth:`offer` runs on the loop."""

    def __init__(self, session: zenoh.Session, key: str) -> None:
        self.session = session
        self.key = key
        self.answerer: Answerer | None = None

    def offer(self, payloads: tuple[bytes, ...]) -> None:
        """Answer with ``payloads`` from now on (none: undeclare the queryable)."""
        if payloads:
            if self.answerer is None:
                self.answerer = Answerer(self.session, self.key)
            self.answerer.snapshot = payloads
        elif self.answerer is not None:
            self.answerer.close()
            self.answerer = None

    def close(self) -> None:
        self.offer(())


class Querier:
    """Runs ``get(key)`` off the loop and calls ``on_replies(payloads, token)`` on the loop;
    ``token`` is what :meth:`request` was given (e.g. a message count at the time of asking)."""

    def __init__(
        self,
        session: zenoh.Session,
        loop: asyncio.AbstractEventLoop,
        key: str,
        on_replies: Callable[[Sequence[bytes], int], object],
        *,
        timeout_s: float = 0.5,
        max_replies: int = 4096,
    ) -> None:
        self.session = session
        self.loop = loop
        self.key = key
        self.on_replies = on_replies
        self.timeout_s = timeout_s
        self.max_replies = max_replies
        self.errors = 0
        self._busy = threading.Lock()

    def request(self, token: int = 0) -> bool:
        """Start a query unless one is in flight; returns True if it started."""
        if not self._busy.acquire(blocking=False):
            return False
        try:
            thread = threading.Thread(target=self._run, args=(token,), name="query", daemon=True)
            thread.start()
        except Exception:
            self._busy.release()
            raise
        return True

    def _run(self, token: int) -> None:  # worker thread
        try:
            payloads = get_all(self.session, self.key, self.timeout_s, self.max_replies)
        except Exception:
            self.errors += 1
            payloads = []
        finally:
            self._busy.release()
        _post(self.loop, self.on_replies, payloads, token)
