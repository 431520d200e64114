"""The RoboClaw packet serial protocol: the CRC16 it uses and the packets this driver sends
(drive speeds, duty, serial timeout), as pure functions of their arguments.

Split out of roboclaw.py (issue 12) so the wire format can be read apart from the serial I/O
and its state; every name here is still importable from ``robot_agent.motors.roboclaw``.
"""

from __future__ import annotations

import struct

CMD_SET_SERIAL_TIMEOUT = 14
CMD_DRIVE_DUTY_M1M2 = 34
CMD_DRIVE_SPEED_M1M2 = 37


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
