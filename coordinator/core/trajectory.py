"""Virtual-leader trajectories (paper eqs 1-2): pure functions of time.

Every trajectory is an immutable object whose ``sample(t_s)`` returns the virtual leader's state
at time ``t_s`` (seconds). Nothing is integrated step by step at run time, so a standby
coordinator that takes over reproduces bit-for-bit the state the active one would have published.

Conventions shared by all trajectories:

* ``t_start_s`` (default 0): before it the leader holds the start pose, stationary
  (``v_mps = omega_radps = 0``), with the heading it will start with. Any ``t_s`` below
  ``t_start_s``, negative times included, clamps to that held start state.
* Headings are wrapped to (-pi, pi]; ``v_mps`` is the signed speed along the heading and
  ``omega_radps`` the heading rate, consistent with the derivatives of x, y and theta (eqs 1-2:
  ``xdot = v cos(theta)``, ``ydot = v sin(theta)``, ``thetadot = omega``).
* Constructors validate their parameters and raise ``ValueError`` with a message naming the class,
  the parameter and the offending value.

``make_trajectory(kind, params)`` builds one from a scenario file's table.
"""

from __future__ import annotations

import bisect
import dataclasses
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

# the state every sample returns and the closed-form samples' arithmetic: their own module,
# compiled with the coordinator's tick
from coordinator.core.leader_state import (
    TWO_PI,
    CircleSampler,
    Figure8Sampler,
    LeaderState,
    LineSampler,
    Sampler,
    circle_state,
    figure8_state,
    line_state,
)
from robot_agent.core.kinematics import wrap_angle  # the one wrap to (-pi, pi]; NaN for non-finite

__all__ = [
    "TRAJECTORY_KINDS",
    "Circle",
    "FigureEight",
    "LeaderState",
    "StraightLine",
    "Trajectory",
    "Waypoints",
    "make_trajectory",
    "sampler",
    "wrap_angle",
]

_TWO_PI = TWO_PI


@runtime_checkable
class Trajectory(Protocol):
    """A virtual-leader trajectory: a pure function of time."""

    def sample(self, t_s: float) -> LeaderState:
        """State of the virtual leader at time ``t_s`` (s)."""
        ...


# --------------------------------------------------------------------------------------------
# Parameter validation helpers


def _real(owner: str, name: str, value: object) -> float:
    """``value`` as a finite float, or ValueError naming ``owner.name``."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ValueError(f"{owner}: {name} must be a number, got {value!r}")
    f = float(value)
    if not math.isfinite(f):
        raise ValueError(f"{owner}: {name} must be finite, got {value!r}")
    return f


def _positive(owner: str, name: str, value: object) -> float:
    f = _real(owner, name, value)
    if f <= 0.0:
        raise ValueError(f"{owner}: {name} must be > 0, got {value!r}")
    return f


def _non_negative(owner: str, name: str, value: object) -> float:
    f = _real(owner, name, value)
    if f < 0.0:
        raise ValueError(f"{owner}: {name} must be >= 0, got {value!r}")
    return f


def _time(owner: object, t_s: float) -> float:
    """``t_s`` (s) as a float; ValueError naming ``owner``'s class if it is not a finite number."""
    if type(t_s) is float and math.isfinite(t_s):  # (every tick: one test)
        return t_s
    if isinstance(t_s, bool) or not isinstance(t_s, int | float) or not math.isfinite(t_s):
        name = type(owner).__name__
        raise ValueError(f"{name}.sample: t_s must be a finite number, got {t_s!r}")
    return float(t_s)


def _set(obj: object, name: str, value: object) -> None:
    """Assign a normalised value to a field of a frozen dataclass during __post_init__."""
    object.__setattr__(obj, name, value)


# --------------------------------------------------------------------------------------------
# Straight line


