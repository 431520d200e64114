"""The coordinator as the durable source of the latched e-stop state (docs/faults.md).

Part of the coordinator's process shell. Every coordinator instance, active or standby, keeps
the latched scopes (:class:`robot_agent.core.estop.EstopLatch`) from the ``estop`` messages, asks
the
other coordinators for theirs when it starts (a respawned instance must not forget an e-stop)
and answers every query on the ``estop`` key with its state (``EstopLatch.answer``): the fleet
scope first, engaged or not, then one engaged ``Estop`` per engagement of each latched robot
(with its engagement ``id``), then its record of released engagements (``engage`` false, with
the ``id`` released): only such a record releases an agent that holds that engagement; an
answer that merely lacks an engagement (this coordinator never received it: partitioned, or
respawned alone after the e-stop) releases nothing (docs/faults.md).

The ``estop`` messages are applied on Zenoh's network thread, on receipt, not when the event
loop gets to them: queries are answered on that thread too, from the snapshot, so a snapshot
updated by the loop was stale for as long as the loop was late (a starved coordinator). An
agent that had latched an e-stop and then asked (its 1 s refresh) got the old state, "nothing
latched", as the whole truth, and released: seen next to CPU hogs as an e-stopped robot
driving again. Applied on receipt, an answer reflects every ``estop`` message this session
received before the query (through one router: every message the asker had received).
"""

from __future__ import annotations

import asyncio
import threading
from collections.abc import Callable, Iterable
from typing import Any, Protocol

import runtime as rt
from bus_schemas import (
    DecodeError,
    Estop,
    decode,
    decode_estop_answer,
    encode_estop_entries,
    keys,
)
from coordinator.node.estop_store import EstopStore, Loaded, held_fleet_error, read_state
from robot_agent.core.estop import ESTOP_QUERY_TIMEOUT_S, EstopLatch
from runtime.bridge import _post

__all__ = ["EstopSource", "Reject", "attach_estop_source"]


class Reject(Protocol):
    """The node's rejection counter: ``<what>-<reason>`` (a DecodeError's reason, else
    ``reason``, else ``invalid``)."""

    def __call__(self, what: str, why: DecodeError | str, reason: str | None = None) -> None: ...


