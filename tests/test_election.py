"""The standby election (coordinator.election) as a pure core: time passed in, typed peers."""

from __future__ import annotations

from hypothesis import given
from hypothesis import strategies as st

from coordinator.election import MAX_PEERS, STANDBY_SETTLE_S, Election, Peer, rank


def standby(name: str = "standby", now: float = 0.0) -> Election:
    e = Election(name, active=False)
    e.start(now)
    return e


def test_rank_puts_main_first() -> None:
    assert sorted(["b", "main", "a"], key=rank) == ["main", "a", "b"]


def test_nothing_is_decided_before_the_settle_time() -> None:
    e = standby(now=10.0)
    assert not e.should_take_over(10.0 + STANDBY_SETTLE_S / 2)
    assert e.should_take_over(10.0 + STANDBY_SETTLE_S)  # nobody else: take over
    assert not Election("x", active=False).should_take_over(1e9)  # never started watching


def test_a_live_active_or_unknown_peer_blocks_a_takeover() -> None:
    e = standby()
    assert e.peer_alive("main", True)
    assert not e.should_take_over(1.0)  # role unknown until its heartbeat
    e.heartbeat("main", True, 3, 100.0)
    assert not e.should_take_over(1.0)  # active
    assert e.peer_alive("main", False)
    assert e.should_take_over(1.0)  # its token vanished
    t = e.take_over()
    assert e.active and e.takeovers == 1
    assert t.epoch == 4  # the highest seen + 1
    assert t.leader_t0 == 100.0  # the trajectory continues


def test_a_live_standby_earlier_in_order_goes_first() -> None:
    e = standby("zeta")
    e.peer_alive("alpha", True)
    e.heartbeat("alpha", False, 0, 0.0)
    assert not e.should_take_over(1.0)
    e.peer_alive("alpha", False)
    assert e.should_take_over(1.0)


def test_without_a_previous_active_the_trajectory_starts_here() -> None:
    e = standby()
    t = e.take_over()
    assert t.leader_t0 is None and t.epoch == 1


def test_leader_t0_comes_from_the_highest_epoch() -> None:
    e = standby()
    e.heartbeat("a", True, 2, 50.0)
    e.heartbeat("b", True, 5, 70.0)
    e.peer_alive("a", False)
    e.peer_alive("b", False)
    assert e.take_over().leader_t0 == 70.0


def test_split_brain_lower_epoch_steps_down() -> None:
    e = Election("b", active=True)
    e.epoch = 2
    assert e.heartbeat("a", True, 1, 0.0) is None  # we win on epoch
    why = e.heartbeat("c", True, 3, 0.0)
    assert why is not None and "epoch 3" in why
    assert e.step_down(5.0)
    assert not e.active and e.stepdowns == 1 and e.started_s == 5.0
    assert not e.step_down(6.0)  # already a standby
    same = Election("b", active=True)
    assert same.heartbeat("a", True, 0, 0.0) is not None  # same epoch: the earlier name wins


def test_own_messages_and_repeats_are_ignored() -> None:
    e = standby("me")
    assert not e.peer_alive("me", True)
    assert e.heartbeat("me", True, 99, 1.0) is None
    assert "me" not in e.peers
    assert e.peer_alive("x", True)
    assert not e.peer_alive("x", True)  # no change
    assert e.peers["x"] == Peer(alive=True, active=None)


def test_peer_table_is_bounded() -> None:
    e = standby()
    for i in range(MAX_PEERS + 10):
        e.peer_alive(f"c{i}", True)
    assert len(e.peers) == MAX_PEERS


@given(st.lists(st.tuples(st.sampled_from(["a", "b", "main"]), st.booleans()), max_size=30))
def test_at_most_one_instance_takes_over_with_everyone_gone(events: list[tuple[str, bool]]) -> None:
    """Whatever the token history, two standbys never both decide to take over while each
    sees the other alive as a standby."""
    x, y = standby("a"), standby("b")
    for name, alive in events:
        for e in (x, y):
            e.peer_alive(name, alive)
    for e, other in ((x, y), (y, x)):
        e.peer_alive(other.name, True)
        e.heartbeat(other.name, False, 0, 0.0)
    for e in (x, y):
        e.peer_alive("main", False)
    assert x.should_take_over(1.0) != y.should_take_over(1.0) or not x.should_take_over(1.0)
    assert not y.should_take_over(1.0)  # "a" comes first
