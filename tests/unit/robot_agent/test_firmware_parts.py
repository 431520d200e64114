"""The firmware's owned parts on their own: the mode machine (firmware_modes.py) and the rejection
counter (firmware_rejects.py). Their behaviour inside a tick is tested through ``Firmware`` in
test_agent_firmware.py; here each part's narrow interface is driven directly."""

from __future__ import annotations

from hypothesis import given
from hypothesis import strategies as st

from bus_schemas.modes import Mode
from robot_agent.core.firmware_modes import _TRANSITIONS, ModeMachine, _Event
from robot_agent.core.firmware_rejects import Rejections
from robot_agent.core.params import AgentConfig
from robot_agent.core.safety_filter import SafetyFilter
from robot_agent.core.tracking import TrackingController


def _machine() -> tuple[ModeMachine, TrackingController]:
    cfg = AgentConfig()
    tracker = TrackingController(cfg.gains)
    return ModeMachine(tracker, SafetyFilter(cfg)), tracker


def _wind_up(tracker: TrackingController) -> None:
    for _ in range(3):
        tracker.update(0.2, -0.1, 0.0, 0.0, 0.05)
    assert tracker.x.integral_ms != 0.0 and tracker.y.integral_ms != 0.0


def test_a_new_machine_is_idle_waiting_for_a_setpoint() -> None:
    modes, _ = _machine()
    assert modes.mode is Mode.IDLE
    assert modes.reason == "no setpoint yet"


@given(st.lists(st.sampled_from(list(_Event)), max_size=30))
def test_every_event_sequence_follows_the_table(events: list[_Event]) -> None:
    modes, _ = _machine()
    expected = Mode.IDLE
    for k, event in enumerate(events):
        nxt = _TRANSITIONS[expected].get(event, expected)
        assert modes.apply(event, f"event {k}") is (nxt is not expected)
        expected = nxt
        assert modes.mode is expected
        assert modes.reason == f"event {k}"


def test_hold_keeps_the_integrals_idle_and_estop_reset_them() -> None:
    modes, tracker = _machine()
    assert modes.enter(Mode.TRACKING, "tracking")
    _wind_up(tracker)
    integral = tracker.x.integral_ms
    assert modes.enter(Mode.HOLD, "pose stale")
    assert tracker.x.integral_ms == integral  # frozen, not reset
    assert modes.enter(Mode.TRACKING, "tracking")
    assert tracker.x.integral_ms == integral  # HOLD -> TRACKING resumes with them
    assert modes.enter(Mode.ESTOP, "estop")
    assert tracker.x.integral_ms == 0.0 and tracker.y.integral_ms == 0.0
    modes2, tracker2 = _machine()
    modes2.enter(Mode.TRACKING, "tracking")
    _wind_up(tracker2)
    modes2.enter(Mode.IDLE, "no setpoint")
    assert tracker2.x.integral_ms == 0.0


def test_entering_the_same_mode_only_updates_the_reason() -> None:
    modes, tracker = _machine()
    modes.enter(Mode.TRACKING, "tracking")
    _wind_up(tracker)
    integral = tracker.x.integral_ms
    assert not modes.enter(Mode.TRACKING, "still tracking")
    assert modes.reason == "still tracking"
    assert tracker.x.integral_ms == integral


def test_a_rejected_object_counts_once_a_scalar_every_time() -> None:
    rejects = Rejections()
    pose = (float("nan"), 0.0, 0.0, 0.0)
    for _ in range(3):
        rejects.pose(pose, "non-finite pose")
    assert (rejects.count, rejects.last_reason) == (1, "non-finite pose")
    setpoint = object()
    rejects.setpoint(setpoint, "bad slot")
    rejects.setpoint(setpoint, "bad slot")
    rejects.pose((float("nan"), 0.0, 0.0, 0.0), "non-finite pose")  # another object
    assert rejects.count == 3
    rejects.add("non-finite neighbour or obstacle", 2)
    rejects.add("non-finite now_s")
    rejects.add("non-finite now_s")
    assert (rejects.count, rejects.last_reason) == (7, "non-finite now_s")
