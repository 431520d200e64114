"""Parameters of one robot's firmware: geometry, tracking gains, repulsion and safety limits.

Every parameter set is a frozen dataclass with documented, validated defaults (units in the
names). Validation happens once, at construction, so the control loop never has to re-check a
gain: a bad value raises ``ValueError`` when the configuration is built, not in flight.

Defaults describe a small differential robot (the paper gives no dimensions): 3 cm wheels on a
10 cm track, 0.3 m/s top speed, 7.5 cm body radius, and the paper's tracking gains
(Kp = 0.21, Ti = 105 s, Td = 0.01 s, which place the ideal closed-loop poles at -0.2 and -0.01).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

__all__ = [
    "DEFAULT_K_REP",
    "AgentConfig",
    "RepulsionParams",
    "RobotGeometry",
    "SafetyParams",
    "TrackingGains",
]


def _require(cond: bool, message: str) -> None:
    if not cond:
        raise ValueError(message)


def _positive(name: str, value: float) -> None:
    _require(
        isinstance(value, (int, float)) and math.isfinite(value) and value > 0.0,
        f"{name} must be a finite number > 0, got {value!r}",
    )


def _non_negative(name: str, value: float) -> None:
    _require(
        isinstance(value, (int, float)) and math.isfinite(value) and value >= 0.0,
        f"{name} must be a finite number >= 0, got {value!r}",
    )


@dataclass(frozen=True, slots=True)
class RobotGeometry:
    """Geometry and actuator limits of a differential-drive robot.

    Attributes:
        wheel_radius_m: wheel radius R (m).
        half_track_m: half the distance between the wheels, L (m); the track is 2L.
        max_wheel_radps: largest wheel speed magnitude the motors reach (rad/s); power 1.0.
        body_radius_m: radius of the circle that contains the robot (m), for separation.
        ref_offset_m: distance l of the reference point ahead of the axle centre (m),
            eqs 10-11. The paper found 2-8 cm good; 5 cm is the default.
    """

    wheel_radius_m: float = 0.03
    half_track_m: float = 0.05
    max_wheel_radps: float = 10.0
    body_radius_m: float = 0.075
    ref_offset_m: float = 0.05

    def __post_init__(self) -> None:
        _positive("wheel_radius_m", self.wheel_radius_m)
        _positive("half_track_m", self.half_track_m)
        _positive("max_wheel_radps", self.max_wheel_radps)
        _positive("body_radius_m", self.body_radius_m)
        _positive("ref_offset_m", self.ref_offset_m)

    @property
    def max_speed_mps(self) -> float:
        """Top forward speed R * max_wheel_radps (m/s), both wheels at the limit."""
        return self.wheel_radius_m * self.max_wheel_radps


@dataclass(frozen=True, slots=True)
class TrackingGains:
    """Gains of the reference-point tracking law, eqs 21-22 (same gains on both axes).

    ``u = ff + kp * (e + I / ti_s + td_s * edot)`` per axis, with ``I`` the integral of the
    error (m*s) and ``edot`` the low-pass-filtered error derivative (m/s).

    Attributes:
        kp: proportional gain Kp (1/s: m/s of command per m of error).
        ti_s: integral time Ti (s).
        td_s: derivative time Td (s).
        d_filter_tau_s: time constant of the first-order low-pass on the error derivative (s);
            0 disables the filter.
        integral_limit_ms: clamp on the magnitude of the error integral I (m*s).
        max_ref_speed_mps: cap on the norm of the commanded reference-point velocity (m/s),
            feed-forward included.
    """

    kp: float = 0.21
    ti_s: float = 105.0
    td_s: float = 0.01
    d_filter_tau_s: float = 0.1
    integral_limit_ms: float = 0.5
    max_ref_speed_mps: float = 0.25

    def __post_init__(self) -> None:
        _non_negative("kp", self.kp)
        _positive("ti_s", self.ti_s)
        _non_negative("td_s", self.td_s)
        _non_negative("d_filter_tau_s", self.d_filter_tau_s)
        _non_negative("integral_limit_ms", self.integral_limit_ms)
        _positive("max_ref_speed_mps", self.max_ref_speed_mps)


# Default repulsion gain. The push at distance d (< d0) is k_rep * (1/d - 1/d0) / d^2. We want
# about 0.1 m/s when two default robots touch (centre distance d = 2 * 0.075 m = 0.15 m) with
# d0 = 0.30 m: (1/0.15 - 1/0.30) / 0.15^2 = 148.1 m^-3, so k_rep = 0.1 / 148.1 = 6.75e-4 m^4/s.
# The push is then 0.0 at 0.30 m, 0.0095 m/s at 0.25 m, 0.1 m/s at 0.15 m and reaches the
# 0.20 m/s cap at about 0.127 m.
DEFAULT_K_REP = 6.75e-4


@dataclass(frozen=True, slots=True)
class RepulsionParams:
    """Potential-field (Khatib) repulsion added to the reference-point velocity.

    Attributes:
        k_rep: gain (m^4/s); see ``DEFAULT_K_REP`` for how the default was chosen
            (0.1 m/s at 0.15 m centre distance with d0 = 0.30 m).
        d0_m: influence distance (m); no push at or beyond it.
        max_speed_mps: cap on the norm of the summed repulsion velocity (m/s).
        enabled: False turns repulsion off (the paper's controller without collision avoidance).
    """

    k_rep: float = DEFAULT_K_REP
    d0_m: float = 0.30
    max_speed_mps: float = 0.20
    enabled: bool = True

    def __post_init__(self) -> None:
        _non_negative("k_rep", self.k_rep)
        _positive("d0_m", self.d0_m)
        _non_negative("max_speed_mps", self.max_speed_mps)
        _require(isinstance(self.enabled, bool), f"enabled must be a bool, got {self.enabled!r}")

    def speed_at(self, d_m: float) -> float:
        """Magnitude (m/s) of the uncapped push from one neighbour at distance ``d_m`` > 0."""
        if d_m >= self.d0_m:
            return 0.0
        return self.k_rep * (1.0 / d_m - 1.0 / self.d0_m) / (d_m * d_m)


@dataclass(frozen=True, slots=True)
class SafetyParams:
    """Staleness limits of the firmware's input data (local receive-clock ages, s).

    Attributes:
        stale_pose_s: a pose received longer ago than this puts the robot in HOLD (s).
        stale_setpoint_s: a setpoint received longer ago than this puts the robot in HOLD (s).
        max_dt_s: a gap between two ``step`` calls longer than this is a stalled loop: the
            controller skips integration on that tick and restarts its derivative (s).
    """

    stale_pose_s: float = 0.2
    stale_setpoint_s: float = 0.2
    max_dt_s: float = 0.2

    def __post_init__(self) -> None:
        _positive("stale_pose_s", self.stale_pose_s)
        _positive("stale_setpoint_s", self.stale_setpoint_s)
        _positive("max_dt_s", self.max_dt_s)


@dataclass(frozen=True, slots=True)
class AgentConfig:
    """Everything one robot's firmware needs."""

    geometry: RobotGeometry = field(default_factory=RobotGeometry)
    gains: TrackingGains = field(default_factory=TrackingGains)
    repulsion: RepulsionParams = field(default_factory=RepulsionParams)
    safety: SafetyParams = field(default_factory=SafetyParams)

    def __post_init__(self) -> None:
        _require(isinstance(self.geometry, RobotGeometry), "geometry must be a RobotGeometry")
        _require(isinstance(self.gains, TrackingGains), "gains must be a TrackingGains")
        _require(isinstance(self.repulsion, RepulsionParams), "repulsion must be RepulsionParams")
        _require(isinstance(self.safety, SafetyParams), "safety must be a SafetyParams")
