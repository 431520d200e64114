"""What one coordinator tick publishes: setpoints, slots, assignment and the leader, encoded.

Part of the coordinator's process shell (``coordinator/node/coordinator.py`` owns the state and the
handlers; this module turns a :class:`~coordinator.core.coordinator.CoordinatorOutput` into bus
messages).
Order: lockstep sends slots, setpoints, assignment and the leader LAST (the plant waits for the
leader: everything of tick k is in before it); realtime sends the setpoints first (latency).
``--batch`` sends :class:`~bus_schemas.SetpointBatch` chunks instead of one key per robot and
every ``slot/<k>`` only every :data:`BATCH_SLOT_PERIOD_S` (docs/scale.md): in lockstep all of
them in one tick a period; in realtime spread over the ticks (a few slots per tick, each slot
once a period) rather than a burst of a hundred messages once a second, which held the
coordinator, the router and the launcher for milliseconds next to a pose frame.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from typing import Any, Final

import runtime as rt
from bus_schemas import (
    BATCH_CHUNK,
    Assignment,
    Leader,
    Movers,
    Setpoint,
    SetpointBatch,
    Slot,
    encode,
    keys,
)
from coordinator.core.coordinator import CoordinatorOutput
from coordinator.core.formation import SlotState

__all__ = ["ASSIGNMENT_REPEAT_S", "BATCH_SLOT_PERIOD_S", "Outgoing", "TickOutputs", "describe"]

ASSIGNMENT_REPEAT_S: Final = 1.0
"""The assignment is re-published at least this often (s; sim time in lockstep)."""
BATCH_SLOT_PERIOD_S: Final = 1.0
"""``--batch``: every ``slot/<k>`` is published this often (s) instead of every tick; the
setpoint batches carry the assigned slots' positions every tick (docs/scale.md)."""

Outgoing = list[tuple[str, bytes, rt.QoS]]
"""(key, payload, QoS) in publishing order."""


