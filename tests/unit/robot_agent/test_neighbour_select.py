"""The neighbour selection of a long list (``robot_agent.core.neighbour_select``): repulsion and
the safety filter on the selected entries give what they give on the whole list, bit for bit
(the velocity, the rows, every counter), for near, far, moving, inflated, non-finite and odd
entries; and a firmware that selects steps exactly as one that does not. Runs on the core that
is active (compiled when built, else pure Python)."""

from __future__ import annotations

import math
from typing import Any

from hypothesis import given, settings
from hypothesis import strategies as st

from robot_agent.core import Firmware, Pose, Setpoint
from robot_agent.core.firmware import SELECT_MIN_ENTRIES
from robot_agent.core.neighbour_select import near_entries
from robot_agent.core.params import AgentConfig
from robot_agent.core.repulsion import repulsion_raw
from robot_agent.core.safety_filter import Neighbour, SafetyFilter

CFG = AgentConfig()
REP = CFG.repulsion
NEVER = 1 << 62

coord = st.floats(min_value=-1.0, max_value=1.0, allow_nan=False)  # (the boxes are ~0.25-0.6 m)
odd = st.sampled_from([math.nan, math.inf, -math.inf, 1e300, -0.0])


def n8(*fields: Any) -> Any:
    """An entry of eight fields, as ``robot_agent.core.neighbours`` builds them (``Neighbour(...)``
    has nine: its ``motion`` defaults to None)."""
    return tuple.__new__(Neighbour, fields)


def bits(values: Any) -> str:
    return repr([v.hex() if isinstance(v, float) else v for v in values])


@st.composite
def entry(draw: st.DrawFn) -> Any:
    """One neighbour entry as a shell may pass it: mostly plain eight-field Neighbours (the
    loop's), some with a velocity or a radius (movers, bodies), a non-finite or absurd field, an
    (x, y) pair, a nine-field entry, a list."""
    x = draw(coord)
    y = draw(coord)
    kind = draw(st.integers(min_value=0, max_value=10))
    theta = draw(st.floats(min_value=-3.2, max_value=3.2))
    age = draw(st.floats(min_value=0.0, max_value=0.6))
    coop = draw(st.booleans())
    if kind <= 4:
        return n8(x, y, theta, age, 0.0, 0.0, coop, 0.0)
    if kind == 5:  # a mover: velocity (a far one reaches further)
        return n8(x, y, theta, age, draw(coord), draw(coord), False, 0.0)
    if kind == 6:  # a body or an uncertain neighbour: a radius (a negative one too)
        return n8(x, y, math.nan, 0.0, 0.0, 0.0, False, draw(st.floats(-0.1, 2.0)))
    if kind == 7:  # a non-finite or absurd field somewhere
        fields = [x, y, theta, age, 0.0, 0.0, coop, 0.0]
        fields[draw(st.sampled_from([0, 1, 2, 3, 4, 5, 7]))] = draw(odd)
        return n8(*fields)
    if kind == 8:
        return (x, y)
    if kind == 9:  # nine fields (no motion view): kept
        return Neighbour(x, y, theta, age, 0.0, 0.0, coop, 0.0)
    return [x, y, theta, age, 0.0, 0.0, coop, 0.0]  # a list: kept as it is


def _filter_run(
    entries: list[Any], px: float, py: float, ux: float, uy: float, extra: float, dt: float
) -> tuple[str, str, dict[str, Any]]:
    flt = SafetyFilter(CFG)
    out = flt.filter(1.0, px, py, ux, uy, 0.1, 0.0, entries, (), extra, dt)
    rows = bits([c for con in flt.constraints(px, py, 0.25, entries, (), extra, dt) for c in con])
    return bits(out), rows, flt.status().as_dict()


@settings(max_examples=300, deadline=None)
@given(
    st.lists(entry(), min_size=0, max_size=24),
    coord,
    coord,
    st.floats(min_value=-math.pi, max_value=math.pi),
    st.tuples(st.floats(-0.3, 0.3), st.floats(-0.3, 0.3)),
    st.sampled_from([0.0, 0.005, 0.03, 0.2, math.inf, math.nan]),
    st.sampled_from([0.0, 0.02, 0.1, 0.5]),
)
def test_selected_entries_give_the_same_repulsion_and_filter_bit_for_bit(
    entries: list[Any],
    x: float,
    y: float,
    th: float,
    u: tuple[float, float],
    extra: float,
    dt: float,
) -> None:
    """Whatever the entries, the pose, the own uncertainty and the tick: repulsion (velocity,
    skipped count) and the filter (command, rows, status counters) are the same on the
    selection as on the whole list, and the selection keeps the entries in their order."""
    l_m = CFG.geometry.ref_offset_m
    rx = x + l_m * math.cos(th)
    ry = y + l_m * math.sin(th)
    flt = SafetyFilter(CFG)
    box = flt.reach_box_m(extra, dt)
    near = near_entries(entries, x, y, REP.influence_m, rx, ry, box)
    kept = iter(entries)
    assert all(any(e is k for k in kept) for e in near)  # a subsequence, the same objects
    d0 = REP.influence_m
    args = (REP.k_rep, d0, 1.0 / d0, REP.max_speed_mps)
    want = repulsion_raw(x, y, entries, (), *args)
    got = repulsion_raw(x, y, near, (), *args)
    assert bits(got) == bits(want)
    # the filter off (its box -inf): the repulsion's own box alone (with the filter on, the
    # filter's larger box holds it)
    alone = near_entries(entries, x, y, d0, rx, ry, -math.inf)
    assert bits(repulsion_raw(x, y, alone, (), *args)) == bits(want)
    assert _filter_run(list(near), rx, ry, *u, extra, dt) == _filter_run(
        entries, rx, ry, *u, extra, dt
    )


