"""How the firmware reads its neighbour entries (the per-neighbour fast paths of repulsion and
the safety filter's neighbour rows): a tuple is read in place (compiled: typed), any other
sequence gives the same bits as its tuple, a far entry's heading and age are not read, and a
malformed entry still raises the same exception type (the firmware counts it). Runs on the core
that is active (compiled when built, else pure Python), so both are held to it."""

from __future__ import annotations

import math
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from robot_agent.core import Firmware, Pose, Setpoint
from robot_agent.core.params import AgentConfig, RepulsionParams
from robot_agent.core.repulsion import repulsion_velocity_counted
from robot_agent.core.safety_filter import Neighbour, SafetyFilter

P = RepulsionParams()
near = st.floats(min_value=-0.6, max_value=0.6, allow_nan=False)
odd = st.sampled_from([math.nan, math.inf, -math.inf, 1e300, 0.0])


def bits(values: Any) -> str:
    return repr([v.hex() if isinstance(v, float) else v for v in values])


@settings(max_examples=60, deadline=None)
@given(
    st.lists(st.tuples(near, near), min_size=1, max_size=6),
    st.lists(odd, max_size=2),
    st.integers(min_value=0, max_value=5),
)
def test_repulsion_of_list_entries_is_the_repulsion_of_their_tuples(
    pts: list[tuple[float, float]], bad: list[float], as_list: int
) -> None:
    """Lists among the entries (the compiled core's typed loop refuses them and starts over on
    tuples) give the same velocity and skipped count, bit for bit, non-finite entries too."""
    entries: list[Any] = [*pts, *((b, 0.1) for b in bad)]
    mixed: list[Any] = [list(e) if k % 6 == as_list else e for k, e in enumerate(entries)]
    want = repulsion_velocity_counted(0.05, -0.02, entries, [], P)
    got = repulsion_velocity_counted(0.05, -0.02, mixed, [], P)
    assert bits(got[:2]) == bits(want[:2])
    assert got[2] == want[2] == sum(1 for b in bad if not math.isfinite(b))
    # a generator of entries (read once) is the same too
    again = repulsion_velocity_counted(0.05, -0.02, (list(e) for e in entries), [], P)
    assert bits(again[:2]) == bits(want[:2])
    assert again[2] == want[2]


def test_repulsion_entry_with_a_bad_field_raises_type_error_in_either_form() -> None:
    bad: list[Any] = [(0.1, "x"), [0.1, "x"]]
    for entry in bad:
        with pytest.raises(TypeError):
            repulsion_velocity_counted(0.0, 0.0, [(0.2, 0.0), entry], [], P)
    with pytest.raises(IndexError):  # one field: no y, as before
        repulsion_velocity_counted(0.0, 0.0, [[0.1]], [], P)


def _rows(entries: list[Any]) -> tuple[str, int, float]:
    flt = SafetyFilter(AgentConfig())
    cons = flt.constraints(0.0, 0.0, 0.3, entries, (), 0.0, 0.02)
    st_ = flt.status()
    return bits([c for con in cons for c in con]), st_.rejected, st_.min_clearance_m


@settings(max_examples=60, deadline=None)
@given(
    st.lists(st.tuples(near, near, st.booleans(), st.floats(0.0, 0.3)), min_size=1, max_size=6),
    st.integers(min_value=0, max_value=5),
)
def test_barrier_rows_of_list_entries_are_those_of_their_tuples(
    pts: list[tuple[float, float, bool, float]], as_list: int
) -> None:
    """Neighbours and (x, y) pairs given as lists build the same rows, counters and least
    clearance as the same entries given as tuples."""
    entries: list[Any] = []
    for k, (x, y, coop, age) in enumerate(pts):
        if k % 2:
            entries.append((x, y))
        else:
            entries.append(Neighbour(x, y, 0.3, age, 0.0, 0.0, coop, 0.0))
    mixed = [list(e) if k % 6 == as_list else e for k, e in enumerate(entries)]
    assert _rows(mixed) == _rows(entries)


def test_a_far_neighbours_heading_and_age_are_not_read() -> None:
    """Past the quick reject only: a far entry with a non-numeric heading or age adds no row
    and raises nothing (pure Python never read them; the compiled core now neither); a near one
    raises TypeError, which the firmware counts as an internal error."""
    far: Any = (50.0, 50.0, "heading?", "age?", 0.0, 0.0, True, 0.0)
    rows, rejected, clearance = _rows([far, (0.4, 0.0)])
    assert rejected == 0
    assert clearance == _rows([(0.4, 0.0)])[2]
    assert rows == _rows([(0.4, 0.0)])[0]
    near_bad: Any = (0.3, 0.0, "heading?", 0.0, 0.0, 0.0, True, 0.0)
    with pytest.raises(TypeError):
        _rows([near_bad])
    fw = Firmware(AgentConfig())
    fw.step(0.0, pose=Pose(0.0, 0.0, 0.0, 0.0), pose_rx_s=0.0,
            setpoint=Setpoint(0.1, 0.0, 0.0, 0.0, 0.0, 0, 0.0), setpoint_rx_s=0.0,
            neighbours=[near_bad])  # fmt: skip
    assert fw.status().last_reject_reason == "internal error: TypeError"


def test_malformed_entries_raise_as_before() -> None:
    """A wrong length is a ValueError (the unpack), an entry without a length a TypeError."""
    with pytest.raises(ValueError):
        _rows([(0.1, 0.2, 0.3)])
    with pytest.raises(ValueError):
        _rows([[0.1, 0.2, 0.3]])
    with pytest.raises(TypeError):
        _rows([5.0])
    with pytest.raises(TypeError):
        _rows([iter((0.1, 0.2))])
