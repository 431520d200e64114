"""The agent's status, read and written: the other robots' ``status`` messages as the agent and
the agent host both take them (:class:`PeerStatusInputs`, into their
:class:`~robot_agent.core.neighbour_table.NeighbourTable`) and the safety filter's counters as
``Status`` carries them.

No I/O: the handlers take a received sample; they never raise.
"""

from __future__ import annotations

import math

import runtime as rt
from bus_schemas import DecodeError, Status, StatusBatch, decode, keys
from bus_schemas.spec import POSITION_MAX_M
from robot_agent.core.neighbour_table import NeighbourTable
from robot_agent.core.safety_types import SafetyFilterStatus
from runtime.faults import Internal, Reject

__all__ = ["PeerStatusInputs", "clearance_or_none", "filter_counters", "status_tracking"]


def status_tracking(key: str, payload: bytes) -> tuple[str, bool] | DecodeError | str:
    """A robot's ``status`` on ``key``: ``(robot id, its mode is TRACKING)``, or why it is
    refused (a decode error, or a ``robot`` field that is not the key's id). The one reading of
    a neighbour's status for the agent and the agent host."""
    parsed = keys.parse_robot_key(key)
    msg = decode(payload, Status)
    if isinstance(msg, DecodeError):
        return msg
    if parsed is None or (msg.robot is not None and msg.robot != parsed[1]):
        return f"robot {msg.robot!r} on key {key[:100]!r}"
    return parsed[1], msg.mode == "tracking"


def filter_counters(flt: SafetyFilterStatus) -> dict[str, int]:
    """The safety filter's counters as the status message carries them (``Status.filter``)."""
    return {
        "ticks": flt.ticks,
        "active": flt.active_ticks,
        "violations": flt.violations,
        "infeasible": flt.infeasible,
        "tiebreaks": flt.tiebreaks,
        "tiebreak_active": int(flt.tiebreak_active),
        "rescaled": flt.rescaled,
        "rejected": flt.rejected,
        "constraints": flt.constraints,
    }


def clearance_or_none(h: float) -> float | None:
    """``Status.min_clearance_m``: nil while nothing was in range (inf), clamped to its bounds."""
    if not math.isfinite(h):
        return None
    return max(-2.0 * POSITION_MAX_M, min(2.0 * POSITION_MAX_M, h))


class PeerStatusInputs:
    """Realtime: the other robots' modes from their status messages (an agent's ``status``, an
    agent host's ``StatusBatch``), noted in ``table`` (rule 3 of ``robot_agent.core.neighbours``:
    a fresh status saying TRACKING makes a robot cooperative). The one set of handlers for the
    agent and the agent host.

    Args:
        table: where the modes go (:meth:`NeighbourTable.note_mode`).
        rx: the node's receive counters (``"status"`` is counted here).
        reject: the node's rejection counter (``runtime.faults.Faults.reject``).
        internal: the node's internal-error counter (``runtime.faults.Faults.internal``).
        own_key: an agent host's own status key, whose batches are ignored.
    """

    __slots__ = ("_internal", "_own_key", "_reject", "_rx", "table")

    def __init__(
        self,
        table: NeighbourTable,
        rx: dict[str, int],
        reject: Reject,
        internal: Internal,
        own_key: str | None = None,
    ) -> None:
        self.table = table
        self._rx = rx
        self._reject = reject
        self._internal = internal
        self._own_key = own_key

    def on_status(self, rx: rt.Received) -> None:
        """A robot's status (``formation agent``): its mode, while fresh."""
        try:
            self._rx["status"] += 1
            got = status_tracking(rx.key, rx.payload)
            if not isinstance(got, tuple):
                self._reject("status", got)
                return
            self.table.note_mode(got[0], got[1], rx.rx_s)
        except Exception as exc:
            self._internal("on_status", exc)

    def on_host_status(self, rx: rt.Received) -> None:
        """An agent host's status batch: each robot as its own status (this host's ignored)."""
        try:
            self._rx["status"] += 1
            if rx.key == self._own_key:
                return
            msg = decode(rx.payload, StatusBatch)
            if isinstance(msg, DecodeError):
                self._reject("status", msg)
                return
            note = self.table.note_mode
            for rid, mode in zip(msg.robots, msg.mode, strict=True):
                note(rid, mode == "tracking", rx.rx_s)
        except Exception as exc:
            self._internal("on_host_status", exc)
