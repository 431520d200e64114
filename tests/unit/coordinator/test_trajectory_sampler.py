"""coordinator.core.trajectory.sampler: the compiled samplers the leader's step calls every tick
in place of a trajectory's interpreted ``sample`` (coordinator.core.leader_state.Sampler).

* for a line, a circle (either way round) and a figure eight, any parameters and any finite
  time (before, at and after the start, ints included), the sampler's state is the trajectory's
  own ``sample`` bit for bit (``repr`` of the floats, which tells -0.0 and 0.0 apart);
* any other trajectory (waypoints, a subclass) has none: the leader calls its ``sample``;
* ``LeaderCore`` gives the trajectory's own ``ValueError`` for a time that is not finite, and
  follows a trajectory assigned after it was made (not the sampler of the one before).
"""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from coordinator.core.leader import LeaderCore
from coordinator.core.leader_state import LeaderState
from coordinator.core.trajectory import (
    Circle,
    FigureEight,
    StraightLine,
    Trajectory,
    Waypoints,
    sampler,
)

_COORD = st.floats(-50.0, 50.0)
_TIME = st.one_of(st.floats(-5.0, 500.0), st.integers(-5, 500))


def _same(a: LeaderState, b: LeaderState) -> bool:
    fields = ("t", "x", "y", "theta", "v_mps", "omega_radps")
    return all(repr(getattr(a, f)) == repr(getattr(b, f)) for f in fields)


def _check(traj: Trajectory, t: float) -> None:
    sp = sampler(traj)
    assert sp is not None
    assert _same(sp.sample(float(t)), traj.sample(t))


@settings(max_examples=300, deadline=None, derandomize=True)
@given(
    x0=_COORD,
    y0=_COORD,
    heading=st.floats(-10.0, 10.0),
    speed=st.floats(0.0, 2.0),
    t_start=st.floats(0.0, 20.0),
    t=_TIME,
)
def test_line(x0: float, y0: float, heading: float, speed: float, t_start: float, t: float) -> None:
    _check(StraightLine(x0, y0, heading, speed, t_start), t)


@settings(max_examples=300, deadline=None, derandomize=True)
@given(
    cx=_COORD,
    cy=_COORD,
    radius=st.floats(0.05, 20.0),
    speed=st.floats(0.001, 2.0),
    start=st.floats(-10.0, 10.0),
    ccw=st.booleans(),
    t_start=st.floats(0.0, 20.0),
    t=_TIME,
)
def test_circle(
    cx: float,
    cy: float,
    radius: float,
    speed: float,
    start: float,
    ccw: bool,
    t_start: float,
    t: float,
) -> None:
    _check(Circle(cx, cy, radius, speed, start, ccw, t_start), t)


@settings(max_examples=300, deadline=None, derandomize=True)
@given(
    cx=_COORD,
    cy=_COORD,
    a=st.floats(0.05, 20.0),
    period=st.floats(1.0, 200.0),
    rotation=st.floats(-10.0, 10.0),
    t_start=st.floats(0.0, 20.0),
    t=_TIME,
)
def test_figure_eight(
    cx: float, cy: float, a: float, period: float, rotation: float, t_start: float, t: float
) -> None:
    _check(FigureEight(cx, cy, a, period, rotation, t_start), t)


def test_no_sampler_for_other_trajectories() -> None:
    class Slower(StraightLine):
        def sample(self, t_s: float) -> LeaderState:
            return super().sample(0.5 * t_s)

    assert sampler(Waypoints([(0.0, 0.0), (1.0, 0.0)], 0.1, 1.0)) is None
    assert sampler(Slower(0.0, 0.0, 0.0, 0.1)) is None
    assert sampler(object()) is None
    # the leader follows the subclass's own sample
    leader = LeaderCore(Slower(0.0, 0.0, 0.0, 0.1))
    assert leader.step(4.0).x == pytest.approx(0.2)


def test_leader_non_finite_time_and_a_new_trajectory() -> None:
    leader = LeaderCore(StraightLine(0.0, 0.0, 0.0, 0.1))
    with pytest.raises(ValueError, match=r"StraightLine\.sample: t_s must be a finite number"):
        leader.step(math.inf)
    with pytest.raises(ValueError, match=r"StraightLine\.sample: t_s must be a finite number"):
        leader.step(math.nan)
    leader = LeaderCore(StraightLine(0.0, 0.0, 0.0, 0.1))
    assert leader.step(2.0).x == pytest.approx(0.2)
    leader.trajectory = StraightLine(1.0, 0.0, 0.0, 0.2)
    assert leader.step(3.0).x == pytest.approx(1.6)
