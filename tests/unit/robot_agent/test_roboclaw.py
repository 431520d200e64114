"""RoboClaw packet-serial backend against the pty emulator (tests/support/roboclaw_emulator.py)."""

from __future__ import annotations

import math
import os
import struct
import time
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path

import pytest
import serial
from support.roboclaw_emulator import RoboClawEmulator

from robot_agent.core.params import RobotGeometry
from robot_agent.motors import BackendContext, BusMotorBackend, MotorBackend, create_backend
from robot_agent.motors.roboclaw import RoboClawBackend
from robot_agent.motors.roboclaw_config import RoboClawConfig
from robot_agent.motors.roboclaw_protocol import (
    crc16,
    duty_packet,
    serial_timeout_packet,
    speed_packet,
    write_packet,
)

MAX_WHEEL_RADPS = 10.0
# 12-line encoder (48 quadrature counts per motor revolution) behind a 10:1 gearbox:
# 480 counts per wheel revolution, 480 / (2 pi) = 76.39 QPPS per rad/s.
COUNTS = 48.0
GEAR = 10.0
K_QPPS = COUNTS * GEAR / (2.0 * math.pi)


@pytest.fixture
def emulator() -> Iterator[RoboClawEmulator]:
    with RoboClawEmulator() as emu:
        yield emu


def make_config(port_path: str, **overrides: object) -> RoboClawConfig:
    base = RoboClawConfig(
        port=port_path,
        encoder_counts_per_rev=COUNTS,
        gear_ratio=GEAR,
        serial_timeout_s=0.3,
        # generous: an ack returns at once; only the fault tests wait it out. The emulator is a
        # thread of this process: next to a CPU hog on two busy pytest workers its reply came
        # later than 0.2 s and open() failed (a missed ack is the property some tests check,
        # not a bound on the controller: the real RoboClaw answers within a millisecond)
        ack_timeout_s=1.0,
        reopen_backoff_s=0.1,
        reopen_backoff_max_s=0.4,
    )
    return replace(base, **overrides)  # type: ignore[arg-type]


@pytest.fixture
def backend(emulator: RoboClawEmulator) -> Iterator[RoboClawBackend]:
    b = RoboClawBackend(make_config(emulator.port), MAX_WHEEL_RADPS)
    try:
        yield b
    finally:
        b.close()


# ---------------------------------------------------------------------- wire format


def test_crc16_is_ccitt_xmodem() -> None:
    assert crc16(b"123456789") == 0x31C3  # the CRC-16/XMODEM check value
    assert crc16(b"") == 0
    # continuing a CRC over two parts equals one pass over the whole
    assert crc16(b"6789", crc16(b"12345")) == 0x31C3


def test_packet_layouts() -> None:
    pkt = speed_packet(0x80, 1000, -1000)
    assert pkt[:2] == bytes((0x80, 37))
    assert struct.unpack(">ii", pkt[2:10]) == (1000, -1000)
    assert int.from_bytes(pkt[10:], "big") == crc16(pkt[:10])
    assert len(pkt) == 12
    dpkt = duty_packet(0x81, -32767, 16384)
    assert dpkt[:2] == bytes((0x81, 34)) and len(dpkt) == 8
    assert struct.unpack(">hh", dpkt[2:6]) == (-32767, 16384)
    assert serial_timeout_packet(0x80, 5)[:3] == bytes((0x80, 14, 5))
    assert write_packet(0x80, 14, b"\x05") == serial_timeout_packet(0x80, 5)


def test_emulator_rejects_bad_crc_and_acks_good_one(emulator: RoboClawEmulator) -> None:
    good = speed_packet(0x80, 500, -500)
    bad = good[:-1] + bytes((good[-1] ^ 0x55,))
    with serial.Serial(emulator.port, 38400, timeout=0.2) as port:
        port.write(bad)
        assert port.read(1) == b""  # no answer to a corrupted packet
        assert emulator.wait_for(lambda: emulator.crc_errors == 1)
        assert emulator.speeds() == (0, 0)
        port.timeout = 2.0
        port.write(good)
        assert port.read(1) == b"\xff"
        assert emulator.speeds() == (500, -500)