@dataclass(frozen=True)
class StraightLine:
    """Constant-velocity straight line from ``(x0, y0)`` (m) along ``heading`` (rad).

    ``speed_mps`` >= 0; 0 gives a parked leader (a static formation).
    """

    x0: float
    y0: float
    heading: float
    speed_mps: float
    t_start_s: float = 0.0

    def __post_init__(self) -> None:
        name = type(self).__name__
        _set(self, "x0", _real(name, "x0", self.x0))
        _set(self, "y0", _real(name, "y0", self.y0))
        _set(self, "heading", wrap_angle(_real(name, "heading", self.heading)))
        _set(self, "speed_mps", _non_negative(name, "speed_mps", self.speed_mps))
        _set(self, "t_start_s", _non_negative(name, "t_start_s", self.t_start_s))

    def sample(self, t_s: float) -> LeaderState:
        """Leader state at ``t_s`` (s); eqs 1-2 with constant v and theta (the arithmetic:
        :func:`~coordinator.core.leader_state.line_state`)."""
        t = _time(self, t_s)
        return line_state(t, self.x0, self.y0, self.heading, self.speed_mps, self.t_start_s)


# --------------------------------------------------------------------------------------------
# Circle


@dataclass(frozen=True)
class Circle:
    """Constant-speed circle of centre ``(cx, cy)`` (m) and radius ``radius_m``.

    The leader starts at polar angle ``start_angle_rad`` about the centre (default -pi/2: below
    the centre, heading +x when counter-clockwise) and turns counter-clockwise when ``ccw``.
    ``omega_radps = +-speed_mps / radius_m``.
    """

    cx: float
    cy: float
    radius_m: float
    speed_mps: float
    start_angle_rad: float = -math.pi / 2.0
    ccw: bool = True
    t_start_s: float = 0.0

    def __post_init__(self) -> None:
        name = type(self).__name__
        _set(self, "cx", _real(name, "cx", self.cx))
        _set(self, "cy", _real(name, "cy", self.cy))
        _set(self, "radius_m", _positive(name, "radius_m", self.radius_m))
        _set(self, "speed_mps", _positive(name, "speed_mps", self.speed_mps))
        _set(self, "start_angle_rad", _real(name, "start_angle_rad", self.start_angle_rad))
        if not isinstance(self.ccw, bool):
            raise ValueError(f"{name}: ccw must be a bool, got {self.ccw!r}")
        _set(self, "t_start_s", _non_negative(name, "t_start_s", self.t_start_s))

    @property
    def omega_radps(self) -> float:
        """Signed turn rate, rad/s (positive counter-clockwise)."""
        return (1.0 if self.ccw else -1.0) * self.speed_mps / self.radius_m

    @property
    def period_s(self) -> float:
        """Time for one lap, s."""
        return _TWO_PI * self.radius_m / self.speed_mps

    def sample(self, t_s: float) -> LeaderState:
        """Leader state at ``t_s`` (s) (the arithmetic:
        :func:`~coordinator.core.leader_state.circle_state`)."""
        t = _time(self, t_s)
        sign = 1.0 if self.ccw else -1.0
        return circle_state(
            t, self.cx, self.cy, self.radius_m, self.speed_mps, self.start_angle_rad, sign,
            self.t_start_s,
        )  # fmt: skip


# --------------------------------------------------------------------------------------------
# Figure eight


# max over the phase p of |sin p cos 2p - 2 cos p sin 2p| / (cos^2 p + cos^2 2p), i.e. |omega| / w
# of the figure eight (independent of its size); reached at p = 0.894815 rad, found numerically.
_F8_TURN_PEAK: float = 3.1712020150776


