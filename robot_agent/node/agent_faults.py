"""An agent's side of the scripted faults in lockstep (``fault`` notices of the active
coordinator, coordinator.node.fault_schedule; docs/faults.md "Faults in scenarios").

A notice names the clock tick it applies at; on that clock, before stepping, the agent applies
the notices for its robot (or the fleet's e-stop) with the in-process run's meaning
(formation/sim/simulate.py): ``kill``: the agent dies (``die``: the agent process SIGKILLs
itself; an agent host stops stepping that robot for good); ``pause``: it does not step until
``resume`` (the arrivals are still stamped, as the in-process run keeps receiving); ``cut_link``:
it steps on the pose it had, with no setpoint or neighbour, and publishes nothing until
``restore_link``; ``estop``/``release``: the latch of that scope (fleet or this robot), as an
``estop`` message would. Realtime notices (no tick) are the launcher's business: ignored here.
Stdlib only.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from bus_schemas import DecodeError, Fault, decode

AgentNode = Any
"""robot_agent.node.agent.AgentNode (not imported: it owns this object; no import cycle)."""

__all__ = ["AgentFaults"]

MAX_PENDING = 256
"""Notices kept for future ticks at most (more are dropped and counted)."""


class AgentFaults:
    """Notices waiting for their clock, and what they left (dead, paused, cut off)."""

    def __init__(self, robot_id: str) -> None:
        self.robot_id = robot_id
        self.pending: list[Fault] = []
        self.dead = False
        self.paused = False
        self.cut_off = False
        self.cut_inputs: tuple[Any, float, float | None] | None = None  # frozen at the cut
        self.die: Callable[[], None] | None = None  # the agent process: SIGKILL itself
        self._seen: set[tuple[int | None, int | None, str, str | None, bool]] = set()

    @property
    def busy(self) -> bool:
        """A notice waits, or the robot is not stepping normally."""
        return bool(self.pending) or self.dead or self.paused or self.cut_off

    def on_fault(self, node: AgentNode, payload: bytes) -> None:
        """A ``fault`` message: a lockstep notice for this robot or the fleet is kept."""
        msg = decode(payload, Fault)
        if isinstance(msg, DecodeError):
            node.faults.reject("fault", msg)
            return
        if msg.request or msg.tick is None or not node.lockstep:
            return  # an operator's request (the coordinator's) or a realtime notice
        if msg.robot is not None and msg.robot != self.robot_id:
            return
        ident = (msg.tick, msg.fault, msg.kind, msg.robot, bool(msg.undo))
        if ident in self._seen:
            return  # a replayed tick's copy
        if len(self.pending) >= MAX_PENDING:
            node.faults.reject("fault", "too many pending notices", "overflow")
            return
        self._seen.add(ident)
        self.pending.append(msg)

    def at_clock(self, node: AgentNode, k: int, t_k: float) -> bool:
        """Clock ``k``: apply the notices due; True when the robot steps as usual."""
        due = [m for m in self.pending if m.tick is not None and m.tick <= k]
        if due:
            self.pending = [m for m in self.pending if m not in due]
            for m in due:
                self._apply(node, m, t_k)
        if self.dead:
            return False
        if self.paused:
            node.take_arrivals(t_k)
            return False
        if self.cut_off:
            node.take_arrivals(t_k)
            if self.cut_inputs is None:  # the pose it has when cut off
                self.cut_inputs = (node.pose, node.pose_rx_s, node.pose_capture_s)
            pose, rx, cap = self.cut_inputs
            node.firmware.step(
                t_k,
                pose=pose,
                pose_rx_s=rx,
                setpoint=None,
                setpoint_rx_s=t_k,
                neighbours=[],
                pose_capture_s=cap,
                wheel_speeds=None,
            )
            return False
        return True

    def _apply(self, node: AgentNode, m: Fault, t_k: float) -> None:
        node.log.info(f"t={t_k:.3f} s: scripted fault {m.kind} of {m.robot or 'the fleet'}")
        kind = m.kind
        if kind == "kill":
            self.dead = True
            if self.die is not None:
                self.die()
        elif kind == "pause":
            self.paused = True
        elif kind == "resume":
            self.paused = False
        elif kind == "cut_link":
            self.cut_off = True
        elif kind == "restore_link":
            self.cut_off = False
            self.cut_inputs = None
        elif kind in ("estop", "release"):
            node.estop.apply(kind == "estop", m.robot, None)
            node.sync_estop("scripted fault")
