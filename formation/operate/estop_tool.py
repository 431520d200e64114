"""``formation fault estop|release``: publish an e-stop and report who acknowledged it.

The e-stop is latched fleet state (robot_agent.core.estop, docs/faults.md): the coordinators keep it
and answer agents that start or resume. This tool publishes the operator's ``estop`` message
(twice, 20 ms apart, against a lost sample; an engage carries a fresh engagement id, the same
in both copies, so that only a coordinator that saw it released can release it at an agent
that missed the release: ``Estop.id``), then watches the robots' ``status`` for
``ack_s`` seconds: a robot *acknowledged* an e-stop when a status received after the publish
says mode ``estop``, a release when it says another mode. It also reads the coordinators'
latched state from their status (``CoordinatorStatus.estop_fleet``, ``estop_robots``), so the
report says whether a durable source holds it. ``estop`` with no acknowledging robot is a
failure (the caller exits non-zero); a release reports the robots still stopped (another scope
may hold them).

Durable (issue 30): an e-stop is reported latched only where it survives what the operator
relies on. A coordinator run with ``--estop-state`` must say in its status that the file holds
it (``estop_store`` ``saved`` with the scope latched: the status reads both under one lock);
one that says ``failed`` or ``pending`` to the end of the window is named, with its error, and
the e-stop is reported NOT durable there. Somebody must hold it beyond the robots' own latches:
a coordinator, or an agent that answers it on ``estop/held/<name>`` (queried after the window).
Any of these missing is a failure with the reason on the line (the caller exits non-zero). A
release is a failure when a coordinator still holds the scope after the window (one whose state
file cannot be written refuses releases: its error is named) or cannot save the release.
"""

from __future__ import annotations

import asyncio
import time
from dataclasses import dataclass, field
from typing import Any, Final

import zenoh

import runtime as rt
from bus_schemas import (
    CoordinatorStatus,
    DecodeError,
    Estop,
    Status,
    StatusBatch,
    decode,
    decode_estop_answer,
    encode,
    keys,
    new_estop_id,
)

__all__ = ["ACK_WAIT_S", "EstopReport", "send_estop"]

ACK_WAIT_S: Final = 1.0
"""How long acknowledgements are collected (s): five status periods of the agents (5 Hz)."""
HELD_QUERY_S: Final = 0.5
"""Timeout of the query of ``estop/held/*`` after the window (s)."""


@dataclass
class EstopReport:
    """What ``send_estop`` saw."""

    engage: bool
    robot: str | None
    t: float
    """``time.monotonic()`` of the first publish."""
    id: int | None = None
    """The engagement id sent (an engage), None on a release."""
    acked: set[str] = field(default_factory=set)
    """Robots whose status after the publish agreed (mode estop, or not estop on a release)."""
    other: set[str] = field(default_factory=set)
    """Robots in scope heard after the publish that did not agree (yet)."""
    coordinators: dict[str, bool] = field(default_factory=dict)
    """Coordinator name -> its latched state covers the scope (engage) / released it."""
    stores: dict[str, tuple[str, str | None]] = field(default_factory=dict)
    """Coordinator name -> (``estop_store``, ``estop_store_error``) of its newest status, for
    the coordinators that run with a state file."""
    held_by: set[str] = field(default_factory=set)
    """Agents and agent hosts answering this engagement on ``estop/held/<name>`` (engage)."""

    def problems(self) -> list[str]:
        """What keeps the e-stop (release) from being as durable as the fleet relies on: each a
        short sentence; empty when it is."""
        out: list[str] = []
        if self.engage and not self.acked:
            out.append("no robot acknowledged")
        for name in sorted(self.stores):
            state, error = self.stores[name]
            holds = self.coordinators.get(name, False)
            if state == "saved" and holds:
                continue
            if state == "failed":
                why = f"its state file cannot be written ({error or 'no reason given'})"
            elif state == "pending":
                why = "its state file was still being written at the end of the window"
            else:
                why = "its state file does not hold it yet"
            if self.engage:
                out.append(f"coordinator {name} has NOT saved it: {why}; a power cut loses it")
            elif not holds:
                out.append(f"coordinator {name} has NOT released it: {why}")
            else:
                out.append(f"coordinator {name} has not recorded the release: {why}")
        if not self.engage:
            for name in sorted(self.coordinators):
                if name not in self.stores and not self.coordinators[name]:
                    out.append(f"coordinator {name} still holds it")
        elif self.acked and not any(self.coordinators.values()) and not self.held_by:
            out.append("nobody holds it but the robots' own latches: no coordinator holds it, "
                       "no agent answers it on estop/held")  # fmt: skip
        return out

    @property
    def ok(self) -> bool:
        """An e-stop is confirmed when at least one robot acknowledged it and it is durable
        where the fleet relies on it (:meth:`problems`); a release when no coordinator holds
        it any more and every state file recorded it."""
        return not self.problems()

    def line(self) -> str:
        """The one-line report."""
        what = "engaged" if self.engage else "released"
        scope = self.robot or "the fleet"
        acked = ", ".join(sorted(self.acked)) or "none"
        eid = f" (id {self.id})" if self.id is not None else ""
        parts = [f"estop {what} for {scope}{eid} at t={self.t:.6f}; acknowledged by {acked}"]
        if self.other:
            verb = "not stopped" if self.engage else "still stopped"
            parts.append(f"{verb}: {', '.join(sorted(self.other))}")
        if self.engage:
            held = [
                f"{n} (saved to its state file)" if self.stores.get(n, ("",))[0] == "saved" else n
                for n in sorted(n for n, ok in self.coordinators.items() if ok)
            ]
            parts.append(
                f"latched by coordinator {', '.join(held)}" if held else "no coordinator holds it"
            )
            if self.held_by:
                parts.append(f"held by {', '.join(sorted(self.held_by))} (estop/held)")
        problems = self.problems()
        if problems:
            parts.append(
                ("NOT DURABLE: " if self.engage else "NOT RELEASED: ") + "; ".join(problems)
            )
        return "; ".join(parts)