class TickOutputs:
    """Encodes ticks for fleet ``fleet``; keeps the per-key sequence numbers and the repeat
    timers of the assignment and (``batch``) the slots."""

    def __init__(
        self,
        fleet: str,
        robot_order: Mapping[str, int],
        *,
        lockstep: bool,
        batch: bool,
        log: rt.NodeLog,
    ) -> None:
        self.fleet = fleet
        self.lockstep = lockstep
        self.batch = batch
        self.log = log
        self._order = robot_order
        self._seq: dict[str, int] = {}
        self._last_slots_t = -math.inf
        self._slot_tick_t = -math.inf  # realtime --batch: the previous tick (spread_slots)
        self._slot_credit = 0.0
        self._slot_next = 0
        self._last_assignment_t = -math.inf
        self.leader_key = keys.leader_key(fleet)
        self.assignment_key = keys.assignment_key(fleet)
        self.setpoints_key = keys.setpoints_key(fleet)
        self.movers_key = keys.movers_key(fleet)
        # Lockstep: setpoints and leader are what the plant and the agents wait for, so they
        # must arrive (BLOCK) and keep their order (one priority, the clock's).
        # Slots and assignment too: a lower priority would let the leader overtake them, and a
        # recorder would see tick k's slots after the plant moved on.
        self.sp_qos = rt.QOS_CRITICAL if lockstep else rt.QOS_CONTROL
        self.leader_qos = rt.QOS_CRITICAL if lockstep else rt.QOS_TELEMETRY
        self.data_qos = rt.QOS_CRITICAL if lockstep else rt.QOS_TELEMETRY

    def next_seq(self, key: str) -> int:
        """The next sequence number of ``key`` (1, 2, ...)."""
        n = self._seq.get(key, 0) + 1
        self._seq[key] = n
        return n

    def encode_tick(
        self,
        out: CoordinatorOutput,
        now_s: float,
        tick: int | None,
        t0_s: float,
        leader_extra: Mapping[str, Any] | None = None,
    ) -> Outgoing:
        """The messages of one tick at ``now_s`` (``tick``: the lockstep clock it answers;
        ``t0_s``: the trajectory origin, for the log line of an assignment change;
        ``leader_extra``: the optional fields of the ``leader`` message, issue 28)."""
        t = max(now_s, 0.0)
        fleet = self.fleet
        setpoints = self._setpoint_batches(out, t, tick) if self.batch else []
        by_slot = out.slots_by_id
        approach = out.approach  # newly assigned robots on their way (coordinator.core.coordinator)
        for rid, slot_id in () if self.batch else out.assignment.items():
            s = by_slot[slot_id] if rid not in approach else out.setpoint_for(rid)
            assert s is not None
            key = keys.setpoint_key(fleet, rid)
            sp = Setpoint(
                t=t,
                seq=self.next_seq(key),
                robot=rid,
                slot=s.slot,
                role=s.role,
                stage=s.stage,
                parent=s.parent,
                x=s.x,
                y=s.y,
                theta=s.theta,
                vx=s.vx,
                vy=s.vy,
                tick=tick,
            )
            setpoints.append((key, encode(sp), self.sp_qos))
        slots: Outgoing = []
        for s in self._slots_due(out.slots, now_s):
            key = keys.slot_key(fleet, s.slot)
            msg = Slot(
                t=t,
                seq=self.next_seq(key),
                slot=s.slot,
                role=s.role,
                stage=s.stage,
                parent=s.parent,
                x=s.x,
                y=s.y,
                theta=s.theta,
                vx=s.vx,
                vy=s.vy,
                tick=tick,
            )
            slots.append((key, encode(msg), self.data_qos))
        extra: Outgoing = []
        if out.changed or now_s - self._last_assignment_t >= ASSIGNMENT_REPEAT_S:
            self._last_assignment_t = now_s
            amsg = Assignment(
                t=t,
                seq=self.next_seq(self.assignment_key),
                leader=out.leader_robot,
                robots=dict(out.assignment),
            )
            extra.append((self.assignment_key, encode(amsg), self.data_qos))
            if out.changed:
                self.log.info(f"t={now_s - t0_s:.3f} s: assignment {describe(out.assignment)}")
        ld = out.leader
        leader = Leader(
            t=t,
            seq=self.next_seq(self.leader_key),
            x=ld.x,
            y=ld.y,
            theta=ld.theta,
            v_mps=ld.v_mps,
            omega_radps=ld.omega_radps,
            tick=tick,
            **(leader_extra or {}),
        )
        leader_out = (self.leader_key, encode(leader), self.leader_qos)
        if out.movers:  # the moving obstacles (issue 30), as urgent as the setpoints
            setpoints.append(self._movers(out, t, tick))
        if self.lockstep:  # slots, setpoints, assignment, then the leader LAST
            return [*slots, *setpoints, *extra, leader_out]
        return [*setpoints, leader_out, *slots, *extra]  # realtime: setpoints first (latency)

    def _movers(
        self, out: CoordinatorOutput, t: float, tick: int | None
    ) -> tuple[str, bytes, rt.QoS]:
        """The tick's movers (``CoordinatorOutput.movers``) as one ``Movers`` message."""
        rows = out.movers[:BATCH_CHUNK]  # (more than a batch of bodies at once: the first)
        msg = Movers(
            t=t,
            seq=self.next_seq(self.movers_key),
            robots=tuple(r[0] for r in rows),
            x=tuple(r[1] for r in rows),
            y=tuple(r[2] for r in rows),
            vx=tuple(r[3] for r in rows),
            vy=tuple(r[4] for r in rows),
            tick=tick,
        )
        return self.movers_key, encode(msg), self.sp_qos

    def _slots_due(self, slots: Sequence[SlotState], now_s: float) -> Sequence[SlotState]:
        """The slots this tick publishes on ``slot/<k>``: every slot every tick without
        ``--batch``; with it, lockstep: all of them once every :data:`BATCH_SLOT_PERIOD_S`
        (sim time: a lockstep run's messages do not change); realtime: all of them at the first
        tick, then in turn, as many per tick as the time since the previous tick is a share of
        the period (2 of 100 slots at 50 Hz), so each is published once a period and no tick
        carries a burst."""
        if not self.batch:
            return slots
        if self.lockstep or not math.isfinite(self._slot_tick_t) or not slots:
            if now_s - self._last_slots_t < BATCH_SLOT_PERIOD_S:
                return ()
            self._last_slots_t = self._slot_tick_t = now_s
            return slots
        n = len(slots)
        elapsed = min(max(now_s - self._slot_tick_t, 0.0), BATCH_SLOT_PERIOD_S)
        self._slot_tick_t = now_s
        self._slot_credit = min(self._slot_credit + n * elapsed / BATCH_SLOT_PERIOD_S, n)
        count = int(self._slot_credit + 1e-9)  # 2.0 made of 0.02 s ticks is 1.9999...
        self._slot_credit -= count
        first = self._slot_next % n
        self._slot_next = (first + count) % n
        return [slots[(first + j) % n] for j in range(count)]

    def _setpoint_batches(self, out: CoordinatorOutput, t: float, tick: int | None) -> Outgoing:
        """``--batch``: every assigned robot's setpoint in SetpointBatch chunks (robot order)."""
        by_slot = out.slots_by_id
        order = self._order
        rows = sorted(out.assignment.items(), key=lambda a: (order.get(a[0], 1 << 30), a[0]))
        msgs: Outgoing = []
        theta = out.theta
        approach = out.approach
        for i in range(0, len(rows), BATCH_CHUNK):
            chunk = [
                (rid, (out.setpoint_for(rid) if rid in approach else None) or by_slot[sid])
                for rid, sid in rows[i : i + BATCH_CHUNK]
            ]
            msg = SetpointBatch(
                t=t,
                seq=self.next_seq(self.setpoints_key),
                robots=tuple(r for r, _ in chunk),
                slot=tuple(s.slot for _, s in chunk),
                role=tuple(s.role for _, s in chunk),
                stage=tuple(s.stage for _, s in chunk),
                x=tuple(s.x for _, s in chunk),
                y=tuple(s.y for _, s in chunk),
                theta=theta,
                vx=tuple(s.vx for _, s in chunk),
                vy=tuple(s.vy for _, s in chunk),
                tick=tick,
            )
            msgs.append((self.setpoints_key, encode(msg), self.sp_qos))
        return msgs


def describe(assignment: Mapping[str, int]) -> str:
    """``r1->0 r2->1; leader r1``: an assignment for logs."""
    parts: Iterable[str] = (f"{rid}->{slot}" for rid, slot in sorted(assignment.items()))
    leader = next((rid for rid, slot in assignment.items() if slot == 0), None)
    return f"{' '.join(parts) or '(none)'}; leader {leader or '-'}"