def test_emulator_joins_a_packet_split_by_a_short_gap_and_drops_one_cut_by_silence(
    emulator: RoboClawEmulator,
) -> None:
    """A packet in two writes 10 ms apart is one packet, and so is one whose second half waited
    150 ms for a starved emulator to look (the bytes were waiting: no silence on the line);
    half a packet followed by silence well over INTER_BYTE_TIMEOUT_S is dropped, and the next
    whole packet is acked."""
    good = speed_packet(0x80, 300, -300)
    with serial.Serial(emulator.port, 38400, timeout=2.0) as port:
        port.write(good[:3])
        time.sleep(0.01)
        port.write(good[3:])
        assert port.read(1) == b"\xff"
        assert emulator.speeds() == (300, -300)
        # a starved emulator: its thread reads the first half, then cannot run for 150 ms (it
        # waits for its lock, held here) while the second half has long been waiting
        with emulator._lock:
            port.write(good[:3])
            time.sleep(0.05)
            port.write(good[3:])
            time.sleep(0.15)
        assert port.read(1) == b"\xff"
        assert emulator.packets_ok == 2 and emulator.crc_errors == 0
        port.write(speed_packet(0x80, 100, 100)[:4])  # cut: never finished
        time.sleep(0.3)
        port.write(good)
        assert port.read(1) == b"\xff"
        assert emulator.speeds() == (300, -300) and emulator.crc_errors == 0
        assert emulator.packets_ok == 3


# ---------------------------------------------------------------------- open


def test_open_reads_firmware_arms_timeout_and_stops(
    emulator: RoboClawEmulator, backend: RoboClawBackend
) -> None:
    assert backend.open() is True
    st = backend.status()
    assert st.connected and st.healthy
    assert st.firmware == "USB Roboclaw 2x7a v4.2.8"
    assert emulator.serial_timeout_tenths == 3  # 0.3 s in 100 ms units, armed at open
    assert emulator.drives[-1].m1 == 0 and emulator.drives[-1].m2 == 0
    assert isinstance(backend, MotorBackend)


def test_open_missing_port_reports_and_does_not_raise(tmp_path: Path) -> None:
    b = RoboClawBackend(make_config(str(tmp_path / "no-such-tty")), MAX_WHEEL_RADPS)
    assert b.open() is False
    st = b.status()
    assert not st.connected and not st.healthy
    assert st.open_failures == 1
    assert st.last_error is not None and "no-such-tty" in st.last_error
    assert b.apply(1.0, 1.0, now_s=0.0) is False  # no raise while the port is missing
    b.close()


def test_open_rejects_firmware_reply_with_bad_crc(emulator: RoboClawEmulator) -> None:
    emulator.corrupt_next_reply(1)
    b = RoboClawBackend(make_config(emulator.port), MAX_WHEEL_RADPS)
    assert b.open() is False
    st = b.status()
    assert st.crc_errors == 1 and not st.connected
    assert st.last_error is not None and "command 21" in st.last_error
    assert b.open() is True, b.status()  # the next reply is clean
    b.close()


# ---------------------------------------------------------------------- speeds and signs


@pytest.mark.parametrize(
    ("overrides", "expected_m1_m2"),
    [
        ({}, (round(2.0 * K_QPPS), round(-1.0 * K_QPPS))),
        ({"invert_left": True}, (round(2.0 * K_QPPS), round(1.0 * K_QPPS))),
        ({"invert_right": True}, (round(-2.0 * K_QPPS), round(-1.0 * K_QPPS))),
        ({"right_channel": "m2"}, (round(-1.0 * K_QPPS), round(2.0 * K_QPPS))),
        (
            {"right_channel": "m2", "invert_right": True, "invert_left": True},
            (round(1.0 * K_QPPS), round(-2.0 * K_QPPS)),
        ),
    ],
)
def test_speeds_and_signs_reach_the_controller(
    emulator: RoboClawEmulator, overrides: dict[str, object], expected_m1_m2: tuple[int, int]
) -> None:
    b = RoboClawBackend(make_config(emulator.port, **overrides), MAX_WHEEL_RADPS)
    assert b.open(), b.status().last_error
    assert b.apply(2.0, -1.0, now_s=1.0) is True
    assert emulator.speeds() == expected_m1_m2
    assert emulator.drives[-1].command == 37
    st = b.status()
    assert (st.omega_r_radps, st.omega_l_radps) == (2.0, -1.0)  # robot convention
    assert st.last_ok_s == 1.0
    b.close()


def test_qpps_conversion_value(emulator: RoboClawEmulator, backend: RoboClawBackend) -> None:
    assert backend.open()
    backend.apply(2.0 * math.pi, 0.0, now_s=0.0)  # one wheel revolution per second
    assert emulator.speeds() == (480, 0)


def test_duty_mode(emulator: RoboClawEmulator) -> None:
    b = RoboClawBackend(make_config(emulator.port, mode="duty"), MAX_WHEEL_RADPS)
    assert b.open()
    assert b.apply(10.0, -2.5, now_s=0.0)
    assert emulator.drives[-1].command == 34
    assert emulator.speeds() == (32767, round(-0.25 * 32767))
    b.close()


