"""The firmware's mode machine in action, and its public accessors: entering a mode (on-entry
actions), the HOLD / zero ticks, the e-stop latch, rejection counting, the status snapshot.

``Firmware`` (firmware.py) inherits these and adds ``__init__`` and ``step``, the control tick;
the modes, events and transition table are in firmware_types.py. Split out of firmware.py
(issue 12) so the control tick reads on its own.
"""

from __future__ import annotations

from robot_agent.core.estimator import Estimator
from robot_agent.core.firmware_types import (
    _TRANSITIONS,
    FirmwareStatus,
    Mode,
    WheelCommand,
    _Event,
    _new_command,
)
from robot_agent.core.params import AgentConfig
from robot_agent.core.safety_filter import SafetyFilter
from robot_agent.core.tracking import TrackingController


class _FirmwareModes:
    """Base class of :class:`robot_agent.core.firmware.Firmware`: the state the methods here change
    is declared here (``__slots__``), the rest by ``Firmware``; ``Firmware.__init__`` sets it."""

    __slots__ = (
        "_last_rejected_pose",
        "_last_rejected_setpoint",
        "_last_saturated",
        "_mode",
        "_pending_cmd",
        "_reason",
        "_rej_reason",
        "_rejected",
    )
    _cfg: AgentConfig
    _mode: Mode
    _reason: str
    _filter: SafetyFilter
    _tracker: TrackingController
    _est: Estimator | None
    _unc: float
    _est_xyt: tuple[float, ...] | None
    _rejected: int
    _rej_reason: str
    _have_setpoint: bool
    _slot: int | None
    _ex: float
    _ey: float
    _saturated: int
    _last_pose_t: float | None
    _steps: int
    _role_changes: int
    _dt_faults: int
    _pose_age: float
    _setpoint_age: float
    _last_saturated: bool
    _last_rejected_pose: object
    _last_rejected_setpoint: object
    _pending_cmd: tuple[float, float, float] | None
    _last_now: float | None
    _act_delay: float

    # ------------------------------------------------------------------ public API

    @property
    def config(self) -> AgentConfig:
        """The configuration this firmware runs with."""
        return self._cfg

    @property
    def mode(self) -> Mode:
        """Current mode."""
        return self._mode

    @property
    def safety_filter(self) -> SafetyFilter:
        """The safety filter (counters via ``status().safety_filter``)."""
        return self._filter

    @property
    def tracker(self) -> TrackingController:
        """The tracking controller (for inspection in tests and logs)."""
        return self._tracker

    @property
    def estimator(self) -> Estimator | None:
        """The pose estimator (None when ``config.estimator.enabled`` is False)."""
        return self._est

    @property
    def pose_uncertainty_m(self) -> float:
        """Uncertainty (m) of the pose used on the last tick: ``n_sigma`` standard deviations
        of the estimator's position (the safety filter's extra radius); NaN without a valid
        estimate on that tick, 0.0 with the estimator disabled."""
        return self._unc

    @property
    def pose_estimate(self) -> tuple[float, float, float] | None:
        """``(x, y, theta)`` of the axle centre the last tick used (estimated at ``now_s``, or
        the measured pose with the estimator disabled), or None."""
        xyt = self._est_xyt  # (a pose may hold ints or numpy scalars: floats out)
        return None if xyt is None else (float(xyt[0]), float(xyt[1]), float(xyt[2]))

    def reject(self, reason: str) -> None:
        """Count one bad input (e.g. a message the shell could not decode) with its reason."""
        self._rejected += 1
        self._rej_reason = reason

    def engage_estop(self) -> None:
        """Latch the emergency stop: wheels are zero from now until ``release_estop()``."""
        self._transition(_Event.ESTOP, "estop")

    def release_estop(self) -> None:
        """Release a latched emergency stop, to HOLD (or IDLE if no setpoint was ever valid).

        The next ``step`` with fresh data resumes TRACKING. No-op when not latched.
        """
        if self._mode is not Mode.ESTOP:
            return
        if self._have_setpoint:
            self._transition(_Event.RELEASE, "estop released")
        else:
            self._transition(_Event.RELEASE_UNCONFIGURED, "estop released, no setpoint yet")

    def status(self) -> FirmwareStatus:
        """Snapshot for the status message."""
        pid_x, pid_y = self._tracker.snapshot()
        return FirmwareStatus(
            mode=self._mode,
            slot=self._slot,
            ex=self._ex,
            ey=self._ey,
            saturated_count=self._saturated,
            rejected_count=self._rejected,
            last_pose_t=self._last_pose_t,
            steps=self._steps,
            reason=self._reason,
            last_reject_reason=self._rej_reason,
            estop_latched=self._mode is Mode.ESTOP,
            role_changes=self._role_changes,
            dt_faults=self._dt_faults,
            pose_age_s=self._pose_age,
            setpoint_age_s=self._setpoint_age,
            pid_x=pid_x,
            pid_y=pid_y,
            safety_filter=self._filter.status(),
        )

    # ------------------------------------------------------------------ internals

    def _set_mode(self, new: Mode, reason: str) -> None:
        """Enter ``new`` (running its on-entry action if it differs from the current mode)."""
        self._reason = reason
        old = self._mode
        if new is old:
            return
        self._mode = new
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
        self._last_saturated = False

    def _transition(self, event: _Event, reason: str) -> Mode:
        new = _TRANSITIONS[self._mode].get(event, self._mode)
        self._set_mode(new, reason)
        return new

    def _zero(self, pose_t: float | None) -> WheelCommand:
        """Zero command in the current mode."""
        return _new_command(0.0, 0.0, 0.0, 0.0, self._mode, pose_t, False)

    def _reject_pose(self, pose: object, reason: str) -> None:
        if pose is not self._last_rejected_pose:
            self._last_rejected_pose = pose
            self.reject(reason)

    def _reject_setpoint(self, setpoint: object, reason: str) -> None:
        if setpoint is not self._last_rejected_setpoint:
            self._last_rejected_setpoint = setpoint
            self.reject(reason)

    def _stop(self, event: _Event, reason: str) -> None:
        """Non-tracking tick: apply the event; the tick's wheels are zero (``_zero``)."""
        self._transition(event, reason)
        self._last_saturated = False
        if self._est is not None and self._last_now is not None:
            self._pending_cmd = (self._last_now + self._act_delay, 0.0, 0.0)

    def _hold(self, event: _Event, reason: str) -> WheelCommand:
        """Non-tracking tick: apply the event, zero wheels."""
        self._stop(event, reason)
        return _new_command(0.0, 0.0, 0.0, 0.0, self._mode, self._last_pose_t, False)
