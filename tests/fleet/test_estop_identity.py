"""E-stop engagement identity: a query answer never releases a robot from an engagement the
answering coordinator did not see released (robot_agent.core.estop, docs/faults.md).

Before, an agent took a query answer "nothing latched" as the whole truth when no ``estop``
message had arrived since the query: an agent e-stopped by a message its coordinator never
received (the coordinator partitioned, or respawned alone after the e-stop: it asks the others
at start, finds none and holds nothing) drove again at its next refresh, within 1 s, without
any release. Now every engage carries a fresh ``id``; an answer adds engagements, and releases
one only if its release record names that id.

Here: the latch's rules one by one, the schema, a hypothesis search over interleavings of
engage / release messages that an agent and two coordinators each receive or miss (the agent is
never released by an answer unless a coordinator saw that engagement released; with a
coordinator that saw everything, the answer releases exactly what the messages released), and
one end-to-end case: a real agent process e-stopped before a real coordinator process started
stays stopped across three refresh periods of "nothing latched" answers and drives again on the
explicit release.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import replace

import msgpack
import pytest
import zenoh
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from support.agent_io import FLEET, Feeder, nonzero, start_agent
from support.bus_watch import Recorder, decoder_of
from support.estop_checks import answer_of, assert_stopped, rejecting_source
from support.routers import RouterHandle
from support.spawn import Spawner

import runtime as rt
from bus_schemas import (
    ESTOP_ID_MAX,
    DecodeError,
    Estop,
    Reason,
    Status,
    Wheels,
    decode,
    decode_estop_answer,
    encode,
    keys,
    new_estop_id,
)
from robot_agent.core.estop import MAX_IDS, MAX_LATCHED, MAX_RELEASED, NO_ID, EstopLatch
from robot_agent.core.params import AgentConfig
from robot_agent.node.agent import AgentNode
from robot_agent.node.host import HostNode
from runtime.query import get_all

Entry = tuple[bool, str | None, int | None]


def _payloads(latch: EstopLatch) -> list[bytes]:
    return [encode(Estop(t=1.0, engage=e, robot=r, id=i)) for e, r, i in latch.answer()]


# --- the latch's rules ------------------------------------------------------------------------


def test_an_answer_without_the_engagement_does_not_release() -> None:
    agent, coordinator = EstopLatch(), EstopLatch()  # the coordinator missed the e-stop
    for scope in (None, "r1"):
        agent.apply(True, scope, 11)
    assert coordinator.answer() == [(False, None, None)]  # "nothing latched"
    assert not agent.merge_answer(coordinator.answer())
    assert agent.stopped("r1") and agent.fleet and agent.robots == {"r1"}
    # the explicit release messages do (operator authority), each for its scope
    agent.apply(False, "r1")
    assert agent.stopped("r1")  # the fleet's e-stop still holds r1
    agent.apply(False, None)
    assert not agent.stopped("r1")


def test_an_answer_that_saw_the_release_releases_only_that_engagement() -> None:
    coordinator = EstopLatch()
    coordinator.apply(True, None, 1)
    coordinator.apply(True, None, 2)  # a second engagement of the same scope
    coordinator.apply(False, None)  # one release clears the scope, both recorded
    assert coordinator.answer() == [(False, None, None), (False, None, 1), (False, None, 2)]
    missed_release = EstopLatch()
    missed_release.apply(True, None, 2)
    assert missed_release.merge_answer(coordinator.answer()) and not missed_release.fleet
    assert (None, 2) in missed_release.released
    # an agent that also holds an engagement the coordinator never saw stays stopped
    more = EstopLatch()
    more.apply(True, None, 1)
    more.apply(True, None, 3)
    assert more.merge_answer(coordinator.answer())  # 1 goes, 3 holds the scope
    assert more.held == {None: {3}}
    # the same id under another scope proves nothing for this one
    robot = EstopLatch()
    robot.apply(True, "r1", 1)
    assert not robot.merge_answer(coordinator.answer()) and robot.stopped("r1")


def test_engagements_without_id_are_held_until_a_release_message() -> None:
    agent = EstopLatch()
    agent.apply(True, None)  # an older sender
    assert agent.held == {None: {NO_ID}}
    coordinator = EstopLatch()
    coordinator.apply(True, None)
    coordinator.apply(False, None)
    assert coordinator.answer() == [(False, None, None)]  # nothing to prove: no id
    agent.merge_answer(coordinator.answer())
    assert agent.fleet
    # an older coordinator's answer (no ids) adds, never releases
    legacy = EstopLatch()
    assert legacy.merge_answer([(False, None, None), (True, "r2", None)])
    assert legacy.stopped("r2") and not legacy.merge_answer([(False, None, None)])
    assert legacy.stopped("r2")
    assert legacy.apply(False, "r2") and not legacy.stopped("r2")


def test_an_answer_adds_engagements_unless_it_or_the_agent_saw_them_released() -> None:
    agent = EstopLatch()
    assert agent.merge_answer([(False, None, None), (True, "r1", 5)])
    assert agent.held == {"r1": {5}}
    agent.apply(False, "r1")  # the release message, then an answer older than it
    assert not agent.merge_answer([(False, None, None), (True, "r1", 5)])
    assert not agent.stopped("r1")
    # two coordinators: one missed the release, the other saw it: released wins
    fresh = EstopLatch()
    assert not fresh.merge_answer([(True, "r2", 6), (False, None, None), (False, "r2", 6)])
    assert not fresh.stopped("r2") and ("r2", 6) in fresh.released
    # a copy of an engage that arrives again (the tool sends two) is held again
    fresh.apply(True, "r2", 6)
    assert fresh.stopped("r2") and ("r2", 6) not in fresh.released


def test_a_coordinator_learning_from_the_others_only_adds() -> None:
    peer = EstopLatch()
    peer.apply(True, "r1", 1)
    peer.apply(False, "r1")
    peer.apply(True, None, 2)
    source = EstopLatch()
    source.apply(True, "r1", 1)  # a late copy reached this one: it keeps it
    source.apply(True, "r3", 3)  # the peer never saw this one
    assert source.merge_answer(peer.answer(), release=False)
    assert source.held == {"r1": {1}, "r3": {3}, None: {2}}
    assert ("r1", 1) not in source.released  # never both held and recorded released
    other = EstopLatch()
    other.merge_answer(peer.answer(), release=False)
    assert other.released == {("r1", 1): None} and other.held == {None: {2}}


def test_memory_is_bounded_on_the_safe_side() -> None:
    latch = EstopLatch()
    for i in range(1, MAX_IDS + 5):
        latch.apply(True, "r1", i)
    assert len(latch.held["r1"]) == MAX_IDS + 1 and NO_ID in latch.held["r1"]
    proof = [(False, "r1", i) for i in range(1, MAX_IDS + 5)]
    latch.merge_answer(proof)
    assert latch.held == {"r1": {NO_ID}}  # pinned: only a release message clears it
    assert latch.apply(False, "r1") and not latch.held
    # the release record keeps the newest MAX_RELEASED, oldest forgotten first
    for i in range(1, MAX_RELEASED + 11):
        latch.apply(True, None, i)
        latch.apply(False, None)
    assert list(latch.released) == [(None, i) for i in range(11, MAX_RELEASED + 11)]
    # made-up robots: beyond MAX_LATCHED the fleet scope latches (pinned)
    many = EstopLatch()
    for i in range(MAX_LATCHED):
        many.apply(True, f"x{i}", i + 1)
    assert not many.fleet
    assert many.apply(True, "one-more", 7) and many.held[None] == {NO_ID}
    assert many.stopped("anyone") and "one-more" not in many.robots


# --- the schema -------------------------------------------------------------------------------


def test_the_id_round_trips_and_is_optional() -> None:
    for eid in (1, 2**40 + 3, ESTOP_ID_MAX, new_estop_id()):
        msg = Estop(t=2.0, engage=True, robot="r1", id=eid)
        assert decode(encode(msg), Estop) == msg
    legacy = msgpack.packb({"v": 1, "t": 2.0, "engage": False, "robot": None})
    assert decode(legacy, Estop) == Estop(t=2.0, engage=False, robot=None)
    assert "id" not in msgpack.unpackb(encode(Estop(t=2.0, engage=False, robot=None)))
    ids = {new_estop_id() for _ in range(200)}
    assert len(ids) == 200 and all(1 <= i <= ESTOP_ID_MAX for i in ids)


@pytest.mark.parametrize(
    ("value", "reason"),
    [
        (0, Reason.OUT_OF_RANGE),
        (-5, Reason.OUT_OF_RANGE),
        (2**63, Reason.OUT_OF_RANGE),
        (2**64 - 1, Reason.OUT_OF_RANGE),
        (True, Reason.WRONG_TYPE),
        (1.0, Reason.WRONG_TYPE),
        ("7", Reason.WRONG_TYPE),
        ([7], Reason.WRONG_TYPE),
    ],
)
def test_absurd_ids_are_rejected(value: object, reason: Reason) -> None:
    raw = msgpack.packb({"v": 1, "t": 2.0, "engage": False, "robot": "r1", "id": value})
    err = decode(raw, Estop)
    assert isinstance(err, DecodeError) and err.reason == reason and err.field == "id", err


def test_a_duplicated_id_key_is_rejected() -> None:
    body = msgpack.packb({"v": 1, "t": 2.0, "engage": False, "robot": "r1", "id": 5})
    # the map header says 5 entries; make it 6 and append a second "id"
    raw = bytes([body[0] + 1]) + body[1:] + msgpack.packb("id") + msgpack.packb(6)
    err = decode(raw, Estop)
    assert isinstance(err, DecodeError) and err.reason == Reason.DUPLICATE_KEY, err


def test_absurd_release_records_are_rejected_and_counted_everywhere() -> None:
    bad = [
        msgpack.packb({"v": 1, "t": 2.0, "engage": False, "robot": "r1", "id": 0}),
        msgpack.packb({"v": 1, "t": 2.0, "engage": False, "robot": "r1", "id": "1"}),
        encode(Estop(t=2.0, engage=False, robot="r1")),  # a robot's record without an id
    ]
    good = encode(Estop(t=2.0, engage=False, robot=None))
    errors: list[DecodeError] = []
    assert decode_estop_answer([*bad, good], errors.append) == [(False, None, None)]
    assert [e.reason for e in errors] == [
        Reason.OUT_OF_RANGE,
        Reason.WRONG_TYPE,
        Reason.INCONSISTENT,
    ]
    # an agent
    node = AgentNode("r1", "demo", AgentConfig(), lambda *_: None, lockstep=True)
    node.on_estop(
        rt.Received(
            "formation/demo/estop", encode(Estop(t=1.0, engage=True, robot="r1", id=1)), 0.0
        )
    )
    from robot_agent.node.agent_estop import estop_answers

    node.on_estop_state(estop_answers(node.faults.reject, [*bad, good]))
    assert node.rejects.by_reason == {
        "estop_state-out_of_range": 1,
        "estop_state-wrong_type": 1,
        "estop_state-inconsistent": 1,
    }
    assert node.firmware.status().estop_latched
    # an agent host (each hosted robot's firmware counts it)
    host = HostNode("h1", ["r1", "r2"], "demo", AgentConfig(), lambda *_: None, lockstep=True)
    host.estop.on_estop_state([*bad, good])
    assert host.rejected == 3
    # a coordinator learning from the others
    rejects: list[str] = []
    source = rejecting_source(rejects)
    source.on_state([*bad, good])
    assert len(rejects) == 3 and all(r.startswith("estop_state: ") for r in rejects), rejects


def test_the_coordinator_answers_with_ids_and_its_release_record() -> None:
    rejects: list[str] = []
    source = rejecting_source(rejects)

    def put(msg: Estop) -> None:
        source.on_estop(rt.Received("formation/demo/estop", encode(msg), 1.0))

    put(Estop(t=1.0, engage=True, robot=None, id=9))
    put(Estop(t=1.0, engage=True, robot="r2", id=8))
    put(Estop(t=1.0, engage=False, robot=None))
    got = decode_estop_answer(source.answer, lambda e: rejects.append(str(e)))
    assert got == [(False, None, None), (True, "r2", 8), (False, None, 9)]
    # a respawned coordinator learns both the engagement and the record from this one
    respawned = rejecting_source(rejects)
    respawned.on_state(source.answer)
    assert respawned.answer == source.answer and not rejects


def test_an_agent_host_releases_a_robot_only_on_proof() -> None:
    host = HostNode("h1", ["r1", "r2"], "demo", AgentConfig(), lambda *_: None, lockstep=True)
    key = keys.estop_key("demo")
    host.estop.on_estop(rt.Received(key, encode(Estop(t=1.0, engage=True, robot="r1", id=4)), 0.0))
    host.estop.on_estop(rt.Received(key, encode(Estop(t=1.0, engage=True, robot=None, id=5)), 0.0))

    def stopped() -> dict[str, bool]:
        return {r: n.firmware.status().estop_latched for r, n in host.nodes.items()}

    assert stopped() == {"r1": True, "r2": True}
    nothing = [encode(Estop(t=1.0, engage=False, robot=None))]
    host.estop.on_estop_state(nothing)
    assert stopped() == {"r1": True, "r2": True}
    fleet_released = [*nothing, encode(Estop(t=1.0, engage=False, robot=None, id=5))]
    host.estop.on_estop_state(fleet_released)
    assert stopped() == {"r1": True, "r2": False}  # r1's own engagement still holds it
    host.estop.on_estop_state(
        [*fleet_released, encode(Estop(t=1.0, engage=False, robot="r1", id=4))]
    )
    assert stopped() == {"r1": False, "r2": False}


# --- interleavings (hypothesis) ---------------------------------------------------------------

SCOPES: tuple[str | None, ...] = (None, "r1", "r2")


@st.composite
def histories(draw: st.DrawFn, *, coordinator_sees_all: bool) -> list[tuple[object, ...]]:
    """Operations: ``("msg", engage, scope, id, to_agent, to_a, to_b)`` (an ``estop``
    message, received or missed by the agent and by coordinators A and B; an engage is sent
    twice, as the tool does, each copy received or missed on its own), ``("learn",)`` (B asks
    A, as at its start) and ``("ask", which)`` (the agent merges the answer of A, B or both)."""
    ops: list[tuple[object, ...]] = []
    next_id = 1
    for _ in range(draw(st.integers(0, 30))):
        kind = draw(st.sampled_from(["engage", "release", "ask", "learn", "legacy"]))
        if kind in ("engage", "release", "legacy"):
            scope = draw(st.sampled_from(SCOPES))
            eid: int | None = None
            if kind == "engage":
                eid, next_id = next_id, next_id + draw(st.integers(1, 3))
            copies = 2 if kind != "release" else 1
            for _ in range(copies):
                to_a = coordinator_sees_all or draw(st.booleans())
                ops.append(("msg", kind != "release", scope, eid, draw(st.booleans()), to_a,
                            draw(st.booleans())))  # fmt: skip
        elif kind == "learn":
            ops.append(("learn",))
        else:
            ops.append(("ask", draw(st.sampled_from(["a", "b", "ab"]))))
    return ops


class _Model:
    """What each coordinator saw released: the engagements it held (from a message, or learned
    from A for B) when a release message of their scope reached it; B also learns A's record."""

    def __init__(self) -> None:
        self.held: dict[str, dict[str | None, set[int]]] = {"a": {}, "b": {}}
        self.saw_released: dict[str, set[tuple[str | None, int]]] = {"a": set(), "b": set()}

    def message(self, who: str, engage: bool, scope: str | None, eid: int | None) -> None:
        held = self.held[who]
        if engage:
            if eid is not None:
                held.setdefault(scope, set()).add(eid)
                self.saw_released[who].discard((scope, eid))
        else:
            self.saw_released[who] |= {(scope, i) for i in held.pop(scope, set())}

    def learn(self) -> None:
        """B adds A's engagements (held since: B's next release message releases them) and
        A's release record."""
        known = self.saw_released["a"] | self.saw_released["b"]
        for scope, ids in self.held["a"].items():
            self.held["b"].setdefault(scope, set()).update(
                i for i in ids if (scope, i) not in known
            )
        self.saw_released["b"] |= self.saw_released["a"]


