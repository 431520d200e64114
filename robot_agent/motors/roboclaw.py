"""Basicmicro RoboClaw motor controller over packet serial (pyserial), as a MotorBackend.

Protocol subset used (RoboClaw Series User Manual, "Packet Serial" and "Advanced Packet
Serial"):

- Every packet starts with the controller's address (0x80..0x87, set with the MODE button;
  USB controllers answer on their configured address too) and a command byte.
- Write commands: ``[address, command, data..., CRC16 high, CRC16 low]``; the controller
  answers one byte ``0xFF`` when the CRC matched and the command was accepted, and nothing
  at all when it did not (so a missing ack is the only sign of a corrupted packet).
- CRC16 is CRC-16/CCITT with polynomial 0x1021, initial value 0, no reflection, no final
  XOR (a.k.a. CRC-16/XMODEM), over every byte of the packet before the CRC. For a read, the
  controller's CRC covers the address and command *sent* plus the data it returns.
- Multi-byte values are big-endian (most significant byte first).

Commands:

====  ===========================================  ======================================
 14   Set Serial Timeout                            ``[addr, 14, value, CRC]`` -> 0xFF;
                                                    value in 100 ms units (0..255 = 0..25.5
                                                    s): the controller stops both motors
                                                    when no packet arrives for that long.
 18   Read Encoder Speed M1                         ``[addr, 18]`` -> ``speed(4), status,
 19   Read Encoder Speed M2                         CRC``; speed in quadrature pulses per
                                                    second (signed 32 bits), status bit 0 =
                                                    direction (1 backwards); a magnitude
                                                    with the direction bit set is negated.
 21   Read Firmware Version                         ``[addr, 21]`` -> ``"text", 10, 0,
                                                    CRC`` (at most 48 bytes of text).
 34   Drive M1/M2 With Signed Duty Cycle            ``[addr, 34, duty1(2), duty2(2), CRC]``
                                                    -> 0xFF; duty -32768..+32767 = +-100 %.
 37   Drive M1/M2 With Signed Speed                 ``[addr, 37, qpps1(4), qpps2(4), CRC]``
                                                    -> 0xFF; signed quadrature pulses per
                                                    second, needs encoders and the
                                                    controller's velocity PID tuned.
====  ===========================================  ======================================

Safety layers: the agent's firmware drives zero wheels on stale data (layer 1); the
controller's own serial timeout (command 14, armed at every open) stops the motors when the
agent stops talking, whatever the reason: a crash, a hang, a cut cable (layer 2).

pyserial is imported when the port is opened, so this module (and its config dataclass)
imports with the standard library only. ``serial.SerialException`` derives from ``IOError``
(= ``OSError``); pyserial lets ``termios.error`` through from ``tcflush``/``tcsetattr`` on a
hung-up port (seen when the USB device vanishes), so ``_SERIAL_ERRORS`` catches both.
"""

from __future__ import annotations

import importlib
import math
import struct
import termios
import time
from dataclasses import dataclass
from typing import Any

from .base import MotorStatus

__all__ = [
    "ACK",
    "CMD_DRIVE_DUTY_M1M2",
    "CMD_DRIVE_SPEED_M1M2",
    "CMD_READ_FIRMWARE",
    "CMD_READ_SPEED_M1",
    "CMD_READ_SPEED_M2",
    "CMD_SET_SERIAL_TIMEOUT",
    "RoboClawBackend",
    "RoboClawConfig",
    "crc16",
    "duty_packet",
    "serial_timeout_packet",
    "speed_packet",
    "write_packet",
]

CMD_SET_SERIAL_TIMEOUT = 14
CMD_READ_SPEED_M1 = 18
CMD_READ_SPEED_M2 = 19
CMD_READ_FIRMWARE = 21
CMD_DRIVE_DUTY_M1M2 = 34
CMD_DRIVE_SPEED_M1M2 = 37
ACK = 0xFF

FIRMWARE_MAX_TEXT = 48
"""Longest firmware string (bytes, terminator included) the controller returns (cmd 21)."""
DUTY_MAX = 32767
INT32_MAX = 2**31 - 1
BAUD_RATES = (2400, 9600, 19200, 38400, 57600, 115200, 230400, 460800)
"""Packet-serial baud rates a RoboClaw can be set to (USB ports ignore the rate)."""
_STOP_ATTEMPTS = 3
_SERIAL_ERRORS = (OSError, termios.error)


