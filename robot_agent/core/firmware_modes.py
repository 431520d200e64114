"""The firmware's mode machine: the modes, the events a tick reports, the transition table and
the on-entry actions.

Modes (``bus_schemas.modes.Mode``: the status message carries the value)::

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
whole PID; every mode but TRACKING resets the safety filter's deadlock monitor.

``Firmware`` (firmware.py) builds one ``ModeMachine`` over its tracker and safety filter and
applies the events its tick stages report; the machine owns the mode and its reason.
"""

from __future__ import annotations

from enum import Enum
from typing import Final

from bus_schemas.modes import Mode
from robot_agent.core.safety_filter import SafetyFilter
from robot_agent.core.tracking import TrackingController

__all__ = ["Mode", "ModeMachine"]


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


_TRACKING: Final = Mode.TRACKING


_ESTOP: Final = Mode.ESTOP


_EV_FRESH: Final = _Event.FRESH


_EV_STALE: Final = _Event.STALE


_EV_INVALID: Final = _Event.INVALID


_EV_NO_SETPOINT: Final = _Event.NO_SETPOINT


_EV_ESTOP: Final = _Event.ESTOP


class ModeMachine:
    """The firmware's mode and why (see the module docstring). ``mode`` and ``reason`` are read
    by the owner; only ``enter`` and ``apply`` change them, running the on-entry actions on the
    tracker and the safety filter the owner built (and shares with it)."""

    __slots__ = ("_filter", "_tracker", "mode", "reason")

    def __init__(self, tracker: TrackingController, safety_filter: SafetyFilter) -> None:
        self._tracker = tracker
        self._filter = safety_filter
        self.mode: Mode = Mode.IDLE
        self.reason = "no setpoint yet"

    def enter(self, new: Mode, reason: str) -> bool:
        """Enter ``new`` for ``reason``, with its on-entry action if it differs from the current
        mode; True when the mode changed."""
        self.reason = reason
        old = self.mode
        if new is old:
            return False
        self.mode = new
        if new is not Mode.TRACKING:
            self._filter.reset_deadlock()
        tracker = self._tracker
        if new is Mode.HOLD:
            # Integrators are frozen simply by not being updated; a fresh derivative means
            # the first tick after resuming has edot = 0 (no kick).
            tracker.reset_derivative()
        elif new is Mode.TRACKING:
            tracker.reset_derivative()
            if old is Mode.IDLE:
                tracker.reset()
        else:  # IDLE or ESTOP: start again from scratch
            tracker.reset()
        return True

    def apply(self, event: _Event, reason: str) -> bool:
        """The transition of ``event`` (``_TRANSITIONS``); True when the mode changed."""
        mode = self.mode
        return self.enter(_TRANSITIONS[mode].get(event, mode), reason)