@dataclass(frozen=True)
class FigureEight:
    """Figure eight (lemniscate of Gerono) centred on ``(cx, cy)`` (m).

    In the figure's frame: ``x = a sin(w t)``, ``y = (a/2) sin(2 w t)`` with ``w = 2 pi /
    period_s``; the figure is ``2 a_m`` long and ``a_m`` wide, rotated by ``rotation_rad``. The
    speed ``a w sqrt(cos^2(w t) + cos^2(2 w t))`` varies between ``sqrt(7)/4 a w`` and
    ``sqrt(2) a w`` (at the crossing) and is never zero, so the heading ``atan2(ydot, xdot)`` and
    the turn rate ``(xdot yddot - ydot xddot) / v^2`` are defined everywhere; ``|omega|`` peaks at
    about ``3.17 w`` on the way into each lobe. It starts at the centre heading
    ``rotation_rad + pi/4``.
    """

    cx: float
    cy: float
    a_m: float
    period_s: float
    rotation_rad: float = 0.0
    t_start_s: float = 0.0

    def __post_init__(self) -> None:
        name = type(self).__name__
        _set(self, "cx", _real(name, "cx", self.cx))
        _set(self, "cy", _real(name, "cy", self.cy))
        _set(self, "a_m", _positive(name, "a_m", self.a_m))
        _set(self, "period_s", _positive(name, "period_s", self.period_s))
        _set(self, "rotation_rad", _real(name, "rotation_rad", self.rotation_rad))
        _set(self, "t_start_s", _non_negative(name, "t_start_s", self.t_start_s))

    @property
    def max_speed_mps(self) -> float:
        """Highest speed along the figure (at the crossing), m/s."""
        return math.sqrt(2.0) * self.a_m * _TWO_PI / self.period_s

    @property
    def min_speed_mps(self) -> float:
        """Lowest speed along the figure, m/s: ``sqrt(7)/4 a w`` (where ``cos^2(w t) = 3/8``)."""
        return math.sqrt(7.0) / 4.0 * self.a_m * _TWO_PI / self.period_s

    @property
    def max_turn_radps(self) -> float:
        """Highest |omega| along the figure, rad/s: ``_F8_TURN_PEAK * w``."""
        return _F8_TURN_PEAK * _TWO_PI / self.period_s

    def sample(self, t_s: float) -> LeaderState:
        """Leader state at ``t_s`` (s) (the arithmetic:
        :func:`~coordinator.core.leader_state.figure8_state`)."""
        t = _time(self, t_s)
        return figure8_state(
            t, self.cx, self.cy, self.a_m, self.period_s, self.rotation_rad, self.t_start_s
        )


# --------------------------------------------------------------------------------------------
# Waypoints: straight segments joined by circular arcs of radius speed / max_turn_rate


@dataclass(frozen=True, slots=True)
class _Piece:
    """One piece of a Waypoints path: a line (``sign == 0``) or an arc (``sign == +-1``).

    Line: starts at ``(x0, y0)`` with heading ``h0``. Arc: centre ``(x0, y0)``, radius
    ``radius_m``, start heading ``h0``, turning left (``+1``) or right (``-1``).
    """

    s0_m: float
    length_m: float
    x0: float
    y0: float
    h0: float
    sign: int
    radius_m: float

    def at(self, ds_m: float) -> tuple[float, float, float]:
        """(x, y, heading) at arc length ``ds_m`` into the piece."""
        if self.sign == 0:
            return (
                self.x0 + ds_m * math.cos(self.h0),
                self.y0 + ds_m * math.sin(self.h0),
                self.h0,
            )
        h = self.h0 + self.sign * ds_m / self.radius_m
        r = self.sign * self.radius_m
        return self.x0 + r * math.sin(h), self.y0 - r * math.cos(h), h


