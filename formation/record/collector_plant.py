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

from typing import Any

from bus_schemas import PlantStatus

__all__ = ["PlantReports"]


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
