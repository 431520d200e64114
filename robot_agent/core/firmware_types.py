"""The firmware's vocabulary: its modes, the inputs and output of one tick, the status snapshot,
and the table-driven mode machine (events and transitions) that ``Firmware.step`` follows.

Modes::

    IDLE      no valid setpoint received yet. Nominal command 0 (see "Evading" below).
    TRACKING  fresh, finite pose and setpoint: run the controller.
    HOLD      we have (had) a setpoint but cannot track safely now: the pose or setpoint is
              older than its staleness limit (``|now_s - *_rx_s|``), missing, or was rejected
              (non-finite field, slot not an int >= 0). Nominal command 0. The integrators
              are frozen (not updated) and the derivative state is reset on entry, so
              resuming gives no kick.
    ESTOP     latched emergency stop. Wheels exactly 0. Only ``release_estop()`` leaves it,
              to IDLE (never had a setpoint) or HOLD; the next fresh tick then goes TRACKING.

Evading (issue 30, "Movers"): in IDLE and HOLD, while the robot's own pose at ``now_s`` is
valid, the safety filter still runs on a zero nominal command (``SafetyFilter.evade``): the
wheels are exactly 0 unless a body or a neighbour comes at the robot or it is inside a
boundary, and then it gets out of the way. Only ESTOP, a lost pose (a dead link: no pose, too
old, invalid estimate) and a disabled filter mean wheels at zero whatever approaches.

Each tick is classified into one event (first match wins): ESTOP (latch set), INVALID (a
non-finite clock value), NO_SETPOINT (no setpoint, or a rejected one before any valid one),
INVALID (rejected setpoint or pose), STALE (pose missing, or pose / setpoint too old), FRESH.
The next mode is ``_TRANSITIONS[mode][event]``; on-entry actions run when the mode changes:
HOLD and TRACKING reset the derivative state, IDLE and ESTOP (and IDLE -> TRACKING) reset the
whole PID.
Data types are ``NamedTuple``s: immutable, positional, and cheap to build on the hot path
(a frozen dataclass costs several times more per instance in CPython).

Split out of firmware.py (issue 12) so the controller's step reads on its own; every name here is
still importable from ``robot_agent.core.firmware``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import Enum, StrEnum
from typing import Any, Final, NamedTuple

from robot_agent.core.safety_filter import SafetyFilterStatus
from robot_agent.core.tracking import PIDInfo


class Mode(StrEnum):
    """Firmware mode; the value is what the status message carries."""

    IDLE = "idle"
    TRACKING = "tracking"
    HOLD = "hold"
    ESTOP = "estop"


class Pose(NamedTuple):
    """Pose of the robot's axle centre: x, y (m), theta (rad), t = source timestamp (s)."""

    x: float
    y: float
    theta: float
    t: float


class Setpoint(NamedTuple):
    """Where the robot's REFERENCE POINT should be (x, y in m), with its velocity (vx, vy in m/s,
    feed-forward), the slot's heading theta (rad), the slot number and the source time t (s)."""

    x: float
    y: float
    vx: float
    vy: float
    theta: float
    slot: int
    t: float


class WheelCommand(NamedTuple):
    """One tick's output.

    Attributes:
        omega_r, omega_l: wheel speeds (rad/s), ``|omega| <= max_wheel_radps``.
        power_r, power_l: the same as a fraction of ``max_wheel_radps``, in [-1, 1].
        mode: the firmware mode after this tick.
        pose_t: ``t`` of the pose the command was computed from (the last valid pose seen,
            also in HOLD / ESTOP), or None if no valid pose was ever received.
        saturated: the wheel saturation stage limited this command.
    """

    omega_r: float
    omega_l: float
    power_r: float
    power_l: float
    mode: Mode
    pose_t: float | None
    saturated: bool