def _run(ops: list[tuple[object, ...]]) -> tuple[EstopLatch, EstopLatch, _Model, dict[str, bool]]:
    agent, coords, model = EstopLatch(), {"a": EstopLatch(), "b": EstopLatch()}, _Model()
    truth: dict[str | None, bool] = {}  # the operator's view: the last message of each scope
    for op in ops:
        if op[0] == "msg":
            _, engage, scope, eid, to_agent, to_a, to_b = op
            assert isinstance(engage, bool) and (scope is None or isinstance(scope, str))
            assert eid is None or isinstance(eid, int)
            truth[scope] = engage
            if to_agent:
                agent.apply(engage, scope, eid)
            for who, got in (("a", to_a), ("b", to_b)):
                if got:
                    coords[who].apply(engage, scope, eid)
                    model.message(who, engage, scope, eid)
        elif op[0] == "learn":
            coords["b"].merge_answer(coords["a"].answer(), release=False)
            model.learn()
        else:
            which = str(op[1])
            answer = [e for who in which for e in coords[who].answer()]
            proof = set().union(*(model.saw_released[who] for who in which))
            before = {(s, i) for s, ids in agent.held.items() for i in ids}
            agent.merge_answer(answer)
            after = {(s, i) for s, ids in agent.held.items() for i in ids}
            gone = before - after
            assert gone <= proof, (gone, proof)  # never released without proof
            assert all(i != NO_ID for _s, i in gone)
    stopped = {r: bool(truth.get(None) or truth.get(r)) for r in ("r1", "r2")}
    return agent, coords["a"], model, stopped


