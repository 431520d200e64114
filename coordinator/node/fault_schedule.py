"""The scenario's scripted faults, run by the active coordinator (``[[fault]]``,
docs/faults.md "Faults in scenarios").

The coordinator is the one node that knows who leads and whether the fleet is in formation, so
it runs the schedule (:class:`scenario.faults.FaultScheduler`, the same one ``formation sim``
runs) and tells the others with ``fault`` notices (bus_schemas.messages_fault):

* lockstep: after its tick k it asks the scheduler what is due at ``t_{k+1}`` and publishes
  those notices with ``tick: k+1`` *before* its ``leader`` message of tick k. The plant waits for
  that leader before it publishes clock k+1, and the agents receive clock k+1 after it, so every
  node holds the notice when tick k+1 comes and applies it there, as the in-process run applies
  it at the start of tick k+1 (same order of decisions, same inputs: bit for bit).
* realtime: on each tick, with ``t`` the run's time (``now - t0``, the virtual leader's clock),
  notices without ``tick``; ``formation up`` (the launcher) acts on them with real signals.

What the coordinator itself does with a fault: an offline robot (killed, paused, cut off) is left
out of the poses the core counts (its liveliness is gone), and a ``kill_coordinator`` withholds
its setpoints until the hot standby would take over (``takeover_s``), which is the in-process
meaning; in realtime the launcher SIGKILLs the active coordinator instead (a real takeover).

An operator's request (``formation fault ... --at T``: a ``fault`` message with ``request:
true``) is added to the schedule at ``T``; one for a time already past fires at the next tick.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import runtime as rt
from bus_schemas import DecodeError, Fault, Slot, decode, encode, keys
from coordinator.core.coordinator import CoordinatorOutput
from robot_agent.core.lockstep import tick_time
from scenario import Scenario
from scenario.faults import Fault as FaultSpec
from scenario.faults import FaultAction, FaultScheduler, FleetFaults, fleet_view

__all__ = ["FaultNotices", "slot_messages"]

Outgoing = list[tuple[str, bytes, rt.QoS]]
REQUEST_INDEX_BASE = 10_000
"""Operator requests get [[fault]] indices from here (the file's own are below)."""


class FaultNotices:
    """The coordinator's side of the scripted faults (module docstring); Zenoh-free."""

    def __init__(self, scenario: Scenario, fleet: str, *, lockstep: bool) -> None:
        self.scenario = scenario
        self.lockstep = lockstep
        self.key = keys.fault_key(fleet)
        self.scheduler = FaultScheduler(scenario.faults)
        self.state = FleetFaults()
        self.l_m = scenario.agent.geometry.ref_offset_m
        self.tol_m = scenario.settle_tol_m
        self.dt_s = scenario.dt_s
        self.robots = frozenset(scenario.robot_ids)
        self.sent: list[dict[str, Any]] = []
        self.requests = 0
        self.rejected = 0
        # lockstep: the leader's QoS (same priority: the notices keep their order before it)
        self.qos = rt.QOS_CRITICAL if lockstep else rt.QOS_CONTROL

    @property
    def live(self) -> bool:
        """Anything left to fire or undo, or a coordinator counted as killed: the tick must
        consult this object (a run without faults pays one attribute read)."""
        return self.scheduler.active or self.state.coordinator_down_until_s is not None

    # -- inputs --------------------------------------------------------------------------------

    def counted(
        self, poses: Mapping[str, tuple[float, float, float]]
    ) -> dict[str, tuple[float, float, float]]:
        """The poses the core counts: an offline robot's liveliness is gone."""
        off = self.state.offline()
        if not off:
            return dict(poses)
        return {r: q for r, q in poses.items() if r not in off}

    def on_request(self, payload: bytes) -> str | None:
        """An operator's ``fault`` request: scheduled (None) or why it was refused."""
        msg = decode(payload, Fault)
        if isinstance(msg, DecodeError):
            self.rejected += 1
            return f"undecodable: {msg}"
        if not msg.request:
            return None  # a notice (ours, or another coordinator's): not a request
        if msg.robot is not None and msg.robot not in self.robots:
            self.rejected += 1
            return f"robot {msg.robot!r} is not in the scenario"
        robot_kinds = {"kill", "pause", "resume", "cut_link", "restore_link", "camera_loss"}
        if msg.kind in robot_kinds and msg.robot is None and msg.role is None:
            self.rejected += 1
            return f"{msg.kind} needs a robot or a role"
        if msg.kind == "cut_link" and not self.lockstep:
            self.rejected += 1
            return "cut_link has no realtime meaning yet"
        spec = FaultSpec(
            index=REQUEST_INDEX_BASE + self.requests,
            kind=msg.kind,
            robot=msg.robot if msg.role is None else None,
            role=msg.role,
            t_s=max(msg.t, 0.0),
            duration_s=msg.duration_s
            if msg.kind in ("pause", "cut_link", "estop", "camera_loss")
            else None,
        )
        self.requests += 1
        self.scheduler.add(spec)
        return None

    # -- the tick ------------------------------------------------------------------------------

    def setpoints_withheld(self, run_t_s: float) -> bool:
        """The coordinator counts as killed (no setpoints) at run time ``run_t_s``."""
        return self.lockstep and self.state.coordinator_down(run_t_s)

    def after_tick(
        self,
        out: CoordinatorOutput,
        counted: Mapping[str, tuple[float, float, float]],
        run_t_s: float,
        tick: int | None,
        now_s: float,
    ) -> Outgoing:
        """The notices of the faults due next (lockstep: at tick + 1; realtime: now, at run
        time ``run_t_s``, stamped with the bus clock ``now_s``), applied to this coordinator's
        own state."""
        leader, in_formation = fleet_view(
            out.assignment, out.rows, out.slot_ids, counted, self.l_m, self.tol_m
        )
        if tick is not None:
            t_next, tick_next = tick_time(tick + 1, self.dt_s), tick + 1
            stamp = t_next
        else:
            t_next, tick_next, stamp = run_t_s, None, now_s
        acts = self.scheduler.due(t_next, leader=leader, in_formation=in_formation)
        return [self._notice(a, stamp, tick_next) for a in acts]

    def _notice(self, act: FaultAction, t_s: float, tick: int | None) -> tuple[str, bytes, rt.QoS]:
        self.state.apply(act)
        self.sent.append({**act.as_dict(), "tick": tick})
        msg = Fault(
            t=max(t_s, 0.0),
            tick=tick,
            fault=act.fault if act.fault < 65536 else None,
            kind=act.kind,
            robot=act.robot,
            duration_s=act.duration_s if act.duration_s is not None and math.isfinite(
                act.duration_s
            ) else None,
            undo=True if act.undo else None,
        )  # fmt: skip
        return (self.key, encode(msg), self.qos)

    def pending(self) -> list[dict[str, Any]]:
        """The faults that never fired (the end-of-run report)."""
        return self.scheduler.pending()


def slot_messages(outputs: Any, out: CoordinatorOutput, now_s: float, tick: int | None) -> Outgoing:
    """Every slot of ``out`` as ``slot/<k>`` messages (``outputs``: the node's TickOutputs, for
    the sequence numbers and QoS): what a ``--batch`` coordinator that withholds its setpoints
    (a scripted kill_coordinator) still publishes, so a recorder knows where the slots were."""
    msgs: Outgoing = []
    t = max(now_s, 0.0)
    for s in out.slots:
        key = keys.slot_key(outputs.fleet, s.slot)
        msg = Slot(
            t=t,
            seq=outputs.next_seq(key),
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
        msgs.append((key, encode(msg), outputs.data_qos))
    return msgs
