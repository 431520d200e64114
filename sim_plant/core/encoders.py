"""Simulated wheel encoders: ``WheelEncoders`` turns the plant's true wheel angles into the mean
wheel speeds a RoboClaw would report from whole encoder counts (with a per-wheel slip).

Split out of plant.py (issue 12): the encoder model is its own concern; still importable from
``sim_plant.core.plant``.
"""

from __future__ import annotations

import math

import numpy as np

_TWO_PI = 2.0 * math.pi


def _check_finite_scalar(name: str, value: float) -> float:
    x = float(value)
    if not math.isfinite(x):
        raise ValueError(f"{name} must be finite, got {value!r}")
    return x


class WheelEncoders:
    """Quadrature encoders on every wheel, read once per control tick (emulation).

    ``read(angles)`` takes :meth:`Plant.wheel_angles` and returns, per robot, the mean wheel
    speeds ``(omega_r, omega_l)`` (rad/s) over the interval since the previous read, as a
    RoboClaw-style speed computed from count differences: angles are scaled by
    ``1 + slip`` (a per-wheel constant drawn once from N(0, ``slip_std``): the wheel slips or its
    radius differs, so the counts over- or under-state the ground motion) and quantised to whole
    counts (``counts_per_rev`` per wheel revolution; 0 = no quantisation). The first read
    returns None (no interval yet).
    """

    def __init__(
        self,
        n: int,
        counts_per_rev: float,
        slip_std: float = 0.0,
        rng: np.random.Generator | None = None,
    ) -> None:
        cpr = _check_finite_scalar("counts_per_rev", counts_per_rev)
        slip = _check_finite_scalar("slip_std", slip_std)
        if cpr < 0.0 or slip < 0.0:
            raise ValueError("counts_per_rev and slip_std must be >= 0")
        if slip > 0.0 and rng is None:
            raise ValueError("rng is required when slip_std > 0")
        self._per_rad = cpr / _TWO_PI
        self.slip: list[tuple[float, float]] = (
            [(float(a), float(b)) for a, b in rng.normal(0.0, slip, (n, 2)).tolist()]
            if slip > 0.0 and rng is not None
            else [(0.0, 0.0)] * n
        )
        self._last: list[tuple[float, float]] | None = None
        self._last_t = math.nan

    def _counts(self, angles: list[tuple[float, float]]) -> list[tuple[float, float]]:
        k = self._per_rad
        out = []
        for (ar, al), (sr, sl) in zip(angles, self.slip, strict=True):
            cr, cl = ar * (1.0 + sr), al * (1.0 + sl)
            if k > 0.0:
                cr, cl = math.floor(cr * k) / k, math.floor(cl * k) / k
            out.append((cr, cl))
        return out

    def read(
        self, t_s: float, angles: list[tuple[float, float]]
    ) -> list[tuple[float, float]] | None:
        """Mean wheel speeds per robot since the previous read at ``t_s`` (s), or None."""
        counts = self._counts(angles)
        last, last_t = self._last, self._last_t
        self._last, self._last_t = counts, t_s
        if last is None or not t_s > last_t:
            return None
        dt = t_s - last_t
        return [
            ((r - r0) / dt, (lft - l0) / dt)
            for (r, lft), (r0, l0) in zip(counts, last, strict=True)
        ]