def _coordinator_latched(
    payload: bytes, engage: bool, robot: str | None
) -> tuple[str, bool, tuple[str, str | None] | None] | None:
    """``(name, the coordinator's latched state matches engage, (estop_store,
    estop_store_error) or None without a state file)`` from its status, or None."""
    st = decode(payload, CoordinatorStatus)
    if isinstance(st, DecodeError):
        return None
    held = st.estop_fleet if robot is None else robot in st.estop_robots
    store = None if st.estop_store is None else (st.estop_store, st.estop_store_error)
    return st.name, held == engage, store


def _held_by(session: Any, fleet: str, robot: str | None, eid: int) -> set[str]:
    """Names answering the engagement ``eid`` of ``robot``'s scope on ``estop/held/*``
    (blocking: run off the loop)."""
    out: set[str] = set()
    replies = session.get(
        keys.estop_held_pattern(fleet),
        target=zenoh.QueryTarget.ALL,
        consolidation=zenoh.ConsolidationMode.NONE,
        timeout=HELD_QUERY_S,
    )
    for reply in replies:
        ok = reply.ok
        if ok is None:
            continue
        entries = decode_estop_answer([ok.payload.to_bytes()], lambda err: None, held=True)
        if (True, robot, eid) in entries:
            out.add(str(ok.key_expr).rsplit("/", 1)[-1])
    return out


async def send_estop(
    session: Any, fleet: str, engage: bool, robot: str | None, ack_s: float = ACK_WAIT_S
) -> EstopReport:
    """Publish the e-stop (or release) of ``robot`` (None: the fleet) and collect the
    acknowledgements for up to ``ack_s`` seconds (module docstring)."""
    loop = asyncio.get_running_loop()
    eid = new_estop_id() if engage else None
    report = EstopReport(engage=engage, robot=robot, t=time.monotonic(), id=eid)
    t_pub = report.t

    def on_status(rx: rt.Received) -> None:
        parsed = keys.parse_robot_key(rx.key)
        if parsed is None or rx.rx_s <= t_pub:
            return
        rid = parsed[1]
        if robot is not None and rid != robot:
            return
        msg = decode(rx.payload, Status)
        if isinstance(msg, DecodeError):
            return
        agrees = (msg.mode == "estop") == engage
        (report.acked if agrees else report.other).add(rid)
        if agrees:
            report.other.discard(rid)

    def on_host_status(rx: rt.Received) -> None:
        """An agent host's batched status: each of its robots acknowledges as its own status
        would (issue 32: an e-stop of a host's robot read "acknowledged by none")."""
        if rx.rx_s <= t_pub:
            return
        msg = decode(rx.payload, StatusBatch)
        if isinstance(msg, DecodeError):
            return
        for rid, mode in zip(msg.robots, msg.mode, strict=True):
            if robot is not None and rid != robot:
                continue
            agrees = (mode == "estop") == engage
            (report.acked if agrees else report.other).add(rid)
            if agrees:
                report.other.discard(rid)

    def on_coordinator(rx: rt.Received) -> None:
        if rx.rx_s <= t_pub:
            return
        got = _coordinator_latched(rx.payload, engage, robot)
        if got is not None:
            name, agrees, store = got
            report.coordinators[name] = agrees
            if store is not None:
                report.stores[name] = store
            else:
                report.stores.pop(name, None)

    subs = [
        rt.subscribe(session, keys.all_status_pattern(fleet), loop, on_status),
        rt.subscribe(session, keys.all_host_status_pattern(fleet), loop, on_host_status),
        rt.subscribe(session, keys.all_coordinator_status_pattern(fleet), loop, on_coordinator),
    ]
    try:
        for _ in range(2):
            msg = Estop(t=time.monotonic(), engage=engage, robot=robot, id=eid)
            session.put(keys.estop_key(fleet), encode(msg))
            await asyncio.sleep(0.02)
        deadline = t_pub + ack_s
        while time.monotonic() < deadline:
            await asyncio.sleep(0.05)
        if eid is not None:
            report.held_by = await loop.run_in_executor(None, _held_by, session, fleet, robot, eid)
    finally:
        for sub in subs:
            sub.undeclare()
    report.other -= report.acked
    return report