@dataclass(frozen=True)
class Waypoints:
    """Constant-speed path through a list of waypoints with a turn-rate limit.

    The path is precomputed at construction: straight segments between the points, each interior
    corner rounded by a circular arc of radius ``speed_mps / max_turn_radps`` tangent to both
    segments. So the speed is exactly ``speed_mps`` and ``|omega|`` is 0 on segments and exactly
    ``max_turn_radps`` on arcs; the path starts at the first point, ends at the last, and passes
    inside each interior corner by ``R (1/cos(delta/2) - 1)`` for a turn of ``delta``.

    ``points``: at least 2 (x, y) pairs in m, consecutive points distinct. ``loop``: close the path
    back to the first point and repeat it forever (needs 3 points; every point is a corner).
    Without ``loop`` the leader stops at the last point and holds it.

    A corner whose arc does not fit (the two tangent lengths ``R tan(|delta|/2)`` exceed a
    segment's length) or a U-turn raises ``ValueError``: lower the speed, raise the turn rate, or
    space the points out.
    """

    points: Sequence[tuple[float, float]]
    speed_mps: float
    max_turn_radps: float
    loop: bool = False
    t_start_s: float = 0.0
    _pieces: tuple[_Piece, ...] = field(init=False, repr=False, compare=False)
    _starts: tuple[float, ...] = field(init=False, repr=False, compare=False)
    length_m: float = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        name = type(self).__name__
        _set(self, "speed_mps", _positive(name, "speed_mps", self.speed_mps))
        _set(self, "max_turn_radps", _positive(name, "max_turn_radps", self.max_turn_radps))
        _set(self, "t_start_s", _non_negative(name, "t_start_s", self.t_start_s))
        if not isinstance(self.loop, bool):
            raise ValueError(f"{name}: loop must be a bool, got {self.loop!r}")
        pts = self._parse_points(name, self.points)
        if len(pts) < (3 if self.loop else 2):
            raise ValueError(
                f"{name}: needs at least {3 if self.loop else 2} points"
                f"{' with loop=true' if self.loop else ''}, got {len(pts)}"
            )
        _set(self, "points", pts)
        pieces = self.build_section(name, pts)
        _set(self, "_pieces", pieces)
        _set(self, "_starts", tuple(p.s0_m for p in pieces))
        _set(self, "length_m", pieces[-1].s0_m + pieces[-1].length_m)

    @staticmethod
    def _parse_points(name: str, points: object) -> tuple[tuple[float, float], ...]:
        if isinstance(points, str | bytes) or not isinstance(points, Sequence):
            raise ValueError(f"{name}: points must be a list of [x, y] pairs, got {points!r}")
        out: list[tuple[float, float]] = []
        for i, p in enumerate(points):
            if isinstance(p, str | bytes) or not isinstance(p, Sequence) or len(p) != 2:
                raise ValueError(f"{name}: points[{i}] must be an [x, y] pair, got {p!r}")
            out.append((_real(name, f"points[{i}][0]", p[0]), _real(name, f"points[{i}][1]", p[1])))
        return tuple(out)

    @property
    def turn_radius_m(self) -> float:
        """Radius of the corner arcs, m: ``speed_mps / max_turn_radps``."""
        return self.speed_mps / self.max_turn_radps

    @property
    def duration_s(self) -> float:
        """Time to run the path once (one lap when ``loop``), s, excluding ``t_start_s``."""
        return self.length_m / self.speed_mps

    @property
    def knot_times_s(self) -> tuple[float, ...]:
        """Times (s) where a piece starts (segment/arc junctions) in the first run of the path;
        ``omega`` is discontinuous there."""
        return tuple(self.t_start_s + s / self.speed_mps for s in self._starts)

    def build_section(self, name: str, pts: tuple[tuple[float, float], ...]) -> tuple[_Piece, ...]:
        n = len(pts)
        n_seg = n if self.loop else n - 1
        seg_len: list[float] = []
        seg_dir: list[tuple[float, float]] = []
        for i in range(n_seg):
            (xa, ya), (xb, yb) = pts[i], pts[(i + 1) % n]
            d = math.hypot(xb - xa, yb - ya)
            if d < 1e-9:
                raise ValueError(
                    f"{name}: segment {i} from points[{i}] to points[{(i + 1) % n}] has zero "
                    f"length ({pts[i]!r})"
                )
            seg_len.append(d)
            seg_dir.append(((xb - xa) / d, (yb - ya) / d))
        radius = self.turn_radius_m
        # Corner k is the vertex where segment k-1 ends and segment k starts.
        corners = range(n) if self.loop else range(1, n - 1)
        turn: dict[int, float] = {}
        tangent: dict[int, float] = {}
        for k in corners:
            ux, uy = seg_dir[k - 1]
            wx, wy = seg_dir[k % n_seg]
            delta = math.atan2(ux * wy - uy * wx, ux * wx + uy * wy)
            if abs(delta) < 1e-12:
                continue
            if abs(delta) > math.pi - 1e-6:
                raise ValueError(
                    f"{name}: points[{k}] is a U-turn (the path doubles back); a constant-speed "
                    "turn-rate-limited path cannot round it. Add points to make the turn wider."
                )
            turn[k] = delta
            tangent[k] = radius * math.tan(abs(delta) / 2.0)
        for i in range(n_seg):
            need = tangent.get(i, 0.0) + tangent.get((i + 1) % n if self.loop else i + 1, 0.0)
            if need > seg_len[i] + 1e-9:
                raise ValueError(
                    f"{name}: the turns at the ends of segment {i} (points[{i}] -> "
                    f"points[{(i + 1) % n}], {seg_len[i]:.4g} m) need {need:.4g} m of straight "
                    f"line for arcs of radius {radius:.4g} m (speed_mps / max_turn_radps); "
                    "space the points out, lower speed_mps or raise max_turn_radps"
                )
        pieces: list[_Piece] = []
        s = 0.0

        def add(length: float, x0: float, y0: float, h0: float, sign: int) -> None:
            nonlocal s
            if length > 1e-12:
                pieces.append(_Piece(s, length, x0, y0, h0, sign, radius))
                s += length

        for i in range(n_seg):
            (xa, ya) = pts[i]
            ux, uy = seg_dir[i]
            h = math.atan2(uy, ux)
            d_in = tangent.get(i, 0.0)
            end_k = (i + 1) % n if self.loop else i + 1
            d_out = tangent.get(end_k, 0.0)
            add(seg_len[i] - d_in - d_out, xa + d_in * ux, ya + d_in * uy, h, 0)
            if end_k in turn:
                sign = 1 if turn[end_k] > 0.0 else -1
                xb, yb = pts[end_k]
                ax, ay = xb - d_out * ux, yb - d_out * uy  # arc start, on segment i
                cx, cy = ax - sign * radius * uy, ay + sign * radius * ux  # centre: left/right
                add(radius * abs(turn[end_k]), cx, cy, h, sign)
        if not pieces:  # pragma: no cover - excluded by the segment-length checks above
            raise ValueError(f"{name}: the path has zero length")
        return tuple(pieces)

    def sample(self, t_s: float) -> LeaderState:
        """Leader state at ``t_s`` (s), evaluated exactly on the precomputed path."""
        t = _time(self, t_s)
        tau = t - self.t_start_s
        if tau <= 0.0:
            first = self._pieces[0]
            x, y, h = first.at(0.0)
            return LeaderState(t, x, y, wrap_angle(h), 0.0, 0.0)
        s = self.speed_mps * tau
        if self.loop:
            s = math.fmod(s, self.length_m)
        elif s >= self.length_m:
            last = self._pieces[-1]
            x, y, h = last.at(last.length_m)
            return LeaderState(t, x, y, wrap_angle(h), 0.0, 0.0)
        i = bisect.bisect_right(self._starts, s) - 1
        piece = self._pieces[max(i, 0)]
        x, y, h = piece.at(min(s - piece.s0_m, piece.length_m))
        omega = piece.sign * self.speed_mps / piece.radius_m
        return LeaderState(t, x, y, wrap_angle(h), self.speed_mps, omega)


