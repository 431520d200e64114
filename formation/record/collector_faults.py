"""The scripted faults' notices a :class:`formation.record.collector.RunCollector` saw
(``bus_schemas.messages_fault``): each kept once (a replayed tick repeats it), at most
:data:`MAX_FAULTS`; they become ``metrics.json``'s ``faults`` and tell which robots a fault keeps
from answering (the plant does not wait for them either). :class:`FaultNotices` owns them."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Final

from bus_schemas import Fault

__all__ = ["MAX_FAULTS", "FaultNotices"]

MAX_FAULTS: Final = 10_000
"""Fault notices kept at most (a run's scripted faults are a handful)."""


class FaultNotices:
    """Fault notices by row key (a tick in lockstep, bus time in realtime)."""

    def __init__(self) -> None:
        self._faults: list[tuple[float, dict[str, Any]]] = []  # (row key, entry)
        self._ids: set[tuple[Any, ...]] = set()

    def add(self, msg: Fault, row: float) -> bool:
        """Keep a notice at row key ``row``; False for a request (the coordinator's business),
        one seen already, or one over the bound."""
        if msg.request:
            return False
        ident = (msg.tick, msg.fault, msg.kind, msg.robot, bool(msg.undo), msg.t)
        if ident in self._ids or len(self._faults) >= MAX_FAULTS:
            return False
        self._ids.add(ident)
        entry = {
            "fault": msg.fault,
            "kind": msg.kind,
            "robot": msg.robot,
            "undo": bool(msg.undo),
            "tick": msg.tick,
        }
        self._faults.append((row, entry))
        return True

    def events(self, key_time: Callable[[float], float]) -> list[dict[str, Any]]:
        """The faults sent, each with ``t_s``: its row key in the log's time base."""
        return [{**entry, "t_s": key_time(key)} for key, entry in self._faults]

    def offline_at(self, key: float) -> set[str]:
        """The robots a fault keeps from answering at row ``key`` (killed, paused or cut off,
        per the notices received)."""
        off: set[str] = set()
        for at, entry in self._faults:
            if at > key or entry["robot"] is None:
                continue
            if entry["kind"] in ("kill", "pause", "cut_link"):
                off.add(entry["robot"])
            elif entry["kind"] in ("resume", "restore_link") and entry["robot"] in off:
                off.discard(entry["robot"])
        return off
