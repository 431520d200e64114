"""The agent host's latched e-stop (``robot_agent.core.estop``, docs/faults.md): an operator's
``estop`` applied to every hosted robot or one, and the coordinators' latched state merged into
each hosted robot's latch (queried at start, on resume and every ``ESTOP_REFRESH_S``).

Part of the agent host's process shell: :class:`HostEstop` is a base of
:class:`robot_agent.node.host.HostNode` (which owns the state; split out of
``robot_agent/node/host.py``).
Handlers never raise.
"""

from __future__ import annotations

import time
from collections.abc import Iterable, Sequence
from typing import TYPE_CHECKING

import runtime as rt
from bus_schemas import DecodeError, Estop, decode, decode_estop_answer
from robot_agent.core.firmware import WheelCommand
from robot_agent.node.agent import AgentNode
from robot_agent.node.estop_shell import EstopHooks

__all__ = ["HostEstop"]


class HostEstop(EstopHooks):
    """The e-stop handlers of :class:`~robot_agent.node.host.HostNode` (its state is the host's,
    declared here for the type checker)."""

    nodes: dict[str, AgentNode]
    lockstep: bool
    log: rt.NodeLog
    rx: dict[str, int]

    if TYPE_CHECKING:

        def _reject(self, what: str, why: DecodeError | str) -> None: ...

        def _publish_steps(
            self,
            steps: Iterable[tuple[AgentNode, WheelCommand | None]],
            tick: int | None = None,
        ) -> list[bytes]: ...

    def on_estop_state(self, payloads: Sequence[bytes], _token: int = 0) -> None:
        """The coordinators' latched e-stop state (a query's answer on ``estop``; ``_token``: the
        querier's, unused): each hosted robot merges its scopes (``AgentNode.on_estop_state``:
        adds engagements, releases only those the answer saw released). No answer: no change."""
        self._merge_answer(payloads, held=False)

    def on_estop_held(self, payloads: Sequence[bytes], _token: int = 0) -> None:
        """The engagements other agents hold (a query's answer on ``estop/held/*``): added to
        each hosted robot's scopes; a release in it is rejected (releases nothing)."""
        self._merge_answer(payloads, held=True)

    def _merge_answer(self, payloads: Sequence[bytes], *, held: bool) -> None:
        try:
            if not payloads:
                return
            answers = decode_estop_answer(
                payloads, lambda err: self._reject("estop_state", err), held=held
            )
            self.witness_answer(answers)
            for node in self.nodes.values():
                node.on_estop_state(answers)
            stopped = sum(n.estop.stopped(n.robot_id) for n in self.nodes.values())
            if stopped:
                self.log.limited("estop-state", f"latched e-stop: {stopped} robot(s) stopped")
        except Exception as exc:
            self._internal("on_estop_state", exc)

    def on_estop(self, rx: rt.Received) -> None:
        """Fleet or one robot's estop: engage (zero wheels at once in realtime) or release."""
        try:
            self.rx["estop"] += 1
            msg = decode(rx.payload, Estop)
            if isinstance(msg, DecodeError):
                self._reject("estop", msg)
                return
            self.witness_message(msg.engage, msg.robot, msg.id)  # answered on estop/held
            if msg.robot is None:
                targets = list(self.nodes.values())
            elif msg.robot in self.nodes:
                targets = [self.nodes[msg.robot]]
            else:
                return
            for node in targets:  # each robot's latched scopes (robot_agent.core.estop)
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