# --------------------------------------------------------------------------------------------
# The compiled samplers of the closed-form trajectories


def sampler(trajectory: object) -> Sampler | None:
    """The compiled sampler of ``trajectory`` (``coordinator.core.leader_state``): its
    ``sample(t)`` is ``trajectory.sample(t)`` bit for bit for a finite float ``t``, without a
    Python frame (``LeaderCore.step`` samples through it every tick). None for any other
    trajectory, a subclass included (its ``sample`` may differ): the caller calls ``sample``."""
    if type(trajectory) is StraightLine:
        t = trajectory
        return LineSampler(t.x0, t.y0, t.heading, t.speed_mps, t.t_start_s)
    if type(trajectory) is Circle:
        c = trajectory
        sign = 1.0 if c.ccw else -1.0  # (as Circle.sample)
        return CircleSampler(
            c.cx, c.cy, c.radius_m, c.speed_mps, c.start_angle_rad, sign, c.t_start_s
        )
    if type(trajectory) is FigureEight:
        f = trajectory
        return Figure8Sampler(f.cx, f.cy, f.a_m, f.period_s, f.rotation_rad, f.t_start_s)
    return None


# --------------------------------------------------------------------------------------------
# Factory for scenario files

_KINDS: dict[str, type[Any] | str] = {
    "line": StraightLine,
    "circle": Circle,
    "figure8": FigureEight,
    "waypoints": Waypoints,
    # a planned path to a goal (issue 27): imported when used (numpy, scipy, shapely)
    "plan": "coordinator.core.planning.trajectory:PlannedTrajectory",
}
_ALIASES = {"straight": "line", "figure_eight": "figure8", "lemniscate": "figure8"}

