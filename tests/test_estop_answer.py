"""The one decoder of a query's answer on the ``estop`` key (``bus_schemas.decode_estop_answer``),
used by agents (robot_agent.node_estop), agent hosts (robot_agent.host) and coordinators
(coordinator.estop_source): a latch's answer round-trips into another latch, invalid payloads
are rejected one by one and never latch or release anything."""

from __future__ import annotations

from bus_schemas import DecodeError, Estop, Reason, decode_estop_answer, encode
from coordinator.estop_source import EstopSource
from robot_agent.estop import EstopLatch
from runtime import NodeLog


def _answer(latch: EstopLatch, t: float = 3.0) -> list[bytes]:
    return [encode(Estop(t=t, engage=e, robot=r)) for e, r in latch.answer()]


def test_a_latch_answer_round_trips_in_order() -> None:
    src = EstopLatch()
    src.apply(True, "r2")
    src.apply(True, "r1")
    errors: list[DecodeError] = []
    pairs = decode_estop_answer(_answer(src), errors.append)
    assert pairs == src.answer() == [(False, None), (True, "r1"), (True, "r2")] and not errors
    dst = EstopLatch()
    assert dst.merge_answer(pairs, replace=True)
    assert (dst.fleet, dst.robots) == (src.fleet, src.robots)


def test_invalid_payloads_are_rejected_one_by_one() -> None:
    good = encode(Estop(t=1.0, engage=True, robot=None))
    bad_id = encode(Estop(t=1.0, engage=True, robot="r1")).replace(b"\xa2r1", b"\xa2R1")
    errors: list[DecodeError] = []
    pairs = decode_estop_answer([b"\xc1", bad_id, good, b"\x93\x01\x02\x03"], errors.append)
    assert pairs == [(True, None)]
    assert [e.reason for e in errors] == [Reason.MALFORMED, Reason.OUT_OF_RANGE, Reason.NOT_A_MAP]
    assert decode_estop_answer([], errors.append) == []


def test_the_coordinator_counts_rejected_answers() -> None:
    rejects: list[str] = []
    source = EstopSource(
        "formation/demo/estop",
        lambda: 1.0,
        lambda what, why: rejects.append(what),
        lambda where, exc: None,
        NodeLog("test"),
    )
    src = EstopLatch()
    src.apply(True, "r3")
    source.on_state([b"\xc1", *_answer(src)])
    assert rejects == ["estop_state"] and source.latch.robots == {"r3"}
