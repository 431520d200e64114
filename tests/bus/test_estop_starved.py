"""The e-stop next to a starved CPU: a coordinator whose event loop is late must not answer a
query with a latched state older than the ``estop`` messages its session already received.

Found by tests/fleet/test_faults.py next to 4 CPU hogs (load 15-23): r2, e-stopped alone, drove
again
for a while. Its agent had latched the e-stop, then asked the coordinators for the latched
state (the 1 s refresh, robot_agent/node/agent_estop.py); they answer on Zenoh's thread from a
snapshot that their (starved) loops had not updated yet, so the answer said "nothing latched";
no ``estop`` message had arrived since the query was sent, so the agent took it as the whole
truth (then ``EstopLatch.merge_answer(replace=True)``) and released until the next refresh.
coordinator/node/estop_source.py now applies ``estop`` messages on the network thread, on receipt.
(Since engagement ids, tests/fleet/test_estop_identity.py, such an answer no longer releases an
agent
at all; the coordinator's answer must still hold the e-stop, for the agents that missed it.)

Real Zenoh through a router; the starved loop is this test's own loop, blocked on purpose.
"""

from __future__ import annotations

import asyncio
import threading
import time
from typing import Any, cast

import pytest

import runtime as rt
from bus_schemas import Estop, decode_estop_answer, encode, keys, new_estop_id
from coordinator.node.estop_source import EstopSource, attach_estop_source
from robot_agent.core.estop import EstopLatch
from runtime.query import get_all

pytestmark = [pytest.mark.zenoh]

FLEET = "starved"


def _answer(session: Any, key: str) -> list[tuple[bool, str | None, int | None]]:
    payloads = get_all(session, key, 2.0)  # as runtime.query.Querier asks
    return decode_estop_answer(payloads, lambda err: pytest.fail(f"bad answer: {err}"))


@pytest.mark.parametrize("robot", [None, "r2"])
async def test_a_starved_coordinator_answers_with_every_estop_its_session_received(
    session: Any, robot: str | None
) -> None:
    key = keys.estop_key(FLEET)
    coord, operator, agent = session(), session(), session()
    problems: list[str] = []
    source = EstopSource(
        key,
        time.monotonic,
        lambda what, why, reason=None: problems.append(f"reject {what}: {why}"),
        lambda where, exc: problems.append(f"internal {where}: {exc!r}"),
        rt.NodeLog("coordinator test"),
    )
    io = rt.NodeIO(
        session=coord,
        loop=asyncio.get_running_loop(),
        pubs=cast(Any, None),
        log=rt.NodeLog("coordinator test"),
        settings=rt.ZenohSettings(),
    )
    await attach_estop_source(source, io)
    try:
        got = threading.Event()
        sub = agent.declare_subscriber(key, lambda _sample: got.set())
        await asyncio.sleep(0.3)  # subscriptions propagated through the router
        assert _answer(agent, key) == [(False, None, None)]  # nothing latched yet

        # From here on the coordinator's loop (this one) does not run: starved.
        eid = new_estop_id()
        operator.put(key, encode(Estop(t=time.monotonic(), engage=True, robot=robot, id=eid)))
        assert got.wait(5.0), "the agent's session never received the estop"
        # The agent has the e-stop and asks (its refresh): the answer must hold it.
        answer = _answer(agent, key)
        assert (True, robot, eid) in answer, f"a starved coordinator answered {answer}"
        mine = EstopLatch()
        mine.merge_answer(answer)
        assert mine.stopped("r2"), f"a starved coordinator answered {answer}: r2 would release"

        # The release is seen the same way (no lag that would re-engage a released robot).
        got.clear()
        operator.put(key, encode(Estop(t=time.monotonic(), engage=False, robot=robot)))
        assert got.wait(5.0)
        released = EstopLatch()
        released.apply(True, robot, eid)  # an agent that missed the release
        answer = _answer(agent, key)
        assert (False, robot, eid) in answer, answer  # the release record proves it
        released.merge_answer(answer)
        assert not released.stopped("r2")
        sub.undeclare()
        await asyncio.sleep(0.05)  # the loop runs again: the log lines and counters
        assert source.messages == 2 and not source.latch.stopped("r2")
        assert not problems, problems
    finally:
        io.close()
