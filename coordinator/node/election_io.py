"""The coordinator's standby election on the bus: peers' tokens, heartbeats, the active's leader
and assignment, take-over and step-down.

:class:`ElectionIO` is a part the coordinator (:class:`coordinator.node.coordinator.
CoordinatorNode`) builds and owns. The decisions are :mod:`coordinator.core.election`'s; this part
decodes the messages, counts the rejections and acts on the decisions through the callables it is
given (publish a heartbeat; take over: the node seeds its core and ticks). Handlers never raise.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable
from typing import Final

import runtime as rt
from bus_schemas import Assignment, DecodeError, Heartbeat, Leader, decode
from coordinator.core.election import Election, Takeover

__all__ = ["MAX_ROBOTS", "ElectionIO"]

MAX_ROBOTS: Final = 4096
"""Distinct robot ids tracked (made-up ids cannot grow memory without bound)."""


class ElectionIO:
    """The election's handlers of a coordinator.

    Args:
        election: the decisions (``coordinator.core.election``).
        lockstep: no take-over on a vanished token (the plant's clock drives the run).
        faults: the node's counters (rejected heartbeats, leaders, assignments).
        rx: the node's receive counters (``"leader"`` is counted here).
        now: the node's clock (sim time in lockstep, ``time.monotonic()`` in realtime).
        publish_heartbeat: publish this instance's heartbeat now (never raises).
        take_over: the node takes over at ``now_s`` with :attr:`peer_assignment` to seed from.
    """

    def __init__(
        self,
        election: Election,
        *,
        lockstep: bool,
        faults: rt.Faults,
        rx: dict[str, int],
        now: Callable[[], float],
        publish_heartbeat: Callable[[], None],
        take_over: Callable[[float, Takeover], None],
    ) -> None:
        self.election = election
        self.lockstep = lockstep
        self._faults = faults
        self._log = faults.log
        self._rx = rx
        self._now = now
        self._publish_heartbeat = publish_heartbeat
        self._take_over = take_over
        self.peer_assignment: dict[str, int] = {}
        """The last assignment seen on the bus (a standby seeds its hysteresis with it)."""

    @property
    def active(self) -> bool:
        """This instance ticks and publishes (the election's decision)."""
        return self.election.active

    def on_peer_alive(self, name: str, alive: bool) -> None:
        """The liveliness token of coordinator instance ``name`` appeared or vanished."""
        if not self.election.peer_alive(name, alive):
            return
        if alive:
            self._log.info(f"coordinator {name} alive")
        else:
            self._log.info(f"coordinator {name} gone")
            if not self.lockstep:
                self.elect(self._now())

    def on_heartbeat(self, rx: rt.Received) -> None:
        """Another instance's heartbeat: its role, epoch and trajectory origin."""
        try:
            msg = decode(rx.payload, Heartbeat)
            if isinstance(msg, DecodeError):
                self._faults.reject("heartbeat", msg)
                return
            # Two actives (a split brain, or two instances started without --standby): the
            # loser stops at once, so the robots get one coordinator's setpoints again within
            # one heartbeat period.
            why = self.election.heartbeat(
                msg.name, msg.active, msg.epoch, msg.leader_t0, now_s=self._now()
            )
            refusal = self.election.last_refusal
            if refusal is not None:
                self._faults.reject("heartbeat", f"from {msg.name}: {refusal}", refusal)
            if why is not None:
                self.step_down(why)
        except Exception as exc:
            self._faults.internal("on_heartbeat", exc)

    def on_leader(self, rx: rt.Received) -> None:
        """The active instance's ``leader``: a standby checks trajectory origins against it
        (coordinator.core.election, spoofed heartbeats)."""
        try:
            if self.active:
                return
            self._rx["leader"] += 1
            msg = decode(rx.payload, Leader)
            if isinstance(msg, DecodeError):
                self._faults.reject("leader", msg)
                return
            if msg.progress_s is not None:  # issue 28: an operator's or a waiting leader is no
                return  # function of t - leader_t0: nothing to check an origin against
            self.election.observe_leader(msg.t, msg.x, msg.y, self._now())
        except Exception as exc:
            self._faults.internal("on_leader", exc)

    def on_assignment(self, rx: rt.Received) -> None:
        """The active instance's assignment: a standby keeps it to seed its hysteresis."""
        try:
            if self.active:
                return
            msg = decode(rx.payload, Assignment)
            if isinstance(msg, DecodeError):
                self._faults.reject("assignment", msg)
                return
            if len(msg.robots) <= MAX_ROBOTS:
                self.peer_assignment = dict(msg.robots)
        except Exception as exc:
            self._faults.internal("on_assignment", exc)

    def elect(self, now_s: float) -> bool:
        """Take over if the election says so at ``now_s``; returns True if it did. Never
        raises."""
        try:
            if not self.election.should_take_over(now_s):
                return False
            self._take_over(now_s, self.election.take_over())
            return True
        except Exception as exc:
            self._faults.internal("elect", exc)
            return False

    def step_down(self, why: str) -> None:
        """Stop publishing (become a standby); never raises."""
        if not self.election.step_down(self._now()):
            return
        self._log.info(f"standby: {why}")
        with contextlib.suppress(Exception):
            self._publish_heartbeat()
