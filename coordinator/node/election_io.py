"""The coordinator's standby election as handlers: peers' tokens, heartbeats, the active's
leader and assignment, take-over and step-down.

Part of the coordinator's process shell: :class:`ElectionHandlers` is a base of
:class:`coordinator.node.coordinator.CoordinatorNode` (which owns the state; split out of
``coordinator/node/coordinator.py``). The decisions are :mod:`coordinator.core.election`'s; these
handlers decode
the messages, count the rejections and act on the decisions. Handlers never raise.
"""

from __future__ import annotations

import contextlib
import time
from typing import TYPE_CHECKING, Final

import runtime as rt
from bus_schemas import Assignment, DecodeError, Heartbeat, Leader, decode
from coordinator.core.election import Election, Takeover

if TYPE_CHECKING:
    from coordinator.core.coordinator import CoordinatorCore, CoordinatorOutput

__all__ = ["MAX_ROBOTS", "ElectionHandlers"]

MAX_ROBOTS: Final = 4096
"""Distinct robot ids tracked (made-up ids cannot grow memory without bound)."""


class ElectionHandlers:
    """The election's handlers of :class:`~coordinator.node.coordinator.CoordinatorNode` (its state
    is the
    node's, declared here for the type checker)."""

    election: Election
    lockstep: bool
    log: rt.NodeLog
    core: CoordinatorCore
    alive: set[str]
    peer_assignment: dict[str, int]
    rx: dict[str, int]
    t0_s: float | None
    sim_t: float

    if TYPE_CHECKING:

        def _now(self) -> float: ...

        def _reject(self, what: str, why: DecodeError | str, reason: str | None = None) -> None: ...

        def _internal(self, where: str, exc: BaseException) -> None: ...

        def publish_heartbeat(self) -> None: ...

        def tick(self, now_s: float, tick: int | None = None) -> CoordinatorOutput | None: ...

    @property
    def active(self) -> bool:
        """This instance ticks and publishes (the election's decision)."""
        return self.election.active

    @property
    def epoch(self) -> int:
        return self.election.epoch

    def on_peer_alive(self, name: str, alive: bool) -> None:
        """The liveliness token of coordinator instance ``name`` appeared or vanished."""
        if not self.election.peer_alive(name, alive):
            return
        if alive:
            self.log.info(f"coordinator {name} alive")
        else:
            self.log.info(f"coordinator {name} gone")
            if not self.lockstep:
                self.elect(time.monotonic())

    def on_heartbeat(self, rx: rt.Received) -> None:
        """Another instance's heartbeat: its role, epoch and trajectory origin."""
        try:
            msg = decode(rx.payload, Heartbeat)
            if isinstance(msg, DecodeError):
                self._reject("heartbeat", msg)
                return
            # Two actives (a split brain, or two instances started without --standby): the
            # loser stops at once, so the robots get one coordinator's setpoints again within
            # one heartbeat period.
            why = self.election.heartbeat(
                msg.name, msg.active, msg.epoch, msg.leader_t0, now_s=self._now()
            )
            refusal = self.election.last_refusal
            if refusal is not None:
                self._reject("heartbeat", f"from {msg.name}: {refusal}", refusal)
            if why is not None:
                self.step_down(why)
        except Exception as exc:
            self._internal("on_heartbeat", exc)

    def on_leader(self, rx: rt.Received) -> None:
        """The active instance's ``leader``: a standby checks trajectory origins against it
        (coordinator.core.election, spoofed heartbeats)."""
        try:
            if self.active:
                return
            self.rx["leader"] += 1
            msg = decode(rx.payload, Leader)
            if isinstance(msg, DecodeError):
                self._reject("leader", msg)
                return
            if msg.progress_s is not None:  # issue 28: an operator's or a waiting leader is no
                return  # function of t - leader_t0: nothing to check an origin against
            self.election.observe_leader(msg.t, msg.x, msg.y, self._now())
        except Exception as exc:
            self._internal("on_leader", exc)

    def on_assignment(self, rx: rt.Received) -> None:
        """The active instance's assignment: a standby keeps it to seed its hysteresis."""
        try:
            if self.active:
                return
            msg = decode(rx.payload, Assignment)
            if isinstance(msg, DecodeError):
                self._reject("assignment", msg)
                return
            if len(msg.robots) <= MAX_ROBOTS:
                self.peer_assignment = dict(msg.robots)
        except Exception as exc:
            self._internal("on_assignment", exc)

    def elect(self, now_s: float) -> bool:
        """Take over if the election says so at ``now_s``; returns True if it did. Never
        raises."""
        try:
            if not self.election.should_take_over(now_s):
                return False
            self._take_over(now_s, self.election.take_over())
            return True
        except Exception as exc:
            self._internal("elect", exc)
            return False

    def _take_over(self, now_s: float, takeover: Takeover) -> None:
        if takeover.leader_t0 is not None and not self.lockstep:
            # Continue the same trajectory: the virtual leader is a pure function of time and
            # t0 is on the same clock (time.monotonic() of this host, see docs/faults.md).
            self.t0_s = takeover.leader_t0
            self.core.t0_s = takeover.leader_t0
        seed = {rid: slot for rid, slot in self.peer_assignment.items() if rid in self.alive}
        self.core.assigner.seed_incumbent(seed)
        self.core.assignment = dict(seed)
        continued = takeover.leader_t0 is not None
        self.log.info(
            f"active (epoch {takeover.epoch}): took over with the trajectory origin "
            f"{'of the previous instance' if continued else 'at this tick'} and "
            f"{len(seed)} incumbents"
        )
        self.publish_heartbeat()
        if not self.lockstep:
            self.tick(now_s)

    def step_down(self, why: str) -> None:
        """Stop publishing (become a standby); never raises."""
        now = time.monotonic() if not self.lockstep else self.sim_t
        if not self.election.step_down(now):
            return
        self.log.info(f"standby: {why}")
        with contextlib.suppress(Exception):
            self.publish_heartbeat()