@dataclass(frozen=True, slots=True)
class FirmwareStatus:
    """Snapshot of the firmware for the status message and logs.

    Attributes:
        mode: current mode.
        slot: slot of the last valid setpoint (None before the first).
        ex, ey: last tracking error of the reference point (m); NaN before the first tick in
            TRACKING.
        saturated_count: ticks whose wheel command saturated.
        rejected_count: bad inputs rejected (see the module docstring for how they count).
        last_pose_t: ``t`` of the last valid pose, or None.
        steps: calls to ``step``.
        reason: why the firmware is in its mode (e.g. ``"pose stale"``).
        last_reject_reason: reason of the last rejection ("" if none).
        estop_latched: the emergency stop is latched.
        role_changes: setpoint slot changes seen (each reset the PID).
        dt_faults: ticks whose dt was <= 0 or > max_dt_s (not counting the first tick).
        pose_age_s, setpoint_age_s: receive ages at the last tick (s); NaN if unknown.
        pid_x, pid_y: last PID snapshots per axis.
        safety_filter: the safety filter's counters (``SafetyFilterStatus``).
    """

    mode: Mode
    slot: int | None
    ex: float
    ey: float
    saturated_count: int
    rejected_count: int
    last_pose_t: float | None
    steps: int
    reason: str
    last_reject_reason: str
    estop_latched: bool
    role_changes: int
    dt_faults: int
    pose_age_s: float
    setpoint_age_s: float
    pid_x: PIDInfo
    pid_y: PIDInfo
    safety_filter: SafetyFilterStatus | None = None

    def as_dict(self) -> dict[str, Any]:
        """msgpack-friendly dict (the status message carries ``mode``, ``slot``, ``pid``,
        ``rejected``; the rest are extra fields)."""
        return {
            "mode": str(self.mode),
            "slot": self.slot,
            "ex": self.ex,
            "ey": self.ey,
            "saturated": self.saturated_count,
            "rejected": self.rejected_count,
            "last_pose_t": self.last_pose_t,
            "steps": self.steps,
            "reason": self.reason,
            "last_reject_reason": self.last_reject_reason,
            "estop": self.estop_latched,
            "role_changes": self.role_changes,
            "dt_faults": self.dt_faults,
            "pose_age_s": self.pose_age_s,
            "setpoint_age_s": self.setpoint_age_s,
            "pid": {"x": self.pid_x.as_dict(), "y": self.pid_y.as_dict()},
            "filter": self.safety_filter.as_dict() if self.safety_filter is not None else None,
        }


class _Event(Enum):
    """What a tick (or an estop call) says about the inputs."""

    FRESH = "fresh"
    STALE = "stale"
    INVALID = "invalid"
    NO_SETPOINT = "no_setpoint"
    ESTOP = "estop"
    RELEASE = "release"  # release_estop() after a valid setpoint was seen
    RELEASE_UNCONFIGURED = "release_unconfigured"  # release_estop() before any setpoint


_M = Mode


_E = _Event


#: The whole mode logic: next mode = _TRANSITIONS[mode][event]. Missing entries mean "stay".
_TRANSITIONS: Final[dict[Mode, dict[_Event, Mode]]] = {
    _M.IDLE: {
        _E.FRESH: _M.TRACKING,
        _E.STALE: _M.HOLD,
        _E.INVALID: _M.HOLD,
        _E.NO_SETPOINT: _M.IDLE,
        _E.ESTOP: _M.ESTOP,
    },
    _M.TRACKING: {
        _E.FRESH: _M.TRACKING,
        _E.STALE: _M.HOLD,
        _E.INVALID: _M.HOLD,
        _E.NO_SETPOINT: _M.HOLD,
        _E.ESTOP: _M.ESTOP,
    },
    _M.HOLD: {
        _E.FRESH: _M.TRACKING,
        _E.STALE: _M.HOLD,
        _E.INVALID: _M.HOLD,
        _E.NO_SETPOINT: _M.HOLD,
        _E.ESTOP: _M.ESTOP,
    },
    _M.ESTOP: {
        _E.FRESH: _M.ESTOP,
        _E.STALE: _M.ESTOP,
        _E.INVALID: _M.ESTOP,
        _E.NO_SETPOINT: _M.ESTOP,
        _E.ESTOP: _M.ESTOP,
        _E.RELEASE: _M.HOLD,
        _E.RELEASE_UNCONFIGURED: _M.IDLE,
    },
}


_NAN = math.nan


_TRACKING: Final = Mode.TRACKING


_ESTOP: Final = Mode.ESTOP


_EV_FRESH: Final = _Event.FRESH


_EV_STALE: Final = _Event.STALE


_EV_INVALID: Final = _Event.INVALID


_EV_NO_SETPOINT: Final = _Event.NO_SETPOINT


_EV_ESTOP: Final = _Event.ESTOP


def _new_command(
    omega_r: float,
    omega_l: float,
    power_r: float,
    power_l: float,
    mode: Mode,
    pose_t: float | None,
    saturated: bool,
) -> WheelCommand:
    """Build a WheelCommand without the NamedTuple ``__new__`` frame (hot path)."""
    return _tuple_new(WheelCommand, (omega_r, omega_l, power_r, power_l, mode, pose_t, saturated))


_tuple_new = tuple.__new__
