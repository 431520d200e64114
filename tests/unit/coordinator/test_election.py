"""The standby election (coordinator.core.election) as a pure core: time passed in, typed peers."""

from __future__ import annotations

from typing import Any

from hypothesis import given
from hypothesis import strategies as st

from bus_schemas import Heartbeat, encode
from bus_schemas.fields import EPOCH_MAX
from coordinator.core.election import (
    EPOCH_JUMP_MAX,
    EPOCH_RATE_PER_S,
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
    e.heartbeat("main", True, 3, 100.0, now_s=0.0)
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
    e.heartbeat("alpha", False, 0, 0.0, now_s=0.0)
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
    assert e.heartbeat("a", True, 2, 50.0, now_s=0.0) is None
    assert e.heartbeat("b", True, 5, 70.0, now_s=0.0) is None  # another origin: refused
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
    assert e.heartbeat("a", True, 1, 0.0, now_s=0.0) is None  # we win on epoch
    why = e.heartbeat("c", True, 3, 0.0, now_s=0.0)
    assert why is not None and "epoch 3" in why
    assert e.step_down(5.0)
    assert not e.active and e.stepdowns == 1 and e.started_s == 5.0
    assert not e.step_down(6.0)  # already a standby
    same = Election("b", active=True)
    same.peer_alive("a", True)
    assert (
        same.heartbeat("a", True, 0, 0.0, now_s=0.0) is not None
    )  # same epoch: the earlier name wins


def test_own_messages_and_repeats_are_ignored() -> None:
    e = standby("me")
    assert not e.peer_alive("me", True)
    assert e.heartbeat("me", True, 99, 1.0, now_s=0.0) is None
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
        e.heartbeat(other.name, False, 0, 0.0, now_s=0.0)
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
    assert b.heartbeat("main", True, 1, 100.0, now_s=0.0) is None
    assert main.heartbeat("b", False, 0, 100.0, now_s=0.0) is None
    return main, b


def test_a_heartbeat_without_a_token_is_refused() -> None:
    main, b = running_pair()
    for e in (main, b):
        assert e.heartbeat("forger", True, 2, 100.0, now_s=0.0) is None
        assert e.rejects == {"no_token": 1}
    assert main.active and not b.should_take_over(10.0)
    assert "forger" not in b.peers or b.peers["forger"].active is None


def test_a_forged_epoch_max_is_refused_and_the_epoch_cannot_overflow() -> None:
    main, b = running_pair()
    # spoofing main's own name (its token is present) with the largest epoch of the contract
    assert b.heartbeat("main", True, EPOCH_MAX, 100.0, now_s=0.0) is None
    assert (
        main.heartbeat("b", True, EPOCH_MAX, 100.0, now_s=0.0) is None
    )  # would have made main step down
    assert main.active and b.rejects == {"epoch_jump": 1} and main.rejects == {"epoch_jump": 1}
    # a real takeover afterwards takes the next epoch, not EPOCH_MAX + 1
    b.peer_alive("main", False)
    t = b.take_over()
    assert t.epoch == 2 and t.leader_t0 == 100.0
    encode(Heartbeat(t=1.0, seq=1, name="b", active=True, epoch=t.epoch, leader_t0=100.0))


def test_epochs_saturate_at_the_contract_bound() -> None:
    e = standby("b")
    e.peer_alive("main", True)
    assert e.heartbeat("main", True, EPOCH_MAX, 5.0, now_s=0.0) is None  # first baseline: accepted
    e.peer_alive("main", False)
    t = e.take_over()
    assert t.epoch == EPOCH_MAX  # saturated, still encodable
    encode(Heartbeat(t=1.0, seq=1, name="b", active=True, epoch=t.epoch, leader_t0=5.0))
    # tie at EPOCH_MAX: the rank decides, deterministically
    e.peer_alive("main", True)
    why = e.heartbeat("main", True, EPOCH_MAX, 5.0, now_s=0.0)
    assert why is not None  # main outranks b at the same epoch


def test_epochs_are_monotonic_per_token_lifetime() -> None:
    _, b = running_pair()
    assert b.heartbeat("main", True, 3, 100.0, now_s=0.0) is None  # e.g. a forged, in-bound epoch
    assert (
        b.heartbeat("main", True, 1, 100.0, now_s=0.0) is None
    )  # main's real one is not locked out
    assert b.rejects == {} and b.peers["main"].epoch == 3 and b.peers["main"].active
    b.peer_alive("main", False)
    b.peer_alive("main", True)  # restarted: a new token lifetime
    assert b.heartbeat("main", False, 0, 100.0, now_s=0.0) is None and b.peers["main"].epoch == 0


def test_a_forged_leader_t0_never_moves_the_virtual_leader() -> None:
    main, b = running_pair()
    for t0 in (0.0, 0.0 - 100.0, 100.0 - 100.0, 1e8):
        assert b.heartbeat("main", True, 1, t0, now_s=0.0) is None
        assert (
            main.heartbeat("b", False, 0, t0, now_s=0.0) is None
        )  # a standby's t0 is not looked at
    assert b.rejects == {"leader_t0": 4} and b.leader_t0 == 100.0
    assert b.peers["main"].leader_t0 == 100.0
    # forged "b is active" with another origin and a higher epoch: main steps down (split brain
    # rule, b holds a token) but keeps its origin; a takeover continues the same trajectory
    why = main.heartbeat("b", True, 2, 0.0, now_s=0.0)
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
        b.heartbeat(name, active, epoch, t0, now_s=0.0)
    b.peer_alive("main", False)
    t = b.take_over()
    assert t.leader_t0 == 100.0
    assert 2 <= t.epoch <= min(EPOCH_MAX, 1 + EPOCH_JUMP_MAX * (len(events) + 1) + 1)
    encode(Heartbeat(t=1.0, seq=1, name="b", active=True, epoch=t.epoch, leader_t0=t.leader_t0))


# -- origins checked against the observed leader messages (issue 13: name spoofing) ------------

SPEED = 0.02  # m/s, a straight line like paper-exp2's virtual leader
T0 = 100.0  # the real active's trajectory origin


def line(t_s: float) -> tuple[float, float]:
    return (SPEED * t_s, 0.5)


def watcher() -> Election:
    """A standby ``b`` that knows the trajectory and sees ``main``'s token, no heartbeat yet."""
    b = Election("b", active=False, position_at=line)
    b.start(0.0)
    b.peer_alive("main", True)
    return b


def real_leaders(b: Election, t_from: float, t_to: float, step: float = 0.02) -> float:
    """The real active's leader messages (stamp = receive time here, same host)."""
    t = t_from
    while t <= t_to:
        b.observe_leader(t, *line(t - T0), now_s=t)
        t += step
    return t


def test_a_spoofed_origin_heard_first_is_never_adopted() -> None:
    b = watcher()
    now = real_leaders(b, 200.0, 200.2)
    # a forger spoofs main's name (its token is alive) before main's first real heartbeat
    assert b.heartbeat("main", True, 1, T0 - 100.0, now_s=now) is None
    assert b.last_refusal == "leader_t0" and b.leader_t0 is None
    assert b.heartbeat("main", True, 1, T0, now_s=now) is None  # the real one: verified
    assert b.last_refusal is None and b.leader_t0 == T0
    now = real_leaders(b, now, now + 0.5)
    assert b.heartbeat("main", True, 1, 0.0, now_s=now) is None  # leader_t0 = 0: 181 m away
    assert b.rejects == {"leader_t0": 2} and b.leader_t0 == T0
    b.peer_alive("main", False)
    assert b.take_over().leader_t0 == T0


def test_without_recent_leader_messages_an_origin_is_not_adopted() -> None:
    b = watcher()
    assert b.heartbeat("main", True, 1, T0 - 50.0, now_s=10.0) is None  # cannot tell
    assert b.last_refusal is None and b.peers["main"].active and b.leader_t0 is None
    assert b.origin_verdict(T0, 10.0) is None
    real_leaders(b, 10.0, 10.1)
    assert b.origin_verdict(T0, 10.1) is True
    assert b.origin_verdict(T0, 10.1 + 5.0) is None  # those messages are old by then


def test_one_forged_leader_message_blocks_a_verification_but_hijacks_nothing() -> None:
    b = watcher()
    now = real_leaders(b, 50.0, 50.5)
    forged_t0 = T0 - 30.0
    b.observe_leader(now, *line(now - forged_t0), now_s=now)  # agrees with the forged origin
    assert b.origin_verdict(forged_t0, now) is False  # the real messages disagree with it
    assert b.heartbeat("main", True, 1, forged_t0, now_s=now) is None
    assert b.leader_t0 is None and b.rejects == {"leader_t0": 1}
    assert b.heartbeat("main", True, 1, T0, now_s=now) is None  # blocked while it is recent
    assert b.leader_t0 is None
    now = real_leaders(b, now + 0.02, now + 1.5)  # the forged message ages out
    assert b.heartbeat("main", True, 1, T0, now_s=now) is None and b.leader_t0 == T0


def test_a_stepped_down_instance_adopts_the_running_origin() -> None:
    """Split brain of two instances started apart: the loser keeps its own origin until the
    winner's is verified, then continues the winner's trajectory at a takeover."""
    b = Election("b", active=True, position_at=line)
    b.observe_t0(T0 + 7.0)
    b.peer_alive("main", True)
    why = b.heartbeat("main", True, 0, T0, now_s=1.0)  # main outranks b at equal epoch
    assert why is not None and b.rejects == {"leader_t0": 1}
    b.step_down(1.0)
    assert b.leader_t0 == T0 + 7.0
    now = real_leaders(b, 1.0, 1.2)
    assert b.heartbeat("main", True, 0, T0, now_s=now) is None and b.leader_t0 == T0


@given(
    st.lists(
        st.one_of(
            st.tuples(  # a forged heartbeat: any token-holding name, role, epoch, origin
                st.just("hb"),
                st.sampled_from(["main", "aaa"]),
                st.booleans(),
                st.integers(0, EPOCH_MAX),
                st.floats(-1e6, 1e6, allow_nan=False),
            ),
            st.tuples(  # a forged leader message: any position, any stamp
                st.just("leader"),
                st.floats(-1e3, 1e3, allow_nan=False),
                st.floats(-1e3, 1e3, allow_nan=False),
                st.floats(0.0, 1e4, allow_nan=False),
                st.just(0.0),
            ),
            st.tuples(st.just("real"), st.just(""), st.just(False), st.just(0), st.just(0.0)),
        ),
        max_size=60,
    )
)
def test_no_mix_of_forged_heartbeats_and_leaders_moves_the_leader(
    events: list[tuple[str, Any, Any, Any, Any]],
) -> None:
    """While the real active's leader messages keep arriving (one per 20 ms), no sequence of
    forged heartbeats (spoofed names whose tokens are alive, any epoch and origin) and forged
    leader messages gives the standby an origin that puts the virtual leader elsewhere."""
    b = watcher()
    b.peer_alive("aaa", True)
    now = real_leaders(b, 300.0, 300.1)
    b.heartbeat("main", True, 1, T0, now_s=now)
    for kind, a, c, d, e in events:
        now += 0.01
        b.observe_leader(now, *line(now - T0), now_s=now)  # the active keeps publishing
        if kind == "hb":
            b.heartbeat(a, c, d, e, now_s=now)
        elif kind == "leader":
            b.observe_leader(d, a, c, now_s=now)
        else:
            now = real_leaders(b, now, now + 0.02)
    b.peer_alive("main", False)
    b.peer_alive("aaa", False)
    t = b.take_over()
    assert t.leader_t0 is not None
    for probe in (now, now + 10.0):
        x, y = line(probe - t.leader_t0)
        rx, ry = line(probe - T0)
        assert abs(x - rx) <= 1e-3 and abs(y - ry) <= 1e-3


# -- the epoch rate bound --------------------------------------------------------------------


@given(
    st.lists(
        st.tuples(st.floats(0.0, 5.0, allow_nan=False), st.integers(0, EPOCH_MAX), st.booleans()),
        max_size=80,
    )
)
def test_the_known_epoch_rises_at_most_at_the_rate_bound(
    events: list[tuple[float, int, bool]],
) -> None:
    """A forger holding a coordinator token, sending any epochs at any times: the highest
    epoch known rises by at most EPOCH_JUMP_MAX + EPOCH_RATE_PER_S x elapsed time."""
    main, b = running_pair()
    base = b.max_epoch
    assert base is not None
    b.peer_alive("aaa", True)
    now = 0.0
    for dt, epoch, active in events:
        now += dt
        b.heartbeat("aaa", active, epoch, 100.0, now_s=now)
        assert b.max_epoch is not None
        assert b.max_epoch - base <= EPOCH_JUMP_MAX + EPOCH_RATE_PER_S * now + 1e-9
    del main


def test_a_forger_needs_years_to_saturate_the_epoch() -> None:
    _, b = running_pair()
    b.peer_alive("aaa", True)
    now = 0.0
    for _ in range(2000):  # 100 s of forged standby heartbeats at 20 Hz, +16 each
        now += 0.05
        known = b.max_epoch or 0
        b.heartbeat("aaa", False, known + EPOCH_JUMP_MAX, 100.0, now_s=now)
    assert b.max_epoch is not None and b.max_epoch <= 1 + EPOCH_JUMP_MAX + EPOCH_RATE_PER_S * now
    assert b.rejects.get("epoch_rate", 0) > 1000
    years = EPOCH_MAX / EPOCH_RATE_PER_S / (365 * 86400)
    assert years > 6  # at the bound's rate


def test_a_real_takeover_epoch_is_accepted_after_a_forger_drained_the_bucket() -> None:
    _, b = running_pair()
    b.peer_alive("aaa", True)
    for i in range(40):  # drain
        b.heartbeat("aaa", False, (b.max_epoch or 0) + EPOCH_JUMP_MAX, 100.0, now_s=i * 1e-3)
    known = b.max_epoch or 0
    assert b.heartbeat("main", True, known + 1, 100.0, now_s=0.05) is None
    assert b.last_refusal == "epoch_rate"
    assert b.heartbeat("main", True, known + 1, 100.0, now_s=0.5) is None  # a moment later
    assert b.last_refusal is None and b.peers["main"].epoch == known + 1


def test_a_standby_that_never_sees_a_leader_message_falls_back_to_the_first_origin() -> None:
    """No leader message ever observed (lockstep, or an ACL that hides them): a takeover uses the
    first active heartbeat's origin rather than restart the trajectory; once leader messages
    were seen, only a verified origin is used."""
    b = watcher()
    assert b.heartbeat("main", True, 1, T0, now_s=1.0) is None
    assert b.heartbeat("main", True, 1, T0 - 9.0, now_s=1.1) is None  # cannot tell either
    b.peer_alive("main", False)
    assert b.take_over().leader_t0 == T0
    seen = watcher()
    real_leaders(seen, 1.0, 1.02)  # fewer than LEADER_CHECK_MIN: no verdict, but seen
    assert seen.heartbeat("main", True, 1, T0 - 9.0, now_s=1.03) is None
    seen.peer_alive("main", False)
    assert seen.take_over().leader_t0 is None


def test_a_takeover_before_any_verification_uses_an_origin_that_agrees_with_every_leader() -> None:
    b = watcher()
    b.observe_leader(5.0, *line(5.0 - T0), now_s=5.0)  # one leader message: no verdict yet
    for t0 in (T0 - 100.0, T0):  # a spoof (refused: it disagrees) and the real one (unverified)
        b.heartbeat("main", True, 1, t0, now_s=5.0)
    assert b.rejects == {"leader_t0": 1} and b.leader_t0 is None
    b.peer_alive("main", False)
    assert b.take_over().leader_t0 == T0
    spoofed = watcher()
    spoofed.heartbeat("main", True, 1, T0 - 100.0, now_s=5.0)  # before any leader message
    spoofed.observe_leader(5.0, *line(5.0 - T0), now_s=5.01)
    spoofed.peer_alive("main", False)
    assert spoofed.take_over().leader_t0 is None  # it disagrees with what was observed
