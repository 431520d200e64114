"""The one decoder of a query's answer on the ``estop`` key (``bus_schemas.decode_estop_answer``),
used by agents (robot_agent.node.agent_estop), agent hosts (robot_agent.node.host) and coordinators
(coordinator.node.estop_source): a latch's answer round-trips into another latch, invalid payloads
are rejected one by one and never latch or release anything."""

from __future__ import annotations

from bus_schemas import DecodeError, Estop, Reason, decode_estop_answer, encode
from coordinator.node.estop_source import EstopSource
from robot_agent.core.estop import EstopLatch
from runtime import NodeLog


def _answer(latch: EstopLatch, t: float = 3.0) -> list[bytes]:
    return [encode(Estop(t=t, engage=e, robot=r, id=i)) for e, r, i in latch.answer()]


def test_a_latch_answer_round_trips_in_order() -> None:
    src = EstopLatch()
    src.apply(True, "r2", 22)
    src.apply(True, "r1")  # an older sender: no id
    src.apply(True, "r4", 44)
    src.apply(False, "r4")
    errors: list[DecodeError] = []
    entries = decode_estop_answer(_answer(src), errors.append)
    want = [(False, None, None), (True, "r1", None), (True, "r2", 22), (False, "r4", 44)]
    assert entries == src.answer() == want and not errors
    dst = EstopLatch()
    assert dst.merge_answer(entries)
    assert (dst.held, dst.released) == (src.held, src.released)


def test_invalid_payloads_are_rejected_one_by_one() -> None:
    good = encode(Estop(t=1.0, engage=True, robot=None))
    bad_id = encode(Estop(t=1.0, engage=True, robot="r1")).replace(b"\xa2r1", b"\xa2R1")
    errors: list[DecodeError] = []
    pairs = decode_estop_answer([b"\xc1", bad_id, good, b"\x93\x01\x02\x03"], errors.append)
    assert pairs == [(True, None, None)]
    assert [e.reason for e in errors] == [Reason.MALFORMED, Reason.OUT_OF_RANGE, Reason.NOT_A_MAP]
    assert decode_estop_answer([], errors.append) == []


def test_the_coordinator_counts_rejected_answers() -> None:
    rejects: list[str] = []
    source = EstopSource(
        "formation/demo/estop",
        lambda: 1.0,
        lambda what, why, reason=None: rejects.append(what),
        lambda where, exc: None,
        NodeLog("test"),
    )
    src = EstopLatch()
    src.apply(True, "r3")
    source.on_state([b"\xc1", *_answer(src)])
    assert rejects == ["estop_state"] and source.latch.robots == {"r3"}
