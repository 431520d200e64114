"""The firmware's data: the inputs and output of one tick (``Pose``, ``Setpoint``,
``WheelCommand``) and the status snapshot (``FirmwareStatus``). The modes and the mode machine:
firmware_modes.py; ``Mode`` itself is the contract's (``bus_schemas.modes``), declared once.

Data types are ``NamedTuple``s: immutable, positional, and cheap to build on the hot path
(a frozen dataclass costs several times more per instance in CPython).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Final, NamedTuple

from bus_schemas.modes import Mode
from robot_agent.core.safety_filter import SafetyFilterStatus
from robot_agent.core.tracking import PIDInfo


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


_NAN: Final = math.nan


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


_tuple_new: Final = tuple.__new__
