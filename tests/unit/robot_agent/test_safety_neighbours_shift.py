"""The safety filter's cooperative neighbour rows skip a far entry before its shift by ``l``
(eqs 10-11) with exactly the rows, counters and least clearance of the shifted box test: checked
against that test written out here (the reciprocal row of ``safety_neighbours``'s module
docstring), on entries around the box's edge, near and beyond the coordinate bound of the early
reject. Runs on the core that is active (compiled when built, else pure Python)."""

from __future__ import annotations

import math
from typing import Any

from hypothesis import given, settings
from hypothesis import strategies as st

from robot_agent.core.kinematics import reference_point
from robot_agent.core.params import AgentConfig
from robot_agent.core.qp import _TOL
from robot_agent.core.safety_filter import Neighbour
from robot_agent.core.safety_neighbours import NeighbourBarriers

CONFIG = AgentConfig()
GAMMA = 10.0
CAP_MPS = 0.3


def _bits(values: Any) -> list[str]:
    return [v.hex() for v in values]


def _reference(
    px: float, py: float, rho: float, entries: list[Neighbour]
) -> tuple[list[str], str, int]:
    """The rows, the least barrier value and the rejections of cooperative entries (finite
    fields, no radius, no velocity, age within bounds): the quick reject, then the shift, then
    the box test, as the rows were written before the early reject."""
    g = CONFIG.geometry
    p = CONFIG.safety_filter
    l_m = g.ref_offset_m
    d_coop = 2.0 * g.body_radius_m + p.margin_m + 2.0 * l_m
    vnb = p.neighbour_speed_mps if p.neighbour_speed_mps > 0.0 else g.max_speed_mps
    reach = (CAP_MPS + _TOL) / GAMMA
    quick = NeighbourBarriers(CONFIG).quick_m(rho, reach)
    cons: list[float] = []
    min_h = math.inf
    rejected = 0
    for nb in entries:
        qx, qy, th, age = nb[0], nb[1], nb[2], nb[3]
        dx = px - qx
        dy = py - qy
        if not (-quick < dx < quick and -quick < dy < quick):
            if (chk := dx + dy) - chk != 0.0:
                rejected += 1
            continue
        age = min(max(age, 0.0), p.max_age_s)
        rad = 0.0 - p.noise_budget_m
        infl = vnb * age + (rad if rad > 0.0 else 0.0) + rho
        rx, ry = reference_point(qx, qy, th, l_m)
        dd = d_coop + infl
        dx = px - rx
        dy = py - ry
        lim = dd + (CAP_MPS + 0.0 + 0.0) / (0.5 * GAMMA) + _TOL
        if not (-lim < dx < lim and -lim < dy < lim):
            if (chk := dx + dy) - chk != 0.0:
                rejected += 1
            continue
        d = math.hypot(dx, dy)
        nx, ny = (dx / d, dy / d) if d > 0.0 else (1.0, 0.0)
        h = d - dd
        min_h = min(min_h, h)
        b = -0.5 * GAMMA * h + nx * 0.0 + ny * 0.0
        if b > -CAP_MPS - _TOL:
            cons.extend((nx, ny, b))
    return _bits(cons), min_h.hex(), rejected


def _rows(px: float, py: float, rho: float, entries: list[Any]) -> tuple[list[str], str, int]:
    barriers = NeighbourBarriers(CONFIG)
    cons: list[tuple[float, float, float]] = []
    reach = (CAP_MPS + _TOL) / GAMMA
    min_h = barriers.append(px, py, CAP_MPS, reach, GAMMA, rho, 0.02, None, entries, cons, math.inf)
    return _bits([c for row in cons for c in row]), min_h.hex(), barriers.rejected


