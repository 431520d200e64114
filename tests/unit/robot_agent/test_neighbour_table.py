"""The neighbour table both the agent and the agent host own (robot_agent.core.neighbour_table):
lockstep arrivals, the cooperative rule, bounded memory under a flood of ids."""

from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st

from robot_agent.core.neighbour_table import NeighbourTable
from robot_agent.core.neighbours import COOPERATIVE_STATUS_S, NEIGHBOUR_STALE_S


def test_lockstep_poses_are_pending_until_the_clock_settles_them() -> None:
    table = NeighbourTable(lockstep=True, max_robots=8)
    table.store("r2", 1.0, 2.0, 0.5, 0.02, None, 0.0)
    assert table.neighbours(0.06) == []  # pending: no receive time yet
    assert table.settle(0.06) is True
    assert table.settle(0.08) is False  # nothing pending any more
    (nb,) = table.neighbours(0.06)
    assert (nb.x, nb.y, nb.theta) == (1.0, 2.0, 0.5)
    assert nb.age_s == 0.06 - 0.02
    assert table.neighbours(0.06 + NEIGHBOUR_STALE_S + 0.01) == []  # received too long ago


def test_lockstep_cooperative_is_what_the_clock_relays() -> None:
    table = NeighbourTable(lockstep=True, max_robots=8, local_tracking=lambda rid: True)
    table.relay(("r3",))
    assert table.cooperative("r3", 0.0) and not table.cooperative("r2", 0.0)
    table.note_mode("r2", True, 0.0)  # a status does not count in lockstep
    assert not table.cooperative("r2", 0.0)


def test_realtime_cooperative_is_a_fresh_status_or_the_local_mode() -> None:
    hosted = {"h1": True, "h2": False}
    table = NeighbourTable(lockstep=False, max_robots=8, local_tracking=hosted.get)
    table.note_mode("r2", True, 10.0)
    table.note_mode("h2", True, 10.0)  # a hosted robot's status is not taken: its own mode is
    assert table.cooperative("r2", 10.0 + COOPERATIVE_STATUS_S)
    assert not table.cooperative("r2", 10.0 + COOPERATIVE_STATUS_S + 0.01)  # stale
    assert table.cooperative("h1", 10.0) and not table.cooperative("h2", 10.0)
    table.note_mode("r2", False, 11.0)
    assert not table.cooperative("r2", 11.0)


def test_a_full_table_drops_stale_ids_first_then_refuses_new_ones() -> None:
    table = NeighbourTable(lockstep=False, max_robots=2)
    assert table.store("a", 0, 0, 0, 1.0, 1.0, 1.0) is not None
    assert table.store("b", 0, 0, 0, 1.0, 1.0, 1.0) is not None
    assert table.store("c", 0, 0, 0, 1.5, 1.5, 1.5) is None  # both current: refused
    later = 1.0 + NEIGHBOUR_STALE_S + 0.1
    assert table.store("c", 0, 0, 0, later, later, later) is not None  # a and b were stale
    assert list(table.seen) == ["c"]
    assert table.store("c", 1, 1, 0, later, later, later) is not None  # a known id: updated
    assert table.seen["c"].x == 1


@settings(max_examples=200, deadline=None)
@given(
    st.booleans(),
    st.lists(
        st.tuples(
            st.sampled_from(["pose", "mode", "clock"]),
            st.text(alphabet="abcdefgh", min_size=1, max_size=2),
            st.floats(0.0, 5.0),
        ),
        max_size=120,
    ),
)
def test_memory_stays_bounded_and_first_seen_order_is_kept(
    lockstep: bool, ops: list[tuple[str, str, float]]
) -> None:
    cap = 5
    table = NeighbourTable(lockstep=lockstep, max_robots=cap)
    now = 0.0
    for kind, rid, dt in ops:
        now += dt
        if kind == "pose":
            table.store(rid, 0.0, 0.0, 0.0, now, None if lockstep else now, now)
            table.end_frame()
        elif kind == "mode":
            table.note_mode(rid, True, now)
        else:
            table.settle(now)
        assert len(table.seen) <= cap
        assert len(table._modes) <= cap
        assert len(table._pending) <= 4 * cap + 1
        orders = [e.order for e in table.seen.values()]
        assert orders == sorted(orders) and len(set(orders)) == len(orders)
