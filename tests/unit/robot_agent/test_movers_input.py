"""robot_agent/node/movers_input.py and rule 4 of robot_agent/core/neighbours.py (issue 30): the
coordinator's movers reach the firmware's neighbour list as non-cooperative neighbours with
their velocity; lockstep by tick (k - 1 at clock k), realtime by receive time; a bad message is
counted."""

from __future__ import annotations

import math

from bus_schemas import Movers, encode
from robot_agent.core.neighbour_table import NeighbourTable
from robot_agent.core.neighbours import MOVERS_STALE_S
from robot_agent.node.movers_input import MoversInput


def _payload(tick: int | None, vx: float = -0.3) -> bytes:
    return encode(
        Movers(t=1.0, seq=1, robots=("r4",), x=(0.5,), y=(0.0,), vx=(vx,), vy=(0.0,), tick=tick)
    )


def test_lockstep_movers_of_tick_k_minus_1_at_clock_k() -> None:
    rejects: list[tuple[object, ...]] = []
    inp = MoversInput(lockstep=True, reject=lambda *a: rejects.append(a))
    inp.on_payload(_payload(7), 0.0)
    assert inp.for_clock(8) == {"r4": (-0.3, 0.0)}
    assert inp.for_clock(9) == {} and inp.for_clock(7) == {}
    inp.on_payload(_payload(None), 0.0)  # no tick in lockstep
    inp.on_payload(b"\x00junk", 0.0)
    assert len(rejects) == 2 and inp.received == 1


def test_realtime_movers_expire() -> None:
    inp = MoversInput(lockstep=False, reject=lambda *a: None)
    inp.on_payload(_payload(None), 10.0)
    assert inp.at(10.0 + MOVERS_STALE_S) == {"r4": (-0.3, 0.0)}
    assert inp.at(10.0 + MOVERS_STALE_S + 0.01) == {}


def test_a_mover_is_a_non_cooperative_neighbour_with_its_velocity() -> None:
    table = NeighbourTable(lockstep=True, max_robots=8)
    for rid, x in (("r2", 0.0), ("r4", 0.5)):
        table.store(rid, x, 0.0, 0.0, 1.0, 1.0, 1.0)
    table.relay(("r2", "r4"))  # both were TRACKING
    plain = table.neighbours(1.0)
    assert [n.cooperative for n in plain] == [True, True]
    moved = table.neighbours(1.0, {"r4": (-0.3, 0.1), "gone": (1.0, 1.0)})
    assert moved[0] == plain[0]
    assert (moved[1].cooperative, moved[1].vx, moved[1].vy) == (False, -0.3, 0.1)
    assert (moved[1].x, moved[1].y, moved[1].age_s) == (plain[1].x, plain[1].y, plain[1].age_s)
    assert math.isclose(moved[1].theta, 0.0)


def test_an_agent_hosts_grid_applies_the_movers() -> None:
    from robot_agent.core.host_grid import NeighbourGrid

    table = NeighbourTable(lockstep=True, max_robots=8)
    for rid, x in (("r1", 0.0), ("r2", 0.3), ("r4", 0.6)):
        table.store(rid, x, 0.0, 0.0, 1.0, 1.0, 1.0)
    table.relay(("r2", "r4"))
    grid = NeighbourGrid(1.0, table.cooperative, table.seen)
    before = grid.neighbours_of("r1", 0.0, 0.0, 1.0)
    grid.set_movers({"r4": (-0.3, 0.0)})
    after = grid.neighbours_of("r1", 0.0, 0.0, 1.0)
    assert after[0] == before[0]
    assert (after[1].cooperative, after[1].vx) == (False, -0.3)
    assert before[1].cooperative