# an offset from the robot around the shifted box's edge (0.21 - 0.34 m with the defaults)
offset = st.floats(min_value=-0.45, max_value=0.45, allow_nan=False)
# a base on either side of the early reject's bound (1e6 m), and far beyond it (where a
# coordinate's step, 1/32 - 1/4 m near 1.4e14 - 1.1e15, is about l: a shift by l rounds to more)
base = st.one_of(
    st.floats(min_value=-5.0, max_value=5.0),
    st.floats(min_value=999_999.0, max_value=1_000_001.0),
    st.floats(min_value=-1_000_001.0, max_value=-999_999.0),
    st.floats(min_value=1.4e14, max_value=1.1e15),
    st.sampled_from([-3.0e17]),
)
# an entry: anywhere around the box, or its axle centre within a few mm of the early reject's
# edge (lim + l) on one axis, heading near the robot or away
anywhere = st.tuples(
    st.just(False),
    offset,
    offset,
    st.floats(min_value=-7.0, max_value=7.0),
    st.floats(min_value=-0.1, max_value=1.0),
)
at_edge = st.tuples(
    st.just(True),
    st.floats(min_value=-0.005, max_value=0.005),
    offset,
    st.one_of(st.floats(min_value=2.5, max_value=3.8), st.floats(min_value=-0.6, max_value=0.6)),
    st.floats(min_value=0.0, max_value=0.2),
)


def _entry(
    px: float, py: float, rho: float, edge: bool, a: float, b: float, th: float, age: float
) -> Neighbour:
    if edge:  # a: the distance from the edge; the axis and side: from b's sign and th
        lim = _reference_lim(rho, age)
        ox = math.copysign(lim + CONFIG.geometry.ref_offset_m + a, b)
        if th > 2.0:  # heading toward the robot on this axis
            th = th if ox > 0.0 else th - math.pi
        return Neighbour(px + ox, py + 0.5 * b, th, age, 0.0, 0.0, True, 0.0)
    return Neighbour(px + a, py + b, th, age, 0.0, 0.0, True, 0.0)


@settings(max_examples=400, deadline=None)
@given(
    base,
    base,
    st.floats(min_value=0.0, max_value=0.05),
    st.lists(st.one_of(anywhere, at_edge), min_size=1, max_size=8),
    st.booleans(),
)
def test_cooperative_rows_are_those_of_the_shifted_box(
    px: float,
    py: float,
    rho: float,
    near: list[tuple[bool, float, float, float, float]],
    as_tuple: bool,
) -> None:
    """Cooperative entries at any heading and age around the box's edge and the early reject's
    edge: the same rows, least barrier value and rejections, bit for bit, given as a list or as
    a tuple."""
    entries = [_entry(px, py, rho, *e) for e in near]
    given_as: Any = tuple(entries) if as_tuple else entries
    assert _rows(px, py, rho, given_as) == _reference(px, py, rho, entries)


def test_an_entry_just_beyond_the_early_reject_is_still_tested_shifted() -> None:
    """An axle centre inside lim + l whose reference point is inside lim binds; one whose
    shift takes it out of the box adds nothing: the early reject only skips what the box
    would."""
    lim = _reference_lim(0.0, 0.0)
    l_m = CONFIG.geometry.ref_offset_m
    # heading pi: the reference point is l behind the axle centre, toward the robot
    inside = Neighbour(lim + 0.5 * l_m, 0.0, math.pi, 0.0, 0.0, 0.0, True, 0.0)
    rows, _, rejected = _rows(0.0, 0.0, 0.0, [inside])
    assert rows
    assert rejected == 0
    assert _rows(0.0, 0.0, 0.0, [inside]) == _reference(0.0, 0.0, 0.0, [inside])
    away = Neighbour(lim + 0.5 * l_m, 0.0, 0.0, 0.0, 0.0, 0.0, True, 0.0)
    assert _rows(0.0, 0.0, 0.0, [away]) == ([], math.inf.hex(), 0)


def _reference_lim(rho: float, age: float) -> float:
    """The shifted box's half-width of a cooperative entry of this age (no radius)."""
    g = CONFIG.geometry
    p = CONFIG.safety_filter
    d_coop = 2.0 * g.body_radius_m + p.margin_m + 2.0 * g.ref_offset_m
    vnb = p.neighbour_speed_mps if p.neighbour_speed_mps > 0.0 else g.max_speed_mps
    return d_coop + vnb * age + rho + CAP_MPS / (0.5 * GAMMA) + _TOL
