"""The virtual leader's state at one time (paper eqs 1-2): :class:`LeaderState`, and the per-tick
arithmetic of the closed-form trajectories that give it (:func:`line_state`, :func:`circle_state`,
:func:`figure8_state`: the bodies of ``StraightLine``, ``Circle`` and ``FigureEight.sample``).

A module of its own so that it runs compiled with the coordinator's tick
(``coordinator/core/_accel.py``) while ``coordinator.core.trajectory``, which imports and
re-exports it, stays Python (docs/architecture.md). One state is made every coordinator tick (by
the trajectory's ``sample`` or the leader's step) and its fields are read by the slots (eqs 3-5),
the leader and the simulator's log.

Why it is not a ``frozen=True`` dataclass: mypyc builds a frozen dataclass through the
dataclass's own Python ``__init__`` (each field stored with ``object.__setattr__``: about 0.6 us
a state), and it could not unpickle one. Here the class is an ``eq`` dataclass with its own
``__init__``, made read-only by its ``__setattr__`` and ``__delattr__`` (the same
``FrozenInstanceError`` as a frozen dataclass's); compiled, ``__init__`` stores the fields
natively (about 35 ns from compiled code, 170 ns from Python), in pure Python through the slots'
descriptors (which do not go through ``__setattr__``). The same fields, equality, hash (over the
fields, as a frozen dataclass's), ``repr``, ``dataclasses.replace`` and pickling either way. A
compiled state holds its fields as floats (an ``int`` given is stored as the same float).

The samples' arithmetic is here for the same reason: ``trajectory``'s classes validate their
parameters and the time (``ValueError``), then call these with checked floats, so the arithmetic,
the ``sin``/``cos`` and the state run compiled; the operations and their order are the ones the
classes had, so the same bits compiled and pure. The :class:`Sampler` classes hold a
trajectory's checked parameters and call these, so the leader's step samples its script without
a Python frame (``coordinator.core.trajectory.sampler``). Pure, stdlib only.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import FrozenInstanceError, dataclass
from types import MemberDescriptorType
from typing import Any, Final

from robot_agent.core.kinematics import wrap_angle  # the one wrap to (-pi, pi]; NaN for non-finite

__all__ = [
    "TWO_PI",
    "CircleSampler",
    "Figure8Sampler",
    "LeaderState",
    "LineSampler",
    "Sampler",
    "circle_state",
    "figure8_state",
    "line_state",
]

TWO_PI: Final = 2.0 * math.pi


@dataclass(unsafe_hash=True, slots=True)
class LeaderState:
    """State of the virtual leader at time ``t`` (s).

    ``x``, ``y`` in m; ``theta`` heading in rad, wrapped to (-pi, pi]; ``v_mps`` speed along the
    heading (m/s); ``omega_radps`` heading rate (rad/s). Read-only (module docstring).
    """

    t: float
    x: float
    y: float
    theta: float
    v_mps: float
    omega_radps: float

    def __init__(
        self, t: float, x: float, y: float, theta: float, v_mps: float, omega_radps: float
    ) -> None:
        if _NATIVE:  # compiled: native stores (they do not call __setattr__)
            self.t = t
            self.x = x
            self.y = y
            self.theta = theta
            self.v_mps = v_mps
            self.omega_radps = omega_radps
        else:  # pure Python: the slots' descriptors (no __setattr__; 0.45 us, not 0.75)
            _SET_T(self, t)
            _SET_X(self, x)
            _SET_Y(self, y)
            _SET_THETA(self, theta)
            _SET_V(self, v_mps)
            _SET_OMEGA(self, omega_radps)

    def __setattr__(self, name: str, value: Any) -> None:
        raise FrozenInstanceError(f"cannot assign to field {name!r}")

    def __delattr__(self, name: str) -> None:
        raise FrozenInstanceError(f"cannot delete field {name!r}")

    def __reduce__(self) -> tuple[type[LeaderState], tuple[float, ...]]:
        return (
            LeaderState,
            (self.t, self.x, self.y, self.theta, self.v_mps, self.omega_radps),
        )

    @property
    def vx(self) -> float:
        """World-frame x velocity, m/s (eq 1)."""
        return self.v_mps * math.cos(self.theta)

    @property
    def vy(self) -> float:
        """World-frame y velocity, m/s (eq 2)."""
        return self.v_mps * math.sin(self.theta)


_DESCRIPTORS = [vars(LeaderState)[f.name] for f in dataclasses.fields(LeaderState)]
#: The fields are slots of a Python class (pure Python), not native attributes (compiled).
_NATIVE: Final = not all(isinstance(d, MemberDescriptorType) for d in _DESCRIPTORS)
# The slot descriptors' setters the pure class's __init__ stores with.
_SET_T, _SET_X, _SET_Y, _SET_THETA, _SET_V, _SET_OMEGA = (d.__set__ for d in _DESCRIPTORS)


def line_state(
    t: float, x0: float, y0: float, heading: float, speed_mps: float, t_start_s: float
) -> LeaderState:
    """``StraightLine.sample`` at the checked time ``t`` (s): eqs 1-2 with constant v and
    theta, the start pose held before ``t_start_s``."""
    tau = t - t_start_s
    if tau <= 0.0:
        return LeaderState(t, x0, y0, heading, 0.0, 0.0)
    d = speed_mps * tau
    return LeaderState(
        t, x0 + d * math.cos(heading), y0 + d * math.sin(heading), heading, speed_mps, 0.0
    )


def circle_state(
    t: float,
    cx: float,
    cy: float,
    radius_m: float,
    speed_mps: float,
    start_angle_rad: float,
    sign: float,
    t_start_s: float,
) -> LeaderState:
    """``Circle.sample`` at the checked time ``t`` (s); ``sign`` +1 counter-clockwise, -1
    clockwise. The phase is reduced modulo one lap (``period_s``), so accuracy does not decay
    over long runs."""
    since = t - t_start_s
    tau = since if since > 0.0 else 0.0  # max(0.0, since), as max picks it
    period_s = TWO_PI * radius_m / speed_mps
    alpha = start_angle_rad + sign * math.remainder(tau, period_s) * (speed_mps / radius_m)
    x = cx + radius_m * math.cos(alpha)
    y = cy + radius_m * math.sin(alpha)
    theta = wrap_angle(alpha + sign * math.pi / 2.0)
    if since <= 0.0:
        return LeaderState(t, x, y, theta, 0.0, 0.0)
    return LeaderState(t, x, y, theta, speed_mps, sign * speed_mps / radius_m)


def figure8_state(
    t: float,
    cx: float,
    cy: float,
    a_m: float,
    period_s: float,
    rotation_rad: float,
    t_start_s: float,
) -> LeaderState:
    """``FigureEight.sample`` at the checked time ``t`` (s): the lemniscate of Gerono, its
    heading ``atan2(ydot, xdot)`` and turn rate ``(xdot yddot - ydot xddot) / v^2``."""
    since = t - t_start_s
    tau = since if since > 0.0 else 0.0  # max(0.0, since), as max picks it
    w = TWO_PI / period_s
    ph = w * math.remainder(tau, period_s)
    a = a_m
    s1, c1 = math.sin(ph), math.cos(ph)
    s2, c2 = math.sin(2.0 * ph), math.cos(2.0 * ph)
    # Figure frame: position and its first two derivatives.
    px, py = a * s1, 0.5 * a * s2
    dx, dy = a * w * c1, a * w * c2
    ddx, ddy = -a * w * w * s1, -2.0 * a * w * w * s2
    cr, sr = math.cos(rotation_rad), math.sin(rotation_rad)
    x = cx + cr * px - sr * py
    y = cy + sr * px + cr * py
    v2 = dx * dx + dy * dy  # >= (a w)^2 > 0
    theta = wrap_angle(math.atan2(dy, dx) + rotation_rad)
    if since <= 0.0:
        return LeaderState(t, x, y, theta, 0.0, 0.0)
    return LeaderState(t, x, y, theta, math.sqrt(v2), (dx * ddy - dy * ddx) / v2)


class Sampler:
    """A closed-form trajectory's checked parameters and its sample, compiled: what
    ``LeaderCore.step`` calls every tick in place of the trajectory's own ``sample`` (a Python
    method, whose frame cost more than its arithmetic). ``coordinator.core.trajectory.sampler``
    makes one from a ``StraightLine``, ``Circle`` or ``FigureEight``; ``sample(t)`` is that
    trajectory's ``sample(t)`` bit for bit for a finite float ``t`` (the same function of the
    same floats), which the caller checks."""

    def sample(self, t: float) -> LeaderState:
        """The state at the finite time ``t`` (s)."""
        raise NotImplementedError


class LineSampler(Sampler):
    """``StraightLine.sample`` (:func:`line_state`)."""

    def __init__(
        self, x0: float, y0: float, heading: float, speed_mps: float, t_start_s: float
    ) -> None:
        self.x0 = x0
        self.y0 = y0
        self.heading = heading
        self.speed_mps = speed_mps
        self.t_start_s = t_start_s

    def sample(self, t: float) -> LeaderState:
        return line_state(t, self.x0, self.y0, self.heading, self.speed_mps, self.t_start_s)


class CircleSampler(Sampler):
    """``Circle.sample`` (:func:`circle_state`)."""

    def __init__(
        self,
        cx: float,
        cy: float,
        radius_m: float,
        speed_mps: float,
        start_angle_rad: float,
        sign: float,
        t_start_s: float,
    ) -> None:
        self.cx = cx
        self.cy = cy
        self.radius_m = radius_m
        self.speed_mps = speed_mps
        self.start_angle_rad = start_angle_rad
        self.sign = sign
        self.t_start_s = t_start_s

    def sample(self, t: float) -> LeaderState:
        return circle_state(
            t, self.cx, self.cy, self.radius_m, self.speed_mps, self.start_angle_rad, self.sign,
            self.t_start_s,
        )  # fmt: skip


class Figure8Sampler(Sampler):
    """``FigureEight.sample`` (:func:`figure8_state`)."""

    def __init__(
        self,
        cx: float,
        cy: float,
        a_m: float,
        period_s: float,
        rotation_rad: float,
        t_start_s: float,
    ) -> None:
        self.cx = cx
        self.cy = cy
        self.a_m = a_m
        self.period_s = period_s
        self.rotation_rad = rotation_rad
        self.t_start_s = t_start_s

    def sample(self, t: float) -> LeaderState:
        return figure8_state(
            t, self.cx, self.cy, self.a_m, self.period_s, self.rotation_rad, self.t_start_s
        )
