"""The agent host's latched e-stop (``robot_agent.core.estop``, docs/faults.md): an operator's
``estop`` applied to every hosted robot or one, and the coordinators' latched state merged into
each hosted robot's latch (queried at start, on resume and every ``ESTOP_REFRESH_S``).

:class:`HostEstop` is a part the agent host (:class:`robot_agent.node.host.HostNode`) builds and
owns; it is given the hosted robots, the host's e-stop witness and counters, and how to step
robots at once. Handlers never raise.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence

import runtime as rt
from bus_schemas import DecodeError, Estop, decode, decode_estop_answer
from robot_agent.node.agent import AgentNode
from robot_agent.node.estop_shell import EstopWitness

__all__ = ["HostEstop"]


class HostEstop:
    """The e-stop handlers of an agent host.

    Args:
        nodes: the hosted robots, by id.
        witness: the host's witness of every engagement seen (answered on ``estop/held``).
        rx: the host's receive counters (``"estop"`` is counted here).
        faults: the host's counters (a bad answer counts against every hosted robot).
        step_now: realtime, steps the given robots now and publishes their commands (an
            engaged e-stop zeroes the wheels at once); None in lockstep.
    """

    def __init__(
        self,
        nodes: Mapping[str, AgentNode],
        witness: EstopWitness,
        rx: dict[str, int],
        faults: rt.Faults,
        *,
        step_now: Callable[[list[AgentNode]], None] | None,
    ) -> None:
        self._nodes = nodes
        self._witness = witness
        self._rx = rx
        self._faults = faults
        self._log = faults.log
        self._step_now = step_now

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
                payloads, lambda err: self._faults.reject("estop_state", err), held=held
            )
            self._witness.answer(answers)
            for node in self._nodes.values():
                node.on_estop_state(answers)
            stopped = sum(n.estop.stopped(n.robot_id) for n in self._nodes.values())
            if stopped:
                self._log.limited("estop-state", f"latched e-stop: {stopped} robot(s) stopped")
        except Exception as exc:
            self._faults.internal("on_estop_state", exc)

    def on_estop(self, rx: rt.Received) -> None:
        """Fleet or one robot's estop: engage (zero wheels at once in realtime) or release."""
        try:
            self._rx["estop"] += 1
            msg = decode(rx.payload, Estop)
            if isinstance(msg, DecodeError):
                self._faults.reject("estop", msg)
                return
            self._witness.message(msg.engage, msg.robot, msg.id)  # answered on estop/held
            if msg.robot is None:
                targets = list(self._nodes.values())
            elif msg.robot in self._nodes:
                targets = [self._nodes[msg.robot]]
            else:
                return
            for node in targets:  # each robot's latched scopes (robot_agent.core.estop)
                node.rx["estop"] += 1
                node.estop.apply(msg.engage, msg.robot, msg.id)
                node.sync_estop()
            what = "all robots" if msg.robot is None else msg.robot
            self._log.info(f"estop {'engaged' if msg.engage else 'released'} ({what})")
            if msg.engage and self._step_now is not None:
                self._step_now(targets)
        except Exception as exc:
            self._faults.internal("on_estop", exc)
