"""The agent host's status messages: one :class:`~bus_schemas.StatusBatch` per chunk of robots.

A process-shell helper of :mod:`robot_agent.node.host` (5 Hz, realtime in pieces: ``HostNode.
publish_status``): each hosted robot's firmware and safety-filter counters and its estimator's
twist (where known), in chunks of :data:`~bus_schemas.BATCH_CHUNK` robots.
"""

from __future__ import annotations

import runtime as rt
from bus_schemas import BATCH_CHUNK, StatusBatch
from robot_agent.core.firmware import Firmware
from robot_agent.core.firmware_types import FirmwareStatus
from robot_agent.core.safety_filter import SafetyFilterStatus
from robot_agent.node.status_twist import estimator_twist

__all__ = ["StatusRow", "status_batches", "status_row"]

StatusRow = tuple[str, FirmwareStatus, SafetyFilterStatus, tuple[float, float] | None]
"""One hosted robot's status: its id, its firmware's and its safety filter's counters, its
estimator's twist ``(v_mps, omega_radps)`` or None (unknown)."""


def status_row(rid: str, firmware: Firmware, now_s: float) -> StatusRow:
    """Robot ``rid``'s row from its firmware at ``now_s`` (the firmware's clock)."""
    return (
        rid,
        firmware.status(),
        firmware.safety_filter.status(),
        estimator_twist(firmware, now_s),
    )


def status_batches(
    rows: list[StatusRow], t: float, seq: int, pid: int, host: str
) -> list[StatusBatch]:
    """The batches of ``rows`` at time ``t``, numbered ``seq + 1``, ``seq + 2``, ..."""
    out: list[StatusBatch] = []
    for i in range(0, len(rows), BATCH_CHUNK):
        chunk = rows[i : i + BATCH_CHUNK]
        sts = [r[1] for r in chunk]
        flts = [r[2] for r in chunk]
        tws = [(r[0], r[3]) for r in chunk if r[3] is not None]
        seq += 1
        out.append(
            StatusBatch(
                t=t,
                seq=seq,
                pid=pid,
                host=host,
                robots=tuple(r[0] for r in chunk),
                mode=tuple(str(s.mode) for s in sts),
                slot=tuple(-1 if s.slot is None else s.slot for s in sts),
                rejected=tuple(s.rejected_count for s in sts),
                ex=tuple(rt.finite_or_none(s.ex) or 0.0 for s in sts),
                ey=tuple(rt.finite_or_none(s.ey) or 0.0 for s in sts),
                filter_active=tuple(f.active_ticks for f in flts),
                filter_violations=tuple(f.violations for f in flts),
                filter_infeasible=tuple(f.infeasible for f in flts),
                filter_tiebreaks=tuple(f.tiebreaks for f in flts),
                twist_robots=tuple(rid for rid, _ in tws) if tws else None,
                v_mps=tuple(tw[0] for _, tw in tws) if tws else None,
                omega_radps=tuple(tw[1] for _, tw in tws) if tws else None,
            )
        )
    return out
