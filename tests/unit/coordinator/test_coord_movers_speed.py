"""coordinator/core/movers.py's ``_slower``: the test that spares ``MoverDetector.update`` the
speed of a driven robot. It may answer True only when the speed it stands for,
``math.hypot(dx, dy) / dt``, is at most the limit (so every decision is the one the speed gives),
and it must answer True well inside the limit (or it spares nothing)."""

from __future__ import annotations

import math

from hypothesis import given, settings
from hypothesis import strategies as st

from coordinator.core.movers import _slower

_FINITE = st.floats(allow_nan=False, allow_infinity=False)
_POSITIVE = st.floats(min_value=5e-324, allow_nan=False, allow_infinity=True)


@settings(max_examples=2000, deadline=None, derandomize=True)
@given(dx=_FINITE, dy=_FINITE, dt=_POSITIVE, limit=_POSITIVE)
def test_slower_is_never_wrong(dx: float, dy: float, dt: float, limit: float) -> None:
    """Any inputs: True implies the rounded speed is at most the limit."""
    if _slower(dx, dy, dt, limit):
        assert math.hypot(dx, dy) / dt <= limit


@settings(max_examples=2000, deadline=None, derandomize=True)
@given(
    dx=st.floats(-10.0, 10.0),
    dy=st.floats(-10.0, 10.0),
    dt=st.floats(0.01, 10.0),
    ulps=st.integers(-10_000, 10_000),
)
def test_slower_at_the_limit(dx: float, dy: float, dt: float, ulps: int) -> None:
    """Limits within a few thousand ulps of the speed itself (where rounding decides): True
    only when the speed is at most the limit."""
    speed = math.hypot(dx, dy) / dt
    limit = speed
    step = math.inf if ulps > 0 else -math.inf
    for _ in range(abs(ulps)):
        limit = math.nextafter(limit, step)
    if limit > 0.0 and _slower(dx, dy, dt, limit):
        assert speed <= limit


def test_slower_says_so_well_inside_the_limit() -> None:
    """A driven robot's usual speed (0.1 m/s over 0.5 s) is below 0.4 m/s: decided without the
    speed; at or past the limit, or where products leave the normal range, it is not."""
    assert _slower(0.03, -0.04, 0.5, 0.4)
    assert _slower(0.0, 0.0, 0.5, 0.4)
    assert not _slower(0.12, 0.16, 0.5, 0.4)  # 0.4 m/s exactly
    assert not _slower(0.2, 0.2, 0.5, 0.4)
    assert not _slower(0.0, 0.0, 1e-160, 1e-160)  # the squared limit underflows
    assert not _slower(0.0, 0.0, 1e160, 1e160)  # ... overflows
    assert not _slower(math.inf, 0.0, 0.5, 0.4)