@settings(max_examples=400, deadline=None)
@given(histories(coordinator_sees_all=False))
def test_an_answer_never_releases_an_engagement_its_coordinator_did_not_see_released(
    ops: list[tuple[object, ...]],
) -> None:
    _run(ops)


def _engages_per_scope(ops: list[tuple[object, ...]]) -> int:
    ids = {(op[2], op[3]) for op in ops if op[0] == "msg" and op[1]}
    return max((sum(1 for s, _ in ids if s == scope) for scope in SCOPES), default=0)


def _with_ids(latch: EstopLatch) -> dict[str | None, set[int]]:
    return {s: ids - {NO_ID} for s, ids in latch.held.items() if ids - {NO_ID}}


@settings(max_examples=300, deadline=None)
@given(histories(coordinator_sees_all=True))
def test_a_coordinator_that_saw_everything_brings_the_agent_to_the_truth(
    ops: list[tuple[object, ...]],
) -> None:
    assume(_engages_per_scope(ops) <= MAX_IDS)  # no scope pinned (that needs a release message)
    agent, a, _model, stopped = _run(ops)
    agent.merge_answer(a.answer())
    assert _with_ids(agent) == _with_ids(a)
    for robot in ("r1", "r2"):
        assert a.stopped(robot) == stopped[robot]
        if stopped[robot]:
            assert agent.stopped(robot)  # A holds it: its answer adds it
        elif agent.stopped(robot):
            # only an engagement without id, whose release message the agent missed
            assert NO_ID in agent.held.get(None, set()) | agent.held.get(robot, set())


