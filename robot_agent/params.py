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
    "EstimatorParams",
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
class EstimatorParams:
    """Pose estimator (``robot_agent.estimator``) and setpoint extrapolation.

    Variances grow per metre travelled, per radian turned and per second while the estimate is
    predicted from wheel speeds; a camera pose shrinks them (scalar Kalman gain per axis). See
    the model in ``robot_agent/estimator.py`` and the defaults in docs/defaults.md.

    Attributes:
        enabled: False gives the firmware of before the estimator: the last measured pose is
            used as if current and a pose older than ``SafetyParams.stale_pose_s`` (receive age)
            holds the robot.
        extrapolate_setpoint: advance a setpoint by its feed-forward velocity over its receive
            age (one tick in lockstep), so a one-tick-old setpoint leaves no steady lag.
        history_s: how far back (s) a late camera pose is still replayed at its own capture
            time; older ones are rejected. Must be >= both dropout bounds.
        max_dropout_odom_s: the estimate stays valid this long (s) after the capture of the last
            camera pose while encoder speeds keep arriving (odometry).
        max_dropout_cmd_s: the same bound predicting from the commanded wheel speeds only.
        odom_timeout_s: encoder speeds older than this (s) no longer count as odometry.
        max_latency_s: a camera pose captured longer than this before ``now`` is rejected (s).
        future_tolerance_s: a capture time up to this far after ``now`` is taken as ``now``
            (clock rounding); later ones are rejected (s).
        actuation_delay_s: a commanded wheel speed is assumed to act this long after the tick
            that computed it (command link latency + motor lag, s).
        meas_pos_std_m: camera position noise (standard deviation per axis, m).
        meas_theta_std_rad: camera heading noise (rad).
        odom_pos_var_per_m: position variance added per metre travelled with encoder odometry
            (m^2/m).
        cmd_pos_var_per_m: the same predicting from commanded wheel speeds (m^2/m).
        odom_pos_var_per_s: position variance added per second with odometry (m^2/s).
        cmd_pos_var_per_s: the same from commanded speeds (m^2/s): a pushed or stalled robot
            is invisible to its own commands.
        theta_var_per_rad: heading variance per radian turned (rad^2/rad).
        theta_var_per_m: heading variance per metre travelled (rad^2/m).
        theta_var_per_s: heading variance per second (rad^2/s).
        gate_m: a camera pose farther than ``gate_m + n_sigma * sigma`` from the prediction at
            its capture time is implausible: rejected and counted (m).
        reset_after: this many implausible poses in a row re-initialise the estimate at the
            last one (the robot was carried or put down elsewhere).
        n_sigma: the reported uncertainty is ``n_sigma`` standard deviations (m).
        max_uncertainty_m: an uncertainty above this makes the estimate invalid (m).
    """

    enabled: bool = False
    extrapolate_setpoint: bool = True
    history_s: float = 1.5
    max_dropout_odom_s: float = 1.5
    max_dropout_cmd_s: float = 0.3
    odom_timeout_s: float = 0.1
    max_latency_s: float = 0.5
    future_tolerance_s: float = 0.005
    actuation_delay_s: float = 0.0
    meas_pos_std_m: float = 0.003
    meas_theta_std_rad: float = 0.01
    odom_pos_var_per_m: float = 1.0e-4
    cmd_pos_var_per_m: float = 4.0e-4
    odom_pos_var_per_s: float = 1.0e-6
    cmd_pos_var_per_s: float = 1.0e-5
    theta_var_per_rad: float = 4.0e-4
    theta_var_per_m: float = 1.0e-3
    theta_var_per_s: float = 1.0e-6
    gate_m: float = 0.2
    reset_after: int = 3
    n_sigma: float = 3.0
    max_uncertainty_m: float = 0.1

    def __post_init__(self) -> None:
        for name in ("enabled", "extrapolate_setpoint"):
            value = getattr(self, name)
            _require(isinstance(value, bool), f"{name} must be a bool, got {value!r}")
        for name in ("history_s", "max_dropout_odom_s", "max_dropout_cmd_s", "odom_timeout_s",
                     "max_latency_s", "max_uncertainty_m"):  # fmt: skip
            _positive(name, getattr(self, name))
        for name in (
            "future_tolerance_s", "actuation_delay_s", "meas_pos_std_m", "meas_theta_std_rad",
            "odom_pos_var_per_m", "cmd_pos_var_per_m", "odom_pos_var_per_s", "cmd_pos_var_per_s",
            "theta_var_per_rad", "theta_var_per_m", "theta_var_per_s", "gate_m", "n_sigma",
        ):  # fmt: skip
            _non_negative(name, getattr(self, name))
        _require(
            isinstance(self.reset_after, int)
            and not isinstance(self.reset_after, bool)
            and self.reset_after >= 1,
            f"reset_after must be an integer >= 1, got {self.reset_after!r}",
        )
        _require(
            self.history_s >= max(self.max_dropout_odom_s, self.max_dropout_cmd_s),
            "history_s must be >= max_dropout_odom_s and max_dropout_cmd_s",
        )
        _require(self.history_s >= self.max_latency_s, "history_s must be >= max_latency_s")


@dataclass(frozen=True, slots=True)
class AgentConfig:
    """Everything one robot's firmware needs."""

    geometry: RobotGeometry = field(default_factory=RobotGeometry)
    gains: TrackingGains = field(default_factory=TrackingGains)
    repulsion: RepulsionParams = field(default_factory=RepulsionParams)
    safety: SafetyParams = field(default_factory=SafetyParams)
    estimator: EstimatorParams = field(default_factory=EstimatorParams)

    def __post_init__(self) -> None:
        _require(isinstance(self.geometry, RobotGeometry), "geometry must be a RobotGeometry")
        _require(isinstance(self.gains, TrackingGains), "gains must be a TrackingGains")
        _require(isinstance(self.repulsion, RepulsionParams), "repulsion must be RepulsionParams")
        _require(isinstance(self.safety, SafetyParams), "safety must be a SafetyParams")
        _require(isinstance(self.estimator, EstimatorParams), "estimator must be EstimatorParams")
