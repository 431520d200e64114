"""An emulated RoboClaw on a pseudo-terminal: try the packet-serial backend without hardware.

``formation motor-emulator [--link PATH]`` runs one (see :func:`main`): it prints the pty's
path (and makes ``PATH`` a symlink to it), then a line whenever the commanded speeds change;
point a robot config's ``[motor] port`` at it and run ``formation agent --config ...``. The
tests use :class:`RoboClawEmulator` directly.

``RoboClawEmulator`` opens a pty pair (``os.openpty``); the backend opens the slave side by
its path (``emulator.port``) exactly as it would open ``/dev/ttyACM0``, and a thread plays
the controller on the master side:

- parses packets addressed to it, checks their CRC16 and answers ``0xFF`` (writes) or the
  data + CRC (reads); a packet with a bad CRC gets no answer and changes nothing;
- implements commands 14 (set serial timeout), 15 (read serial timeout), 18 / 19 (read encoder
  speed M1 / M2: the commanded QPPS in speed mode, an ideal velocity loop, or ``encoder_qpps``
  when set; signed 32 bits + a status byte whose bit 0 is the direction), 21 (read firmware
  version), 34 (M1/M2 duty) and 37 (M1/M2 speed), recording every drive command;
- implements the serial timeout: when no valid packet arrived for the configured time, both
  motors are stopped (``timeout_stops`` counts it);
- fault injection: ``silent`` (reads and ignores everything), ``corrupt_next_rx(n)`` (flips a
  bit in the next n packets received, as line noise would), ``corrupt_next_reply(n)`` (bad
  CRC on the next n read replies), ``disconnect()`` (closes the master: the port vanishes
  like an unplugged USB device).

A partial packet is discarded after ``INTER_BYTE_TIMEOUT_S`` of silence, like the real
controller resynchronises on a gap: silence seen by the emulator (that long, and as many
looks that found nothing to read as fit in it), not the time between two of its reads, which a
starved thread stretches.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import select
import signal
import struct
import sys
import threading
import time
import tty
from dataclasses import dataclass
from pathlib import Path

from robot_agent.motors.roboclaw_protocol import crc16

INTER_BYTE_TIMEOUT_S = 0.05
_LOOK_S = 0.005  # how long one look at the line waits for a byte (s)

# command -> number of data bytes of a write (CRC follows), or None for a read (no CRC sent)
_WRITE_LENGTHS = {14: 1, 34: 4, 37: 8}
_READS = {15, 18, 19, 21}


@dataclass(frozen=True, slots=True)
class DriveRecord:
    """One accepted drive command: monotonic time (s), command, M1 and M2 values."""

    t: float
    command: int
    m1: int
    m2: int


class RoboClawEmulator:
    """A RoboClaw answering on a pty; use as a context manager or call ``close()``."""

    def __init__(
        self,
        address: int = 0x80,
        firmware: str = "USB Roboclaw 2x7a v4.2.8",
    ) -> None:
        self.address = address
        self.firmware = firmware
        self._master_fd, self._slave_fd = os.openpty()
        tty.setraw(self._slave_fd)  # no echo, no line discipline, before anyone opens it
        self.port = os.ttyname(self._slave_fd)
        self._lock = threading.Lock()
        self._stop = threading.Event()
        # state (guarded by _lock)
        self.m1 = 0
        self.m2 = 0
        self.mode = "idle"  # "speed", "duty" or "idle" after a timeout stop
        self.serial_timeout_tenths = 0
        self.last_valid_s: float | None = None
        self.drives: list[DriveRecord] = []
        self.packets_ok = 0
        self.crc_errors = 0
        self.timeout_stops = 0
        self.silent = False
        self.encoder_qpps: tuple[int, int] | None = None  # measured speeds to report (18/19)
        self._corrupt_rx = 0
        self._corrupt_reply = 0
        self._thread = threading.Thread(target=self._run, name="roboclaw-emulator", daemon=True)
        self._thread.start()

    # ------------------------------------------------------------------ controls

    def corrupt_next_rx(self, n: int = 1) -> None:
        """Flip one bit in each of the next ``n`` packets received (before the CRC check)."""
        with self._lock:
            self._corrupt_rx += n

    def corrupt_next_reply(self, n: int = 1) -> None:
        """Send the next ``n`` read replies with a wrong CRC."""
        with self._lock:
            self._corrupt_reply += n

    def speeds(self) -> tuple[int, int]:
        """Current M1 and M2 command values (QPPS or duty)."""
        with self._lock:
            return self.m1, self.m2

    def wait_for(self, predicate: object, timeout_s: float = 1.0) -> bool:
        """Poll ``predicate()`` (a callable) until true or ``timeout_s``; returns its result."""
        assert callable(predicate)
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if predicate():
                return True
            time.sleep(0.002)
        return bool(predicate())

    def disconnect(self) -> None:
        """Close the master side: the slave port hangs up, as when the USB cable is pulled."""
        self._stop.set()
        self._thread.join(timeout=1.0)
        for fd in (self._master_fd, self._slave_fd):
            with contextlib.suppress(OSError):
                os.close(fd)
        self._master_fd = self._slave_fd = -1

    def close(self) -> None:
        """Stop the thread and release the pty (same as ``disconnect``)."""
        if self._master_fd >= 0:
            self.disconnect()

    def __enter__(self) -> RoboClawEmulator:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------------ controller

    def _run(self) -> None:
        buf = bytearray()
        last_byte_s = time.monotonic()
        quiet_looks = 0  # looks in a row that found nothing to read, since the last byte
        while not self._stop.is_set():
            try:
                ready, _, _ = select.select([self._master_fd], [], [], _LOOK_S)
            except (OSError, ValueError):
                return
            now = time.monotonic()
            if ready:
                try:
                    data = os.read(self._master_fd, 256)
                except OSError:  # EIO while no process has the slave open: keep waiting
                    data = b""
                    time.sleep(0.002)
                if data:
                    # (no gap test here: the bytes were waiting when this thread looked, so a
                    # late look, on a loaded machine, is no silence on the line)
                    buf += data
                    last_byte_s = now
                    quiet_looks = 0
                    with self._lock:
                        silent = self.silent
                    if silent:
                        buf.clear()
                    else:
                        self._parse(buf)
            elif buf:
                # silence: as long as the gap, and seen by as many empty looks as it takes
                # (a thread starved between two looks stretches the time, not the looks)
                quiet_looks += 1
                if now - last_byte_s > INTER_BYTE_TIMEOUT_S and quiet_looks * _LOOK_S >= (
                    INTER_BYTE_TIMEOUT_S
                ):
                    buf.clear()
            self._check_timeout(now)

    def _check_timeout(self, now: float) -> None:
        with self._lock:
            if (
                self.serial_timeout_tenths > 0
                and self.last_valid_s is not None
                and now - self.last_valid_s > self.serial_timeout_tenths / 10.0
                and (self.m1 != 0 or self.m2 != 0)
            ):
                self.m1 = self.m2 = 0
                self.mode = "idle"
                self.timeout_stops += 1

    def _parse(self, buf: bytearray) -> None:
        """Consume every complete packet at the start of ``buf``."""
        while buf:
            if buf[0] != self.address:
                del buf[0]  # not for us (or garbage): resynchronise on the next byte
                continue
            if len(buf) < 2:
                return
            command = buf[1]
            if command in _READS:
                header = bytes(buf[:2])
                del buf[:2]
                self._handle_read(header)
                continue
            length = _WRITE_LENGTHS.get(command)
            if length is None:
                del buf[:2]  # unknown command: ignored, no reply
                continue
            total = 2 + length + 2
            if len(buf) < total:
                return
            packet: bytearray = buf[:total]
            del buf[:total]
            with self._lock:
                if self._corrupt_rx > 0:
                    self._corrupt_rx -= 1
                    packet[2] ^= 0x01  # a flipped data bit, as line noise would do
            body, crc = bytes(packet[:-2]), int.from_bytes(packet[-2:], "big")
            if crc16(body) != crc:
                with self._lock:
                    self.crc_errors += 1
                continue  # the real controller stays silent on a bad CRC
            self._handle_write(command, body[2:])
            self._reply(bytes((0xFF,)))

    def _handle_write(self, command: int, data: bytes) -> None:
        now = time.monotonic()
        with self._lock:
            self.packets_ok += 1
            self.last_valid_s = now
            if command == 14:
                self.serial_timeout_tenths = data[0]
            elif command == 37:
                self.m1, self.m2 = struct.unpack(">ii", data)
                self.mode = "speed"
                self.drives.append(DriveRecord(now, command, self.m1, self.m2))
            elif command == 34:
                self.m1, self.m2 = struct.unpack(">hh", data)
                self.mode = "duty"
                self.drives.append(DriveRecord(now, command, self.m1, self.m2))

    def _handle_read(self, header: bytes) -> None:
        command = header[1]
        with self._lock:
            self.packets_ok += 1
            self.last_valid_s = time.monotonic()
            corrupt = self._corrupt_reply > 0
            if corrupt:
                self._corrupt_reply -= 1
            tenths = self.serial_timeout_tenths
            if self.encoder_qpps is not None:
                enc = self.encoder_qpps
            else:
                enc = (self.m1, self.m2) if self.mode == "speed" else (0, 0)
        # 21: firmware string + LF + NUL; 15: the serial timeout setting; 18/19 encoder speed
        if command in (18, 19):
            qpps = enc[0] if command == 18 else enc[1]
            data = struct.pack(">i", qpps) + bytes((1 if qpps < 0 else 0,))
        elif command == 21:
            data = self.firmware.encode("ascii") + b"\n\x00"
        else:
            data = bytes((tenths,))
        crc = crc16(header + data)
        if corrupt:
            crc ^= 0xFFFF
        self._reply(data + crc.to_bytes(2, "big"))

    def _reply(self, data: bytes) -> None:
        with contextlib.suppress(OSError):
            os.write(self._master_fd, data)


def main(argv: list[str] | None = None) -> int:
    """``formation motor-emulator``: run an emulated RoboClaw until SIGINT/SIGTERM."""
    parser = argparse.ArgumentParser(
        prog="formation motor-emulator",
        description="An emulated RoboClaw (packet serial) on a pseudo-terminal, to try the "
        "roboclaw motor backend without hardware.",
        epilog="examples:\n  formation motor-emulator --link /tmp/roboclaw  (then port = "
        '"/tmp/roboclaw" in the robot config\'s [motor] section)',
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument(
        "--link", metavar="PATH", help="also make PATH a symlink to the pty (removed at exit)"
    )
    parser.add_argument(
        "--address",
        type=lambda t: int(t, 0),
        default=0x80,
        help="packet-serial address 0x80..0x87 (default 0x80)",
    )
    ns = parser.parse_args(argv)
    if not 0x80 <= ns.address <= 0x87:
        parser.error(f"--address must be 0x80..0x87, got {ns.address:#x}")
    stop = threading.Event()

    def on_signal(signum: int, frame: object) -> None:
        stop.set()

    signal.signal(signal.SIGINT, on_signal)
    signal.signal(signal.SIGTERM, on_signal)
    link = Path(ns.link) if ns.link else None
    with RoboClawEmulator(address=ns.address) as emu:
        if link is not None:
            if link.is_symlink():
                link.unlink()
            elif link.exists():
                print(f"formation motor-emulator: {link} exists and is not a symlink",
                      file=sys.stderr)  # fmt: skip
                return 2
            link.symlink_to(emu.port)
        where = f"{emu.port}" + (f" (link {link})" if link is not None else "")
        print(f"roboclaw emulator at address {ns.address:#x} on {where}", flush=True)
        last: tuple[object, ...] = ()
        try:
            while not stop.wait(0.1):
                with emu._lock:
                    now = (emu.mode, emu.m1, emu.m2, emu.timeout_stops)
                if now != last:
                    mode, m1, m2, stops = now
                    print(f"mode {mode} m1 {m1} m2 {m2} timeout stops {stops}", flush=True)
                    last = now
        finally:
            if link is not None and link.is_symlink():
                link.unlink()
    print("roboclaw emulator stopped", flush=True)
    return 0