# --- end to end: a real agent, a real coordinator started after the e-stop --------------------


def _held(client: zenoh.Session, name: str, want: list[Estop]) -> None:
    """Agent ``name``'s answer on ``estop/held/<name>`` becomes ``want`` (t aside)."""
    key = keys.estop_held_key(FLEET, name)
    answer_of(client, key, lambda a: [replace(e, t=0.0) for e in a] == want)


@pytest.mark.zenoh
def test_an_estop_no_coordinator_received_holds_agents_started_later_until_released(
    spawn: Spawner, router: RouterHandle, session: Callable[..., zenoh.Session]
) -> None:
    """No coordinator runs when the fleet is e-stopped. The agent that got it answers
    ``estop/held/r1`` with the engagement; an agent started afterwards learns it there and comes
    up stopped, and so does a coordinator started alone (it then answers with it); the operator's
    release lets both drive and empties the held answer. (Before agents answered: the coordinator
    said "nothing latched" and a robot started then drove at once.)"""
    client = session()
    pubs = rt.Publishers(client)
    start_agent(spawn, router)
    wheels = Recorder(client, keys.wheels_key(FLEET, "r1"), decoder_of(Wheels))
    status = Recorder(client, keys.status_key(FLEET, "r1"), decoder_of(Status))
    wheels2 = Recorder(client, keys.wheels_key(FLEET, "r2"), decoder_of(Wheels))
    status2 = Recorder(client, keys.status_key(FLEET, "r2"), decoder_of(Status))
    key = keys.estop_key(FLEET)
    with (
        Feeder(pubs, "r1", pose=lambda: (0.0, 0.0, 0.0), setpoint=lambda: (0.45, 0.0)),
        Feeder(pubs, "r2", pose=lambda: (0.0, 1.5, 0.0), setpoint=lambda: (0.45, 1.5)),
    ):
        wheels.wait_for(lambda _r, _k, w: nonzero(w), timeout_s=10.0)
        _held(client, "r1", [])  # nothing held: no queryable, no answer
        t_engage = time.monotonic()
        engage = Estop(t=t_engage, engage=True, robot=None, id=new_estop_id())
        pubs.put(key, encode(engage), rt.QOS_CRITICAL)
        wheels.wait_for(lambda r, _k, w: r > t_engage and not nonzero(w), timeout_s=1.0)
        _held(client, "r1", [replace(engage, t=0.0)])

        # An agent started now: no coordinator anywhere, r1 tells it.
        t_r2 = time.monotonic()
        start_agent(spawn, router, robot="r2")
        # Only now a coordinator starts: it never received the e-stop and finds no other
        # coordinator; it learns the engagement from the agents and answers with it.
        spawn(
            "coordinator", "--scenario", "paper-exp1", "--fleet", FLEET,
            "--endpoint", router.endpoint, ready="coord",
        )  # fmt: skip
        t_coord = time.monotonic()
        answer_of(client, key, lambda a: [replace(e, t=0.0) for e in a] == [replace(engage, t=0.0)])
        time.sleep(3.2)  # three refresh periods (ESTOP_REFRESH_S)
        t_end = time.monotonic()
        assert_stopped(wheels, status, t_coord, t_end, min_wheels=30, min_status=10)
        assert_stopped(wheels2, status2, t_r2, t_end, min_wheels=30, min_status=10)
        _held(client, "r2", [replace(engage, t=0.0)])

        # the operator's release (no id: scope only) lets both drive again
        t_release = time.monotonic()
        pubs.put(key, encode(Estop(t=t_release, engage=False, robot=None)), rt.QOS_CRITICAL)
        for w, st in ((wheels, status), (wheels2, status2)):
            w.wait_for(lambda r, _k, w: r > t_release and nonzero(w), timeout_s=2.0)
            st.wait_for(lambda r, _k, s: r > t_release and s.mode != "estop", timeout_s=2.0)
        _held(client, "r1", [])
        _held(client, "r2", [])


