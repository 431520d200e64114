"""The RoboClaw driver's configuration: ``RoboClawConfig`` (serial port, address, encoder and
gearing, limits, timeouts), validated on construction.

Split out of roboclaw.py (issue 12) so the settings a deployer edits can be read apart from the
driver; still importable from ``robot_agent.motors.roboclaw``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

BAUD_RATES = (2400, 9600, 19200, 38400, 57600, 115200, 230400, 460800)


def _require(cond: bool, message: str) -> None:
    if not cond:
        raise ValueError(message)


def _is_number(value: object) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


@dataclass(frozen=True, slots=True)
class RoboClawConfig:
    """How one robot's RoboClaw is wired and configured.

    Attributes:
        port: serial device (``/dev/roboclaw`` is the udev symlink of deploy/udev).
        baud: packet-serial baud rate (ignored by the USB port, which is still opened at it).
        address: packet-serial address 0x80..0x87.
        mode: "speed" (command 37, closed-loop on the encoders, needs the controller's
            velocity PID and QPPS set up in Motion Studio) or "duty" (command 34, open loop:
            duty = omega / max_wheel_radps).
        encoder_counts_per_rev: quadrature counts per *motor shaft* revolution (4 x the
            encoder's lines/pulses per revolution); required (> 0) in speed mode.
        gear_ratio: motor shaft revolutions per wheel revolution (> 0).
        invert_right: the right motor turns backwards for a positive command (wiring or
            mounting); the sign is flipped before sending.
        invert_left: same for the left motor.
        right_channel: "m1" or "m2", the controller channel of the right wheel (the left
            wheel is on the other one).
        serial_timeout_s: the controller's own watchdog (command 14), 0.1..25.5 s in 0.1 s
            steps: motors stop when the agent has sent nothing for this long.
        ack_timeout_s: how long to wait for the 0xFF acknowledgement of a command (s).
        write_timeout_s: how long a write may block before the port is considered lost (s).
        reopen_backoff_s: first delay before re-opening a lost port (s); doubles per failure.
        reopen_backoff_max_s: cap of that delay (s).
        max_consecutive_failures: this many unacknowledged commands in a row and the port is
            closed and re-opened (which re-reads the firmware and re-arms command 14, needed
            after a controller brown-out reset its settings).
    """

    port: str
    baud: int = field(default=38400, metadata={"range": (2400, 460800)})
    address: int = field(default=0x80, metadata={"range": (0x80, 0x87)})
    mode: str = "speed"
    encoder_counts_per_rev: float = field(default=0.0, metadata={"range": (0.0, 1.0e6)})
    gear_ratio: float = field(default=1.0, metadata={"range": (0.01, 10000.0)})
    invert_right: bool = False
    invert_left: bool = False
    right_channel: str = "m1"
    serial_timeout_s: float = field(default=0.5, metadata={"range": (0.1, 5.0)})
    ack_timeout_s: float = field(default=0.02, metadata={"range": (0.001, 1.0)})
    write_timeout_s: float = field(default=0.1, metadata={"range": (0.001, 5.0)})
    reopen_backoff_s: float = field(default=0.5, metadata={"range": (0.01, 60.0)})
    reopen_backoff_max_s: float = field(default=5.0, metadata={"range": (0.01, 600.0)})
    max_consecutive_failures: int = field(default=5, metadata={"range": (1, 1000)})

    def __post_init__(self) -> None:
        _require(
            isinstance(self.port, str) and self.port.strip() != "",
            f"port must be a non-empty device path, got {self.port!r}",
        )
        _require(
            isinstance(self.baud, int) and self.baud in BAUD_RATES,
            f"baud must be one of {BAUD_RATES}, got {self.baud!r}",
        )
        _require(
            isinstance(self.address, int)
            and not isinstance(self.address, bool)
            and 0x80 <= self.address <= 0x87,
            f"address must be an integer 0x80..0x87 (128..135), got {self.address!r}",
        )
        _require(
            self.mode in ("speed", "duty"), f"mode must be 'speed' or 'duty', got {self.mode!r}"
        )
        _require(
            _is_number(self.encoder_counts_per_rev)
            and math.isfinite(self.encoder_counts_per_rev)
            and self.encoder_counts_per_rev >= 0.0,
            f"encoder_counts_per_rev must be a finite number >= 0, "
            f"got {self.encoder_counts_per_rev!r}",
        )
        _require(
            self.mode != "speed" or self.encoder_counts_per_rev > 0.0,
            "encoder_counts_per_rev must be > 0 in speed mode "
            "(quadrature counts per motor revolution)",
        )
        _require(
            _is_number(self.gear_ratio) and math.isfinite(self.gear_ratio) and self.gear_ratio > 0,
            f"gear_ratio must be a finite number > 0, got {self.gear_ratio!r}",
        )
        for name in ("invert_right", "invert_left"):
            value = getattr(self, name)
            _require(isinstance(value, bool), f"{name} must be true or false, got {value!r}")
        _require(
            self.right_channel in ("m1", "m2"),
            f"right_channel must be 'm1' or 'm2', got {self.right_channel!r}",
        )
        _require(
            _is_number(self.serial_timeout_s) and 0.1 <= self.serial_timeout_s <= 25.5,
            f"serial_timeout_s must be within 0.1..25.5 s, got {self.serial_timeout_s!r}",
        )
        for name, low, high in (
            ("ack_timeout_s", 0.001, 1.0),
            ("write_timeout_s", 0.001, 5.0),
            ("reopen_backoff_s", 0.01, 60.0),
            ("reopen_backoff_max_s", 0.01, 600.0),
        ):
            value = getattr(self, name)
            _require(
                _is_number(value) and low <= value <= high,
                f"{name} must be within {low}..{high} s, got {value!r}",
            )
        _require(
            self.reopen_backoff_max_s >= self.reopen_backoff_s,
            "reopen_backoff_max_s must be >= reopen_backoff_s",
        )
        _require(
            isinstance(self.max_consecutive_failures, int)
            and not isinstance(self.max_consecutive_failures, bool)
            and 1 <= self.max_consecutive_failures <= 1000,
            f"max_consecutive_failures must be an integer 1..1000, "
            f"got {self.max_consecutive_failures!r}",
        )

    @property
    def serial_timeout_tenths(self) -> int:
        """The command-14 value: ``serial_timeout_s`` in 100 ms units, 1..255."""
        return max(1, min(255, round(self.serial_timeout_s * 10.0)))

    @property
    def qpps_per_radps(self) -> float:
        """Encoder counts per second at the motor for one rad/s at the wheel."""
        return self.encoder_counts_per_rev * self.gear_ratio / (2.0 * math.pi)
