"""Parameters of one robot's firmware: geometry, tracking gains, repulsion and safety limits.

Every parameter set is a frozen dataclass with documented, validated defaults (units in the
names). Each parameter is declared once, here: its type and unit (the name), its default and
plausible range (:func:`ranged`) and its meaning (the class docstring's ``Attributes``). The
robot-config loader, the scenario loader and docs/parameters.md all read that declaration.
Validation happens once, at construction, so the control loop never has to re-check a gain: a bad
value raises ``ValueError`` when the configuration is built, not in flight.

Defaults describe a small differential robot (the paper gives no dimensions): 3 cm wheels on a
10 cm track, 0.3 m/s top speed, 7.5 cm body radius, and the paper's tracking gains
(Kp = 0.21, Ti = 105 s, Td = 0.01 s, which place the ideal closed-loop poles at -0.2 and -0.01).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field, replace
from typing import Any, TypeVar, cast

_T = TypeVar("_T")

__all__ = [
    "D0_CLEARANCE_M",
    "DEFAULT_K_REP",
    "AgentConfig",
    "Arena",
    "CircleObstacle",
    "EstimatorParams",
    "RepulsionParams",
    "RobotGeometry",
    "SafetyFilterParams",
    "SafetyParams",
    "SegmentObstacle",
    "TrackingGains",
    "WorldMap",
    "declared_range",
    "derived_d0_m",
    "ranged",
]


def ranged(default: _T, low: float, high: float) -> _T:
    """Declare a parameter: its default and the plausible range ``[low, high]`` that a robot
    config or a scenario file may set (``robot_agent.core.config_tables`` refuses a value outside
    it, so a typo such as ``stale_pose_s = 1e6`` never reaches the wheels). Its meaning is the
    line of its class's docstring; ``python -m scenario.docs`` renders all of them."""
    return cast(_T, field(default=default, metadata={"range": (low, high)}))


def declared_range(cls: type[Any], name: str) -> tuple[float, float] | None:
    """The plausible range a field of parameter dataclass ``cls`` was declared with, or None."""
    for f in dataclasses.fields(cls):
        if f.name == name:
            rng = f.metadata.get("range")
            return None if rng is None else (float(rng[0]), float(rng[1]))
    return None


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


def _finite(name: str, value: float) -> None:
    _require(
        isinstance(value, (int, float)) and math.isfinite(value),
        f"{name} must be finite, got {value!r}",
    )


