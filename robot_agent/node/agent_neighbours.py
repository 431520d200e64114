"""The agent's neighbours: the other robots' poses (batched frames) kept for repulsion and the
safety filter, and which of them are cooperative (``robot_agent.core.neighbours`` rule 3: relayed by
the lockstep clock, or a fresh status saying TRACKING in realtime).

Part of the agent's process shell: :class:`NodeNeighbours` is a base of
:class:`robot_agent.node.agent.AgentNode` (which owns the state; split out of
``robot_agent/node/agent.py``,
which re-exports :data:`MAX_NEIGHBOURS`). Handlers never raise.
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING, Any, Final

import runtime as rt
from bus_schemas import DecodeError, PoseBatch, StatusBatch, decode
from robot_agent.core.clocksync import ClockOffsets
from robot_agent.core.lockstep import Arrivals
from robot_agent.core.neighbours import NEIGHBOUR_STALE_S, is_cooperative, is_current, neighbour
from robot_agent.core.safety_filter import Neighbour
from robot_agent.node.peer_status import status_tracking

__all__ = ["MAX_NEIGHBOURS", "NodeNeighbours"]

MAX_NEIGHBOURS: Final = 1024
"""Distinct neighbour ids kept (a flood of made-up ids cannot grow memory without bound)."""


class NodeNeighbours:
    """The neighbour handlers of :class:`~robot_agent.node.agent.AgentNode` (its state is the
    agent's, declared here for the type checker)."""

    robot_id: str
    lockstep: bool
    sim_t: float
    rx: dict[str, int]
    clocks: ClockOffsets
    tracking_ids: frozenset[str]
    _neighbours: dict[str, list[Any]]
    _pending_neighbours: Arrivals[str]
    _status_modes: dict[str, list[Any]]

    if TYPE_CHECKING:

        def _reject(self, what: str, why: DecodeError | str, reason: str | None = None) -> None: ...

        def _internal(self, where: str, exc: BaseException) -> None: ...

    def on_poses(self, rx: rt.Received) -> None:
        """Batched poses: the other robots' poses and capture times, for repulsion and the
        safety filter (``robot_agent.core.neighbours``)."""
        try:
            self.rx["poses"] += 1
            msg = decode(rx.payload, PoseBatch)
            if isinstance(msg, DecodeError):
                self._reject("poses", msg)
                return
            me = self.robot_id
            nb = self._neighbours
            rx_s: float | None = None if self.lockstep else rx.rx_s
            if self.lockstep:
                cap = msg.stamp
            else:
                cap = self.clocks.capture_to_local(rx.key, msg.t, msg.stamp, rx.rx_s)
            for rid, x, y, th in zip(msg.robots, msg.x, msg.y, msg.theta, strict=True):
                if rid == me:
                    continue
                entry = nb.get(rid)
                if entry is None:
                    if len(nb) >= MAX_NEIGHBOURS:
                        self._prune_neighbours()
                        if len(nb) >= MAX_NEIGHBOURS:
                            continue
                    nb[rid] = [x, y, th, cap, rx_s]
                else:
                    entry[0] = x
                    entry[1] = y
                    entry[2] = th
                    entry[3] = cap
                    entry[4] = rx_s
                if rx_s is None:
                    self._pending_neighbours.add(rid)
            if len(self._pending_neighbours) > 4 * MAX_NEIGHBOURS:  # no clock for ages
                self._pending_neighbours.compact()
        except Exception as exc:
            self._internal("on_poses", exc)

    def on_status(self, rx: rt.Received) -> None:
        """Realtime: another robot's status; its mode makes it cooperative while fresh."""
        try:
            self.rx["status"] += 1
            got = status_tracking(rx.key, rx.payload)
            if not isinstance(got, tuple):
                self._reject("status", got)
                return
            self.note_mode(got[0], got[1], rx.rx_s)
        except Exception as exc:
            self._internal("on_status", exc)

    def on_host_status(self, rx: rt.Received) -> None:
        """Realtime: an agent host's status batch (each robot as its own status)."""
        try:
            self.rx["status"] += 1
            msg = decode(rx.payload, StatusBatch)
            if isinstance(msg, DecodeError):
                self._reject("status", msg)
                return
            for rid, mode in zip(msg.robots, msg.mode, strict=True):
                self.note_mode(rid, mode == "tracking", rx.rx_s)
        except Exception as exc:
            self._internal("on_host_status", exc)

    def note_mode(self, rid: str, tracking: bool, rx_s: float) -> None:
        """Realtime: robot ``rid`` said (``tracking``) at local time ``rx_s``."""
        if rid == self.robot_id:
            return
        modes = self._status_modes
        entry = modes.get(rid)
        if entry is None:
            if len(modes) >= MAX_NEIGHBOURS:
                for old in [r for r, (_, t) in modes.items() if rx_s - t > NEIGHBOUR_STALE_S]:
                    del modes[old]
                if len(modes) >= MAX_NEIGHBOURS:
                    return
            modes[rid] = [tracking, rx_s]
        else:
            entry[0] = tracking
            entry[1] = rx_s

    def cooperative(self, rid: str, now_s: float) -> bool:
        """Whether neighbour ``rid`` counts as cooperative at ``now_s`` (rule 3 of
        ``robot_agent.core.neighbours``): relayed by the clock (lockstep) or a fresh status."""
        if self.lockstep:
            return rid in self.tracking_ids
        entry = self._status_modes.get(rid)
        return entry is not None and is_cooperative(now_s, entry[0], entry[1])

    def _prune_neighbours(self) -> None:
        now = self.sim_t if self.lockstep else time.monotonic()
        stale = [
            rid
            for rid, e in self._neighbours.items()
            if e[4] is not None and now - e[4] > NEIGHBOUR_STALE_S
        ]
        for rid in stale:
            del self._neighbours[rid]

    def neighbours(self, now_s: float) -> list[Neighbour]:
        """The other robots whose poses were received within :data:`NEIGHBOUR_STALE_S` of
        ``now_s``, as the safety filter sees them (``robot_agent.core.neighbours``)."""
        coop = self.cooperative
        return [
            neighbour(x, y, th, cap, now_s, coop(rid, now_s))
            for rid, (x, y, th, cap, rx_s) in self._neighbours.items()
            if rx_s is not None and is_current(now_s, rx_s)
        ]
