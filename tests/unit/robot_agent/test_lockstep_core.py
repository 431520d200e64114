"""The lockstep rules (robot_agent.core.lockstep) and the stall/resume detector (runtime.stall),
tested directly: pure cores, time passed in."""

from __future__ import annotations

import math
from collections import deque

import pytest
from hypothesis import given
from hypothesis import strategies as st

from robot_agent.core.lockstep import (
    SETPOINT_DELAY_TICKS,
    Arrivals,
    Replay,
    SetpointWindow,
    tick_time,
)
from runtime.stall import (
    HANG_GAP_MIN_S,
    HANG_GAP_NO_LEASE_S,
    HANG_GAP_S,
    RESUME_QUARANTINE_S,
    StallDetector,
    hang_gap_for,
)

# --- lockstep ----------------------------------------------------------------------------------


@given(st.integers(0, 10**7), st.sampled_from([0.02, 0.01, 0.05, 1 / 30]))
def test_tick_time_is_exact_multiplication(k: int, dt: float) -> None:
    assert tick_time(k, dt) == k * dt  # never an accumulated sum


def test_setpoint_window_gives_the_previous_tick() -> None:
    w: SetpointWindow[str] = SetpointWindow()
    assert w.for_clock(0) is None
    w.add(0, "sp0")
    assert w.for_clock(0) is None  # computed on tick 0: used on tick 1
    assert w.for_clock(1) == "sp0"
    w.add(1, "sp1")  # may arrive before clock 1 is handled
    assert w.for_clock(1) == "sp0"
    assert w.for_clock(2) == "sp1"
    w.add(2, "sp2")  # only two ticks kept
    assert w.for_clock(1) is None
    assert SETPOINT_DELAY_TICKS == 1


def test_setpoint_window_missing_tick_means_no_setpoint() -> None:
    w: SetpointWindow[str] = SetpointWindow()
    w.add(3, "sp3")
    assert w.for_clock(5) is None  # nothing computed on tick 4: the firmware holds
    w.add(3, "sp3b")  # a repeated tick: the newest wins
    assert w.for_clock(4) == "sp3b"
    w.clear()
    assert w.for_clock(4) is None


_WINDOW_OPS = st.lists(
    st.one_of(
        st.tuples(st.just("add"), st.integers(0, 6), st.integers()),
        st.tuples(st.just("ask"), st.integers(0, 7), st.just(0)),
        st.tuples(st.just("clear"), st.just(0), st.just(0)),
    ),
    max_size=40,
)


def test_setpoint_window_repeats_of_a_tick_do_not_push_out_the_previous_tick() -> None:
    """A re-announced clock k+1 makes the coordinator send setpoint(k+1) again; an agent that
    takes those repeats before clock k+1 (its tick thread) still steps on setpoint(k)."""
    w: SetpointWindow[str] = SetpointWindow()
    w.add(4, "sp4")
    for n in range(3):
        w.add(5, f"sp5 repeat {n}")
    assert w.for_clock(5) == "sp4"
    assert w.for_clock(6) == "sp5 repeat 2"


@given(_WINDOW_OPS)
def test_setpoint_window_is_the_newest_of_the_last_two_ticks_added(
    ops: list[tuple[str, int, int]],
) -> None:
    """The window against its definition: the entries of the last two distinct ticks added (a
    tick added again replaces its entry and becomes the newest), on clock k the one computed on
    tick k - SETPOINT_DELAY_TICKS."""
    w: SetpointWindow[int] = SetpointWindow()
    model: deque[tuple[int, int]] = deque(maxlen=2)
    for op, tick, item in ops:
        if op == "add":
            w.add(tick, item)
            for old in [e for e in model if e[0] == tick]:
                model.remove(old)
            model.append((tick, item))
        elif op == "clear":
            w.clear()
            model.clear()
        else:
            want = [i for t, i in model if t == tick - SETPOINT_DELAY_TICKS]
            assert w.for_clock(tick) == (want[-1] if want else None)


def test_arrivals_are_handed_over_once_in_order() -> None:
    a: Arrivals[str] = Arrivals()
    assert not a
    for key in ("r2", "r1", "r2"):
        a.add(key)
    assert len(a) == 3
    a.compact()
    assert a.take() == ["r2", "r1"]
    assert a.take() == []
    objs = [object(), object()]
    b: Arrivals[object] = Arrivals()
    for o in (objs[0], objs[1], objs[0]):
        b.add(o)
    b.compact(key=id)
    assert b.take() == objs


