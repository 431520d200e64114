"""RoboClaw encoder speeds (commands 18 / 19) for the firmware's estimator, on the pty emulator."""

from __future__ import annotations

import math
from collections.abc import Iterator

import pytest
from support.roboclaw_emulator import RoboClawEmulator

from robot_agent.motors.roboclaw import RoboClawBackend
from robot_agent.motors.roboclaw_config import RoboClawConfig

COUNTS = 1200.0
GEAR = 1.0


@pytest.fixture
def emulator() -> Iterator[RoboClawEmulator]:
    with RoboClawEmulator() as emu:
        yield emu


def _backend(port: str, **kw: object) -> RoboClawBackend:
    cfg = RoboClawConfig(
        port=port, encoder_counts_per_rev=COUNTS, gear_ratio=GEAR, ack_timeout_s=0.2,
        **kw,  # type: ignore[arg-type]
    )  # fmt: skip
    return RoboClawBackend(cfg, max_wheel_radps=10.0)


def test_encoder_speeds_read_back_in_wheel_units(emulator: RoboClawEmulator) -> None:
    with _backend(emulator.port) as be:
        assert be.apply(3.0, -2.0, 0.0)
        got = be.read_wheel_speeds()
        assert got is not None
        step = 2.0 * math.pi / COUNTS  # one count per second in rad/s
        assert got[0] == pytest.approx(3.0, abs=step)
        assert got[1] == pytest.approx(-2.0, abs=step)


def test_channel_mapping_and_inversion_are_undone(emulator: RoboClawEmulator) -> None:
    with _backend(emulator.port, right_channel="m2", invert_left=True) as be:
        k = COUNTS * GEAR / (2.0 * math.pi)
        emulator.encoder_qpps = (round(-1.5 * k), round(4.0 * k))  # m1 = -left, m2 = right
        got = be.read_wheel_speeds()
        assert got is not None
        assert got == pytest.approx((4.0, 1.5), abs=1e-2)


def test_corrupt_reply_is_rejected_and_counted(emulator: RoboClawEmulator) -> None:
    with _backend(emulator.port) as be:
        emulator.corrupt_next_reply(1)
        assert be.read_wheel_speeds() is None
        assert be.status().crc_errors == 1
        assert be.read_wheel_speeds() is not None


def test_duty_mode_has_no_encoder_speeds(emulator: RoboClawEmulator) -> None:
    with _backend(emulator.port, mode="duty") as be:
        assert be.read_wheel_speeds() is None
