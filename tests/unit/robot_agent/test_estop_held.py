"""The agents hold the e-stop too (robot_agent.node.estop_shell, docs/faults.md "The agents hold it
too"): an agent or agent host that holds an engagement answers ``estop/held/<name>`` with it
(never a release); agents add what the others hold; a starting coordinator adds it last, after
the other coordinators' and its file's release records. End to end with real processes:
``tests/fleet/test_estop_identity.py::test_an_estop_no_coordinator_received_holds_agents_started_later_until_released``;
the bus ACL: ``tests/bus/test_acl.py::test_live_estop_held_query``.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from support.estop_checks import rejecting_source

import runtime as rt
from bus_schemas import DecodeError, Estop, Reason, decode_estop_answer, encode, keys
from coordinator.node.estop_store import EstopStore, read_state
from robot_agent.core.estop import EstopLatch
from robot_agent.core.params import AgentConfig
from robot_agent.node.agent import AgentNode
from robot_agent.node.host import HostNode

Entry = tuple[bool, str | None, int | None]
KEY = keys.estop_key("demo")


def _held(payloads: tuple[bytes, ...]) -> list[Entry]:
    return decode_estop_answer(payloads, lambda e: (_ for _ in ()).throw(AssertionError(e)))


def _msg(engage: bool, robot: str | None, eid: int | None = None) -> rt.Received:
    return rt.Received(KEY, encode(Estop(t=1.0, engage=engage, robot=robot, id=eid)), 0.0)


def test_a_release_in_an_agents_answer_is_rejected_and_counted() -> None:
    payloads = [
        encode(Estop(t=1.0, engage=True, robot=None, id=3)),
        encode(Estop(t=1.0, engage=False, robot=None, id=3)),  # a forged proof of release
        encode(Estop(t=1.0, engage=False, robot=None)),  # "nothing latched"
    ]
    errors: list[DecodeError] = []
    assert decode_estop_answer(payloads, errors.append, held=True) == [(True, None, 3)]
    assert [e.reason for e in errors] == [Reason.INCONSISTENT] * 2
    # an agent that holds the engagement is not released by it, and counts both
    node = AgentNode("r1", "demo", AgentConfig(), lambda *_: None, lockstep=True)
    node.on_estop(_msg(True, None, 3))
    from robot_agent.node.agent_estop import estop_answers

    node.on_estop_state(estop_answers(node.faults.reject, payloads, held=True))
    assert node.firmware.status().estop_latched
    assert node.faults.rejects.by_reason == {"estop_state-inconsistent": 2}


def test_an_agent_offers_what_it_holds_and_only_on_a_change() -> None:
    node = AgentNode("r1", "demo", AgentConfig(), lambda *_: None, lockstep=True)
    offered: list[tuple[bytes, ...]] = []
    node.witness.offer = offered.append
    node.on_estop(_msg(True, None, 5))
    node.on_estop(_msg(True, None, 5))  # the tool's second copy: no change, no new offer
    node.on_estop(_msg(True, "r2", 7))  # another robot's: held as a witness, not obeyed
    assert [_held(p) for p in offered] == [[(True, None, 5)], [(True, None, 5), (True, "r2", 7)]]
    assert node.estop.held == {None: {5}}
    node.on_estop_state([(False, None, None), (False, None, 5)])  # a coordinator saw 5 released
    node.on_estop(_msg(False, "r2"))
    assert [_held(p) for p in offered[2:]] == [[(True, "r2", 7)], []]  # nothing: undeclared
    assert not node.firmware.status().estop_latched
    # a robot inside an agent host (no answer of its own) keeps no witness
    hosted = AgentNode("r3", "demo", AgentConfig(), lambda *_: None, lockstep=True)
    hosted.on_estop(_msg(True, "r2", 8))
    assert hosted.witness.latch.held == {} and hosted.estop.held == {}


def test_an_agent_host_offers_every_engagement_it_saw() -> None:
    host = HostNode("h1", ["r1", "r2"], "demo", AgentConfig(), lambda *_: None, lockstep=True)
    offered: list[tuple[bytes, ...]] = []
    host.witness.offer = offered.append
    host.estop.on_estop(_msg(True, None, 5))
    host.estop.on_estop(_msg(True, "r2", 6))
    host.estop.on_estop(_msg(True, "r9", 8))  # not hosted here: witnessed
    assert [_held(p) for p in offered] == [
        [(True, None, 5)],
        [(True, None, 5), (True, "r2", 6)],
        [(True, None, 5), (True, "r2", 6), (True, "r9", 8)],
    ]
    # another agent's held answer adds to every hosted robot; a release in it does nothing
    host.estop.on_estop_held([encode(Estop(t=1.0, engage=True, robot="r1", id=9))])
    assert _held(offered[-1]) == [
        (True, None, 5),
        (True, "r1", 9),
        (True, "r2", 6),
        (True, "r9", 8),
    ]
    host.estop.on_estop_held([encode(Estop(t=1.0, engage=False, robot=None, id=5))])
    assert all(n.firmware.status().estop_latched for n in host.nodes.values())
    assert host.faults.rejected == 1
    for scope in (None, "r1", "r2", "r9"):
        host.estop.on_estop(_msg(False, scope))
    assert _held(offered[-1]) == []
    assert not any(n.firmware.status().estop_latched for n in host.nodes.values())


def test_a_starting_coordinator_adds_the_agents_engagements_last(tmp_path: Path) -> None:
    """An engagement an agent still holds is taken back unless a coordinator's answer or the
    state file names its release: stale holds never outvote a release record."""
    rejects: list[str] = []
    peer = rejecting_source(rejects)  # another coordinator: engaged 1 and 2, released 1
    for engage, eid in ((True, 1), (True, 2), (False, None)):
        peer.on_estop(_msg(engage, None, eid))
    peer.on_estop(_msg(True, None, 3))
    path = tmp_path / "estop.msgpack"
    filed = rejecting_source(rejects)  # this coordinator before its restart: released 4
    filed.on_estop(_msg(True, "r2", 4))
    filed.on_estop(_msg(False, "r2"))
    store = EstopStore(path, "demo", lambda _line: None)
    store.offer(filed.answer)
    store.close()
    agents = [  # one missed both releases, one holds r1's engagement 5
        encode(Estop(t=1.0, engage=True, robot=None, id=1)),
        encode(Estop(t=1.0, engage=True, robot="r2", id=4)),
        encode(Estop(t=1.0, engage=True, robot="r1", id=5)),
    ]
    source = rejecting_source(rejects)
    source.on_state(peer.answer)
    source.restore(read_state(path, "demo"), path)
    source.on_state(agents, held=True)
    assert source.latch.held == {None: {3}, "r1": {5}}  # 1 and 4 released, 5 learned
    assert not rejects
    # alone and without a file it learns everything the agents hold (the safe side)
    alone = rejecting_source(rejects)
    alone.on_state(agents, held=True)
    assert alone.latch.held == {None: {1}, "r2": {4}, "r1": {5}}
    # a release record from an agent is refused and releases nothing
    alone.on_state([encode(Estop(t=1.0, engage=False, robot=None, id=1))], held=True)
    assert alone.latch.held[None] == {1} and len(rejects) == 1


# --- interleavings (hypothesis) ---------------------------------------------------------------

ROBOTS = ("r1", "r2", "r3")


@st.composite
def _histories(draw: st.DrawFn) -> list[tuple[object, ...]]:
    """``("msg", engage, scope, id, receivers)``: an operator's ``estop`` reaching a subset of
    the agents and the coordinator ``c``; ``("refresh", robot)``: an agent asks (the
    coordinator's answer and the others' held answers); ``("restart", who)``: an agent or the
    coordinator loses its memory and asks as at start (the coordinator has no state file)."""
    ops: list[tuple[object, ...]] = []
    next_id = 1
    who = st.sampled_from([*ROBOTS, "c"])
    for _ in range(draw(st.integers(0, 25))):
        kind = draw(st.sampled_from(["engage", "release", "refresh", "restart"]))
        if kind in ("engage", "release"):
            eid = None
            if kind == "engage":
                eid, next_id = next_id, next_id + 1
            scope = draw(st.sampled_from([None, *ROBOTS]))
            ops.append(("msg", kind == "engage", scope, eid, draw(st.sets(who))))
        elif kind == "refresh":
            ops.append(("refresh", draw(st.sampled_from(ROBOTS))))
        else:
            ops.append(("restart", draw(who)))
    return ops


class _Agent:
    """A real ``AgentNode`` (lockstep: no clock) with its held answer as the shell keeps it."""

    def __init__(self, robot: str) -> None:
        self.node = AgentNode(robot, "demo", AgentConfig(), lambda *_: None, lockstep=True)
        self.answer: tuple[bytes, ...] = ()

        def keep(payloads: tuple[bytes, ...]) -> None:
            self.answer = payloads

        self.node.witness.offer = keep

    def ask(self, coord: EstopLatch, others: list[_Agent]) -> None:
        """Both queries, as ``node_estop.attach_estop`` hands them over."""
        from robot_agent.node.agent_estop import estop_answers

        node = self.node
        reject = node.faults.reject
        node.on_estop_state(estop_answers(reject, [encode(Estop(t=1.0, engage=e, robot=r, id=i))
                                                   for e, r, i in coord.answer()]))  # fmt: skip
        before = {(s, i) for s, ids in node.estop.held.items() for i in ids}
        node.on_estop_state(estop_answers(reject, [p for a in others for p in a.answer], held=True))
        after = {(s, i) for s, ids in node.estop.held.items() for i in ids}
        assert before <= after, "a held answer released something"
        assert not node.faults.rejects.by_reason


@settings(max_examples=300, deadline=None)
@given(_histories())
def test_an_estop_anyone_holds_stops_every_agent_that_starts(
    ops: list[tuple[object, ...]],
) -> None:
    """Whatever messages are lost and whoever restarts (the coordinator without a file): while
    the operator's last message of a scope (the fleet or one robot) is an engagement whose
    message reached any agent or the coordinator that still runs, an agent of that scope that
    (re)starts comes up stopped; held answers release nothing."""
    agents = {r: _Agent(r) for r in ROBOTS}
    coord = EstopLatch()
    last: dict[str | None, tuple[bool, int | None]] = {}
    received: dict[int, set[str]] = {}  # engagement id -> who got its message and runs since

    def others(robot: str) -> list[_Agent]:
        return [a for r, a in agents.items() if r != robot]

    def forget(who: str) -> None:
        for got in received.values():
            got.discard(who)

    for op in ops:
        if op[0] == "msg":
            _, engage, scope, eid, receivers = op
            assert isinstance(engage, bool) and isinstance(receivers, set)
            assert scope is None or isinstance(scope, str)
            assert eid is None or isinstance(eid, int)
            last[scope] = (engage, eid)
            if eid is not None:
                received[eid] = set(receivers)
            if "c" in receivers:
                coord.apply(engage, scope, eid)
            for r in ROBOTS:
                if r in receivers:
                    agents[r].node.on_estop(_msg(engage, scope, eid))
        elif op[0] == "refresh":
            robot = str(op[1])
            agents[robot].ask(coord, others(robot))
        elif op[1] == "c":
            forget("c")
            coord = EstopLatch()
            coord.merge_answer(
                decode_estop_answer([p for a in agents.values() for p in a.answer],
                                    lambda e: pytest.fail(str(e)), held=True),
                release=False,
            )  # fmt: skip
        else:
            robot = str(op[1])
            forget(robot)
            agents[robot] = _Agent(robot)
            agents[robot].ask(coord, others(robot))
        for scope, (engaged, eid) in last.items():
            # a robot that joins (fleet scope) or the robot of that scope restarting: it asks
            # the coordinator and every other agent
            robot = scope or "r4"
            asked = others(robot)
            if not engaged or eid is None or not received[eid] - {robot}:
                continue
            fresh = _Agent(robot)
            fresh.ask(coord, asked)
            assert fresh.node.firmware.status().estop_latched, (scope, eid, coord.held)
