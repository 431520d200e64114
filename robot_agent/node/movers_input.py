"""The coordinator's moving obstacles as one agent (or agent host) receives them (issue 30).

Part of the agent's process shell: decodes ``formation/<fleet>/movers``
(:class:`bus_schemas.Movers`) and keeps what the firmware's neighbour list needs, by the rule 4
of :mod:`robot_agent.core.neighbours`: in lockstep the message computed on tick ``k - 1`` at
clock ``k`` (as the setpoints, so a run over Zenoh equals the in-process simulator, which uses
``CoordinatorOutput.movers`` of the previous tick); in realtime the latest one received within
:data:`~robot_agent.core.neighbours.MOVERS_STALE_S`. A message that does not decode, or a
lockstep one without a tick, is rejected and counted (``reject``).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping

from bus_schemas import DecodeError, Movers, decode
from robot_agent.core.lockstep import SetpointWindow
from robot_agent.core.neighbours import MOVERS_STALE_S

__all__ = ["MoversInput", "Velocities"]

Velocities = Mapping[str, tuple[float, float]]
"""Mover id -> its velocity ``(vx, vy)`` (m/s)."""

_NONE: Velocities = {}


class MoversInput:
    """The latest movers report (realtime) or the last few by tick (lockstep).

    Args:
        lockstep: choose by clock tick (else by receive time).
        reject: ``reject(topic, why_or_error, reason)`` counts a refused message (the node's
            fault counters).
    """

    __slots__ = ("_latest", "_latest_rx", "_reject", "_window", "lockstep", "received")

    def __init__(self, *, lockstep: bool, reject: Callable[..., None]) -> None:
        self.lockstep = lockstep
        self._reject = reject
        self._window: SetpointWindow[Velocities] = SetpointWindow()
        self._latest: Velocities = _NONE
        self._latest_rx = -math.inf
        self.received = 0
        """Movers messages accepted."""

    def on_payload(self, payload: bytes, rx_s: float) -> None:
        """A ``movers`` message's bytes, received at ``rx_s`` (local clock)."""
        msg = decode(payload, Movers)
        if isinstance(msg, DecodeError):
            self._reject("movers", msg)
            return
        velocities = {rid: (vx, vy) for rid, vx, vy in zip(msg.robots, msg.vx, msg.vy, strict=True)}
        if self.lockstep:
            if msg.tick is None:
                self._reject("movers", "lockstep movers without a tick", "no_tick")
                return
            self._window.add(msg.tick, velocities)
        else:
            self._latest, self._latest_rx = velocities, rx_s
        self.received += 1

    def for_clock(self, k: int) -> Velocities:
        """Lockstep clock ``k``: the movers of tick ``k - 1`` (none if it had none)."""
        got = self._window.for_clock(k)
        return _NONE if got is None else got

    def at(self, now_s: float) -> Velocities:
        """Realtime: the latest movers if received within ``MOVERS_STALE_S`` of ``now_s``."""
        if -MOVERS_STALE_S <= now_s - self._latest_rx <= MOVERS_STALE_S:
            return self._latest
        return _NONE

    def clear(self) -> None:
        """Forget every report (the process resumed from a stop)."""
        self._window.clear()
        self._latest, self._latest_rx = _NONE, -math.inf