@pytest.mark.zenoh
async def test_a_query_gets_every_entry_of_every_coordinator(
    session: Callable[..., zenoh.Session],
) -> None:
    """The answer is many replies on one key, from each coordinator: Zenoh's default query
    (consolidation "latest" per key, target "best matching") kept one reply of one responder,
    so an agent saw only the last entry of one coordinator's answer (found by this work: a
    release record last in the answer hid the engagements before it)."""
    import asyncio

    from runtime.query import Answerer

    key = keys.estop_key("consolidation")
    one, two = EstopLatch(), EstopLatch()
    one.apply(True, "r1", 1)
    one.apply(True, "r2", 2)
    one.apply(True, None, 3)
    one.apply(False, None)
    two.apply(True, "r3", 4)
    answerers = [Answerer(session(), key), Answerer(session(), key)]
    for answerer, latch in zip(answerers, (one, two), strict=True):
        answerer.snapshot = tuple(_payloads(latch))
    asker = session()
    await asyncio.sleep(0.3)  # the queryables declared through the router
    try:
        got = decode_estop_answer(get_all(asker, key, 0.5), lambda e: pytest.fail(str(e)))
        assert sorted(got, key=repr) == sorted(one.answer() + two.answer(), key=repr)
    finally:
        for answerer in answerers:
            answerer.close()
