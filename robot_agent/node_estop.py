"""The latched e-stop state (robot_agent.estop) of an agent over queries: at start, an agent asks
the coordinators for it (``estop``) and the other agents for the engagements they hold
(``estop/held/*``) before it subscribes to anything that moves it (so an agent that starts or
restarts under an e-stop comes up stopped), and again on resume and every ``ESTOP_REFRESH_S`` in
realtime; while it holds an engagement it answers ``estop/held/<robot>`` itself
(robot_agent.estop_hooks). Split out of robot_agent/node.py.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING

import runtime as rt
from bus_schemas import decode_estop_answer, keys
from robot_agent.estop import ESTOP_QUERY_TIMEOUT_S
from robot_agent.node import AgentNode

if TYPE_CHECKING:
    from runtime.query import Querier

__all__ = ["attach_estop_state", "estop_answers", "query_estop"]


def estop_answers(
    node: AgentNode, payloads: Sequence[bytes], *, held: bool = False
) -> list[tuple[bool, str | None, int | None]]:
    """Decode a query's answer (``bus_schemas.decode_estop_answer``; ``held``: the agents' on
    ``estop/held/*``, engagements only); invalid ones are counted as the node's rejects."""
    return decode_estop_answer(payloads, lambda err: node._reject("estop_state", err), held=held)


async def attach_estop_state(node: AgentNode, io: rt.NodeIO) -> None:
    """Subscribe to ``estop``, answer ``estop/held/<robot>`` while this robot holds an
    engagement (robot_agent.estop_hooks), ask the coordinators' latched state and the other
    agents' held engagements *now* (so an agent that starts or restarts under an e-stop comes up
    stopped, even when no coordinator remembers it) and install the hook that asks again on
    resume and every ``ESTOP_REFRESH_S`` (realtime). Call it before the subscriptions that make
    the robot move."""
    from runtime.query import LazyAnswerer

    io.subscribe(node.estop_key, node.on_estop)
    held = LazyAnswerer(io.session, keys.estop_held_key(node.fleet, node.robot_id))
    io._keep.append(held)
    node.estop_held = held.offer

    def on_state(payloads: Sequence[bytes], _token: int) -> None:
        node.on_estop_state(estop_answers(node, payloads))

    def on_held(payloads: Sequence[bytes], _token: int) -> None:
        node.on_estop_state(estop_answers(node, payloads, held=True))

    queriers = await query_estop(io, node.estop_key, node.fleet, on_state, on_held, node._internal)
    node.estop_queried_s = time.monotonic()

    def ask() -> None:
        for querier in queriers:
            querier.request()

    node.estop_query = ask


async def query_estop(
    io: rt.NodeIO,
    estop_key: str,
    fleet: str,
    on_state: Callable[[Sequence[bytes], int], None],
    on_held: Callable[[Sequence[bytes], int], None],
    internal: Callable[[str, BaseException], None],
) -> tuple[Querier, Querier]:
    """Ask the coordinators' latched state (``estop``) and the agents' held engagements
    (``estop/held/*``) now, in parallel, and hand each answer to its handler, the coordinators'
    first; the two queriers (kept by ``io``) ask again on :meth:`Querier.request`."""
    from runtime.query import Querier

    queriers = (
        Querier(io.session, io.loop, estop_key, on_state, timeout_s=ESTOP_QUERY_TIMEOUT_S),
        Querier(
            io.session,
            io.loop,
            keys.estop_held_pattern(fleet),
            on_held,
            timeout_s=ESTOP_QUERY_TIMEOUT_S,
        ),
    )
    io._keep.extend(queriers)
    got = await asyncio.gather(
        *(io.loop.run_in_executor(None, q.run_now) for q in queriers), return_exceptions=True
    )
    answers: list[list[bytes]] = []
    for result in got:
        if isinstance(result, BaseException):  # no answer: start from the messages alone
            internal("estop_query", result)
            answers.append([])
        else:
            answers.append(result)
    on_state(answers[0], 0)
    on_held(answers[1], 0)
    return queriers
