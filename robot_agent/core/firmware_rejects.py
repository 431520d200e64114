"""The firmware's count of rejected inputs: how many, and the reason of the last one.

A rejected ``Pose`` / ``Setpoint`` object is counted once however many ticks the shell presents
it again (identity: the shell hands the same object until a new message arrives); non-finite
scalar arguments and neighbour entries count on every tick they appear; the shell adds the
messages it dropped while decoding (``Firmware.reject``). ``Firmware`` builds and owns one
``Rejections``; its status snapshot reports ``count`` and ``last_reason``.
"""

from __future__ import annotations

__all__ = ["Rejections"]


class Rejections:
    """Counter of rejected inputs (see the module docstring). ``count`` and ``last_reason`` are
    read by the owner; only the methods here change them."""

    __slots__ = ("_last_pose", "_last_setpoint", "count", "last_reason")

    def __init__(self) -> None:
        self.count = 0
        self.last_reason = ""
        self._last_pose: object = None  # (identity only: the shells' objects)
        self._last_setpoint: object = None

    def add(self, reason: str, n: int = 1) -> None:
        """Count ``n`` bad inputs for ``reason``."""
        self.count += n
        self.last_reason = reason

    def pose(self, pose: object, reason: str) -> None:
        """Count a rejected pose object, once however often it is presented."""
        if pose is not self._last_pose:
            self._last_pose = pose
            self.add(reason)

    def setpoint(self, setpoint: object, reason: str) -> None:
        """Count a rejected setpoint object, once however often it is presented."""
        if setpoint is not self._last_setpoint:
            self._last_setpoint = setpoint
            self.add(reason)