def crc16(data: bytes, crc: int = 0) -> int:
    """CRC-16/CCITT (poly 0x1021, init 0, MSB first) of ``data``, as the RoboClaw computes it.

    ``crc`` continues a previous computation (e.g. over the sent header, then the reply).
    Check value: ``crc16(b"123456789") == 0x31C3``.
    """
    for byte in data:
        crc ^= byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) if crc & 0x8000 else (crc << 1)
            crc &= 0xFFFF
    return crc


def write_packet(address: int, command: int, payload: bytes = b"") -> bytes:
    """A complete write packet: address, command, payload and the big-endian CRC16."""
    body = bytes((address, command)) + payload
    return body + crc16(body).to_bytes(2, "big")


def speed_packet(address: int, m1_qpps: int, m2_qpps: int) -> bytes:
    """Command 37: drive M1 and M2 at signed speeds (quadrature pulses per second)."""
    return write_packet(address, CMD_DRIVE_SPEED_M1M2, struct.pack(">ii", m1_qpps, m2_qpps))


def duty_packet(address: int, m1_duty: int, m2_duty: int) -> bytes:
    """Command 34: drive M1 and M2 at signed duty cycles (-32768..32767 = -100..100 %)."""
    return write_packet(address, CMD_DRIVE_DUTY_M1M2, struct.pack(">hh", m1_duty, m2_duty))


def serial_timeout_packet(address: int, tenths_s: int) -> bytes:
    """Command 14: stop both motors after ``tenths_s`` x 100 ms without a packet (0 = off)."""
    return write_packet(address, CMD_SET_SERIAL_TIMEOUT, bytes((tenths_s,)))


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
    baud: int = 38400
    address: int = 0x80
    mode: str = "speed"
    encoder_counts_per_rev: float = 0.0
    gear_ratio: float = 1.0
    invert_right: bool = False
    invert_left: bool = False
    right_channel: str = "m1"
    serial_timeout_s: float = 0.5
    ack_timeout_s: float = 0.02
    write_timeout_s: float = 0.1
    reopen_backoff_s: float = 0.5
    reopen_backoff_max_s: float = 5.0
    max_consecutive_failures: int = 5

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


