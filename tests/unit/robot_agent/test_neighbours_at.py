"""``robot_agent.core.neighbours.neighbours_at`` (the in-process loop's one call a tick) builds
the entries the per-robot rule builds: ``neighbour`` of each current pose, None for no pose or a
stale one, with the motion view of each robot's claims when rings are given, bit for bit."""

from __future__ import annotations

import math
from typing import Any

from hypothesis import given, settings
from hypothesis import strategies as st

from robot_agent.core.firmware_types import Pose
from robot_agent.core.neighbour_motion import Claim, motion_view
from robot_agent.core.neighbours import ClaimRing, is_current, neighbour, neighbours_at

L_M = 0.05
VMAX = 0.3
MAX_AGE = 0.5


def bits(entry: Any) -> Any:
    if entry is None:
        return None
    return repr(
        [v.hex() if isinstance(v, float) else bits(v) if isinstance(v, tuple) else v for v in entry]
    )


def one_by_one(
    poses: list[Any], rx: list[float], now: float, coop: list[bool], rings: list[ClaimRing] | None
) -> list[Any]:
    """The rule robot by robot, as the loop applied it before (its ``pts`` comprehension)."""
    out: list[Any] = []
    for j, p in enumerate(poses):
        if p is None or not is_current(now, rx[j]):
            out.append(None)
            continue
        view = (
            None if rings is None else motion_view(rings[j].claims, p[3], now, L_M, VMAX, MAX_AGE)
        )
        out.append(neighbour(p[0], p[1], p[2], p[3], now, coop[j], view))
    return out


# a coordinate: a float, or now and then an int (read as its float by the compiled core)
coord = st.one_of(st.floats(-2, 2), st.integers(-2, 2))
robot = st.tuples(
    st.one_of(st.none(), st.tuples(coord, coord, st.one_of(st.floats(-4, 4), st.integers(-4, 4)))),
    st.floats(min_value=-0.1, max_value=1.5),  # capture age at now (< 0: in the future)
    st.floats(min_value=-0.1, max_value=1.5),  # receive age at now (> 1 s: stale)
    st.booleans(),
    st.lists(st.floats(min_value=-0.6, max_value=0.05), max_size=4),  # claim times - now
)


@settings(max_examples=200, deadline=None)
@given(st.lists(robot, max_size=8), st.floats(0.0, 100.0), st.booleans())
def test_the_fleet_call_is_the_rule_robot_by_robot(
    fleet: list[Any], now: float, with_rings: bool
) -> None:
    poses: list[Any] = []
    rx: list[float] = []
    coop: list[bool] = []
    rings: list[ClaimRing] = []
    for xyt, cap_age, rx_age, tracking, claim_dts in fleet:
        poses.append(None if xyt is None else Pose(xyt[0], xyt[1], xyt[2], now - cap_age))
        rx.append(now - rx_age)
        coop.append(tracking)
        ring = ClaimRing()
        for dt in sorted(claim_dts):
            ring.add(Claim(now + dt, 0.05, -0.02, 0.1, 0.5))
        rings.append(ring)
    use = rings if with_rings else None
    got = neighbours_at(poses, rx, now, coop, use, L_M, VMAX, MAX_AGE)
    want = one_by_one(poses, rx, now, coop, use)
    assert [bits(e) for e in got] == [bits(e) for e in want]
    assert all(e is None or len(e) == (9 if with_rings and e[8:] else 8) for e in got)


def test_stale_and_missing_poses_are_none_and_a_future_capture_is_age_zero() -> None:
    now = 10.0
    poses: list[Any] = [None, Pose(0.0, 0.0, 0.0, 9.9), Pose(1.0, 0.0, 0.0, 10.2)]
    got = neighbours_at(poses, [10.0, 8.5, 10.0], now, [True, True, False])
    assert got == [None, None, neighbour(1.0, 0.0, 0.0, 10.2, now, False)]
    assert got[2] is not None and got[2].age_s == 0.0 and math.copysign(1.0, got[2].age_s) == 1.0
