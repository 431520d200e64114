"""The fleet's neighbour grid (``robot_agent.core.neighbour_index``): a robot's view is its list
(the others' entries in order, then the tail), and the view's near entries are exactly what
``near_entries`` selects from that list (the same objects, in the same order) for any fleet,
pose, half-width and cell size; a firmware stepping on views steps as one on lists, bit for bit.
Runs on the core that is active (compiled when built, else pure Python)."""

from __future__ import annotations

import math
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from robot_agent.core import Firmware, Pose, Setpoint
from robot_agent.core.neighbour_index import COORD_LIMIT_M, NeighbourIndex, NeighbourView
from robot_agent.core.neighbour_select import near_entries
from robot_agent.core.params import AgentConfig
from robot_agent.core.safety_filter import Neighbour

CFG = AgentConfig()
REP = CFG.repulsion

coord = st.floats(min_value=-3.0, max_value=3.0, allow_nan=False)
odd = st.sampled_from([math.nan, math.inf, -math.inf, 1e300, -0.0, 2.0 * COORD_LIMIT_M])


def n8(*fields: Any) -> Any:
    """An entry of eight fields, as ``robot_agent.core.neighbours`` builds them."""
    return tuple.__new__(Neighbour, fields)


@st.composite
def entry(draw: st.DrawFn) -> Any:
    """One robot's entry as the loop may hold it: mostly plain eight-field Neighbours, some
    None (no current pose), movers, radii, odd fields, pairs, nine fields, lists, ints, text."""
    x = draw(coord)
    y = draw(coord)
    kind = draw(st.integers(min_value=0, max_value=13))
    if kind <= 5:
        return n8(x, y, 0.1, 0.02, 0.0, 0.0, draw(st.booleans()), 0.0)
    if kind == 6:
        return None
    if kind == 7:  # a mover
        return n8(x, y, 0.0, 0.0, draw(coord), draw(coord), False, 0.0)
    if kind == 8:  # a radius (a negative one too)
        return n8(x, y, math.nan, 0.0, 0.0, 0.0, False, draw(st.floats(-0.1, 2.0)))
    if kind == 9:  # a non-finite or absurd field
        fields: list[Any] = [x, y, 0.0, 0.0, 0.0, 0.0, True, 0.0]
        fields[draw(st.sampled_from([0, 1, 2, 3, 4, 5, 7]))] = draw(odd)
        return n8(*fields)
    if kind == 10:  # an int where a float belongs
        return n8(int(x), y, 0.0, 0.0, 0, 0.0, True, 0)
    if kind == 11:
        return draw(st.sampled_from([(x, y), [x, y, 0.0, 0.0, 0.0, 0.0, True, 0.0]]))
    if kind == 12:
        return Neighbour(x, y, 0.0, 0.0, 0.0, 0.0, True, 0.0)  # nine fields
    return n8("a", y, 0.0, 0.0, 0.0, 0.0, True, 0.0)  # malformed: near_entries keeps all


def same_objects(got: Any, want: Any) -> bool:
    got = list(got)
    want = list(want)
    return len(got) == len(want) and all(a is b for a, b in zip(got, want, strict=True))


half = st.sampled_from([0.25, 0.54, 0.0, -0.1, -math.inf, math.inf, math.nan, 5.0])


@settings(max_examples=400, deadline=None)
@given(
    st.lists(entry(), min_size=1, max_size=30),
    st.lists(entry().filter(lambda e: e is not None), max_size=2),
    st.data(),
    st.sampled_from([0.05, 0.3, 0.6, 1.7, 50.0]),
    half,
    half,
)
def test_a_view_selects_what_near_entries_selects_from_its_list(
    entries: list[Any],
    tail: list[Any],
    data: st.DataObject,
    cell_m: float,
    d0: float,
    box: float,
) -> None:
    """Every robot's view: its list is the others' entries (Nones left out) then the tail, and
    its near entries are ``near_entries`` of that list, the same objects in the same order."""
    grid = NeighbourIndex(entries, cell_m)
    for i in range(len(entries)):
        view = grid.view(i, tail)
        want_list = [e for j, e in enumerate(entries) if j != i and e is not None] + tail
        assert same_objects(view.full(), want_list)
        assert len(view) == len(want_list)
        assert bool(view) == bool(want_list)
        assert same_objects(view, want_list)  # (iteration)
        x = data.draw(st.one_of(coord, odd), label="x")
        y = data.draw(coord, label="y")
        rx = x + 0.05
        ry = y + data.draw(st.sampled_from([0.0, 0.05, -0.05]), label="ry")
        want = near_entries(want_list, x, y, d0, rx, ry, box)
        assert same_objects(view.near(x, y, d0, rx, ry, box), want)


