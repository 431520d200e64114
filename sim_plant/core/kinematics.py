"""The plant's vectorised kinematics: angle wrapping (``wrap_angle``, ``wrap_angles``), the
exact unicycle step (``unicycle_integrate``), the ``PoseRows`` type the plant hands out and the
``GeometryLike`` protocol it needs of a robot.

Split out of plant.py (issue 12) so the ``Plant`` class reads as state, faults and stepping;
every name here is still importable from ``sim_plant.core.plant``.
"""

from __future__ import annotations

import math
from typing import Protocol

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]
_TWO_PI = 2.0 * math.pi


PoseRow = tuple[float, float, float]


class PoseRows(tuple[PoseRow, ...]):
    """Poses as the plant hands them out: an immutable tuple of ``(x_m, y_m, theta_rad)`` float
    triples, theta in (-pi, pi]. Only the plant builds these, so a consumer that sees this exact
    type (the camera) can skip re-validating it."""

    __slots__ = ()


_PI = math.pi


class GeometryLike(Protocol):
    """What the plant needs of a robot's geometry (``robot_agent.core.params.RobotGeometry``)."""

    @property
    def wheel_radius_m(self) -> float:
        """Wheel radius R in metres."""
        ...

    @property
    def half_track_m(self) -> float:
        """Half the distance between the wheels, L in metres (track width is 2L)."""
        ...

    @property
    def max_wheel_radps(self) -> float:
        """Largest wheel speed magnitude the motors reach, rad/s."""
        ...


def wrap_angles(a: npt.ArrayLike) -> FloatArray:
    """Wrap angles (rad) elementwise to the half-open interval (-pi, pi]."""
    arr = np.asarray(a, dtype=np.float64)
    # np.mod lies in [0, 2 pi], so pi - mod lies in [-pi, pi]; mod rounds up to exactly 2 pi only
    # for a hair above pi (pi - a a tiny negative number), whose wrap is pi.
    r = np.mod(math.pi - arr, _TWO_PI)
    r = np.where(r >= _TWO_PI, 0.0, r)  # NaN stays NaN (as robot_agent.core.kinematics.wrap_angle)
    return np.asarray(math.pi - r, dtype=np.float64)


def wrap_angle(a: float) -> float:
    """Scalar :func:`wrap_angles`: ``a`` (rad) to (-pi, pi], the same bits for the same input.

    The plant keeps this pair (not ``robot_agent.core.kinematics.wrap_angle``, which uses
    ``math.remainder``) because its vectorised and scalar paths must agree bit for bit; both
    give NaN for a non-finite angle, as the firmware's does."""
    r = (_PI - a) % _TWO_PI  # float % is fmod adjusted to the divisor's sign, as np.mod
    if r >= _TWO_PI:
        r = 0.0
    return _PI - r


def unicycle_integrate(
    pose: FloatArray, v_mps: FloatArray, omega_radps: FloatArray, dt_s: FloatArray | float
) -> FloatArray:
    """Exact integration of the unicycle (paper eq. 9) for constant ``(v, omega)`` over ``dt_s``.

    ``pose`` is ``(n, 3)`` ``[x_m, y_m, theta_rad]``; ``v_mps``, ``omega_radps`` are ``(n,)``;
    ``dt_s`` is a scalar or ``(n,)`` (seconds, >= 0). Returns a new ``(n, 3)`` array.

    The displacement is the chord of the arc, ``v dt sin(omega dt / 2) / (omega dt / 2)``, along
    the mid-step heading ``theta + omega dt / 2``; at ``omega = 0`` this is the straight line
    ``v dt`` along ``theta`` (the ratio ``sin(h)/h`` is taken as its limit 1 at ``h = 0``).
    """
    theta = pose[:, 2]
    half_turn = omega_radps * (0.5 * dt_s)
    # sin(h) / h with the limit 1 at h == 0 (cheaper than np.sinc, same value).
    ratio = np.divide(
        np.sin(half_turn), half_turn, out=np.ones_like(half_turn), where=half_turn != 0.0
    )
    chord = v_mps * dt_s * ratio
    mid_heading = theta + half_turn
    out = np.empty_like(pose)
    out[:, 0] = pose[:, 0] + chord * np.cos(mid_heading)
    out[:, 1] = pose[:, 1] + chord * np.sin(mid_heading)
    out[:, 2] = wrap_angles(mid_heading + half_turn)
    return out