TRAJECTORY_KINDS: tuple[str, ...] = tuple(_KINDS)
"""Kinds accepted by :func:`make_trajectory`."""


def trajectory_class(kind: str) -> type[Any]:
    """The class of trajectory ``kind`` (a key of the kinds table; a lazy entry is imported)."""
    cls = _KINDS[kind]
    if isinstance(cls, str):
        import importlib

        module, _, name = cls.partition(":")
        cls = _KINDS[kind] = getattr(importlib.import_module(module), name)
    return cls


def make_trajectory(kind: str, params: Mapping[str, Any]) -> Trajectory:
    """Build a trajectory from a scenario table.

    ``kind`` is one of ``"line"``, ``"circle"``, ``"figure8"``, ``"waypoints"``, ``"plan"``
    (``coordinator.core.planning.trajectory``: its table needs the ``context`` that
    ``scenario.load`` adds); ``params`` holds
    the constructor's keyword arguments (e.g. ``{"x0": 0, "y0": 0, "heading": 0,
    "speed_mps": 0.05}`` for a line). Unknown kinds, unknown or missing parameters and invalid
    values raise ``ValueError``.
    """
    if not isinstance(kind, str):
        raise ValueError(f"trajectory kind must be a string, got {kind!r}")
    key = _ALIASES.get(kind.strip().lower(), kind.strip().lower())
    cls = trajectory_class(key) if key in _KINDS else None
    if cls is None:
        raise ValueError(
            f"unknown trajectory kind {kind!r}; expected one of {', '.join(TRAJECTORY_KINDS)}"
        )
    if not isinstance(params, Mapping):
        raise ValueError(f"trajectory {key!r}: params must be a table/mapping, got {params!r}")
    fields = [f for f in dataclasses.fields(cls) if f.init]
    allowed = {f.name for f in fields}
    required = [
        f.name
        for f in fields
        if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING
    ]
    unknown = sorted(str(k) for k in params if k not in allowed)
    if unknown:
        raise ValueError(
            f"trajectory {key!r}: unknown parameter(s) {', '.join(unknown)}; "
            f"allowed: {', '.join(f.name for f in fields)}"
        )
    missing = [name for name in required if name not in params]
    if missing:
        raise ValueError(f"trajectory {key!r}: missing required parameter(s) {', '.join(missing)}")
    trajectory: Trajectory = cls(**dict(params))
    return trajectory