class RoboClawBackend:
    """Drives the two wheels through a RoboClaw; a :class:`~robot_agent.motors.MotorBackend`.

    ``max_wheel_radps`` (normally ``RobotGeometry.max_wheel_radps``) is the speed limit: a
    command above it is scaled down, both wheels by the same factor so the turn is kept, and
    counted. In duty mode it is also the speed that maps to 100 % duty.

    Every method runs on the caller's thread and blocks at most about ``write_timeout_s +
    ack_timeout_s`` per packet (``open()`` a little longer: it reads the firmware string).
    Not thread-safe: one control loop owns it.
    """

    name = "roboclaw"

    def __init__(self, config: RoboClawConfig, max_wheel_radps: float) -> None:
        _require(
            _is_number(max_wheel_radps) and math.isfinite(max_wheel_radps) and max_wheel_radps > 0,
            f"max_wheel_radps must be a finite number > 0, got {max_wheel_radps!r}",
        )
        self.config = config
        self.max_wheel_radps = float(max_wheel_radps)
        self._port: Any = None
        self._ever_connected = False
        self._next_reopen_s: float | None = None  # None: schedule from the next now_s seen
        self._backoff_s = config.reopen_backoff_s
        self._last_now_s: float | None = None
        self._omega_r = 0.0
        self._omega_l = 0.0
        self._firmware: str | None = None
        self._commands = 0
        self._acks = 0
        self._no_ack = 0
        self._io_errors = 0
        self._crc_errors = 0
        self._rejected = 0
        self._clamped = 0
        self._reconnects = 0
        self._open_failures = 0
        self._consecutive = 0
        self._last_error: str | None = None
        self._last_ok_s: float | None = None

    # ------------------------------------------------------------------ public API

    @property
    def connected(self) -> bool:
        """True while the serial port is open and the link was verified at open."""
        return self._port is not None

    def open(self) -> bool:
        """Open the port, read the firmware (21), arm the serial timeout (14), stop the wheels.

        Returns True when all three exchanges were acknowledged. On failure the port is left
        closed, the reason is in ``status().last_error`` and ``apply`` keeps retrying with
        backoff (the device may appear later, e.g. the USB controller is powered after the
        board). Never raises.
        """
        if self._port is not None:
            return True
        ok = self._open_device()
        if not ok:
            self._next_reopen_s = None
        return ok

    def apply(self, omega_r_radps: float, omega_l_radps: float, now_s: float) -> bool:
        """Command wheel speeds (rad/s, positive drives the robot forward).

        Non-finite input commands zero for both wheels (counted in ``rejected_inputs``).
        Speeds above ``max_wheel_radps`` are scaled down keeping their ratio (``clamped``).
        When the port is closed this tries to reopen it once the backoff has elapsed, and
        returns False otherwise. Returns True when the controller acknowledged the command.
        """
        if math.isfinite(now_s):
            self._last_now_s = now_s
        if not (math.isfinite(omega_r_radps) and math.isfinite(omega_l_radps)):
            self._rejected += 1
            self._last_error = "non-finite wheel speed commanded; sent zero"
            omega_r_radps = omega_l_radps = 0.0
        omega_r, omega_l = self._limit(float(omega_r_radps), float(omega_l_radps))

        if self._port is None and not self._maybe_reopen(now_s):
            return False
        ok = self._send_write(self._drive_packet(omega_r, omega_l), now_s)
        if ok:
            self._omega_r, self._omega_l = omega_r, omega_l
        return ok

    def stop(self) -> bool:
        """Command zero on both wheels now (up to three attempts); True when acknowledged.

        With the port closed nothing can be sent: returns False, and the controller's serial
        timeout stops the motors on its own.
        """
        if self._port is None:
            return False
        packet = self._drive_packet(0.0, 0.0)
        for _ in range(_STOP_ATTEMPTS):
            if self._send_write(packet, self._last_now_s):
                self._omega_r = self._omega_l = 0.0
                return True
            if self._port is None:  # the port was lost during the attempt
                break
        return False

    def read_wheel_speeds(self) -> tuple[float, float] | None:
        """Wheel speeds ``(omega_r, omega_l)`` (rad/s, positive = forward) the encoders
        measure (commands 18 and 19), for the firmware's estimator (``Firmware.step``'s
        ``wheel_speeds``). None in duty mode (no encoder scale), with the port closed, or when a
        reply is missing or fails its CRC (counted in ``no_ack`` / ``crc_errors``). Never
        raises. Optional: the shell calls it when the backend has it."""
        cfg = self.config
        if self._port is None or cfg.mode != "speed" or cfg.qpps_per_radps <= 0.0:
            return None
        m1 = self._read_speed(CMD_READ_SPEED_M1)
        if m1 is None:
            return None
        m2 = self._read_speed(CMD_READ_SPEED_M2)
        if m2 is None:
            return None
        k = cfg.qpps_per_radps
        right, left = (m1, m2) if cfg.right_channel == "m1" else (m2, m1)
        omega_r, omega_l = right / k, left / k
        if cfg.invert_right:
            omega_r = -omega_r
        if cfg.invert_left:
            omega_l = -omega_l
        return omega_r, omega_l

    def close(self) -> None:
        """Stop the wheels (best effort) and close the port. Idempotent, never raises."""
        if self._port is not None:
            self.stop()
        self._close_port()

    def status(self) -> MotorStatus:
        """Health and counters; ``healthy`` = port open and the last command acknowledged."""
        errors = self._no_ack + self._io_errors + self._crc_errors + self._rejected
        errors += self._open_failures
        return MotorStatus(
            backend=self.name,
            healthy=self._port is not None and self._consecutive == 0,
            connected=self._port is not None,
            omega_r_radps=self._omega_r,
            omega_l_radps=self._omega_l,
            commands=self._commands,
            acks=self._acks,
            errors=errors,
            no_ack=self._no_ack,
            io_errors=self._io_errors,
            crc_errors=self._crc_errors,
            rejected_inputs=self._rejected,
            clamped=self._clamped,
            reconnects=self._reconnects,
            open_failures=self._open_failures,
            consecutive_failures=self._consecutive,
            last_error=self._last_error,
            last_ok_s=self._last_ok_s,
            firmware=self._firmware,
        )

    def __enter__(self) -> RoboClawBackend:
        self.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------------ conversions

    def _limit(self, omega_r: float, omega_l: float) -> tuple[float, float]:
        """Scale both wheels by one factor so neither exceeds ``max_wheel_radps``."""
        peak = max(abs(omega_r), abs(omega_l))
        if peak > self.max_wheel_radps:
            scale = self.max_wheel_radps / peak
            self._clamped += 1
            return omega_r * scale, omega_l * scale
        return omega_r, omega_l

    def _to_channels(self, right: float, left: float) -> tuple[float, float]:
        """Apply the invert flags and the channel mapping: (m1, m2) in wheel units."""
        cfg = self.config
        if cfg.invert_right:
            right = -right
        if cfg.invert_left:
            left = -left
        return (right, left) if cfg.right_channel == "m1" else (left, right)

    def _drive_packet(self, omega_r: float, omega_l: float) -> bytes:
        m1, m2 = self._to_channels(omega_r, omega_l)
        cfg = self.config
        if cfg.mode == "speed":
            k = cfg.qpps_per_radps
            q1 = max(-INT32_MAX, min(INT32_MAX, round(m1 * k)))
            q2 = max(-INT32_MAX, min(INT32_MAX, round(m2 * k)))
            return speed_packet(cfg.address, q1, q2)
        k = DUTY_MAX / self.max_wheel_radps
        d1 = max(-DUTY_MAX, min(DUTY_MAX, round(m1 * k)))
        d2 = max(-DUTY_MAX, min(DUTY_MAX, round(m2 * k)))
        return duty_packet(cfg.address, d1, d2)

    # ------------------------------------------------------------------ link management

    def _fail(self, message: str) -> None:
        self._last_error = message
        self._consecutive += 1

    def _open_device(self) -> bool:
        cfg = self.config
        try:
            serial_mod = importlib.import_module("serial")
        except ImportError:
            self._open_failures += 1
            self._fail("pyserial is not installed (install the 'agent' extra)")
            return False
        try:
            self._port = serial_mod.Serial(
                port=cfg.port,
                baudrate=cfg.baud,
                timeout=cfg.ack_timeout_s,
                write_timeout=cfg.write_timeout_s,
                exclusive=True,  # flock: a second agent on the same port fails here
            )
        except (*_SERIAL_ERRORS, ValueError) as exc:
            self._port = None
            self._open_failures += 1
            self._fail(f"cannot open {cfg.port}: {exc}")
            return False

        firmware = self._read_firmware()
        if firmware is None:
            self._open_failures += 1
            reason = self._last_error or "no reply"
            self._close_port()
            self._last_error = (
                f"no valid firmware reply (command 21) from address 0x{cfg.address:02x} "
                f"on {cfg.port}: {reason}"
            )
            return False
        now_s = self._last_now_s
        if not self._send_write(
            serial_timeout_packet(cfg.address, cfg.serial_timeout_tenths), now_s
        ):
            self._open_failures += 1
            self._close_port()
            self._last_error = "controller did not acknowledge set serial timeout (command 14)"
            return False
        if not self._send_write(self._drive_packet(0.0, 0.0), now_s):
            self._open_failures += 1
            self._close_port()
            self._last_error = "controller did not acknowledge the initial stop"
            return False
        self._firmware = firmware
        self._omega_r = self._omega_l = 0.0
        if self._ever_connected:
            self._reconnects += 1
        self._ever_connected = True
        self._backoff_s = cfg.reopen_backoff_s
        self._next_reopen_s = None
        self._last_error = None
        return True

    def _maybe_reopen(self, now_s: float) -> bool:
        """Try to reopen the port if the backoff has elapsed; True when it is open again."""
        if not math.isfinite(now_s):
            return False
        if self._next_reopen_s is None:
            self._next_reopen_s = now_s + self._backoff_s
            return False
        if now_s < self._next_reopen_s:
            return False
        if self._open_device():
            return True
        self._backoff_s = min(self._backoff_s * 2.0, self.config.reopen_backoff_max_s)
        self._next_reopen_s = now_s + self._backoff_s
        return False

    def _lose_port(self, now_s: float | None) -> None:
        """Close the port after a fault and schedule the first reopen attempt."""
        self._close_port()
        self._next_reopen_s = None if now_s is None else now_s + self._backoff_s

    def _close_port(self) -> None:
        port, self._port = self._port, None
        if port is not None:
            try:
                port.close()
            except (*_SERIAL_ERRORS, ValueError):
                pass

    # ------------------------------------------------------------------ exchanges

    def _send_write(self, packet: bytes, now_s: float | None) -> bool:
        """Send one write packet and wait for the 0xFF acknowledgement."""
        port = self._port
        if port is None:
            return False
        self._commands += 1
        try:
            port.reset_input_buffer()  # a late ack of an earlier command must not count
            port.write(packet)
            reply = port.read(1)
        except _SERIAL_ERRORS as exc:  # SerialException, SerialTimeoutException, EIO, ...
            self._io_errors += 1
            self._fail(f"serial I/O error on {self.config.port}: {exc}")
            self._lose_port(now_s)
            return False
        if reply == bytes((ACK,)):
            self._acks += 1
            self._consecutive = 0
            if now_s is not None:
                self._last_ok_s = now_s
            return True
        self._no_ack += 1
        if reply:
            self._fail(f"unexpected reply 0x{reply[0]:02x} to command {packet[1]}")
        else:
            self._fail(
                f"no acknowledgement to command {packet[1]} within "
                f"{self.config.ack_timeout_s * 1000:.0f} ms"
            )
        if self._consecutive >= self.config.max_consecutive_failures:
            self._lose_port(now_s)
        return False

    def _read_speed(self, command: int) -> int | None:
        """Command 18 / 19: one channel's encoder speed (QPPS, signed), or None."""
        port = self._port
        header = bytes((self.config.address, command))
        try:
            port.reset_input_buffer()
            port.write(header)
            self._commands += 1
            reply = port.read(7)  # speed (4), status (1), CRC (2)
        except _SERIAL_ERRORS as exc:
            self._io_errors += 1
            self._fail(f"serial I/O error on {self.config.port}: {exc}")
            self._lose_port(self._last_now_s)
            return None
        if len(reply) < 7:
            self._no_ack += 1
            self._fail(f"incomplete reply to command {command} ({len(reply)} bytes)")
            return None
        if crc16(header + reply[:5]) != int.from_bytes(reply[5:7], "big"):
            self._crc_errors += 1
            self._fail(f"reply to command {command} failed its CRC check")
            return None
        (qpps,) = struct.unpack(">i", reply[:4])
        if reply[4] & 0x01 and qpps > 0:  # magnitude + direction bit
            qpps = -qpps
        self._acks += 1
        self._consecutive = 0
        return int(qpps)

    def _read_firmware(self) -> str | None:
        """Command 21: the controller's name and version, or None (reason in last_error)."""
        port = self._port
        address = self.config.address
        header = bytes((address, CMD_READ_FIRMWARE))
        deadline = time.monotonic() + max(0.2, 10.0 * self.config.ack_timeout_s)
        text = bytearray()
        try:
            port.reset_input_buffer()
            port.write(header)
            self._commands += 1
            while len(text) < FIRMWARE_MAX_TEXT + 2 and time.monotonic() < deadline:
                chunk = port.read(1)
                if chunk:
                    text += chunk
                    if text.endswith(b"\n\x00"):
                        break
            crc_bytes = b""
            while len(crc_bytes) < 2 and time.monotonic() < deadline:
                crc_bytes += port.read(2 - len(crc_bytes))
        except _SERIAL_ERRORS as exc:
            self._io_errors += 1
            self._fail(f"serial I/O error on {self.config.port}: {exc}")
            return None
        if not text.endswith(b"\n\x00") or len(crc_bytes) < 2:
            self._no_ack += 1
            self._fail(f"incomplete reply ({len(text)} bytes)")
            return None
        if crc16(header + bytes(text)) != int.from_bytes(crc_bytes, "big"):
            self._crc_errors += 1
            self._fail("firmware reply failed its CRC check")
            return None
        self._acks += 1
        self._consecutive = 0
        return text[:-2].decode("ascii", "replace").strip()