def test_clamp_keeps_the_turn(emulator: RoboClawEmulator, backend: RoboClawBackend) -> None:
    assert backend.open()
    assert backend.apply(20.0, 10.0, now_s=0.0)
    st = backend.status()
    assert st.clamped == 1
    assert (st.omega_r_radps, st.omega_l_radps) == (10.0, 5.0)
    assert emulator.speeds() == (round(10.0 * K_QPPS), round(5.0 * K_QPPS))


def test_non_finite_input_sends_zero(emulator: RoboClawEmulator, backend: RoboClawBackend) -> None:
    assert backend.open()
    backend.apply(3.0, 3.0, now_s=0.0)
    assert backend.apply(math.nan, 1.0, now_s=0.1) is True
    assert emulator.speeds() == (0, 0)
    assert backend.status().rejected_inputs == 1
    backend.apply(1.0, math.inf, now_s=0.2)
    assert emulator.speeds() == (0, 0)
    assert backend.status().rejected_inputs == 2


def test_stop_sends_zeros(emulator: RoboClawEmulator, backend: RoboClawBackend) -> None:
    assert backend.open()
    backend.apply(4.0, -4.0, now_s=0.0)
    assert emulator.speeds() != (0, 0)
    assert backend.stop() is True
    assert emulator.speeds() == (0, 0)
    assert (emulator.drives[-1].m1, emulator.drives[-1].m2) == (0, 0)
    st = backend.status()
    assert (st.omega_r_radps, st.omega_l_radps) == (0.0, 0.0)


# ---------------------------------------------------------------------- faults


def test_corrupted_packet_is_rejected_and_counted(emulator: RoboClawEmulator) -> None:
    # the missed ack is waited out within the controller's 0.3 s serial timeout, so the wheels
    # still hold the last good command when the check below reads them
    backend = RoboClawBackend(make_config(emulator.port, ack_timeout_s=0.2), MAX_WHEEL_RADPS)
    try:
        assert backend.open(), backend.status().last_error
        backend.apply(1.0, 1.0, now_s=0.0)
        before = emulator.speeds()
        emulator.corrupt_next_rx(1)  # line noise flips a bit of the next packet
        assert backend.apply(5.0, 5.0, now_s=0.05) is False
        assert emulator.wait_for(lambda: emulator.crc_errors == 1)
        assert emulator.speeds() == before  # the controller ignored the corrupted packet
        st = backend.status()
        assert st.no_ack == 1 and st.consecutive_failures == 1 and not st.healthy
        assert st.connected  # one missed ack is not a lost link
        assert (st.omega_r_radps, st.omega_l_radps) == (1.0, 1.0)  # what the wheels really got
        assert backend.apply(5.0, 5.0, now_s=0.1) is True
        assert backend.status().healthy
        assert emulator.speeds() == (round(5.0 * K_QPPS), round(5.0 * K_QPPS))
    finally:
        backend.close()


def test_controller_timeout_stops_motors_when_agent_goes_quiet(
    emulator: RoboClawEmulator, backend: RoboClawBackend
) -> None:
    assert backend.open()  # arms a 0.3 s serial timeout
    # last_sent is read before the packet is written: the controller's timer starts when the
    # packet arrives, which is after that instant (read after the ack, it could be up to the
    # ack's latency too late, and the stop seemed to come before 0.3 s on a loaded machine)
    t0 = last_sent = time.monotonic()
    while last_sent - t0 < 0.5:  # agent alive at 50 Hz for 0.5 s: motors keep running
        time.sleep(0.02)
        last_sent = time.monotonic()
        assert backend.apply(3.0, 3.0, now_s=last_sent)
    assert emulator.timeout_stops == 0
    assert emulator.speeds() != (0, 0)
    # the agent stops sending (crash, hang, cut cable): the controller stops on its own
    assert emulator.wait_for(lambda: emulator.speeds() == (0, 0), timeout_s=2.0)
    stopped_after = time.monotonic() - last_sent
    assert emulator.timeout_stops == 1
    assert 0.3 <= stopped_after <= 1.0  # the 0.3 s armed at open, plus scheduling slack


def test_disconnected_port_is_reported_not_raised(
    emulator: RoboClawEmulator, backend: RoboClawBackend
) -> None:
    assert backend.open()
    assert backend.apply(1.0, 1.0, now_s=0.0)
    emulator.disconnect()  # the USB cable is pulled
    assert backend.apply(1.0, 1.0, now_s=0.02) is False
    st = backend.status()
    assert not st.connected and not st.healthy
    assert st.io_errors == 1
    assert st.last_error is not None and "I/O error" in st.last_error
    assert backend.stop() is False  # nothing to send to; no raise
    # reopen attempts follow the backoff (0.1 s, doubling, capped at 0.4 s) on now_s
    for i in range(100):
        assert backend.apply(1.0, 1.0, now_s=0.02 + 0.01 * (i + 1)) is False
    st = backend.status()
    # attempts at about t = 0.12, 0.32, 0.72 (+0.1, +0.2, +0.4): three, not one per tick
    assert st.open_failures == 3
    assert st.errors >= st.io_errors + st.open_failures
    backend.close()


