"""The coordinator's reference points (eqs 10-11) are the firmware's, bit for bit.

``CoordinatorCore._ref_points`` writes out the arithmetic of
``robot_agent.core.kinematics.reference_point`` (a call into the firmware's compiled build costs
more than the arithmetic); these properties pin the two to the same floats, for every pose, and
the same rule for the poses left out (a reference point that is not finite), compiled or pure.
"""

from __future__ import annotations

import math
import struct

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from robot_agent.core.kinematics import reference_point
from scenario import load
from scenario.assemble import coordinator_core

SCN = load("paper-exp2")
L_M = SCN.agent.geometry.ref_offset_m

_any = st.floats(allow_nan=True, allow_infinity=True)
_pose = st.tuples(
    st.one_of(st.floats(-1e6, 1e6), _any),
    st.one_of(st.floats(-1e6, 1e6), _any),
    st.one_of(st.floats(-1e3, 1e3), _any),
)


def _bits(xy: tuple[float, float]) -> bytes:
    return struct.pack("<dd", *xy)


@settings(max_examples=300, deadline=None)
@given(st.dictionaries(st.sampled_from([f"r{i}" for i in range(8)]), _pose, max_size=8))
def test_reference_points_are_the_firmwares_bit_for_bit(
    poses: dict[str, tuple[float, float, float]],
) -> None:
    core = coordinator_core(SCN)
    try:
        want = {rid: reference_point(*p, L_M) for rid, p in poses.items()}
    except ValueError:  # an infinite heading: math.cos's domain error, the same way
        with pytest.raises(ValueError, match="math domain error"):
            core.reference_points(poses)
        return
    got = core.reference_points(poses)
    finite = {rid: q for rid, q in want.items() if math.isfinite(q[0]) and math.isfinite(q[1])}
    assert list(got) == list(finite)  # the finite ones, in input order
    assert {rid: _bits(q) for rid, q in got.items()} == {rid: _bits(q) for rid, q in finite.items()}


def test_a_non_finite_pose_has_no_reference_point() -> None:
    core = coordinator_core(SCN)
    poses = {
        "r1": (0.1, 0.2, 0.3),
        "r2": (math.nan, 0.0, 0.0),
        "r3": (0.0, math.inf, 0.0),
        "r4": (0.0, 0.0, math.nan),
    }
    assert core.reference_points(poses) == {"r1": reference_point(0.1, 0.2, 0.3, L_M)}
    with pytest.raises(ValueError, match="math domain error"):  # as reference_point does
        core.reference_points({"r1": (0.0, 0.0, math.inf)})
