"""What a motor driver does to a wheel command before the motors see it (:class:`CommandGuard`).

A robot whose command holds NaN/inf gets ``(0, 0)`` (counted per robot); with ``wheel_limit``
each wheel is clamped independently to ``+-max_wheel_radps`` (a motor cannot exceed its speed;
the turn-preserving scaling is the firmware's job, not the motor's), and a robot with at least
one clamped wheel counts one clamp. Pure numpy.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from sim_plant.core.kinematics import FloatArray

__all__ = ["CommandGuard"]

BoolArray = npt.NDArray[np.bool_]
IntArray = npt.NDArray[np.int64]


class CommandGuard:
    """The wheel-command sanitiser and its counters, for ``n`` robots."""

    def __init__(self, n: int, max_wheel_radps: float, wheel_limit: bool) -> None:
        self.max_wheel_radps = max_wheel_radps
        self.wheel_limit = wheel_limit
        self._saturated: BoolArray = np.zeros(n, dtype=np.bool_)
        self._sat_any = False  # cache of self._saturated.any()
        self._clamp_counts: IntArray = np.zeros(n, dtype=np.int64)
        self._nonfinite_counts: IntArray = np.zeros(n, dtype=np.int64)

    @property
    def saturated(self) -> BoolArray:
        """Copy of the mask of robots whose last command had a clamped wheel, ``(n,)`` bool."""
        return self._saturated.copy()

    @property
    def clamp_counts(self) -> IntArray:
        """Per-robot counts of steps with a clamped wheel, ``(n,)``."""
        return self._clamp_counts.copy()

    @property
    def nonfinite_counts(self) -> IntArray:
        """Per-robot counts of commands that held NaN or inf, ``(n,)``."""
        return self._nonfinite_counts.copy()

    def sanitise(self, wheel_cmd: npt.ArrayLike, n: int) -> FloatArray:
        """A copy of ``wheel_cmd`` (``(n, 2)``) as the motors will see it; counts what it fixed."""
        cmd = np.array(wheel_cmd, dtype=np.float64, copy=True)
        if cmd.shape != (n, 2):
            raise ValueError(f"wheel_cmd must have shape ({n}, 2), got {cmd.shape}")
        finite = np.isfinite(cmd)
        if not finite.all():
            bad = ~finite.all(axis=1)
            cmd[bad] = 0.0
            self._nonfinite_counts += bad
        if self.wheel_limit:
            lim = self.max_wheel_radps
            over = np.abs(cmd) > lim
            if over.any():
                sat: BoolArray = np.asarray(over.any(axis=1), dtype=np.bool_)
                np.clip(cmd, -lim, lim, out=cmd)
                self._clamp_counts += sat
                self._saturated = sat
                self._sat_any = True
            elif self._sat_any:
                self.none_saturated(n)
        return cmd

    def none_saturated(self, n: int) -> None:
        """A command went through unchanged (the plant's small-fleet path checked it)."""
        if self._sat_any:
            self._saturated = np.zeros(n, dtype=np.bool_)
            self._sat_any = False

    def append(self) -> None:
        """A new robot (last row)."""
        self._saturated = np.append(self._saturated, False)
        self._clamp_counts = np.append(self._clamp_counts, np.int64(0))
        self._nonfinite_counts = np.append(self._nonfinite_counts, np.int64(0))

    def delete(self, i: int) -> None:
        """Robot ``i`` is gone; the rows after it move down one."""
        self._saturated = np.delete(self._saturated, i)
        self._clamp_counts = np.delete(self._clamp_counts, i)
        self._nonfinite_counts = np.delete(self._nonfinite_counts, i)
        self._sat_any = bool(self._saturated.any())