def test_replay_answers_a_repeated_clock_without_a_step() -> None:
    r: Replay[bytes] = Replay()
    assert r.repeat(0) is None
    r.record(0, b"wheels0")
    assert r.repeat(0) == b"wheels0"
    assert r.repeat(1) is None
    r.record(1, None)  # handled, not answered (yet): a repeat steps again
    assert r.repeat(1) is None


# --- stall / resume ----------------------------------------------------------------------------


def test_hang_gap_from_lease() -> None:
    assert hang_gap_for(None) == HANG_GAP_S
    assert hang_gap_for(None, default_s=HANG_GAP_NO_LEASE_S) == HANG_GAP_NO_LEASE_S
    assert hang_gap_for(1000) == pytest.approx(0.9)
    assert hang_gap_for(100) == HANG_GAP_MIN_S  # a short lease never goes below the floor


def test_no_stall_while_the_loop_turns() -> None:
    d = StallDetector(gap_s=0.5)
    assert d.stalled_for(123.0) is None  # never turned: nothing to compare
    for i in range(100):
        now = 10.0 + 0.02 * i
        assert d.resume(now) is None
        assert not d.quarantined(now)
        d.turned(now)
    assert d.resumes == 0


def test_resume_after_a_stop_starts_a_quarantine() -> None:
    d = StallDetector(gap_s=0.5)
    d.turned(10.0)
    assert d.stalled_for(10.4) is None
    assert d.stalled_for(10.6) == pytest.approx(0.6)
    assert d.stalled_for(10.6) == pytest.approx(0.6)  # no side effect
    stopped = d.resume(12.0)
    assert stopped == pytest.approx(2.0)
    assert d.resumes == 1
    assert d.quarantined(12.0)
    assert d.quarantined(12.0 + RESUME_QUARANTINE_S - 1e-6)
    assert not d.quarantined(12.0 + RESUME_QUARANTINE_S)
    assert d.resume(12.1) is None  # the resume counted once
    assert d.resumes == 1


@given(
    st.lists(st.floats(0.0, 2.0, allow_nan=False), min_size=1, max_size=50),
    st.floats(0.05, 1.0),
)
def test_resumes_count_exactly_the_gaps_above_the_limit(gaps: list[float], gap_s: float) -> None:
    d = StallDetector(gap_s=gap_s)
    now = 0.0
    d.turned(now)
    expected = 0
    for g in gaps:
        before, now = now, now + g
        expected += (now - before) > gap_s
        d.resume(now)
        d.turned(now)
    assert d.resumes == expected
    assert math.isfinite(d.quarantine_until_s) == (expected > 0)


def test_a_late_loop_without_sigcont_is_no_stop() -> None:
    """Scheduling delay (a loaded machine) is not a stop: with SIGCONTs watched, only a gap
    with a SIGCONT in it (or longer than the unsignalled bound) counts (issue 13 item 7)."""
    d = StallDetector(gap_s=0.5, require_continue=True, unsignalled_gap_s=5.0)
    d.turned(10.0)
    assert d.stalled_for(11.0) is None and d.resume(11.0) is None  # 1 s late, no SIGCONT
    d.turned(11.0)
    assert d.ignored_gaps == 1
    d.note_continue()  # SIGSTOP ... SIGCONT
    assert d.stalled_for(12.0) == pytest.approx(1.0)
    assert d.resume(12.0) == pytest.approx(1.0) and d.quarantined(12.1)
    d.turned(12.0)
    assert d.stalled_for(12.9) is None  # the SIGCONT was consumed by that resume
    assert d.stalled_for(17.5) == pytest.approx(5.5)  # a suspend that sends no SIGCONT


def test_watch_sigcont_counts_real_signals() -> None:
    import os
    import signal

    d = StallDetector(gap_s=0.5)
    previous = signal.getsignal(signal.SIGCONT)
    try:
        assert d.watch_sigcont() and d.require_continue
        os.kill(os.getpid(), signal.SIGCONT)
        assert d.continued == 1
    finally:
        signal.signal(signal.SIGCONT, previous)
