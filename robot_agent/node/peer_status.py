"""The agent's status, read and written: one reading of a neighbour's ``status`` (shared by the
agent and the agent host) and the safety filter's counters as ``Status`` carries them.

Pure (no I/O); split out of robot_agent/node/agent.py, which re-exports ``status_tracking``.
"""

from __future__ import annotations

import math

from bus_schemas import DecodeError, Status, decode, keys
from bus_schemas.spec import POSITION_MAX_M
from robot_agent.core.safety_types import SafetyFilterStatus

__all__ = ["clearance_or_none", "filter_counters", "status_tracking"]


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
