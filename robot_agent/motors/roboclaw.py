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
from typing import Any

from robot_agent.motors.base import MotorStatus
from robot_agent.motors.roboclaw_config import (
    RoboClawConfig,
    _is_number,
    _require,
)
from robot_agent.motors.roboclaw_protocol import (
    crc16,
    duty_packet,
    serial_timeout_packet,
    speed_packet,
)

__all__ = ["ACK", "CMD_READ_FIRMWARE", "CMD_READ_SPEED_M1", "CMD_READ_SPEED_M2", "RoboClawBackend"]

CMD_READ_SPEED_M1 = 18
CMD_READ_SPEED_M2 = 19
CMD_READ_FIRMWARE = 21
ACK = 0xFF

FIRMWARE_MAX_TEXT = 48
"""Longest firmware string (bytes, terminator included) the controller returns (cmd 21)."""
DUTY_MAX = 32767
INT32_MAX = 2**31 - 1
"""Packet-serial baud rates a RoboClaw can be set to (USB ports ignore the rate)."""
_STOP_ATTEMPTS = 3
_SERIAL_ERRORS = (OSError, termios.error)


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
