"""The standby election (coordinator.election) as a pure core: time passed in, typed peers."""

from __future__ import annotations

from hypothesis import given
from hypothesis import strategies as st

from bus_schemas import Heartbeat, encode
from bus_schemas.fields import EPOCH_MAX
from coordinator.election import (
    EPOCH_JUMP_MAX,
    MAX_PEERS,
    STANDBY_SETTLE_S,
    Election,
    Peer,
    rank,
)


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


def test_leader_t0_is_the_observed_one() -> None:
    e = standby()
    e.peer_alive("a", True)
    e.peer_alive("b", True)
    assert e.heartbeat("a", True, 2, 50.0) is None
    assert e.heartbeat("b", True, 5, 70.0) is None  # another origin: refused
    assert e.rejects == {"leader_t0": 1} and e.last_refusal == "leader_t0"
    e.peer_alive("a", False)
    e.peer_alive("b", False)
    t = e.take_over()
    assert t.leader_t0 == 50.0 and t.epoch == 3


def test_split_brain_lower_epoch_steps_down() -> None:
    e = Election("b", active=True)
    e.epoch = 2
    for name in ("a", "c"):
        e.peer_alive(name, True)
    assert e.heartbeat("a", True, 1, 0.0) is None  # we win on epoch
    why = e.heartbeat("c", True, 3, 0.0)
    assert why is not None and "epoch 3" in why
    assert e.step_down(5.0)
    assert not e.active and e.stepdowns == 1 and e.started_s == 5.0
    assert not e.step_down(6.0)  # already a standby
    same = Election("b", active=True)
    same.peer_alive("a", True)
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


# -- forged heartbeats (issue 13 item 2) --------------------------------------------------------


def running_pair() -> tuple[Election, Election]:
    """``main`` active at epoch 1 ticking from t0 = 100 s, ``b`` its standby that has seen it."""
    main = Election("main", active=True)
    main.epoch = 1
    main.observe_t0(100.0)
    b = standby("b")
    main.peer_alive("b", True)
    b.peer_alive("main", True)
    assert b.heartbeat("main", True, 1, 100.0) is None
    assert main.heartbeat("b", False, 0, 100.0) is None
    return main, b


def test_a_heartbeat_without_a_token_is_refused() -> None:
    main, b = running_pair()
    for e in (main, b):
        assert e.heartbeat("forger", True, 2, 100.0) is None
        assert e.rejects == {"no_token": 1}
    assert main.active and not b.should_take_over(10.0)
    assert "forger" not in b.peers or b.peers["forger"].active is None


def test_a_forged_epoch_max_is_refused_and_the_epoch_cannot_overflow() -> None:
    main, b = running_pair()
    # spoofing main's own name (its token is present) with the largest epoch of the contract
    assert b.heartbeat("main", True, EPOCH_MAX, 100.0) is None
    assert main.heartbeat("b", True, EPOCH_MAX, 100.0) is None  # would have made main step down
    assert main.active and b.rejects == {"epoch_jump": 1} and main.rejects == {"epoch_jump": 1}
    # a real takeover afterwards takes the next epoch, not EPOCH_MAX + 1
    b.peer_alive("main", False)
    t = b.take_over()
    assert t.epoch == 2 and t.leader_t0 == 100.0
    encode(Heartbeat(t=1.0, seq=1, name="b", active=True, epoch=t.epoch, leader_t0=100.0))


def test_epochs_saturate_at_the_contract_bound() -> None:
    e = standby("b")
    e.peer_alive("main", True)
    assert e.heartbeat("main", True, EPOCH_MAX, 5.0) is None  # first baseline: accepted
    e.peer_alive("main", False)
    t = e.take_over()
    assert t.epoch == EPOCH_MAX  # saturated, still encodable
    encode(Heartbeat(t=1.0, seq=1, name="b", active=True, epoch=t.epoch, leader_t0=5.0))
    # tie at EPOCH_MAX: the rank decides, deterministically
    e.peer_alive("main", True)
    why = e.heartbeat("main", True, EPOCH_MAX, 5.0)
    assert why is not None  # main outranks b at the same epoch


def test_epochs_are_monotonic_per_token_lifetime() -> None:
    _, b = running_pair()
    assert b.heartbeat("main", True, 3, 100.0) is None  # e.g. a forged, in-bound epoch
    assert b.heartbeat("main", True, 1, 100.0) is None  # main's real one is not locked out
    assert b.rejects == {} and b.peers["main"].epoch == 3 and b.peers["main"].active
    b.peer_alive("main", False)
    b.peer_alive("main", True)  # restarted: a new token lifetime
    assert b.heartbeat("main", False, 0, 100.0) is None and b.peers["main"].epoch == 0


def test_a_forged_leader_t0_never_moves_the_virtual_leader() -> None:
    main, b = running_pair()
    for t0 in (0.0, 0.0 - 100.0, 100.0 - 100.0, 1e8):
        assert b.heartbeat("main", True, 1, t0) is None
        assert main.heartbeat("b", False, 0, t0) is None  # a standby's t0 is not looked at
    assert b.rejects == {"leader_t0": 4} and b.leader_t0 == 100.0
    assert b.peers["main"].leader_t0 == 100.0
    # forged "b is active" with another origin and a higher epoch: main steps down (split brain
    # rule, b holds a token) but keeps its origin; a takeover continues the same trajectory
    why = main.heartbeat("b", True, 2, 0.0)
    assert why is not None and main.rejects == {"leader_t0": 1}
    main.step_down(1.0)
    assert main.leader_t0 == 100.0
    main.peer_alive("b", False)
    assert main.take_over().leader_t0 == 100.0


@given(
    st.lists(
        st.tuples(
            st.sampled_from(["main", "b", "forger", "zz", "aaa"]),
            st.booleans(),
            st.integers(0, EPOCH_MAX),
            st.floats(-1e9, 1e9, allow_nan=False),
            st.booleans(),
        ),
        max_size=40,
    )
)
def test_no_forged_heartbeat_sequence_moves_the_leader_or_overflows(
    events: list[tuple[str, bool, int, float, bool]],
) -> None:
    """Whatever schema-valid heartbeats arrive (any name, role, epoch, origin; tokens of the
    real peers only), the standby's takeover continues the observed trajectory and its epoch
    is encodable and at most the observed epoch + EPOCH_JUMP_MAX + 1."""
    _, b = running_pair()
    for name, active, epoch, t0, toggle in events:
        if toggle and name == "main":  # the real active's token flaps (a router restart)
            b.peer_alive("main", not b.peers["main"].alive)
        b.heartbeat(name, active, epoch, t0)
    b.peer_alive("main", False)
    t = b.take_over()
    assert t.leader_t0 == 100.0
    assert 2 <= t.epoch <= min(EPOCH_MAX, 1 + EPOCH_JUMP_MAX * (len(events) + 1) + 1)
    encode(Heartbeat(t=1.0, seq=1, name="b", active=True, epoch=t.epoch, leader_t0=t.leader_t0))