def _check_fields(
    obj: object,
    *,
    positive: tuple[str, ...] = (),
    non_negative: tuple[str, ...] = (),
    finite: tuple[str, ...] = (),
    flags: tuple[str, ...] = (),
) -> None:
    """The bounds checks of a parameter set, by field name: bools, finite numbers, finite numbers
    > 0, finite numbers >= 0 (in that order). Raises ValueError naming the first bad field."""
    for name in flags:
        value = getattr(obj, name)
        _require(isinstance(value, bool), f"{name} must be a bool, got {value!r}")
    for name in finite:
        _finite(name, getattr(obj, name))
    for name in positive:
        _positive(name, getattr(obj, name))
    for name in non_negative:
        _non_negative(name, getattr(obj, name))


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

    wheel_radius_m: float = ranged(0.03, 0.005, 0.5)
    half_track_m: float = ranged(0.05, 0.01, 1.0)
    max_wheel_radps: float = ranged(10.0, 0.1, 200.0)
    body_radius_m: float = ranged(0.075, 0.01, 1.5)
    ref_offset_m: float = ranged(0.05, 0.001, 1.0)

    def __post_init__(self) -> None:
        _check_fields(
            self,
            positive=(
                "wheel_radius_m", "half_track_m", "max_wheel_radps", "body_radius_m",
                "ref_offset_m",
            ),
        )  # fmt: skip

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
        ti_s: integral time Ti (s); a huge Ti (1e9) switches the integral off.
        td_s: derivative time Td (s).
        d_filter_tau_s: time constant of the first-order low-pass on the error derivative (s);
            0 disables the filter.
        integral_limit_ms: clamp on the magnitude of the error integral I (m*s).
        max_ref_speed_mps: cap on the norm of the commanded reference-point velocity (m/s),
            feed-forward included.
    """

    kp: float = ranged(0.21, 0.0, 50.0)
    ti_s: float = ranged(105.0, 0.001, 1.0e12)  # 1e9: no integral (anchor-triangle)
    td_s: float = ranged(0.01, 0.0, 10.0)
    d_filter_tau_s: float = ranged(0.1, 0.0, 10.0)
    integral_limit_ms: float = ranged(0.5, 0.0, 10.0)
    max_ref_speed_mps: float = ranged(0.25, 0.001, 5.0)

    def __post_init__(self) -> None:
        _check_fields(
            self,
            non_negative=("kp", "td_s", "d_filter_tau_s", "integral_limit_ms"),
            positive=("ti_s", "max_ref_speed_mps"),
        )


# Default repulsion gain. The push at distance d (< d0) is k_rep * (1/d - 1/d0) / d^2. It was
# chosen for about 0.1 m/s when two default robots touch (centre distance d = 2 * 0.075 m =
# 0.15 m) with d0 = 0.30 m: (1/0.15 - 1/0.30) / 0.15^2 = 148.1 m^-3, k_rep = 0.1 / 148.1 =
# 6.75e-4 m^4/s. With the derived d0 = 2 * 0.075 + 0.10 = 0.25 m (see ``derived_d0_m``) the
# push is 0.0 at 0.25 m, 0.08 m/s at 0.15 m (touching) and reaches the 0.20 m/s cap at about
# 0.12 m.
DEFAULT_K_REP = 6.75e-4

_DEFAULT_BODY_RADIUS_M = 0.075  # RobotGeometry's default (a slots dataclass has no class value)

#: Clearance (m) added to two body radii to get the potential field's influence distance d0.
D0_CLEARANCE_M = 0.10


def derived_d0_m(body_radius_m: float) -> float:
    """The potential field's default influence distance: ``2 * body_radius_m + 0.10`` (m).

    Derived from the body, not from the formation spacing, so a formation whose robots are
    spaced at least this far apart is not pushed on (with the 0.075 m default body: 0.25 m,
    below the 0.3 m spacing of the Robotarium task and of the default formations).
    """
    return 2.0 * body_radius_m + D0_CLEARANCE_M


@dataclass(frozen=True, slots=True)
class RepulsionParams:
    """Potential-field (Khatib) repulsion added to the reference-point velocity.

    Attributes:
        k_rep: gain (m^4/s); see ``DEFAULT_K_REP`` for how the default was chosen
            (0.1 m/s at 0.15 m centre distance with d0 = 0.30 m).
        d0_m: influence distance (m); no push at or beyond it. None (the default) means
            derived from the body: ``derived_d0_m(body_radius_m)``, resolved by ``AgentConfig``
            with the robot's geometry (0.25 m for the default 0.075 m body); a
            ``RepulsionParams`` used on its own resolves None with the default body.
        max_speed_mps: cap on the norm of the summed repulsion velocity (m/s).
        enabled: False turns repulsion off (the paper's controller without collision avoidance).
    """

    k_rep: float = ranged(DEFAULT_K_REP, 0.0, 1.0)
    d0_m: float | None = ranged(None, 0.01, 5.0)
    max_speed_mps: float = ranged(0.20, 0.0, 5.0)
    enabled: bool = True

    def __post_init__(self) -> None:
        _non_negative("k_rep", self.k_rep)
        if self.d0_m is not None:
            _positive("d0_m", self.d0_m)
        _non_negative("max_speed_mps", self.max_speed_mps)
        _require(isinstance(self.enabled, bool), f"enabled must be a bool, got {self.enabled!r}")

    @property
    def influence_m(self) -> float:
        """``d0_m``, or the value derived from the default body when it is None (m)."""
        return self.d0_m if self.d0_m is not None else derived_d0_m(_DEFAULT_BODY_RADIUS_M)

    def speed_at(self, d_m: float) -> float:
        """Magnitude (m/s) of the uncapped push from one neighbour at distance ``d_m`` > 0."""
        d0 = self.influence_m
        if d_m >= d0:
            return 0.0
        return self.k_rep * (1.0 / d_m - 1.0 / d0) / (d_m * d_m)


@dataclass(frozen=True, slots=True)
class SafetyParams:
    """Staleness limits of the firmware's input data (local receive-clock ages, s).

    Attributes:
        stale_pose_s: a pose received longer ago than this puts the robot in HOLD (s).
        stale_setpoint_s: a setpoint received longer ago than this puts the robot in HOLD (s).
        max_dt_s: a gap between two ``step`` calls longer than this is a stalled loop: the
            controller skips integration on that tick and restarts its derivative (s).
    """

    stale_pose_s: float = ranged(0.2, 0.01, 5.0)
    stale_setpoint_s: float = ranged(0.2, 0.01, 5.0)
    max_dt_s: float = ranged(0.2, 0.001, 5.0)

    def __post_init__(self) -> None:
        _check_fields(self, positive=("stale_pose_s", "stale_setpoint_s", "max_dt_s"))


@dataclass(frozen=True, slots=True)
class SafetyFilterParams:
    """The barrier-certificate safety filter (``robot_agent.core.safety_filter``), last before eq
    16.

    Attributes:
        enabled: False passes the command through unchanged (the paper's controller).
        margin_m: safety distance between two robots' centres is ``Ds = 2 * body_radius_m +
            margin_m`` (0.19 m with the defaults); a robot's centre keeps ``body_radius_m +
            margin_m`` from an obstacle's surface and from the arena's walls. The margin
            absorbs what the proof leaves out: camera noise on two positions
            (``noise_budget_m`` each, 3 sigma of 3 mm: 2 x 9 mm in the worst case, 13 mm in
            quadrature), one tick of motion (0.3 m/s x 33 ms: 10 mm), the heading change
            within a tick (about 1 mm) and a residual of latency: 0.04 m. Bodies touch at
            ``2 * body_radius_m``; the tests check that is never reached.
        noise_budget_m: the part of ``margin_m`` that pays for ONE position's measurement noise
            (m; 3 sigma of the camera's 3 mm per axis: 9 mm). The margin holds it for each of
            the two positions of a pair, so ``2 * noise_budget_m <= margin_m``. An uncertainty
            radius handed to the filter (this robot's estimate uncertainty or
            ``extra_radius_m``, a neighbour's ``radius_m``) inflates a barrier only by its
            excess over this budget: the noise it stands for is already in the margin. The true
            centres then keep at least ``2 * body_radius_m + margin_m - 2 * noise_budget_m``
            (proof: ``safety_filter.py``, "Noise model").
        gamma_per_s: barrier gain gamma (1/s): ``dh/dt >= -gamma * h``; the robot may approach a
            boundary no faster than gamma times its remaining clearance. The filter uses
            ``min(gamma, 1 / dt)`` with the tick's ``dt`` (``1 / max_dt_s`` when unknown) so
            ``gamma * dt <= 1`` holds: the discrete-time guarantee.
        neighbour_speed_mps: how fast a neighbour can move (m/s), to inflate a position of age
            ``a`` by ``neighbour_speed_mps * a``; 0 means this robot's own top speed
            (``RobotGeometry.max_speed_mps``).
        max_age_s: cap on the age used to inflate a neighbour position (s): an older position
            is still kept (a robot that stopped reporting is an obstacle where last seen), but
            its inflation stops growing, so an ancient entry cannot cover the arena.
        stuck_time_s: a robot near a boundary whose tracking error (above ``stuck_error_m``)
            has not shrunk by ``stuck_speed_mps * stuck_time_s`` within this time is
            deadlocked (s).
        stuck_speed_mps: mean progress rate below which the robot counts as stuck (m/s).
        stuck_error_m: tracking errors below this never count as a deadlock (m).
        tiebreak_time_s: how long a tie-break lasts once triggered (s).
        tiebreak_angle_rad: the tie-break steers this far to the right of the direction to the
            setpoint (rad, in (0, pi/2]); deterministic "pass on the right".
        tiebreak_speed_mps: the speed of the tie-break command when the nominal one is slower
            (m/s).
        shared_frame: every robot gets each camera frame at the same control tick (the
            in-process simulator and lockstep; NOT realtime, where two robots can be on
            different frames: the realtime shells force it off). Then a cooperative neighbour
            measured in the same frame as this robot's own latest camera pose is kept apart by
            the frame's separating plane (``safety_plane.py``) instead of
            the reciprocal barrier inflated by ``neighbour_speed_mps * age``: each robot answers
            for its own motion since the frame, so the neighbour's speed and the frame's age
            cost nothing.
        convoy_share: how much of a shared-frame pair's gap goes to the robot behind in a convoy
            (in [0, 0.5]; 0 = half each): the split is ``1/2 +- convoy_share * (c_i - c_j) *
            g``, ``c`` how much each robot heads toward the other, ``g`` in [0, 1] how parallel
            their headings are (0 beyond ``convoy_angle_rad``). Any split is safe (both robots
            compute it from the same frame); this one lets a follower close on a leader that
            drives away.
        convoy_angle_rad: headings further apart than this get equal halves (rad, in (0, pi/2]).
        convoy_gain: the side of a shared-frame pair holding all of the split gap closes on it
            at this many times ``gamma_per_s`` (linearly from 1 at an even split; always capped
            at ``1 / dt``, the discrete-time bound): >= 1.
        convoy_gap_m: only this much of a pair's gap is split unevenly; the rest is halved, so
            a far neighbour stays out of range (m).
        frame_max_age_s: the shared-frame plane is used for frames at most this old (s); an
            older frame falls back to the inflated reciprocal barrier (both robots of a pair
            see the same age, so both fall back together).
        accel_bound_mps2: the motion bound this robot enforces and publishes (m/s^2; 0: none,
            the default): its firmware changes the body twist ``(v, l omega)`` of its wheel
            command by at most this times the elapsed time, in every mode (an e-stop ramps
            down), and each command is published with its reference-point velocity (a motion
            claim, ``robot_agent.core.neighbour_motion``). A neighbour with a fresh, sane claim
            is extrapolated with the claimed velocity and inflated by what the bound lets it
            deviate (about ``0.5 A a^2``) instead of ``neighbour_speed_mps * a``.
        claim_max_age_s: a neighbour's newest motion claim older than this (s, local clock),
            or none at all, means the worst case (``neighbour_speed_mps * a``).
    """

    enabled: bool = True
    margin_m: float = ranged(0.04, 0.0, 1.0)
    noise_budget_m: float = ranged(0.009, 0.0, 0.5)
    gamma_per_s: float = ranged(10.0, 0.01, 1000.0)
    neighbour_speed_mps: float = ranged(0.0, 0.0, 5.0)
    max_age_s: float = ranged(0.5, 0.01, 10.0)
    stuck_time_s: float = ranged(1.0, 0.01, 60.0)
    stuck_speed_mps: float = ranged(0.02, 0.0, 5.0)
    stuck_error_m: float = ranged(0.05, 0.0, 5.0)
    tiebreak_time_s: float = ranged(3.0, 0.0, 60.0)
    tiebreak_angle_rad: float = ranged(1.0, 0.0, math.pi)
    tiebreak_speed_mps: float = ranged(0.1, 0.0, 5.0)
    shared_frame: bool = False
    convoy_share: float = ranged(0.5, 0.0, 0.5)
    convoy_angle_rad: float = ranged(0.7854, 0.01, math.pi / 2)
    convoy_gain: float = ranged(2.5, 1.0, 10.0)
    convoy_gap_m: float = ranged(0.05, 0.0, 0.5)
    frame_max_age_s: float = ranged(0.1, 0.0, 0.5)
    accel_bound_mps2: float = ranged(0.0, 0.0, 100.0)
    claim_max_age_s: float = ranged(0.25, 0.0, 1.0)

    def __post_init__(self) -> None:
        _require(isinstance(self.enabled, bool), f"enabled must be a bool, got {self.enabled!r}")
        _require(
            isinstance(self.shared_frame, bool),
            f"shared_frame must be a bool, got {self.shared_frame!r}",
        )
        _non_negative("convoy_share", self.convoy_share)
        _require(self.convoy_share <= 0.5, "convoy_share must be <= 0.5")
        _positive("convoy_angle_rad", self.convoy_angle_rad)
        _require(self.convoy_angle_rad <= math.pi / 2, "convoy_angle_rad must be <= pi/2")
        _non_negative("convoy_gap_m", self.convoy_gap_m)
        _positive("convoy_gain", self.convoy_gain)
        _require(self.convoy_gain >= 1.0, "convoy_gain must be >= 1")
        _non_negative("frame_max_age_s", self.frame_max_age_s)
        _non_negative("accel_bound_mps2", self.accel_bound_mps2)
        _non_negative("claim_max_age_s", self.claim_max_age_s)
        _non_negative("margin_m", self.margin_m)
        _non_negative("noise_budget_m", self.noise_budget_m)
        _require(
            2.0 * self.noise_budget_m <= self.margin_m,
            f"noise_budget_m ({self.noise_budget_m}) must be at most half of margin_m "
            f"({self.margin_m}): the margin pays for the noise of both positions of a pair",
        )
        _positive("gamma_per_s", self.gamma_per_s)
        _non_negative("neighbour_speed_mps", self.neighbour_speed_mps)
        _non_negative("max_age_s", self.max_age_s)
        _positive("stuck_time_s", self.stuck_time_s)
        _non_negative("stuck_speed_mps", self.stuck_speed_mps)
        _non_negative("stuck_error_m", self.stuck_error_m)
        _positive("tiebreak_time_s", self.tiebreak_time_s)
        _positive("tiebreak_angle_rad", self.tiebreak_angle_rad)
        _require(self.tiebreak_angle_rad <= math.pi / 2, "tiebreak_angle_rad must be <= pi/2")
        _non_negative("tiebreak_speed_mps", self.tiebreak_speed_mps)


@dataclass(frozen=True, slots=True)
class CircleObstacle:
    """A static disc the robot must keep clear of: centre ``(x, y)`` and ``radius_m`` (m)."""

    x: float
    y: float
    radius_m: float

    def __post_init__(self) -> None:
        _check_fields(self, finite=("x", "y"), non_negative=("radius_m",))


@dataclass(frozen=True, slots=True)
class SegmentObstacle:
    """A static wall: the segment from ``(x1, y1)`` to ``(x2, y2)`` (m), ``radius_m`` thick on
    each side (0 = a thin wall). A polygon is given as its edges (see ``robot_config``)."""

    x1: float
    y1: float
    x2: float
    y2: float
    radius_m: float = 0.0

    def __post_init__(self) -> None:
        _check_fields(self, finite=("x1", "y1", "x2", "y2"), non_negative=("radius_m",))


@dataclass(frozen=True, slots=True)
class Arena:
    """The rectangle the robot's whole body must stay inside (m)."""

    x_min: float
    y_min: float
    x_max: float
    y_max: float

    def __post_init__(self) -> None:
        _check_fields(self, finite=("x_min", "y_min", "x_max", "y_max"))
        _require(self.x_min < self.x_max, "arena x_min must be < x_max")
        _require(self.y_min < self.y_max, "arena y_min must be < y_max")


@dataclass(frozen=True, slots=True)
class WorldMap:
    """What the firmware knows of the world: static obstacles and the arena (None = none)."""

    obstacles: tuple[CircleObstacle | SegmentObstacle, ...] = ()
    arena: Arena | None = None

    def __post_init__(self) -> None:
        _require(isinstance(self.obstacles, tuple), "obstacles must be a tuple")
        for o in self.obstacles:
            _require(
                isinstance(o, (CircleObstacle, SegmentObstacle)),
                f"obstacle must be a CircleObstacle or SegmentObstacle, got {o!r}",
            )
        _require(self.arena is None or isinstance(self.arena, Arena), "arena must be an Arena")


@dataclass(frozen=True, slots=True)
class EstimatorParams:
    """Pose estimator (``robot_agent.core.estimator``) and setpoint extrapolation.

    Variances grow per metre travelled, per radian turned and per second while the estimate is
    predicted from wheel speeds; a camera pose shrinks them (scalar Kalman gain per axis). See
    the model in ``robot_agent/core/estimator.py`` and the defaults in docs/defaults.md.

    Attributes:
        enabled: False gives the firmware of before the estimator: the last measured pose is
            used as if current and a pose older than ``SafetyParams.stale_pose_s`` (receive age)
            holds the robot. True: the estimate at ``now`` is used and the robot rides through
            camera dropouts up to the bounds below. On by default (docs/benchmarks.md,
            "Issue 16": the firmware step costs ~2x with it, ~17 us against ~8 us on the shared
            bench machine, the < 10 us goal is not met). The firmware tests cover both rules
            (tests/unit/robot_agent/test_agent_firmware.py,
            tests/unit/robot_agent/test_agent_firmware_inputs.py).
        extrapolate_setpoint: advance a setpoint by its feed-forward velocity over its receive
            age (one tick in lockstep), so a one-tick-old setpoint leaves no steady lag.
        setpoint_lead_s: with ``extrapolate_setpoint``, advance it by this much more (s): the
            actuation lag (command link latency + motor time constant + one tick), so the
            command aims where the slot will be when the wheels follow it. 0 = none.
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

    enabled: bool = True
    extrapolate_setpoint: bool = True
    setpoint_lead_s: float = ranged(0.0, 0.0, 1.0)
    history_s: float = ranged(1.5, 0.01, 60.0)
    max_dropout_odom_s: float = ranged(1.5, 0.0, 60.0)
    max_dropout_cmd_s: float = ranged(0.3, 0.0, 60.0)
    odom_timeout_s: float = ranged(0.1, 0.001, 10.0)
    max_latency_s: float = ranged(0.5, 0.0, 10.0)
    future_tolerance_s: float = ranged(0.005, 0.0, 1.0)
    actuation_delay_s: float = ranged(0.0, 0.0, 1.0)
    meas_pos_std_m: float = ranged(0.003, 0.0, 1.0)
    meas_theta_std_rad: float = ranged(0.01, 0.0, math.pi)
    odom_pos_var_per_m: float = ranged(1.0e-4, 0.0, 1.0)
    cmd_pos_var_per_m: float = ranged(4.0e-4, 0.0, 1.0)
    odom_pos_var_per_s: float = ranged(1.0e-6, 0.0, 1.0)
    cmd_pos_var_per_s: float = ranged(1.0e-5, 0.0, 1.0)
    theta_var_per_rad: float = ranged(4.0e-4, 0.0, 1.0)
    theta_var_per_m: float = ranged(1.0e-3, 0.0, 1.0)
    theta_var_per_s: float = ranged(1.0e-6, 0.0, 1.0)
    gate_m: float = ranged(0.2, 0.0, 10.0)
    reset_after: int = ranged(3, 1, 1000)
    n_sigma: float = ranged(3.0, 0.1, 100.0)
    max_uncertainty_m: float = ranged(0.1, 0.0, 10.0)

    def __post_init__(self) -> None:
        for name in ("enabled", "extrapolate_setpoint"):
            value = getattr(self, name)
            _require(isinstance(value, bool), f"{name} must be a bool, got {value!r}")
        for name in ("history_s", "max_dropout_odom_s", "max_dropout_cmd_s", "odom_timeout_s",
                     "max_latency_s", "max_uncertainty_m"):  # fmt: skip
            _positive(name, getattr(self, name))
        for name in (
            "future_tolerance_s", "actuation_delay_s", "setpoint_lead_s", "meas_pos_std_m",
            "meas_theta_std_rad",
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
    """Everything one robot's firmware needs.

    A ``repulsion.d0_m`` of None is resolved here to ``derived_d0_m(geometry.body_radius_m)``.
    """

    geometry: RobotGeometry = field(default_factory=RobotGeometry)
    gains: TrackingGains = field(default_factory=TrackingGains)
    repulsion: RepulsionParams = field(default_factory=RepulsionParams)
    safety: SafetyParams = field(default_factory=SafetyParams)
    safety_filter: SafetyFilterParams = field(default_factory=SafetyFilterParams)
    world: WorldMap = field(default_factory=WorldMap)
    estimator: EstimatorParams = field(default_factory=EstimatorParams)

    def __post_init__(self) -> None:
        _require(isinstance(self.geometry, RobotGeometry), "geometry must be a RobotGeometry")
        _require(isinstance(self.gains, TrackingGains), "gains must be a TrackingGains")
        _require(isinstance(self.repulsion, RepulsionParams), "repulsion must be RepulsionParams")
        _require(isinstance(self.safety, SafetyParams), "safety must be a SafetyParams")
        _require(
            isinstance(self.safety_filter, SafetyFilterParams),
            "safety_filter must be SafetyFilterParams",
        )
        _require(isinstance(self.world, WorldMap), "world must be a WorldMap")
        _require(isinstance(self.estimator, EstimatorParams), "estimator must be EstimatorParams")
        if self.repulsion.d0_m is None:
            object.__setattr__(
                self,
                "repulsion",
                replace(self.repulsion, d0_m=derived_d0_m(self.geometry.body_radius_m)),
            )

    @property
    def safety_distance_m(self) -> float:
        """Ds: the least centre distance the filter keeps between two robots (m)."""
        return 2.0 * self.geometry.body_radius_m + self.safety_filter.margin_m

    def realtime(self) -> AgentConfig:
        """This config as a realtime shell runs it: ``safety_filter.shared_frame`` off (in
        realtime two robots can be on different camera frames at the same moment, and the
        shared-frame plane needs them on the same one; ``safety_filter.py``)."""
        if not self.safety_filter.shared_frame:
            return self
        return replace(self, safety_filter=replace(self.safety_filter, shared_frame=False))