def test_the_grid_reads_only_the_near_cells() -> None:
    """Not vacuous: on a spread fleet the candidates of a query are the near entries and the
    special ones, not everything; an unanswerable query (a NaN centre) is -1."""
    fleet: list[Any] = [n8(0.4 * j, 0.0, 0.0, 0.0, 0.0, 0.0, True, 0.0) for j in range(20)]
    fleet[15] = n8(6.0, 0.0, 0.0, 0.0, 0.3, 0.0, False, 0.0)  # a mover: always a candidate
    fleet[16] = None
    grid = NeighbourIndex(fleet, 0.6)
    assert grid.cell_m == 0.6
    mask = grid.candidates(2, 0.8, 0.0, 0.25, 0.85, 0.0, 0.54)
    assert mask >= 0
    got = {j for j in range(20) if mask >> j & 1}
    assert 2 not in got
    assert {1, 3, 15} <= got
    assert not {10, 16, 19} & got
    assert len(got) <= 8
    assert grid.candidates(2, math.nan, 0.0, 0.25, 0.85, 0.0, 0.54) == -1
    assert grid.candidates(2, 0.8, 0.0, 0.25, 0.85, 0.0, math.inf) == -1
    # both boxes off: the special entries only
    assert grid.candidates(2, 0.8, 0.0, -math.inf, 0.85, 0.0, -math.inf) == 1 << 15
    # a sparse fleet: larger cells, the same answers
    sparse: list[Any] = [n8(1e5 * j, 0.0, 0.0, 0.0, 0.0, 0.0, True, 0.0) for j in range(3)]
    assert NeighbourIndex(sparse, 0.6).cell_m > 1e3
    view = grid.view(2)
    near = view.near(0.8, 0.0, 0.25, 0.85, 0.0, 0.54)
    assert same_objects(near, near_entries(view.full(), 0.8, 0.0, 0.25, 0.85, 0.0, 0.54))
    assert 2 <= len(near) < len(view) == 18


def test_a_bad_cell_size_is_refused() -> None:
    for bad in (0.0, -1.0, math.nan, math.inf):
        with pytest.raises(ValueError, match="cell_m"):
            NeighbourIndex([], bad)


def _fleet(k: int, tick: int) -> list[Any]:
    """A line of robots 0.3 m apart moving right, one moving fast, one with no pose."""
    out: list[Any] = []
    for j in range(k):
        if j == 7:
            out.append(None)
            continue
        vx = -0.2 if j == 3 else 0.0
        x = -1.5 + 0.3 * j + 0.01 * (j % 3) + 0.001 * tick
        out.append(n8(x, 0.25 - 0.02 * j, 0.1 * j, 0.02 * (j % 4), vx, 0.0, j % 2 == 0, 0.0))
    return out


def test_a_firmware_on_views_steps_as_one_on_lists() -> None:
    """Two firmwares through a line of neighbours, one given views of a grid and one the same
    entries as lists: the same commands and status, bit for bit (both select when compiled)."""
    on_view = Firmware(CFG)
    on_list = Firmware(CFG)
    body = n8(0.5, 0.6, math.nan, 0.0, 0.0, 0.0, False, 0.1)
    for k in range(150):
        t = 0.02 * k
        pose = Pose(-1.6 + 0.006 * k, 0.2, 0.05, t)
        sp = Setpoint(-1.4 + 0.006 * k, 0.2, 0.3, 0.0, 0.05, 0, t)
        entries = [None, *_fleet(14, k)]  # robot 0 is the one stepping
        view = NeighbourIndex(entries, 0.6).view(0, [body])
        listed = [e for e in entries[1:] if e is not None] + [body]
        a = on_view.step(t, pose=pose, pose_rx_s=t, setpoint=sp, setpoint_rx_s=t, neighbours=view)
        b = on_list.step(t, pose=pose, pose_rx_s=t, setpoint=sp, setpoint_rx_s=t, neighbours=listed)
        assert repr(a) == repr(b)
        assert isinstance(view, NeighbourView)
    assert on_view.status() == on_list.status()
    sf = on_view.status().safety_filter
    assert sf is not None
    assert sf.active_ticks > 0  # the line did bind


def test_an_idle_firmware_evades_on_a_view() -> None:
    """Without a setpoint the filter evades on the view's whole list: as on the list."""
    a_fw = Firmware(CFG)
    b_fw = Firmware(CFG)
    near = n8(0.1, 0.0, 0.0, 0.0, -0.2, 0.0, False, 0.0)  # a mover coming at the robot
    entries: list[Any] = [None, near, n8(3.0, 0.0, 0.0, 0.0, 0.0, 0.0, True, 0.0)]
    for k in range(20):
        t = 0.02 * k
        pose = Pose(0.0, 0.0, 0.0, t)
        view = NeighbourIndex(entries, 0.6).view(0)
        a = a_fw.step(t, pose=pose, pose_rx_s=t, setpoint=None, setpoint_rx_s=t, neighbours=view)
        b = b_fw.step(
            t, pose=pose, pose_rx_s=t, setpoint=None, setpoint_rx_s=t, neighbours=entries[1:]
        )
        assert repr(a) == repr(b)
    assert repr(a_fw.status()) == repr(b_fw.status())  # (NaN errors: no setpoint)
    sf = a_fw.status().safety_filter
    assert sf is not None
    assert sf.violations > 0  # the mover was in range of the idle robot's filter
    assert a.omega_r < 0.0  # and pushed it back


@pytest.mark.parametrize("n", [1, 3, 9, 30])
@pytest.mark.parametrize("holes", [False, True])
def test_every_view_is_the_others_entries_then_the_tail(n: int, holes: bool) -> None:
    """``views``: robot i's is every other entry (Nones left out), in order, then the tail."""
    entries: list[Any] = [n8(0.4 * j, 0.1 * j, 0.0, 0.0, 0.0, 0.0, True, 0.0) for j in range(n)]
    if holes:
        entries[n // 2] = None
    tail = [n8(1.0, 1.0, math.nan, 0.0, 0.0, 0.0, False, 0.2)]
    views = NeighbourIndex(entries, 0.3).views(tail)
    assert len(views) == n
    for i, got in enumerate(views):
        want = [e for j, e in enumerate(entries) if j != i and e is not None] + tail
        assert same_objects(got, want)
        assert same_objects(
            got.near(0.4 * i, 0.1 * i, 0.25, 0.4 * i + 0.05, 0.1 * i, 0.54),
            near_entries(want, 0.4 * i, 0.1 * i, 0.25, 0.4 * i + 0.05, 0.1 * i, 0.54),
        )