def test_reconnects_when_the_device_comes_back(tmp_path: Path) -> None:
    link = tmp_path / "roboclaw"  # what udev's /dev/roboclaw symlink does
    first = RoboClawEmulator()
    os.symlink(first.port, link)
    b = RoboClawBackend(make_config(str(link)), MAX_WHEEL_RADPS)
    try:
        assert b.open()
        assert b.apply(2.0, 2.0, now_s=0.0)
        first.disconnect()
        assert b.apply(2.0, 2.0, now_s=0.01) is False
        with RoboClawEmulator() as second:  # replugged: a new tty, the symlink follows
            link.unlink()
            os.symlink(second.port, link)
            assert b.apply(2.0, 2.0, now_s=0.05) is False  # still backing off
            assert b.apply(2.0, 2.0, now_s=0.2) is True
            st = b.status()
            assert st.connected and st.healthy and st.reconnects == 1
            assert second.serial_timeout_tenths == 3  # re-armed on the new link
            assert second.speeds() == (round(2.0 * K_QPPS), round(2.0 * K_QPPS))
            b.close()
    finally:
        b.close()
        first.close()


def test_silent_controller_is_reopened(emulator: RoboClawEmulator) -> None:
    b = RoboClawBackend(
        # each silent packet waits out the ack timeout; the reopen's three exchanges need their
        # acks within it too, from the emulator's thread on a loaded machine (0.1 s was missed
        # next to a CPU hog)
        make_config(emulator.port, max_consecutive_failures=3, ack_timeout_s=0.5),
        MAX_WHEEL_RADPS,
    )
    assert b.open(), b.status().last_error
    emulator.silent = True  # e.g. the controller browned out
    for i in range(3):
        assert b.apply(1.0, 1.0, now_s=0.01 * i) is False
    st = b.status()
    assert st.no_ack == 3 and not st.connected  # closed after 3 missed acks in a row
    emulator.silent = False
    assert b.apply(1.0, 1.0, now_s=0.05) is False  # backoff not elapsed
    assert b.apply(1.0, 1.0, now_s=0.2) is True
    assert b.status().reconnects == 1
    b.close()


def test_close_is_idempotent_and_stops(emulator: RoboClawEmulator) -> None:
    b = RoboClawBackend(make_config(emulator.port), MAX_WHEEL_RADPS)
    assert b.open()
    b.apply(2.0, 2.0, now_s=0.0)
    b.close()
    assert emulator.speeds() == (0, 0)
    b.close()
    assert not b.status().connected


# ---------------------------------------------------------------------- config and factory


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        ({"address": 0x7F}, "address"),
        ({"address": 0x88}, "address"),
        ({"baud": 12345}, "baud"),
        ({"encoder_counts_per_rev": 0.0}, "encoder_counts_per_rev"),
        ({"gear_ratio": -1.0}, "gear_ratio"),
        ({"serial_timeout_s": 0.0}, "serial_timeout_s"),
        ({"serial_timeout_s": 30.0}, "serial_timeout_s"),
        ({"right_channel": "m3"}, "right_channel"),
        ({"mode": "position"}, "mode"),
        ({"invert_left": 1}, "invert_left"),
        ({"port": ""}, "port"),
    ],
)
def test_config_validation(overrides: dict[str, object], message: str) -> None:
    with pytest.raises(ValueError, match=message):
        make_config("/dev/roboclaw", **overrides)


def test_duty_mode_needs_no_encoder() -> None:
    cfg = RoboClawConfig(port="/dev/roboclaw", mode="duty")
    assert cfg.serial_timeout_tenths == 5


def test_bus_backend_and_factory() -> None:
    bus = BusMotorBackend()
    assert isinstance(bus, MotorBackend)
    assert bus.open()
    assert bus.apply(1.0, -1.0, now_s=2.0)
    assert bus.apply(math.nan, 0.0, now_s=2.1)
    st = bus.status()
    assert st.healthy and st.rejected_inputs == 1 and st.commands == 2
    assert (st.omega_r_radps, st.omega_l_radps) == (0.0, 0.0)
    bus.close()

    context = BackendContext(RobotGeometry(max_wheel_radps=10.0))
    assert isinstance(create_backend("bus", None, context), BusMotorBackend)
    rc = create_backend("roboclaw", RoboClawConfig(port="/dev/x", mode="duty"), context)
    assert isinstance(rc, RoboClawBackend)
    with pytest.raises(ValueError, match="unknown motor backend"):
        create_backend("can", None, context)
    with pytest.raises(ValueError, match="needs settings"):
        create_backend("roboclaw", None, context)