def test_far_plain_entries_are_dropped_and_the_others_kept() -> None:
    """Not vacuous: a far plain entry goes, a near one, a far mover (its velocity widens the
    filter's reach), a far non-finite one (counted by both loops) and an (x, y) pair stay."""
    far = n8(2.0, 0.0, 0.0, 0.0, 0.0, 0.0, True, 0.0)
    close = n8(0.3, 0.0, 0.0, 0.0, 0.0, 0.0, True, 0.0)
    mover = n8(2.0, 0.0, 0.0, 0.0, -5.0, 0.0, False, 0.0)
    bad = n8(math.inf, 0.0, 0.0, 0.0, 0.0, 0.0, False, 0.0)
    pair = (2.0, 2.0)
    box = SafetyFilter(CFG).reach_box_m(0.0, 0.02)
    assert 0.3 < box < 2.0
    got = near_entries([far, close, mover, bad, pair], 0.0, 0.0, 0.25, 0.05, 0.0, box)
    assert got == [close, mover, bad, pair]
    # repulsion off (-inf): the filter's box alone; both off: every plain finite entry goes
    ninf = -math.inf
    assert near_entries([far, close], 0.0, 0.0, ninf, 0.05, 0.0, box) == [close]
    assert near_entries([far, close], 0.0, 0.0, ninf, 0.05, 0.0, ninf) == []
    # a NaN bound or position keeps everything; a malformed entry returns the list itself
    assert near_entries([far, close], 0.0, 0.0, 0.25, 0.05, 0.0, math.nan) == [far, close]
    assert near_entries([far, close], math.nan, 0.0, 0.25, math.nan, 0.0, box) == [far, close]
    malformed: list[Any] = [far, ("a", "b", 0.0, 0.0, 0.0, 0.0, True, 0.0)]
    assert near_entries(malformed, 0.0, 0.0, 0.25, 0.05, 0.0, box) is malformed
    as_tuple = (far, close)
    assert near_entries(as_tuple, 0.0, 0.0, 0.25, 0.05, 0.0, box) is as_tuple


def _fleet(k: int) -> list[Any]:
    """A line of robots 0.3 m apart around the origin, one moving, one with a NaN heading."""
    out: list[Any] = []
    for j in range(k):
        x = -1.5 + 0.3 * j + 0.01 * (j % 3)
        vx = -0.2 if j == 3 else 0.0
        th = math.nan if j == 5 else 0.1 * j
        out.append(n8(x, 0.25 - 0.02 * j, th, 0.02 * (j % 4), vx, 0.0, j % 2 == 0, 0.0))
    return out


def test_a_selecting_firmware_steps_as_one_that_does_not() -> None:
    """Two firmwares, one selecting from lists of any length and one never, over ticks moving
    through a line of neighbours: the same commands and status, bit for bit."""
    on = Firmware(CFG)
    off = Firmware(CFG)
    on._select_min = 0  # (the switch under test)
    off._select_min = NEVER
    fleet = _fleet(SELECT_MIN_ENTRIES + 4)
    for k in range(150):
        t = 0.02 * k
        pose = Pose(-1.6 + 0.006 * k, 0.2, 0.05, t)
        sp = Setpoint(-1.4 + 0.006 * k, 0.2, 0.3, 0.0, 0.05, 0, t)
        moved = [n8(n[0] + 0.001 * k, *n[1:]) for n in fleet]
        a = on.step(t, pose=pose, pose_rx_s=t, setpoint=sp, setpoint_rx_s=t, neighbours=moved)
        b = off.step(t, pose=pose, pose_rx_s=t, setpoint=sp, setpoint_rx_s=t, neighbours=moved)
        assert bits(a) == bits(b)
    assert on.status() == off.status()
    sf = on.status().safety_filter
    assert sf is not None
    assert sf.active_ticks > 0  # the line did bind
