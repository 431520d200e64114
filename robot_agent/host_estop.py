"""The agent host's latched e-stop (``robot_agent.estop``, docs/faults.md): an operator's
``estop`` applied to every hosted robot or one, and the coordinators' latched state merged into
each hosted robot's latch (queried at start, on resume and every ``ESTOP_REFRESH_S``).

Part of the agent host's process shell: :class:`HostEstop` is a base of
:class:`robot_agent.host.HostNode` (which owns the state; split out of ``robot_agent/host.py``).
Handlers never raise.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable, Sequence
from typing import TYPE_CHECKING

import runtime as rt
from bus_schemas import DecodeError, Estop, decode, decode_estop_answer
from robot_agent.firmware import WheelCommand
from robot_agent.node import AgentNode

__all__ = ["HostEstop"]


class HostEstop:
    """The e-stop handlers of :class:`~robot_agent.host.HostNode` (its state is the host's,
    declared here for the type checker)."""

    nodes: dict[str, AgentNode]
    lockstep: bool
    log: rt.NodeLog
    rx: dict[str, int]
    estop_query: Callable[[], None] | None
    estop_queried_s: float

    if TYPE_CHECKING:

        def _reject(self, what: str, why: DecodeError | str) -> None: ...

        def _internal(self, where: str, exc: BaseException) -> None: ...

        def _publish_steps(
            self,
            steps: Iterable[tuple[AgentNode, WheelCommand | None]],
            tick: int | None = None,
        ) -> list[bytes]: ...

    def on_estop_state(self, payloads: Sequence[bytes], _token: int = 0) -> None:
        """The coordinators' latched e-stop state (a query's answer; ``_token``: the querier's,
        unused): each hosted robot merges its scopes (``AgentNode.on_estop_state``: adds
        engagements, releases only those the answer saw released). No answer: no change."""
        try:
            if not payloads:
                return
            answers = decode_estop_answer(payloads, lambda err: self._reject("estop_state", err))
            for node in self.nodes.values():
                node.on_estop_state(answers)
            stopped = sum(n.estop.stopped(n.robot_id) for n in self.nodes.values())
            if stopped:
                self.log.limited("estop-state", f"latched e-stop: {stopped} robot(s) stopped")
        except Exception as exc:
            self._internal("on_estop_state", exc)

    def request_estop_state(self, now_s: float) -> None:
        """Ask the coordinators for the latched e-stop state (through :attr:`estop_query`)."""
        self.estop_queried_s = now_s
        if self.estop_query is not None:
            try:
                self.estop_query()
            except Exception as exc:
                self._internal("estop_query", exc)

    def on_estop(self, rx: rt.Received) -> None:
        """Fleet or one robot's estop: engage (zero wheels at once in realtime) or release."""
        try:
            self.rx["estop"] += 1
            msg = decode(rx.payload, Estop)
            if isinstance(msg, DecodeError):
                self._reject("estop", msg)
                return
            if msg.robot is None:
                targets = list(self.nodes.values())
            elif msg.robot in self.nodes:
                targets = [self.nodes[msg.robot]]
            else:
                return
            for node in targets:  # each robot's latched scopes (robot_agent.estop)
                node.rx["estop"] += 1
                node.estop.apply(msg.engage, msg.robot, msg.id)
                node.sync_estop()
            what = "all robots" if msg.robot is None else msg.robot
            self.log.info(f"estop {'engaged' if msg.engage else 'released'} ({what})")
            if msg.engage and not self.lockstep:
                now = time.monotonic()
                self._publish_steps((n, n.step(now)) for n in targets)
        except Exception as exc:
            self._internal("on_estop", exc)