class EstopSource:
    """The latched state and its answer; handlers never raise.

    ``now``: the node's clock (sim time in lockstep); ``reject(what, why)`` and
    ``internal(where, exc)``: the node's counters. :meth:`on_estop` may run on any thread (the
    latch and the answer change under a lock); once :attr:`loop` is set, the counters and the
    log are called on that loop."""

    def __init__(
        self,
        key: str,
        now: Callable[[], float],
        reject: Reject,
        internal: Callable[[str, BaseException], None],
        log: rt.NodeLog,
    ) -> None:
        self.key = key
        self.latch = EstopLatch()
        self._now = now
        self._reject = reject
        self._internal = internal
        self.log = log
        self.messages = 0
        self.answer: tuple[bytes, ...] = self._payloads()
        self.on_answer: Callable[[tuple[bytes, ...]], None] | None = None
        """Called with the new answer (the shell's queryable), under the lock."""
        self.loop: asyncio.AbstractEventLoop | None = None
        """Where the counters and the log are called (None: on the calling thread)."""
        self.lock = threading.Lock()
        self.store: EstopStore | None = None
        """Where every change is saved (``--estop-state``; coordinator.node.estop_store)."""

    def _on_loop(self, fn: Callable[..., object], *args: Any) -> None:
        if self.loop is None:
            fn(*args)
        else:
            _post(self.loop, fn, *args)

    def _payloads(self) -> tuple[bytes, ...]:
        return encode_estop_entries(self.latch.answer(), self._now())

    def _changed(self) -> None:
        self.answer = self._payloads()
        if self.on_answer is not None:
            self.on_answer(self.answer)
        if self.store is not None:
            self.store.offer(self.answer)

    def on_estop(self, rx: rt.Received) -> None:
        """An operator's ``estop``: latch or release its scope (the fleet's durable state); any
        thread (the shell calls it on Zenoh's network thread, on receipt)."""
        try:
            msg = decode(rx.payload, Estop)
            refused: str | None = None
            with self.lock:
                self.messages += 1
                changed = False
                if not isinstance(msg, DecodeError):
                    refused = self._unrecordable(msg)
                    if refused is None:
                        changed = self.latch.apply(msg.engage, msg.robot, msg.id)
                if changed:
                    self._changed()
            if isinstance(msg, DecodeError):
                self._on_loop(self._reject, "estop", msg)
            elif refused is not None:
                self._on_loop(self._reject, "estop", refused, "unrecorded")
                self._on_loop(self.log.info, refused)
            elif changed:
                scope = "fleet" if msg.robot is None else msg.robot
                what = "engaged" if msg.engage else "released"
                eid = f", id {msg.id}" if msg.engage and msg.id is not None else ""
                self._on_loop(self.log.info, f"estop {what} ({scope}{eid})")
        except Exception as exc:
            self._on_loop(self._internal, "on_estop", exc)

    def _unrecordable(self, msg: Estop) -> str | None:
        """Why the release ``msg`` is refused (the state file cannot record it), or None; under
        :attr:`lock`."""
        store = self.store
        if msg.engage or store is None or not store.failing:
            return None
        if msg.robot not in self.latch.held:
            return None  # nothing to release here: nothing to record
        scope = "fleet" if msg.robot is None else msg.robot
        return (
            f"estop release ({scope}) refused: the e-stop state file {store.path} cannot be "
            f"written ({store.error}); the e-stop stays latched here until it can record it"
        )

    def on_state(self, payloads: Iterable[Any], *, held: bool = False) -> None:
        """The other coordinators' latched state (queried at start on ``estop``), or with
        ``held`` the engagements the agents hold (``estop/held/*``, merged last: an engagement
        that a coordinator's or the file's release record names is not taken back): engagements
        and release records are added; nothing held here is released (a coordinator only
        adds)."""
        try:
            answers = decode_estop_answer(
                payloads, lambda err: self._reject("estop_state", err), held=held
            )
            with self.lock:
                before = dict(self.latch.released)
                changed = self.latch.merge_answer(answers, release=False)
                changed = changed or before != self.latch.released
                if changed:
                    self._changed()
            if changed:
                who = "the agents" if held else "the other coordinators"
                self.log.info(f"estop state from {who}: {self.text()}")
        except Exception as exc:
            self._internal("on_estop_state", exc)

    def restore(self, loaded: Loaded, path: object) -> None:
        """The state file read at start (after the other coordinators' answers): its
        engagements and release record are added like another coordinator's answer; a file
        that cannot be trusted latches the fleet scope without an id (only a release message
        clears it) and is counted as a rejection."""
        try:
            if loaded.missing:
                self.log.info(f"estop state file {path}: none yet (first start), nothing held")
                return
            with self.lock:
                if loaded.error is not None:
                    changed = self.latch.apply(True, None, None)
                else:
                    before = dict(self.latch.released)
                    changed = self.latch.merge_answer(loaded.entries, release=False)
                    changed = changed or before != self.latch.released
                if changed:
                    self._changed()
            if loaded.error is not None:
                self._reject("estop_state_file", held_fleet_error(loaded.error))
                self.log.info(
                    f"estop state file {path} cannot be trusted ({loaded.error}): the fleet is "
                    "e-stopped until an operator releases it (formation fault release)"
                )
            else:
                self.log.info(f"estop state restored from {path}: {self.text()}")
        except Exception as exc:
            self._internal("estop_restore", exc)

    def text(self) -> str:
        """The latched scopes, for logs."""
        parts = ["fleet"] if self.latch.fleet else []
        return ", ".join([*parts, *sorted(self.latch.robots)]) or "none"

    def status(self) -> dict[str, Any]:
        """The coordinator status's e-stop fields (``estop_fleet``, ``estop_robots``,
        ``estop_store``, ``estop_store_error``), read together under :attr:`lock`: a status
        saying ``saved`` with an engagement means the file holds that engagement (the store
        was offered every change before the lock was released)."""
        with self.lock:
            store = self.store
            state = None if store is None else store.state()
            return {
                "estop_fleet": self.latch.fleet,
                "estop_robots": tuple(sorted(self.latch.robots)[:64]),
                "estop_store": state,
                "estop_store_error": None if store is None else store.error,
            }


async def attach_estop_source(
    source: EstopSource, io: rt.NodeIO, store: EstopStore | None = None
) -> None:
    """Make ``source`` durable on ``io``: subscribe to ``estop`` (applied on Zenoh's network
    thread, on receipt: the module docstring), learn what the other coordinators hold, then
    what ``store``'s file held (coordinator.node.estop_store; saved on every change from then on),
    then the engagements the agents hold (``estop/held/*``: a coordinator restarted alone
    without its file learns an e-stop the robots still obey), then answer every query on the
    ``estop`` key with the state."""
    from runtime.query import Answerer, get_all_now

    source.loop = io.loop
    io._keep.append(rt.subscribe_on_thread(io.session, source.key, source.on_estop))
    info = keys.parse_key(source.key)
    if info is None or info.leaf != keys.ESTOP:
        raise ValueError(f"not an estop key: {source.key!r}")
    asked = (source.key, keys.estop_held_pattern(info.fleet))
    answers = await get_all_now(
        io.loop,
        io.session,
        asked,
        ESTOP_QUERY_TIMEOUT_S,
        lambda exc: source._internal("estop_query", exc),
    )
    source.on_state(answers[0])
    if store is not None:
        loaded = await io.loop.run_in_executor(None, read_state, store.path, store.fleet)
        source.restore(loaded, store.path)
        with source.lock:
            source.store = store
            store.offer(source.answer)  # the file says what this instance holds from now on
    source.on_state(answers[1], held=True)
    answerer = Answerer(io.session, source.key)

    def update(answer: tuple[bytes, ...]) -> None:
        answerer.snapshot = answer

    with source.lock:
        answerer.snapshot = source.answer
        source.on_answer = update
    io._keep.append(answerer)
