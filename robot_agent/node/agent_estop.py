"""The latched e-stop state (robot_agent.core.estop) of an agent over queries: at start, an agent
asks the coordinators for it (``estop``) and the other agents for the engagements they hold
(``estop/held/*``) before it subscribes to anything that moves it (so an agent that starts or
restarts under an e-stop comes up stopped), and again on resume and every ``ESTOP_REFRESH_S`` in
realtime; while it holds an engagement it answers ``estop/held/<robot>`` itself. The parts it
connects are :mod:`robot_agent.node.estop_shell`'s (an agent host's too: ``host_main``).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence

import runtime as rt
from bus_schemas import decode_estop_answer, keys
from robot_agent.core.estop import ESTOP_QUERY_TIMEOUT_S
from robot_agent.node.agent import AgentNode
from robot_agent.node.estop_shell import EstopQuery, EstopWitness
from runtime.faults import Internal, Reject

__all__ = ["attach_estop", "attach_estop_state", "estop_answers"]


def estop_answers(
    reject: Reject, payloads: Sequence[bytes], *, held: bool = False
) -> list[tuple[bool, str | None, int | None]]:
    """Decode a query's answer (``bus_schemas.decode_estop_answer``; ``held``: the agents' on
    ``estop/held/*``, engagements only); invalid ones are counted by ``reject``."""
    return decode_estop_answer(payloads, lambda err: reject("estop_state", err), held=held)


async def attach_estop_state(node: AgentNode, io: rt.NodeIO) -> None:
    """:func:`attach_estop` for an agent: it answers ``estop/held/<robot>``."""
    reject = node.faults.reject

    def on_state(payloads: Sequence[bytes], _token: int) -> None:
        node.on_estop_state(estop_answers(reject, payloads))

    def on_held(payloads: Sequence[bytes], _token: int) -> None:
        node.on_estop_state(estop_answers(reject, payloads, held=True))

    await attach_estop(
        io,
        fleet=node.fleet,
        name=node.robot_id,
        on_estop=node.on_estop,
        query=node.estop_query,
        witness=node.witness,
        internal=node.faults.internal,
        on_state=on_state,
        on_held=on_held,
    )


async def attach_estop(
    io: rt.NodeIO,
    *,
    fleet: str,
    name: str,
    on_estop: Callable[[rt.Received], None],
    query: EstopQuery,
    witness: EstopWitness,
    internal: Internal,
    on_state: Callable[[Sequence[bytes], int], None],
    on_held: Callable[[Sequence[bytes], int], None],
) -> None:
    """Subscribe ``on_estop`` (an agent's or an agent host's) to ``estop``, answer
    ``estop/held/<name>`` with what ``witness`` holds, ask the coordinators' latched state
    (``estop``, to ``on_state``) and the other agents' held engagements (``estop/held/*``, to
    ``on_held``) *now*, both at once, the coordinators' answer handled first (so an agent that
    starts or restarts under an e-stop comes up stopped, even when no coordinator remembers it),
    and give ``query`` the means to ask both again on resume and every ``ESTOP_REFRESH_S``
    (realtime). Call it before the subscriptions that make a robot move."""
    from runtime.query import LazyAnswerer, Querier, get_all_now

    estop_key = keys.estop_key(fleet)
    io.subscribe(estop_key, on_estop)
    held = LazyAnswerer(io.session, keys.estop_held_key(fleet, name))
    io._keep.append(held)
    witness.offer = held.offer
    timeout = ESTOP_QUERY_TIMEOUT_S
    queriers = (
        Querier(io.session, io.loop, estop_key, on_state, timeout_s=timeout),
        Querier(io.session, io.loop, keys.estop_held_pattern(fleet), on_held, timeout_s=timeout),
    )
    io._keep.extend(queriers)
    answers = await get_all_now(
        io.loop,
        io.session,
        [q.key for q in queriers],
        timeout,
        lambda exc: internal("estop_query", exc),
    )
    on_state(answers[0], 0)
    on_held(answers[1], 0)
    query.asked_s = time.monotonic()

    def ask() -> None:
        for querier in queriers:
            querier.request()

    query.ask = ask
