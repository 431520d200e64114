"""Differential-drive kinematics and the reference point (paper eqs 7-16, corrected).

Symbols: R wheel radius (m), L half the track (m, track = 2L), l reference-point offset (m),
theta heading (rad), v forward speed (m/s), omega yaw rate (rad/s), omega_r / omega_l wheel
speeds (rad/s). The printed eqs 7-8 lose a factor of 2 and eq 13 is misprinted; the forms here
are the standard ones (see docs/paper-errata.md).

All functions are pure and allocation-light (they return tuples). The maps propagate NaN like
any arithmetic; ``saturate_wheels`` is the safety stage and never returns a non-finite value.
"""

from __future__ import annotations

import math
from math import cos as _cos  # (imported, not assigned: mypyc compiles these to C calls)
from math import sin as _sin
from typing import Final

from robot_agent.core.params import RobotGeometry

__all__ = [
    "axle_from_reference_point",
    "ref_point_velocity",
    "reference_point",
    "saturate_wheels",
    "twist_from_ref_velocity",
    "twist_from_wheels",
    "twist_from_wheels_raw",
    "wheels_from_twist",
    "wheels_from_twist_raw",
    "wrap_angle",
]

_PI: Final = math.pi
_TWO_PI: Final = 2.0 * math.pi
_isfinite: Final = math.isfinite


def wrap_angle(a: float) -> float:
    """Wrap an angle (rad) to (-pi, pi]. Non-finite input gives NaN (never raises)."""
    if not _isfinite(a):
        return math.nan
    w = math.remainder(a, _TWO_PI)  # in [-pi, pi]
    if w <= -_PI:
        w += _TWO_PI
    return w


def wheels_from_twist(v_mps: float, omega_radps: float, geom: RobotGeometry) -> tuple[float, float]:
    """Wheel speeds (omega_r, omega_l) in rad/s from a twist; eq 8 corrected.

    ``omega_r = (v + L omega) / R``, ``omega_l = (v - L omega) / R``.
    """
    return wheels_from_twist_raw(v_mps, omega_radps, geom.half_track_m, geom.wheel_radius_m)


def wheels_from_twist_raw(
    v_mps: float, omega_radps: float, half_track_m: float, wheel_radius_m: float
) -> tuple[float, float]:
    """:func:`wheels_from_twist` with the geometry read once (the firmware's per-tick call):
    eq 8 corrected, ``L = half_track_m``, ``R = wheel_radius_m``."""
    turn = half_track_m * omega_radps
    return (v_mps + turn) / wheel_radius_m, (v_mps - turn) / wheel_radius_m


def twist_from_wheels(omega_r: float, omega_l: float, geom: RobotGeometry) -> tuple[float, float]:
    """Twist (v in m/s, omega in rad/s) from wheel speeds (rad/s); eq 7 corrected.

    ``v = R (omega_r + omega_l) / 2``, ``omega = R (omega_r - omega_l) / (2 L)``.
    """
    return twist_from_wheels_raw(omega_r, omega_l, geom.half_track_m, geom.wheel_radius_m)


def twist_from_wheels_raw(
    omega_r: float, omega_l: float, half_track_m: float, wheel_radius_m: float
) -> tuple[float, float]:
    """:func:`twist_from_wheels` with the geometry read once (the firmware's per-tick call):
    eq 7 corrected, ``L = half_track_m``, ``R = wheel_radius_m``."""
    half_r = 0.5 * wheel_radius_m
    return half_r * (omega_r + omega_l), half_r * (omega_r - omega_l) / half_track_m


def saturate_wheels(omega_r: float, omega_l: float, max_radps: float) -> tuple[float, float, bool]:
    """Limit both wheel speeds to ``|omega| <= max_radps`` keeping the turn.

    Returns ``(omega_r, omega_l, saturated)``. As PX4's
    ``DifferentialActControl::computeInverseKinematics``: the command is split into a common
    (forward) part ``c = (wr + wl) / 2`` and a differential (turn) part ``d = (wr - wl) / 2``; the
    peak wheel speed is ``|c| + |d|``. If it exceeds the limit the turn is kept and the forward
    part shrinks (same sign) to ``max - |d|``; if the turn alone exceeds the limit it is scaled to
    the limit with no forward part (rotate in place at full speed). A robot that cannot do both
    therefore still steers toward its goal instead of running wide.

    Non-finite wheel speeds, or a non-finite / non-positive limit, give ``(0.0, 0.0, True)``.
    """
    if not (_isfinite(omega_r) and _isfinite(omega_l) and max_radps > 0.0 and max_radps < math.inf):
        return 0.0, 0.0, True
    if -max_radps <= omega_r <= max_radps and -max_radps <= omega_l <= max_radps:
        return omega_r, omega_l, False
    common = 0.5 * omega_r + 0.5 * omega_l  # halves first: no overflow near float max
    diff = 0.5 * omega_r - 0.5 * omega_l
    if abs(diff) >= max_radps:
        diff = math.copysign(max_radps, diff)
        common = 0.0
    else:
        common = math.copysign(max_radps - abs(diff), common)
    r = common + diff
    lft = common - diff
    # Rounding in (max - |d|) + |d| can exceed max by one ulp; clip so the bound is exact.
    if r > max_radps:
        r = max_radps
    elif r < -max_radps:
        r = -max_radps
    if lft > max_radps:
        lft = max_radps
    elif lft < -max_radps:
        lft = -max_radps
    return r, lft, True


def reference_point(x: float, y: float, theta: float, l_m: float) -> tuple[float, float]:
    """Reference point (m) at distance ``l_m`` ahead of the axle centre; eqs 10-11.

    ``x_r = x + l cos(theta)``, ``y_r = y + l sin(theta)``.
    """
    return x + l_m * _cos(theta), y + l_m * _sin(theta)


def axle_from_reference_point(
    x_r: float, y_r: float, theta: float, l_m: float
) -> tuple[float, float]:
    """Axle centre (m) whose reference point is ``(x_r, y_r)`` at heading ``theta``: the inverse
    of :func:`reference_point` (eqs 10-11)."""
    return x_r - l_m * _cos(theta), y_r - l_m * _sin(theta)


def ref_point_velocity(v: float, omega: float, theta: float, l_m: float) -> tuple[float, float]:
    """Velocity (m/s) of the reference point for a twist; eqs 14-15 (eq 13 corrected).

    ``xdot_r = v cos(theta) - l omega sin(theta)``, ``ydot_r = v sin(theta) + l omega cos(theta)``.
    """
    c = _cos(theta)
    s = _sin(theta)
    lw = l_m * omega
    return v * c - lw * s, v * s + lw * c


def twist_from_ref_velocity(
    xdot_r: float, ydot_r: float, theta: float, l_m: float
) -> tuple[float, float]:
    """Twist (v m/s, omega rad/s) that gives the reference point a velocity (m/s); eq 16.

    ``v = cos(theta) xdot_r + sin(theta) ydot_r``,
    ``omega = (-sin(theta) xdot_r + cos(theta) ydot_r) / l``. This is the Robotarium simulator's
    ``si_to_uni`` map with projection distance ``l``. Defined for any ``l_m > 0``.

    Raises:
        ValueError: if ``l_m`` is not > 0 (configuration error; ``RobotGeometry`` prevents it).
    """
    if not l_m > 0.0:
        raise ValueError(f"reference offset l_m must be > 0, got {l_m!r}")
    c = _cos(theta)
    s = _sin(theta)
    return c * xdot_r + s * ydot_r, (c * ydot_r - s * xdot_r) / l_m
