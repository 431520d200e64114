"""coordinator.core.leader_state: the virtual leader's state behaves as the frozen dataclass it
replaced, compiled (with the coordinator's build, when ``make accel`` made it) and pure.

* read-only: assigning or deleting any attribute raises ``FrozenInstanceError``;
* a dataclass: its fields, ``replace``, equality and hash over the fields, ``repr``;
* it pickles and copies to an equal state;
* the pure sources (``FORMATION_ACCEL=0``, in a child process) give the same ``repr``, pickle
  bytes and ``vx``/``vy`` bits as the build this process loaded, and the same samples of the
  closed-form trajectories (line, circle, figure eight: their arithmetic is compiled here too),
  before, at and after their start.
"""

from __future__ import annotations

import copy
import dataclasses
import math
import os
import pickle
import subprocess
import sys
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from coordinator.core import leader_state
from coordinator.core.leader_state import LeaderState
from coordinator.core.trajectory import LeaderState as ReExported
from robot_agent.core._accel import ENV

ROOT = Path(__file__).resolve().parents[3]
FIELDS = ("t", "x", "y", "theta", "v_mps", "omega_radps")
floats = st.floats(allow_nan=False, allow_infinity=False, width=64)
states = st.builds(LeaderState, floats, floats, floats, floats, floats, floats)


def test_trajectory_re_exports_the_one_class() -> None:
    assert ReExported is LeaderState
    assert tuple(f.name for f in dataclasses.fields(LeaderState)) == FIELDS
    assert LeaderState.__match_args__ == FIELDS


@given(states, floats)
def test_read_only(s: LeaderState, value: float) -> None:
    before = dataclasses.astuple(s)
    for name in (*FIELDS, "other"):
        with pytest.raises(dataclasses.FrozenInstanceError, match=name):
            setattr(s, name, value)
    for name in FIELDS:
        with pytest.raises(dataclasses.FrozenInstanceError, match=name):
            delattr(s, name)
    assert dataclasses.astuple(s) == before


@given(states, floats)
def test_a_dataclass_over_its_fields(s: LeaderState, x: float) -> None:
    fields = tuple(getattr(s, name) for name in FIELDS)
    twin = LeaderState(*fields)
    assert twin == s and hash(twin) == hash(s) == hash(fields)
    moved = dataclasses.replace(s, x=x)
    assert dataclasses.astuple(moved) == (s.t, x, s.y, s.theta, s.v_mps, s.omega_radps)
    assert (moved == s) == (x == s.x)
    shown = ", ".join(f"{n}={v!r}" for n, v in zip(FIELDS, fields, strict=True))
    assert repr(s) == f"LeaderState({shown})"
    assert s.vx == s.v_mps * math.cos(s.theta) and s.vy == s.v_mps * math.sin(s.theta)


@given(states)
def test_pickles_and_copies(s: LeaderState) -> None:
    for other in (pickle.loads(pickle.dumps(s)), copy.copy(s), copy.deepcopy(s)):
        assert type(other) is LeaderState and other == s


_CHILD = """
import pickle, sys
from coordinator.core.leader_state import LeaderState
from coordinator.core.trajectory import Circle, FigureEight, StraightLine
states = [LeaderState(0.1 * k, -1.5 + k, 2.0 / (k + 1), 0.3 * k - 3.0, 0.07 * k, -0.01 * k)
          for k in range(7)]
sys.stdout.write(repr([(repr(s), pickle.dumps(s).hex(), s.vx.hex(), s.vy.hex()) for s in states]))
trajectories = [StraightLine(0.3, -1.0, 2.5, 0.07, 1.0), StraightLine(-0.0, 0.0, -3.0, 0.0),
                Circle(0.5, -0.2, 1.3, 0.11, 0.4, False, 2.0), Circle(0.0, 0.0, 0.7, 0.05),
                FigureEight(-0.3, 0.2, 1.1, 37.0, 0.9, 1.5), FigureEight(0.0, 0.0, 0.8, 20.0)]
times = [-1.0, -0.0, 0.0, 1e-300, 1.0, 1.5, 2.0, 12345.678] + [0.02 * k for k in range(2000)]
for tr in trajectories:
    sys.stdout.write(repr([repr(tr.sample(t)) for t in times]))
"""


def _child(pure: bool) -> str:
    env = {**os.environ, ENV: "0"} if pure else {k: v for k, v in os.environ.items() if k != ENV}
    out = subprocess.run(
        [sys.executable, "-c", _CHILD], cwd=ROOT, env=env, capture_output=True, text=True,
        check=True, timeout=120,
    )  # fmt: skip
    return out.stdout


def test_compiled_and_pure_states_are_the_same() -> None:
    assert _child(pure=True) == _child(pure=False)
    compiled = not str(leader_state.__file__).endswith(".py")
    assert leader_state._NATIVE is compiled
