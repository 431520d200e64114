"""The motor backend contract: what the agent's control loop calls to move the wheels.

A backend turns wheel speeds (rad/s, right and left, positive = the wheel drives the robot
forward) into whatever the hardware needs. The control loop calls, in this order:

``open()`` once at start; ``apply(omega_r_radps, omega_l_radps, now_s)`` every tick;
``stop()`` whenever the wheels must be zero now (HOLD, ESTOP, shutdown); ``close()`` once.

Rules every backend follows (firmware-grade: the loop must never die because of a motor):

- No method raises into the caller. I/O faults, missing acknowledgements and bad inputs are
  *counted* and visible in :meth:`MotorBackend.status`; the return value says whether the
  command reached the hardware.
- ``apply`` with a non-finite speed commands zero for both wheels (and counts it).
- ``apply`` is bounded in time (no retries loops, no sleeps); a backend that lost its device
  tries to reopen it from ``apply``, with an exponential backoff on ``now_s``.
- ``now_s`` is the caller's clock (s), used only for backoff and the ``last_ok_s`` stamp.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

__all__ = ["BusMotorBackend", "MotorBackend", "MotorStatus"]


@dataclass(frozen=True, slots=True)
class MotorStatus:
    """A snapshot of a backend's health and counters (for the agent's status message).

    Attributes:
        backend: backend name ("bus", "roboclaw").
        healthy: True when the last command reached the hardware and the link is up.
        connected: the device is open (always True for backends without a device).
        omega_r_radps: last right wheel speed commanded to the hardware (rad/s), after
            sign conventions are undone and the clamp applied.
        omega_l_radps: last left wheel speed commanded (rad/s), as above.
        commands: commands sent to the hardware (drive commands, stop included).
        acks: commands the hardware acknowledged.
        errors: every fault counted below plus rejected inputs, in total.
        no_ack: commands that got no (or a wrong) acknowledgement in time.
        io_errors: operating-system level failures (device gone, write failed, ...).
        crc_errors: replies whose checksum did not match.
        rejected_inputs: ``apply`` calls with a non-finite speed (zero was commanded).
        clamped: commands scaled down to the backend's speed limit.
        reconnects: successful re-opens after the device was lost.
        open_failures: failed attempts to open the device (initial and re-opens).
        consecutive_failures: failed commands since the last acknowledged one.
        last_error: text of the most recent fault, or None.
        last_ok_s: ``now_s`` of the last acknowledged command, or None.
        firmware: the hardware's identification string when it has one, else None.
    """

    backend: str
    healthy: bool
    connected: bool
    omega_r_radps: float = 0.0
    omega_l_radps: float = 0.0
    commands: int = 0
    acks: int = 0
    errors: int = 0
    no_ack: int = 0
    io_errors: int = 0
    crc_errors: int = 0
    rejected_inputs: int = 0
    clamped: int = 0
    reconnects: int = 0
    open_failures: int = 0
    consecutive_failures: int = 0
    last_error: str | None = None
    last_ok_s: float | None = None
    firmware: str | None = None


@runtime_checkable
class MotorBackend(Protocol):
    """What the agent needs from a motor driver (see the module docstring for the rules)."""

    name: str

    def open(self) -> bool:
        """Open the device and bring the wheels to zero; True when the link is verified."""
        ...

    def apply(self, omega_r_radps: float, omega_l_radps: float, now_s: float) -> bool:
        """Command wheel speeds (rad/s); True when the hardware acknowledged them."""
        ...

    def stop(self) -> bool:
        """Command zero speed on both wheels now; True when acknowledged."""
        ...

    def close(self) -> None:
        """Stop the wheels (best effort) and release the device. Idempotent."""
        ...

    def status(self) -> MotorStatus:
        """A snapshot of health and counters."""
        ...


class BusMotorBackend:
    """The backend of a simulated robot: the wheel command *is* the bus message.

    In simulation the plant subscribes to ``formation/<fleet>/robot/<id>/wheels``, which the
    agent publishes anyway, so there is no device to drive. This backend only records the
    last command (so ``status()`` is meaningful) and applies the same input rules as a real
    backend: a non-finite speed becomes zero and is counted.
    """

    name = "bus"

    def __init__(self) -> None:
        self._omega_r = 0.0
        self._omega_l = 0.0
        self._commands = 0
        self._rejected = 0
        self._last_ok_s: float | None = None
        self._open = False

    def open(self) -> bool:
        """Nothing to open; always True."""
        self._open = True
        self._omega_r = self._omega_l = 0.0
        return True

    def apply(self, omega_r_radps: float, omega_l_radps: float, now_s: float) -> bool:
        """Record the command (zero for both wheels if either is non-finite)."""
        if not (math.isfinite(omega_r_radps) and math.isfinite(omega_l_radps)):
            self._rejected += 1
            omega_r_radps = omega_l_radps = 0.0
        self._omega_r = float(omega_r_radps)
        self._omega_l = float(omega_l_radps)
        self._commands += 1
        if math.isfinite(now_s):
            self._last_ok_s = now_s
        return True

    def stop(self) -> bool:
        """Record zero speeds."""
        self._omega_r = self._omega_l = 0.0
        self._commands += 1
        return True

    def close(self) -> None:
        """Record zero speeds and mark closed."""
        self.stop()
        self._open = False

    def status(self) -> MotorStatus:
        """Always healthy; counts commands and rejected inputs."""
        return MotorStatus(
            backend=self.name,
            healthy=True,
            connected=self._open,
            omega_r_radps=self._omega_r,
            omega_l_radps=self._omega_l,
            commands=self._commands,
            acks=self._commands,
            errors=self._rejected,
            rejected_inputs=self._rejected,
            last_ok_s=self._last_ok_s,
        )
