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
"""

from __future__ import annotations

import asyncio
import time
from dataclasses import dataclass, field
from typing import Any, Final

import runtime as rt
from bus_schemas import (
    CoordinatorStatus,
    DecodeError,
    Estop,
    Status,
    StatusBatch,
    decode,
    encode,
    keys,
    new_estop_id,
)

__all__ = ["ACK_WAIT_S", "EstopReport", "send_estop"]

ACK_WAIT_S: Final = 1.0
"""How long acknowledgements are collected (s): five status periods of the agents (5 Hz)."""


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

    @property
    def ok(self) -> bool:
        """An e-stop is confirmed when at least one robot acknowledged it; a release always."""
        return bool(self.acked) or not self.engage

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
        held = sorted(n for n, ok in self.coordinators.items() if ok)
        if self.engage:
            parts.append(
                f"latched by coordinator {', '.join(held)}" if held else "no coordinator holds it"
            )
        return "; ".join(parts)


def _coordinator_latched(
    payload: bytes, engage: bool, robot: str | None
) -> tuple[str, bool] | None:
    """``(name, the coordinator's latched state matches engage)`` from its status, or None."""
    st = decode(payload, CoordinatorStatus)
    if isinstance(st, DecodeError):
        return None
    held = st.estop_fleet if robot is None else robot in st.estop_robots
    return st.name, held == engage


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
            report.coordinators[got[0]] = got[1]

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
    finally:
        for sub in subs:
            sub.undeclare()
    report.other -= report.acked
    return report
