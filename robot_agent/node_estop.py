"""The latched e-stop state (robot_agent.estop) of an agent over a query: at start, an agent asks
the coordinators for it before it subscribes to anything that moves it (so an agent that starts
or restarts under an e-stop comes up stopped), and again on resume and every
``ESTOP_REFRESH_S`` in realtime. Split out of robot_agent/node.py.
"""

from __future__ import annotations

import time
from collections.abc import Sequence

import runtime as rt
from bus_schemas import decode_estop_answer
from robot_agent.estop import ESTOP_QUERY_TIMEOUT_S
from robot_agent.node import AgentNode

__all__ = ["attach_estop_state", "estop_answers"]


def estop_answers(
    node: AgentNode, payloads: Sequence[bytes]
) -> list[tuple[bool, str | None, int | None]]:
    """Decode a query's answer (``bus_schemas.decode_estop_answer``); invalid ones are counted
    as the node's rejects."""
    return decode_estop_answer(payloads, lambda err: node._reject("estop_state", err))


async def attach_estop_state(node: AgentNode, io: rt.NodeIO) -> None:
    """Subscribe to ``estop``, ask the coordinators for the latched state *now* (so an agent
    that starts or restarts under an e-stop comes up stopped) and install the hook that asks
    again on resume and every ``ESTOP_REFRESH_S`` (realtime). Call it before the subscriptions
    that make the robot move."""
    from runtime.query import Querier

    io.subscribe(node.estop_key, node.on_estop)

    def on_replies(payloads: Sequence[bytes], _token: int) -> None:
        node.on_estop_state(estop_answers(node, payloads))

    querier = Querier(
        io.session, io.loop, node.estop_key, on_replies, timeout_s=ESTOP_QUERY_TIMEOUT_S
    )
    try:
        payloads = await io.loop.run_in_executor(None, querier.run_now)
    except Exception as exc:  # no answer: start from the messages alone
        node._internal("estop_query", exc)
        payloads = []
    node.on_estop_state(estop_answers(node, payloads))
    node.estop_queried_s = time.monotonic()
    io._keep.append(querier)

    def ask() -> None:
        querier.request()

    node.estop_query = ask
