"""The simulated plant's own account of a run as a :class:`formation.record.collector.RunCollector`
sees it on the bus: its ``PlantStatus`` (``formation/<fleet>/plant/status``, 5 Hz).
:class:`PlantReports` owns the newest one.

What it is for: a lockstep run equals the in-process simulator only while the plant waited for
every answer of every tick. When a participant is more than the plant's ``--lockstep-timeout``
late (a machine starved for seconds, a hung or stopped node, a flood of forged samples), the
plant goes on with that robot's previous command and counts a timeout; from then on the run is
no longer ``formation sim``'s. The count reaches the run's ``metrics.json`` (``meta.plant``,
``source`` ``"status"``; ``formation up`` puts the plant's own last word over it, the file it
writes as it exits: formation.launch.results.plant_account) and the launcher says it on one
line (docs/runtime.md, "When a lockstep run is not exact")."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from bus_schemas import PlantStatus

__all__ = ["PlantReports", "inexact_line"]


class PlantReports:
    """The plant's newest status (by ``seq``; a plant restarted by the launcher starts its
    ``seq`` again, so a status of a later ``t`` counts as newer too)."""

    def __init__(self) -> None:
        self.newest: PlantStatus | None = None
        self.most_timeouts = 0
        """The largest ``timeouts`` any status said (a respawned plant counts from 0 again)."""

    def add(self, msg: PlantStatus) -> bool:
        """One status; True (it is used). An older one than the newest changes only
        :attr:`most_timeouts`."""
        self.most_timeouts = max(self.most_timeouts, msg.timeouts)
        old = self.newest
        if old is None or msg.seq > old.seq or msg.t > old.t:
            self.newest = msg
        return True

    def summary(self) -> dict[str, Any] | None:
        """``metrics.json``'s ``meta.plant``: the plant's mode, state and last tick, its
        lockstep ``timeouts`` (the most any status said), what it rejected and its internal
        errors; None if no status arrived."""
        st = self.newest
        if st is None:
            return None
        return {
            "mode": st.mode,
            "state": st.state,
            "tick": st.tick,
            "timeouts": self.most_timeouts,
            "rejected": st.rejected,
            "internal_errors": st.internal_errors,
            "source": "status",
        }


def inexact_line(plant: Mapping[str, Any] | None) -> str | None:
    """The one line that says a lockstep run's plant went on without every answer (``plant``:
    ``meta.plant``, :meth:`PlantReports.summary` or the plant's own file), or None when it
    waited for all of them (or nothing is known)."""
    n = 0 if plant is None else int(plant.get("timeouts") or 0)
    if not n:
        return None
    return (
        f"lockstep: the plant went on {n} time{'s' if n != 1 else ''} without every answer "
        "(a node more than the plant's --lockstep-timeout late: a starved machine, a stopped "
        "or hung node, a flood); this run is not formation sim's from then on (logs/plant.log "
        "names the late nodes; a longer --lockstep-timeout waits them out)"
    )
