"""The RoboClaw pty emulator now ships in the package (robot_agent/motors/emulator.py, the
``formation motor-emulator`` command); kept importable under its old test name."""

from robot_agent.motors.emulator import DriveRecord, RoboClawEmulator

__all__ = ["DriveRecord", "RoboClawEmulator"]
