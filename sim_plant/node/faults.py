"""The plant's side of the scripted faults (``fault`` notices of the active coordinator,
coordinator.node.fault_schedule; docs/faults.md "Faults in scenarios").

Lockstep: a notice carries the tick it applies at; the plant keeps it and applies it at the
start of that tick, before the tick's disturbances, as the in-process run does
(formation/sim/simulate.py, step 0): a robot that goes offline (killed, paused, cut off) has its
wheels stopped and is no longer waited for; one that comes back (resumed, link restored) is
waited for again from that tick; a camera loss occludes the robot from that tick for its
duration. Realtime: a camera loss applies on receipt (the launcher does the signals).
A notice for a tick already run (it came late: a bug or a foreign publisher) is applied at
once and counted.
"""

from __future__ import annotations

from typing import Any

from bus_schemas import DecodeError, Fault, decode

PlantNode = Any
"""sim_plant.node.plant.PlantNode (not imported: it owns this object; no import cycle)."""
_Sim = Any
"""sim_plant.node.inputs._Sim: plant, camera, link, monitor of a run."""

__all__ = ["PlantFaults"]

OFFLINE = frozenset({"kill", "pause", "cut_link"})
BACK = frozenset({"resume", "restore_link"})
MAX_PENDING = 4096
"""Notices kept for future ticks at most (more are dropped and counted)."""


class PlantFaults:
    """Notices waiting for their tick and the robots they put offline."""

    def __init__(self) -> None:
        self.pending: list[Fault] = []
        self.offline: set[str] = set()
        self.applied = 0
        self.late = 0
        self._seen: set[tuple[int | None, int | None, str, str | None, bool]] = set()

    def on_fault(self, node: PlantNode, payload: bytes) -> None:
        """A ``fault`` message: a notice is kept for its tick (realtime: applied now)."""
        msg = decode(payload, Fault)
        if isinstance(msg, DecodeError):
            node.faults.reject("fault", msg)
            return
        if msg.request or msg.fault is None:
            return  # an operator's request (the coordinator's), or the record of a tool's act
        if msg.robot is not None and msg.robot not in node.index:
            node.faults.reject("fault", f"robot {msg.robot!r} is not simulated here")
            return
        ident = (msg.tick, msg.fault, msg.kind, msg.robot, bool(msg.undo))
        if ident in self._seen:
            return  # a replayed tick's copy
        self._seen.add(ident)
        if msg.tick is None or not node.lockstep:
            if node.sim is not None:
                self._apply(node, node.sim, msg, node.sim_t)
            return
        if len(self.pending) >= MAX_PENDING:
            node.faults.reject("fault", "too many pending notices")
            return
        self.pending.append(msg)

    def apply_tick(self, node: PlantNode, sim: _Sim, k: int, t_s: float) -> None:
        """Lockstep tick ``k`` at ``t_s``: the notices due, in the order they were sent."""
        if not self.pending:
            return
        due = [m for m in self.pending if m.tick is not None and m.tick <= k]
        if not due:
            return
        self.pending = [m for m in self.pending if m not in due]
        for m in due:
            if m.tick is not None and m.tick < k:
                self.late += 1
                node.log.info(f"tick {k}: fault notice for tick {m.tick} came late: {m}")
            self._apply(node, sim, m, t_s)

    def _apply(self, node: PlantNode, sim: _Sim, m: Fault, t_s: float) -> None:
        self.applied += 1
        rid = m.robot
        node.log.info(f"t={t_s:.3f} s: fault {m.kind} of {rid or 'the fleet'}")
        if rid is None:
            return
        if m.kind == "camera_loss":
            start = t_s
            sim.camera.occlude(node.index[rid], start, start + (m.duration_s or 0.0))
        elif m.kind in OFFLINE and node.lockstep:
            self.offline.add(rid)
            if rid in node.inputs.alive:
                node.inputs.drop_agent(rid)
        elif m.kind in BACK and node.lockstep and rid in self.offline:
            self.offline.discard(rid)
            node.inputs.alive.add(
                rid
            )  # its token never went (in-process meaning): wait for it again
