"""The coordinator's run-time plans as a :class:`formation.record.collector.RunCollector` sees
them on the bus (issue 27, deliverable 8): each instance's ``CoordinatorStatus`` carries the
planner's fields (``plan``, ``plan_why``, ``plans``, ``replans``, ``plan_ms``,
``plan_clearance_m``, ``plan_late``; docs/planning.md "What the coordinator reports").
:class:`PlanNotices` owns what they say.

The status is the only place a run-time plan shows on the bus, at 5 Hz, and it does not carry
the plan's path: a recorded plan is an event (``RunLog.replans``) with the time of the first
status that counted it (up to one status period after the switch), the reason the status gave
(the last plan's: when two plans fall between two statuses the earlier one's reason is not
known, and is said so), the compute time of the last plan and no path nor length. The path the
leader then followed is the logged ``leader`` track (the figures draw the replan's mark on it).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Final

from bus_schemas import CoordinatorStatus

__all__ = ["MAX_PLAN_EVENTS", "PlanNotices"]

MAX_PLAN_EVENTS: Final = 10_000
"""Plan events kept at most (a run's plans are a handful; a status that counts absurdly many is
counted, not stored)."""
UNSEEN_REASON: Final = "unknown (between two statuses)"


class PlanNotices:
    """The run-time plans per coordinator instance (by its status's ``name``)."""

    def __init__(self) -> None:
        self._last: dict[str, CoordinatorStatus] = {}  # name -> its newest status with plans
        self._events: list[tuple[float, dict[str, Any]]] = []  # (row key, entry)
        self.dropped = 0
        """Plan events over :data:`MAX_PLAN_EVENTS` (counted, not kept)."""

    def add(self, msg: CoordinatorStatus, row: float) -> bool:
        """One status at row key ``row``; True if it carries the planner's fields. A status
        older than the instance's newest (``seq``; a replay) changes nothing."""
        if msg.plans is None:
            return False
        before = self._last.get(msg.name)
        if before is not None and msg.seq <= before.seq:
            return True
        self._last[msg.name] = msg
        new = msg.plans - ((before.plans or 0) if before is not None else 0)
        if new <= 0:
            return True
        ms = msg.plan_ms
        for k in range(new):
            if len(self._events) >= MAX_PLAN_EVENTS:
                self.dropped += new - k
                break
            last = k == new - 1
            reason = (msg.plan_why or "?") if last else UNSEEN_REASON
            self._events.append((row, {
                "reason": reason if msg.plan != "no_way" or not last else f"no way: {reason}",
                "plan_time_s": None if ms is None or not last else ms / 1e3,
                "length_m": None,
                "coordinator": msg.name,
            }))  # fmt: skip
        return True

    def events(self, key_time: Callable[[float], float]) -> list[dict[str, Any]]:
        """``RunLog.replans``: each plan with ``t_s``, its row key in the log's time base."""
        return [{"t_s": key_time(key), **entry} for key, entry in self._events]

    def counts(self) -> dict[str, Any] | None:
        """The planner's figures over the run (``plan_view.planner_counts``' names): plans and
        replans summed over the instances (a standby that took over counts its own), the
        last plan's compute time and the least planned clearance of the newest status that has
        them; None if no status carried the planner's fields."""
        if not self._last:
            return None
        newest = max(self._last.values(), key=lambda s: s.t)
        return {
            "plans": sum(s.plans or 0 for s in self._last.values()),
            "replans": sum(s.replans or 0 for s in self._last.values()),
            "plan_ms": newest.plan_ms,
            "min_clearance_m": newest.plan_clearance_m,
            "late": sum(s.plan_late or 0 for s in self._last.values()),
            "state": newest.plan,
            "why": newest.plan_why,
        }
