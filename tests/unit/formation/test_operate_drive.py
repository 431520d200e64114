"""The operator tools' pure parts (formation/operate/drive.py): the keyboard's teleop state, the
gamepad's joystick events, waypoints from the command line."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from formation.operate.drive import (
    JS_AXIS,
    JS_BUTTON,
    JS_EVENT,
    JS_INIT,
    SPEED_MAX_MPS,
    TURN_MAX_RADPS,
    Gamepad,
    TeleopKeys,
    parse_waypoints,
)


def _ev(kind: int, number: int, value: int) -> bytes:
    return JS_EVENT.pack(1234, value, kind, number)


def test_keys_step_the_twist_and_stop_and_quit() -> None:
    k = TeleopKeys()
    for key in "www":
        assert k.press(key)
    k.press("a")
    assert (k.v_mps, k.omega_radps) == (0.03, 0.05)
    k.press("d")
    k.press("d")
    assert k.omega_radps == -0.05
    assert not k.press("z") and (k.v_mps, k.omega_radps) == (0.03, -0.05)
    k.press(" ")
    assert (k.v_mps, k.omega_radps) == (0.0, 0.0) and not k.quit
    k.press("q")
    assert k.quit


@given(st.text(alphabet="wxads q", max_size=200))
def test_keys_never_ask_beyond_the_tool_limits(keys_: str) -> None:
    k = TeleopKeys()
    for key in keys_:
        k.press(key)
    assert abs(k.v_mps) <= SPEED_MAX_MPS and abs(k.omega_radps) <= TURN_MAX_RADPS


def test_gamepad_stick_sets_the_twist_with_a_deadzone() -> None:
    pad = Gamepad()
    assert pad.twist(0.1, 0.3) is None  # nothing read yet: the keyboard's
    pad.feed(_ev(JS_AXIS | JS_INIT, 0, 0) + _ev(JS_AXIS | JS_INIT, 1, 0))
    assert pad.twist(0.1, 0.3) == (0.0, 0.0)
    data = _ev(JS_AXIS, 1, -32767) + _ev(JS_AXIS, 0, 1000)  # full forward, a drift to the right
    pad.feed(data[:5])  # any chunking
    pad.feed(data[5:])
    assert pad.twist(0.1, 0.3) == (0.1, 0.0)
    pad.feed(_ev(JS_AXIS, 0, -32767))  # full left
    assert pad.twist(0.1, 0.3) == (0.1, 0.3)
    pad.feed(_ev(JS_BUTTON, 0, 1))
    assert pad.stop_pressed


@given(st.binary(max_size=400))
def test_gamepad_takes_any_bytes(data: bytes) -> None:
    pad = Gamepad()
    pad.feed(data)
    tw = pad.twist(0.1, 0.3)
    assert tw is None or (abs(tw[0]) <= 0.1 and abs(tw[1]) <= 0.3)


def test_waypoints_parse_and_refuse() -> None:
    assert parse_waypoints(["1,0", "1.5,0.5 1,1"]) == [(1.0, 0.0), (1.5, 0.5), (1.0, 1.0)]
    for bad in (["1"], ["1,2,3"], ["a,1"], ["1,inf"], ["1,1", "1,1"], ["1e300,0"], [""]):
        with pytest.raises(ValueError):
            parse_waypoints(bad)


def test_the_operator_tools_bounds_are_the_coordinators() -> None:
    """``formation shape`` and ``formation path`` check their arguments against the contract's
    bounds (bus_schemas, light to import); the coordinator refuses by its own constants, which
    must be the same."""
    from bus_schemas.messages_operator import PATH_POINTS_MAX, SPACING_MAX_M, SPACING_MIN_M
    from coordinator.core.leader import MAX_PATH_POINTS
    from coordinator.core.reshape import SPACING_RANGE_M

    assert (SPACING_MIN_M, SPACING_MAX_M) == SPACING_RANGE_M
    assert PATH_POINTS_MAX == MAX_PATH_POINTS
