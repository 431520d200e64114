"""Firmware of one robot: a table-driven mode machine around the reference-point controller.

Theory of operation
===================

The shell (I/O) calls ``Firmware.step(now_s, pose=..., setpoint=..., ...)`` once per control
tick with the latest pose (axle centre, from localization), the latest setpoint (where the
robot's *reference point* should be, with its velocity as feed-forward), the local receive time
of each, and the other robots' axle-centre positions. ``step`` returns one ``WheelCommand``. The
core reads no clock: ``now_s`` and the ``*_rx_s`` stamps come from the shell's one local clock,
so staleness never compares two hosts' clocks, and ``dt_s`` is the difference of successive
``now_s``.

``Firmware`` builds and owns its parts, each with its own state: the ``Estimator``, the
``TrackingController``, the ``SafetyFilter``, the ``ModeMachine`` (modes, events, the
transition table and the on-entry actions: ``firmware_modes.py``) and the ``Rejections``
counter (``firmware_rejects.py``); the data of a tick are in ``firmware_types.py``. This module
holds the tick, its stages and the public accessors.
In TRACKING the controller can still fail (overflow from absurd but finite input): that tick
outputs zero and goes to HOLD like an INVALID event. Any exception inside ``step`` is caught,
counted as a rejection and gives a zero command in HOLD (or ESTOP): ``step`` never raises.

Estimator (``config.estimator.enabled``, on by default; ``robot_agent/core/estimator.py``): every
tick, in any mode, a new ``Pose`` object (each object once) is fused at its capture time
``pose_capture_s`` (the shell's clock; ``pose_rx_s`` when not given) and the encoder speeds
``wheel_speeds`` (mean over the interval since the previous tick) extend the odometry; the
wheels commanded on a tick are the prediction's input from that tick on when no encoder speeds
replace them. The pose the controller uses is the estimate at ``now_s``; an invalid estimate
(no pose yet, the camera lost beyond the dropout bound, too uncertain) is a STALE event (HOLD)
and replaces the ``stale_pose_s`` rule. A rejected pose is counted and the estimate rides on.
``pose_uncertainty_m`` is the estimate's uncertainty (m); the safety filter adds it (or the
shell's ``extra_radius_m`` if larger) to the robot's radius on the same tick.

Setpoint extrapolation (``config.estimator.extrapolate_setpoint``, on by default): the setpoint
is advanced by its feed-forward velocity over its receive age ``now_s - setpoint_rx_s`` (one
tick in lockstep, where the setpoint of tick k-1 is used at tick k), so a one-tick-old setpoint
leaves no steady lag; and by ``setpoint_lead_s`` more (default 0), the actuation lag (command
link + motor time constant + one tick): the command computed now moves the robot that much
later, so it aims where the slot will be then.

Pipeline in TRACKING (one tick); ``step`` calls these stages in this order::

    1. estimate           _estimate: Estimator.tick (odometry, camera pose, pose at now_s)
    2. inputs             _setpoint_now: setpoint + ff * age; _pose_estimated /
                          _pose_measured: the pose at now_s (or HOLD / IDLE)
    3. reference point    kinematics.reference_point (eqs 10-11); the error
                          e = p_setpoint - p_r (eqs 17-18)
    4. tracking           TrackingController.update: PID + feed-forward per axis (eqs 21-22),
                          cap on |commanded speed|
    5. repulsion          repulsion_raw: from neighbours / obstacles, evaluated at the axle
                          centre (the paper's potential field), added
    6. safety filter      SafetyFilter.filter: barrier certificate on the reference-point
                          velocity (keeps Ds to neighbours, clear of obstacles, inside the
                          arena; the last Cartesian stage)
    7. eq 16              kinematics.twist_from_ref_velocity: to (v, omega)
    8. wheel map (eq 8)   kinematics.wheels_from_twist_raw
    9. saturation         _saturate: keeping the turn (or one factor on both wheels if keeping
                          the turn would leave the filter's constraints); then
                          power = omega / max_wheel_radps in [-1, 1]

Each stage calls the one implementation of its math (kinematics, tracker, repulsion, filter),
so the composition test of tests/unit/robot_agent/test_agent_firmware.py holds by construction;
the one copy is eq 7 in ``_estimate`` (the encoder speeds' twist, the same operations as
``kinematics.twist_from_wheels_raw``: a Python call less per tick for the pure-Python core).

The integrators are frozen (may only shrink) on a tick after one whose wheels saturated: the
PID cannot see this tick's saturation before it has computed this tick's command (the usual
one-tick-lag anti-windup of a cascaded loop). A change of the setpoint's slot (a role
change) resets the PID: the old integral and derivative belong to another target.

Time: the first tick has no dt; ``dt_s <= 0`` (duplicate or backwards ``now_s``) or
``dt_s > safety.max_dt_s`` (a stalled loop) integrates nothing and restarts the derivative; the
command is then P + stored I + FF.

Counting: ``rejected_count`` counts bad inputs. A rejected ``Pose`` / ``Setpoint`` object is
counted once however many ticks the shell presents it again (identity); non-finite scalar
arguments and neighbour entries are counted on every tick they appear; ``reject(reason)`` lets
the shell add messages it dropped while decoding to the same counter.

Types: ``step`` validates its arguments instead of trusting their annotations (``float |
object``, ...: the firmware core is also compiled with mypyc, whose typed parameters would raise
TypeError at the call, outside the tick's ``try``). A real number of another type than float
(int, a numpy scalar, a Fraction) is used as its float value; a pose or setpoint may be any
sequence of its fields; anything else (None, a string) raises inside the tick and is counted like
any bad input (``internal error: TypeError``), in pure Python and compiled alike.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Sequence
from typing import Any, Final

from robot_agent.core.estimator import Estimator
from robot_agent.core.firmware_modes import (
    _ESTOP,
    _EV_ESTOP,
    _EV_FRESH,
    _EV_INVALID,
    _EV_NO_SETPOINT,
    _EV_STALE,
    _TRACKING,
    Mode,
    ModeMachine,
    _Event,
)
from robot_agent.core.firmware_rejects import Rejections
from robot_agent.core.firmware_types import (
    _NAN,
    FirmwareStatus,
    Pose,
    Setpoint,
    WheelCommand,
    _new_command,
    _tuple_new,
)

from .kinematics import (
    ref_point_velocity,
    reference_point,
    saturate_wheels,
    twist_from_ref_velocity,
    twist_from_wheels_raw,
    wheels_from_twist_raw,
)
from .neighbour_index import NeighbourView
from .neighbour_motion import Claim, MotionLimiter
from .neighbour_select import SELECT_MIN_ENTRIES as SELECT_MIN_ENTRIES
from .neighbour_select import near_entries, select_min_entries
from .params import AgentConfig
from .repulsion import repulsion_raw
from .safety_filter import Neighbour, SafetyFilter
from .tracking import TrackingController

__all__ = [
    "Firmware",
    "FirmwareStatus",
    "Mode",
    "Pose",
    "Setpoint",
    "WheelCommand",
]

_isfinite: Final = math.isfinite
_NEG_INF: Final = -math.inf
#: ``Firmware._setpoint_now``'s answer when the tick holds (no valid setpoint): age NaN (not
#: Final: mypyc cannot tell a Final tuple of NaNs from an unset one, a NameError)
_NO_SETPOINT = (_NAN, _NAN, _NAN, _NAN, _NAN)


def _real(value: object) -> float:
    """``value`` as a float if it is a real number (``numbers.Real``: an int, a bool, a float
    subclass such as numpy.float64, a numpy integer, a Fraction); else TypeError. The step's
    fast path takes a float as it is; this is the rest (the same in pure Python and compiled)."""
    if isinstance(value, (float, int, numbers.Real)):
        return float(value)
    raise TypeError(f"a real number expected, got {type(value).__name__}")


class Firmware:
    """One robot's controller: call ``step`` once per tick (see the module docstring). It
    builds and owns its parts: the estimator, the tracking controller, the safety filter, the
    mode machine (over the tracker and the filter) and the rejection counter."""

    __slots__ = (
        "_act_delay",
        "_cfg",
        "_dt_faults",
        "_est",
        "_est_xyt",
        "_ex",
        "_extrap",
        "_ey",
        "_filter",
        "_filter_on",
        "_fused_pose",
        "_geom",
        "_half_r",
        "_half_track",
        "_have_setpoint",
        "_l",
        "_last_now",
        "_last_pose_t",
        "_last_saturated",
        "_lead",
        "_limiter",
        "_max_dt",
        "_modes",
        "_pend_t",
        "_pend_wl",
        "_pend_wr",
        "_pose_age",
        "_rejects",
        "_rep",
        "_rep_cap",
        "_rep_d0",
        "_rep_inv_d0",
        "_rep_k",
        "_rep_on",
        "_role_changes",
        "_saturated",
        "_select_min",
        "_select_on",
        "_setpoint_age",
        "_shared_frame",
        "_slot",
        "_stale_pose",
        "_stale_sp",
        "_steps",
        "_tracker",
        "_unc",
        "_wheel_r",
        "_wmax",
        "_wmax_neg",
        "_xyt_seen",
    )

    def __init__(self, config: AgentConfig | None = None) -> None:
        cfg = config if config is not None else AgentConfig()
        if not isinstance(cfg, AgentConfig):
            raise TypeError(f"config must be an AgentConfig, got {type(cfg).__name__}")
        self._cfg = cfg
        self._geom = cfg.geometry
        self._half_track = cfg.geometry.half_track_m
        self._wheel_r = cfg.geometry.wheel_radius_m
        self._half_r = 0.5 * self._wheel_r  # eq 7's 0.5 * r (the same bits as inline)
        self._l = cfg.geometry.ref_offset_m
        self._wmax = cfg.geometry.max_wheel_radps
        self._wmax_neg = -self._wmax  # (the tick's range test without a negation)
        self._rep = cfg.repulsion
        self._rep_on = cfg.repulsion.enabled
        # the repulsion parameters read once (repulsion_raw, the per-tick call)
        self._rep_k = cfg.repulsion.k_rep
        self._rep_d0 = cfg.repulsion.influence_m
        self._rep_inv_d0 = 1.0 / self._rep_d0
        self._rep_cap = cfg.repulsion.max_speed_mps
        self._stale_pose = cfg.safety.stale_pose_s
        self._stale_sp = cfg.safety.stale_setpoint_s
        self._max_dt = cfg.safety.max_dt_s
        self._tracker = TrackingController(cfg.gains)
        self._filter = SafetyFilter(cfg)
        self._filter_on = self._filter.enabled
        self._shared_frame = self._filter.enabled and cfg.safety_filter.shared_frame
        # the far neighbours dropped once per tick (neighbour_select), not with the
        # shared-frame plane (its bound may be larger than the one the selection uses)
        self._select_on = (self._rep_on or self._filter_on) and not self._shared_frame
        self._select_min = select_min_entries()
        self._modes = ModeMachine(self._tracker, self._filter)
        self._rejects = Rejections()
        self._have_setpoint = False
        self._slot: int | None = None
        self._last_now: float | None = None
        self._last_pose_t: float | None = None
        self._last_saturated = False
        self._ex = _NAN
        self._ey = _NAN
        self._pose_age = _NAN
        self._setpoint_age = _NAN
        self._steps = 0
        self._saturated = 0
        self._role_changes = 0
        self._dt_faults = 0
        ep = cfg.estimator
        self._est: Estimator | None = Estimator(ep) if ep.enabled else None
        self._extrap = ep.extrapolate_setpoint
        self._act_delay = ep.actuation_delay_s
        self._lead = ep.setpoint_lead_s
        self._fused_pose: object = None  # the last pose object fused (identity only)
        # the last command (from _pend_t on: omega_r, omega_l), handed to the estimator on the
        # next tick unless encoder speeds replace it (it only matters for times after that
        # tick); _pend_t NaN: none (three attributes, not a tuple: compiled, three unboxed
        # floats instead of four objects a tick)
        self._pend_t = _NAN
        self._pend_wr = 0.0
        self._pend_wl = 0.0
        self._unc = _NAN
        # the pose (first three fields: x, y, theta) the last tick used: a Pose or an estimate
        self._est_xyt: tuple[float, ...] | None = None
        if self._est is None:
            self._unc = 0.0
        # stage 10, the motion bound (robot_agent.core.neighbour_motion): every tick, any mode
        self._limiter: MotionLimiter | None = MotionLimiter.of(cfg)
        self._xyt_seen: object = None  # (identity only: the pose the limiter last took theta of)

    def step(
        self,
        now_s: float | object,
        *,
        pose: Pose | object | None,
        pose_rx_s: float | object,
        setpoint: Setpoint | object | None,
        setpoint_rx_s: float | object,
        neighbours: Sequence[tuple[float, float] | Neighbour] | NeighbourView = (),
        obstacles: Sequence[tuple[float, float, float]] = (),
        extra_radius_m: float | object = 0.0,
        pose_capture_s: float | object | None = None,
        wheel_speeds: tuple[float, float] | object | None = None,
    ) -> WheelCommand:
        """Run one control tick.

        Args:
            now_s: the shell's clock now (s), same clock as the ``*_rx_s``.
            pose: latest pose of this robot's axle centre, or None if none yet.
            pose_rx_s: local time the pose was received (s); ignored when ``pose`` is None.
            setpoint: latest setpoint for this robot, or None (none yet / unassigned).
            setpoint_rx_s: local time the setpoint was received (s).
            neighbours: other robots' axle-centre positions (m), for repulsion and the safety
                filter: ``(x, y)`` tuples (a fresh position of a robot treated as an obstacle)
                or ``safety_filter.Neighbour``s (with heading, age, velocity, cooperative); or a
                ``neighbour_index.NeighbourView``, a list over the in-process fleet's grid.
            obstacles: circles ``(x, y, radius_m)`` (m), for repulsion and the safety filter
                (on top of the configured ``AgentConfig.world``).
            extra_radius_m: extra position uncertainty (m) of this robot, which the safety
                filter adds to every clearance; with the estimator the firmware uses at least
                this tick's ``pose_uncertainty_m`` on its own, so shells pass nothing.
            pose_capture_s: capture time of ``pose`` on the shell's clock (s), for latency
                compensation; None takes ``pose_rx_s`` (no latency known). Used only with the
                estimator. In lockstep and in-process ``pose.t`` is on that clock.
            wheel_speeds: ``(omega_r, omega_l)`` (rad/s) the encoders measured, mean over the
                interval since the previous ``step``; None when the motor backend has no
                encoders (the estimator then predicts from the commanded speeds).

        Returns:
            The wheel command. In IDLE and HOLD the wheels are zero unless the safety filter
            must move the robot out of the way (``_evade``: zero nominal command); in ESTOP,
            without a pose and with the filter disabled exactly zero; with a motion bound
            (``safety_filter.accel_bound_mps2``) every one of these ramps to its value at that
            bound (stage 10). Never raises.
        """
        cmd = self._pipeline(now_s, pose, pose_rx_s, setpoint, setpoint_rx_s, neighbours,
                             obstacles, extra_radius_m, pose_capture_s, wheel_speeds)  # fmt: skip
        if self._limiter is None:
            return cmd
        return self._bound(self._limiter, cmd)

    def step_positional(
        self,
        now_s: float | object,
        pose: Pose | object | None,
        pose_rx_s: float | object,
        setpoint: Setpoint | object | None,
        setpoint_rx_s: float | object,
        neighbours: Sequence[tuple[float, float] | Neighbour] | NeighbourView,
        pose_capture_s: float | object | None,
        wheel_speeds: tuple[float, float] | object | None,
    ) -> WheelCommand:
        """:meth:`step` with every argument by position and no obstacles or extra radius: the
        same tick, for a caller in another compiled group (the in-process loop), where parsing
        ``step``'s keyword arguments costs more than the call (about 4k instructions).

        ``step(now_s, pose=p, pose_rx_s=r, setpoint=s, setpoint_rx_s=sr, neighbours=nb,
        pose_capture_s=c, wheel_speeds=w)`` is ``step_positional(now_s, p, r, s, sr, nb, c, w)``.
        """
        cmd = self._pipeline(now_s, pose, pose_rx_s, setpoint, setpoint_rx_s, neighbours,
                             (), 0.0, pose_capture_s, wheel_speeds)  # fmt: skip
        if self._limiter is None:
            return cmd
        return self._bound(self._limiter, cmd)

    def _pipeline(  # noqa: PLR0915 (the paper's pipeline, stage by stage, in one place)
        self,
        now_s: float | object,
        pose: Pose | object | None,
        pose_rx_s: float | object,
        setpoint: Setpoint | object | None,
        setpoint_rx_s: float | object,
        neighbours: Sequence[tuple[float, float] | Neighbour] | NeighbourView,
        obstacles: Sequence[tuple[float, float, float]],
        extra_radius_m: float | object,
        pose_capture_s: float | object | None,
        wheel_speeds: tuple[float, float] | object | None,
    ) -> WheelCommand:
        """Stages 1-9 of one tick (``step``'s arguments and result, without the bound)."""
        self._steps += 1
        # The whole tick runs inside one try (zero-cost in CPython 3.11 unless it raises): a
        # firmware loop must not die, it stops the wheels instead. The arguments are outside
        # data, validated where a stage uses them, not trusted to their annotations (compiled
        # with mypyc, a typed parameter would raise TypeError before this try): a number is a
        # float, or converted by _real (int, numpy.float64, ...); anything else raises
        # TypeError, which the except below counts as a rejection. An argument the tick ignores
        # (pose_rx_s without a pose) may be anything. An input stage that answers "hold" (None,
        # or the setpoint's NaN age) has put the firmware in HOLD / IDLE (``_stop``): the
        # tick's wheels are zero.
        try:
            now = now_s if type(now_s) is float else _real(now_s)
            # (finite: x - x is 0.0 for a finite x only; the test without a call, as below)
            if now - now != 0.0:
                self._rejects.add("non-finite now_s")
                return self._hold(_EV_INVALID, "non-finite clock")
            # time: dt_s is 0.0 on the first tick and on a duplicate, backwards or stalled one
            # (counted in dt_faults; the derivative restarts, nothing integrates)
            last = self._last_now
            self._last_now = now
            dt = 0.0
            if last is not None:
                dt = now - last
                if not 0.0 < dt <= self._max_dt:
                    self._dt_faults += 1
                    self._tracker.reset_derivative()
                    dt = 0.0
            # 1. estimate: the pose at now_s (in every mode, so the estimate stays current)
            est = self._est
            got: tuple[float, float, float, float] | None = None
            if est is not None:
                got = self._estimate(est, now, last, pose, pose_rx_s, pose_capture_s, wheel_speeds)
            modes = self._modes
            if modes.mode is _ESTOP:
                return self._hold(_EV_ESTOP, "estop")
            # 2. inputs: the setpoint advanced to now_s, the pose at now_s, both fresh
            spx, spy, spvx, spvy, sp_age = self._setpoint_now(now, setpoint, setpoint_rx_s)
            if sp_age != sp_age:  # NaN: no valid setpoint (IDLE, or HOLD): evade only
                if est is None:
                    got = self._pose_quiet(now, pose, pose_rx_s)
                return self._evade(now, dt, got, neighbours, obstacles, extra_radius_m)
            if est is None:
                xytu = self._pose_measured(now, pose, pose_rx_s)
            else:
                xytu = self._pose_estimated(est, now, pose, pose_rx_s, got)
            if xytu is None:
                return self._zero(self._last_pose_t)
            lim = self._stale_sp
            if not -lim <= sp_age <= lim:
                self._stop(_EV_STALE, "setpoint stale")
                return self._evade(now, dt, xytu, neighbours, obstacles, extra_radius_m)
            if modes.mode is not _TRACKING:
                self._apply(_EV_FRESH, "tracking")
            x, y, th, unc = xytu
            # 3. reference point (eqs 10-11) and the error e = p_setpoint - p_r (eqs 17-18)
            l_m = self._l
            rx, ry = reference_point(x, y, th, l_m)
            ex = spx - rx
            ey = spy - ry
            self._ex = ex
            self._ey = ey
            # 4. tracking: PID + feed-forward per axis, then the speed cap (eqs 21-22)
            tracker = self._tracker
            vx, vy = tracker.update(ex, ey, spvx, spvy, dt, self._last_saturated)
            if not tracker.last_valid:
                self._rejects.add("controller overflow")
                return self._hold(_EV_INVALID, "controller overflow")
            # 5a. of a long list, the neighbours that can matter to stages 5 and 6 (the same
            # entries in the same order, less those both would skip without a trace)
            # (a NeighbourView, the in-process loop's list over the fleet's grid: its near
            # entries from the grid, the same ones; else its whole list)
            view: NeighbourView | None = None
            listed: Sequence[Any] = ()
            if isinstance(neighbours, NeighbourView):
                view = neighbours
            else:
                listed = neighbours
            near = listed
            if (
                self._select_on
                and (view is not None or isinstance(listed, list))
                and len(neighbours) >= self._select_min
                and type(extra_radius_m) is float
            ):
                d0 = self._rep_d0 if self._rep_on else _NEG_INF
                box = _NEG_INF
                if self._filter_on:
                    er = extra_radius_m  # (as stage 6 takes it)
                    if unc > er:
                        er = unc
                    box = self._filter.reach_box_m(er, dt)
                if view is not None:
                    near = view.near(x, y, d0, rx, ry, box)
                else:
                    near = near_entries(listed, x, y, d0, rx, ry, box)
            elif view is not None:
                near = view.full()
            # 5. repulsion from neighbours / obstacles, at the axle centre (called whenever there
            # are neighbours at all: its sum of no pushes, 0.0, is added as before)
            if self._rep_on and (neighbours or obstacles):
                rvx, rvy, skipped = repulsion_raw(x, y, near, obstacles, self._rep_k,
                                                  self._rep_d0, self._rep_inv_d0,
                                                  self._rep_cap)  # fmt: skip
                if skipped:  # (non-finite entries are skipped and counted)
                    self._rejects.add("non-finite neighbour or obstacle", skipped)
                vx += rvx
                vy += rvy
            # 6. safety filter: the last Cartesian stage
            if self._filter_on:
                # (the own extra radius: at least this tick's estimate uncertainty)
                er = extra_radius_m if type(extra_radius_m) is float else _real(extra_radius_m)
                if unc > er:
                    er = unc
                frame = None  # (shared_frame: the own latest camera pose and its age)
                if self._shared_frame and pose is not None:
                    frame = self._own_frame(now, pose, pose_capture_s)
                # (a method call, not a bound method kept in an attribute: compiled, a native
                # call with unboxed floats instead of a Python call with keyword parsing)
                vx, vy = self._filter.filter(now, rx, ry, vx, vy, ex, ey, near, obstacles,
                                             er, dt, frame)  # fmt: skip
            # 7. eq 16: reference-point velocity -> (v, omega)
            v, w = twist_from_ref_velocity(vx, vy, th, l_m)
            # 8. eq 8: (v, omega) -> wheel speeds
            wr, wl = wheels_from_twist_raw(v, w, self._half_track, self._wheel_r)
            # 9. saturation
            wmax = self._wmax
            nwmax = self._wmax_neg
            # (_saturate's fast path inlined, a call less per tick: inside the limits; also
            # False for NaN)
            if wr <= wmax and wr >= nwmax and wl <= wmax and wl >= nwmax:
                sat = False
            else:
                wr, wl, sat = self._saturate(wr, wl, th)
            self._last_saturated = sat
            if est is not None:  # for the prediction (see _pend_t)
                self._pend_t = now + self._act_delay
                self._pend_wr = wr
                self._pend_wl = wl
            # (_new_command inlined: one Python call less per tick)
            return _tuple_new(WheelCommand, (wr, wl, wr / wmax, wl / wmax, _TRACKING,
                                             self._last_pose_t, sat))  # fmt: skip
        except Exception as exc:
            self._rejects.add(f"internal error: {type(exc).__name__}")
            self._last_saturated = False
            if self._modes.mode is not _ESTOP:
                self._enter(Mode.HOLD, "internal error")
            return self._zero(self._last_pose_t)

    # ------------------------------------------------------------------ public API

    @property
    def config(self) -> AgentConfig:
        """The configuration this firmware runs with."""
        return self._cfg

    @property
    def mode(self) -> Mode:
        """Current mode."""
        return self._modes.mode

    @property
    def safety_filter(self) -> SafetyFilter:
        """The safety filter (counters via ``status().safety_filter``)."""
        return self._filter

    @property
    def tracker(self) -> TrackingController:
        """The tracking controller (for inspection in tests and logs)."""
        return self._tracker

    @property
    def estimator(self) -> Estimator | None:
        """The pose estimator (None when ``config.estimator.enabled`` is False)."""
        return self._est

    @property
    def pose_uncertainty_m(self) -> float:
        """Uncertainty (m) of the pose used on the last tick: ``n_sigma`` standard deviations
        of the estimator's position (the safety filter's extra radius); NaN without a valid
        estimate on that tick, 0.0 with the estimator disabled."""
        return self._unc

    @property
    def pose_estimate(self) -> tuple[float, float, float] | None:
        """``(x, y, theta)`` of the axle centre the last tick used (estimated at ``now_s``, or
        the measured pose with the estimator disabled), or None."""
        xyt = self._est_xyt  # (a pose may hold ints or numpy scalars: floats out)
        return None if xyt is None else (float(xyt[0]), float(xyt[1]), float(xyt[2]))

    def reject(self, reason: str) -> None:
        """Count one bad input (e.g. a message the shell could not decode) with its reason."""
        self._rejects.add(reason)

    def engage_estop(self) -> None:
        """Latch the emergency stop: wheels are zero from now until ``release_estop()``."""
        self._apply(_EV_ESTOP, "estop")

    def release_estop(self) -> None:
        """Release a latched emergency stop, to HOLD (or IDLE if no setpoint was ever valid).

        The next ``step`` with fresh data resumes TRACKING. No-op when not latched.
        """
        if self._modes.mode is not Mode.ESTOP:
            return
        if self._have_setpoint:
            self._apply(_Event.RELEASE, "estop released")
        else:
            self._apply(_Event.RELEASE_UNCONFIGURED, "estop released, no setpoint yet")

    def status(self) -> FirmwareStatus:
        """Snapshot for the status message."""
        pid_x, pid_y = self._tracker.snapshot()
        modes = self._modes
        rejects = self._rejects
        return FirmwareStatus(
            mode=modes.mode,
            slot=self._slot,
            ex=self._ex,
            ey=self._ey,
            saturated_count=self._saturated,
            rejected_count=rejects.count,
            last_pose_t=self._last_pose_t,
            steps=self._steps,
            reason=modes.reason,
            last_reject_reason=rejects.last_reason,
            estop_latched=modes.mode is Mode.ESTOP,
            role_changes=self._role_changes,
            dt_faults=self._dt_faults,
            pose_age_s=self._pose_age,
            setpoint_age_s=self._setpoint_age,
            pid_x=pid_x,
            pid_y=pid_y,
            safety_filter=self._filter.status(),
        )

    # ------------------------------------------------------------------ mode changes

    def _enter(self, new: Mode, reason: str) -> None:
        """Enter mode ``new`` (the mode machine's on-entry actions); a change of mode also
        drops the one-tick saturation memory of the anti-windup (``_last_saturated``)."""
        if self._modes.enter(new, reason):
            self._last_saturated = False

    def _apply(self, event: _Event, reason: str) -> None:
        """Apply ``event`` to the mode machine (``_enter`` with the table's next mode)."""
        if self._modes.apply(event, reason):
            self._last_saturated = False

    def _zero(self, pose_t: float | None) -> WheelCommand:
        """Zero command in the current mode."""
        return _new_command(0.0, 0.0, 0.0, 0.0, self._modes.mode, pose_t, False)

    def _stop(self, event: _Event, reason: str) -> None:
        """Non-tracking tick: apply the event; the tick's wheels are zero (``_zero``) unless
        the robot must evade."""
        self._apply(event, reason)
        self._last_saturated = False
        if self._est is not None and self._last_now is not None:
            self._pend_t = self._last_now + self._act_delay
            self._pend_wr = 0.0
            self._pend_wl = 0.0

    def _hold(self, event: _Event, reason: str) -> WheelCommand:
        """Non-tracking tick: apply the event, zero wheels."""
        self._stop(event, reason)
        return _new_command(0.0, 0.0, 0.0, 0.0, self._modes.mode, self._last_pose_t, False)

    # ------------------------------------------------------------------ the stages of step

    def _bound(self, lim: MotionLimiter, cmd: WheelCommand) -> WheelCommand:
        """Stage 10, the motion bound (``robot_agent.core.neighbour_motion``): the tick's wheels
        with their twist change bounded, in every mode; the claim published with them."""
        try:
            now = self._last_now
            if now is None:  # (no valid clock yet: at rest, the first tick's command)
                return cmd
            xyt = self._est_xyt
            th = _NAN
            if xyt is not None and xyt is not self._xyt_seen:  # a heading of this tick
                th = float(xyt[2])
            self._xyt_seen = xyt
            wr, wl = lim.limit(now, cmd.omega_r, cmd.omega_l, th)
            if wr == cmd.omega_r and wl == cmd.omega_l:
                return cmd
            if self._est is not None:  # the prediction's input is what the wheels get
                self._pend_t = now + self._act_delay
                self._pend_wr = wr
                self._pend_wl = wl
            wmax = self._wmax
            return _new_command(wr, wl, wr / wmax, wl / wmax, cmd.mode, cmd.pose_t, cmd.saturated)
        except Exception as exc:  # (a firmware loop must not die: the last twist, held)
            self.reject(f"internal error: {type(exc).__name__}")
            wr, wl = lim.held_wheels()
            wmax = self._wmax
            return _new_command(wr, wl, wr / wmax, wl / wmax, cmd.mode, cmd.pose_t, cmd.saturated)

    @property
    def motion_claim(self) -> Claim | None:
        """The claim of the last tick's command (``robot_agent.core.neighbour_motion``): None
        without a motion bound or while the heading is unknown."""
        return None if self._limiter is None else self._limiter.claim

    @property
    def bound_limited(self) -> int:
        """Ticks on which the motion bound changed the command (0 without one)."""
        return 0 if self._limiter is None else self._limiter.limited

    def _evade(
        self,
        now: float,
        dt: float,
        xytu: tuple[float, float, float, float] | None,
        neighbours: Sequence[Any] | NeighbourView,
        obstacles: Sequence[tuple[float, float, float]],
        extra_radius_m: object,
    ) -> WheelCommand:
        """A tick that does not track (IDLE, HOLD) but knows where the robot is (``xytu``, the
        pose at ``now``; None: it does not, and the wheels are zero): the safety filter with a
        zero nominal command (``SafetyFilter.evade``, issue 30), then stages 7-9. Zero wheels
        unless a body approaches or the robot is inside a boundary: it still gets out of the
        way. Only ESTOP, a lost pose and a disabled filter mean wheels at zero regardless."""
        if xytu is None or not self._filter_on:
            return self._zero(self._last_pose_t)
        x, y, th, unc = xytu
        l_m = self._l
        rx, ry = reference_point(x, y, th, l_m)
        er = extra_radius_m if type(extra_radius_m) is float else _real(extra_radius_m)
        if unc > er:
            er = unc
        listed = neighbours.full() if isinstance(neighbours, NeighbourView) else neighbours
        vx, vy = self._filter.evade(rx, ry, listed, obstacles, er, dt)
        if vx == 0.0 and vy == 0.0:
            return self._zero(self._last_pose_t)
        v, w = twist_from_ref_velocity(vx, vy, th, l_m)  # eq 16
        wr, wl = wheels_from_twist_raw(v, w, self._half_track, self._wheel_r)  # eq 8
        wr, wl, sat = self._saturate(wr, wl, th)
        if self._est is not None:
            self._pend_t = now + self._act_delay
            self._pend_wr = wr
            self._pend_wl = wl
        wmax = self._wmax
        return _new_command(wr, wl, wr / wmax, wl / wmax, self._modes.mode, self._last_pose_t, sat)

    def _read_pose(
        self, pose: object, pose_rx_s: object
    ) -> tuple[float, float, float, float, float] | None:
        """``pose`` (x, y, theta, t) and its receive time as floats, or None for a non-finite
        or non-numeric one (rejected and counted once): what both pose stages read."""
        ox: object
        oy: object
        oth: object
        ot: object
        if isinstance(pose, tuple):
            ox, oy, oth, ot = pose
        else:
            ps: Any = pose
            ox, oy, oth, ot = ps
        x = ox if type(ox) is float else _real(ox)
        y = oy if type(oy) is float else _real(oy)
        th = oth if type(oth) is float else _real(oth)
        pose_t = ot if type(ot) is float else _real(ot)
        prx = pose_rx_s if type(pose_rx_s) is float else _real(pose_rx_s)
        if not _isfinite(x + y + th + pose_t + prx):
            self._rejects.pose(pose, "non-finite pose")
            return None
        return x, y, th, pose_t, prx

    def _pose_quiet(
        self, now: float, pose: object, pose_rx_s: object
    ) -> tuple[float, float, float, float] | None:
        """Without the estimator, on a tick with no setpoint: the latest pose as measured if
        finite and fresh, ``(x, y, theta, 0.0)``, else None; no mode change (a bad pose is
        counted once, as in ``_pose_measured``)."""
        read = None if pose is None else self._read_pose(pose, pose_rx_s)
        if read is None:
            return None
        x, y, th, _pose_t, prx = read
        lim = self._stale_pose
        if not -lim <= now - prx <= lim:
            return None
        return x, y, th, 0.0

    def _estimate(
        self,
        est: Estimator,
        now: float,
        last: float | None,
        pose: object,
        pose_rx_s: object,
        pose_capture_s: object,
        wheel_speeds: object,
    ) -> tuple[float, float, float, float] | None:
        """Stage 1, estimate: one ``Estimator.tick`` (the twist since the last tick, the camera
        pose if this object is new, fused at its capture time, the estimate at ``now``):
        ``(x, y, theta, uncertainty_m)`` or None (invalid). The twist: the encoder speeds
        over ``[last, now)`` (eq 7; bad ones are counted), else the last command from its
        actuation time, else none (``seg_t`` NaN). A rejected pose is counted."""
        # (eq 7 inline, twice: kinematics.twist_from_wheels_raw, the same operations)
        odo = False
        if wheel_speeds is not None and last is not None:
            try:
                ws: Any = wheel_speeds
                owr, owl = ws
                wr = owr if type(owr) is float else _real(owr)
                wl = owl if type(owl) is float else _real(owl)
                hr = self._half_r
                v = hr * (wr + wl)
                w = hr * (wr - wl) / self._half_track
                s = v + w
                ok = now > last and s - s == 0.0  # finite (also catches overflow)
            except (TypeError, ValueError):
                ok = False
            if ok:
                seg_t = last
                odo = True
            else:
                seg_t = _NAN  # no twist this tick
                v = w = 0.0
                if now > last:
                    self._rejects.add("bad wheel speeds")
        else:
            seg_t = self._pend_t
            if seg_t == seg_t:  # a command pending (not NaN)
                pwr = self._pend_wr
                pwl = self._pend_wl
                hr = self._half_r
                v = hr * (pwr + pwl)
                w = hr * (pwr - pwl) / self._half_track
            else:  # (seg_t NaN: no twist this tick)
                v = w = 0.0
        self._pend_t = _NAN
        if pose is None or pose is self._fused_pose:
            return est.tick(now, seg_t, v, w, odo, None, 0.0, 0.0, 0.0)
        self._fused_pose = pose
        ox: object
        oy: object
        oth: object
        ot: object
        if isinstance(pose, tuple):
            ox, oy, oth, ot = pose
        else:
            ps: Any = pose
            ox, oy, oth, ot = ps
        mx = ox if type(ox) is float else _real(ox)
        my = oy if type(oy) is float else _real(oy)
        mth = oth if type(oth) is float else _real(oth)
        mt = ot if type(ot) is float else _real(ot)
        if mt - mt != 0.0:  # not finite
            self._rejects.add("non-finite pose")
            return est.tick(now, seg_t, v, w, odo, None, mx, my, mth)
        oc = pose_rx_s if pose_capture_s is None else pose_capture_s
        cap = oc if type(oc) is float else _real(oc)
        got = est.tick(now, seg_t, v, w, odo, cap, mx, my, mth)
        reason = est.last_reason
        if reason is None:
            self._last_pose_t = mt
        else:
            self._rejects.add(reason)
        return got

    def _setpoint_now(
        self, now: float, setpoint: object, setpoint_rx_s: object
    ) -> tuple[float, float, float, float, float]:
        """Stage 2a, the setpoint: validated (a bad one counted once), a slot change resets
        the PID, and advanced by its feed-forward velocity over its receive age plus
        ``setpoint_lead_s`` (``extrapolate_setpoint``): ``(x, y, vx, vy, age_s)``. No setpoint
        or a rejected one: the firmware holds and ``age_s`` is NaN (a plain tuple, not an
        Optional: unboxed in the compiled core)."""
        if setpoint is None:
            self._setpoint_age = _NAN
            self._stop(_EV_NO_SETPOINT, "no setpoint")
            return _NO_SETPOINT
        ox: object
        oy: object
        ovx: object
        ovy: object
        oth: object
        slot: object
        ot: object
        if isinstance(setpoint, tuple):
            ox, oy, ovx, ovy, oth, slot, ot = setpoint
        else:
            ss: Any = setpoint
            ox, oy, ovx, ovy, oth, slot, ot = ss
        spx = ox if type(ox) is float else _real(ox)
        spy = oy if type(oy) is float else _real(oy)
        spvx = ovx if type(ovx) is float else _real(ovx)
        spvy = ovy if type(ovy) is float else _real(ovy)
        spth = oth if type(oth) is float else _real(oth)
        spt = ot if type(ot) is float else _real(ot)
        srx = setpoint_rx_s if type(setpoint_rx_s) is float else _real(setpoint_rx_s)
        # (the slot: an int >= 0, not a bool)
        s = spx + spy + spvx + spvy + spth + spt + srx
        if s - s != 0.0 or not (  # not finite
            type(slot) is int and slot >= 0
        ):
            self._rejects.setpoint(setpoint, "non-finite setpoint or bad slot")
            if self._have_setpoint:
                self._stop(_EV_INVALID, "setpoint rejected")
            else:
                self._stop(_EV_NO_SETPOINT, "setpoint rejected, none valid yet")
            return _NO_SETPOINT
        self._have_setpoint = True
        if slot != self._slot:  # role change: the old PID state belongs to another target
            if self._slot is not None:
                self._role_changes += 1
            self._slot = slot
            self._tracker.reset()
        sp_age = now - srx
        self._setpoint_age = sp_age
        # where the setpoint is now (exactly one tick old in lockstep), and setpoint_lead_s on
        if self._extrap and sp_age > 0.0:
            lead = sp_age + self._lead
            spx += spvx * lead
            spy += spvy * lead
        return spx, spy, spvx, spvy, sp_age

    def _pose_measured(
        self, now: float, pose: object, pose_rx_s: object
    ) -> tuple[float, float, float, float] | None:
        """Stage 2b without the estimator: the latest pose as measured, validated (a bad one
        counted once) and fresh (``|now - pose_rx_s| <= stale_pose_s``): ``(x, y, theta,
        0.0)``, or None (the firmware holds)."""
        if pose is None:
            self._pose_age = _NAN
            self._stop(_EV_STALE, "no pose")
            return None
        read = self._read_pose(pose, pose_rx_s)
        if read is None:
            self._stop(_EV_INVALID, "pose rejected")
            return None
        x, y, th, pose_t, prx = read
        self._last_pose_t = pose_t
        pose_age = now - prx
        self._pose_age = pose_age
        # staleness (|age|: a receive time in the future is as wrong as an old one)
        lim = self._stale_pose
        if not -lim <= pose_age <= lim:
            self._stop(_EV_STALE, "pose stale")
            return None
        # (a tuple as it is: pose_estimate converts its fields on reading)
        self._est_xyt = pose if isinstance(pose, tuple) else (x, y, th)
        return x, y, th, 0.0

    def _pose_estimated(
        self,
        est: Estimator,
        now: float,
        pose: object,
        pose_rx_s: object,
        got: tuple[float, float, float, float] | None,
    ) -> tuple[float, float, float, float] | None:
        """Stage 2b with the estimator: its pose at ``now`` (``got``), ``(x, y, theta,
        uncertainty_m)``; None when invalid (no pose yet, the camera lost beyond the dropout
        bound, or too uncertain: the firmware holds)."""
        if pose is not None:
            prx = pose_rx_s if type(pose_rx_s) is float else _real(pose_rx_s)
            self._pose_age = now - prx
        else:
            self._pose_age = _NAN
        self._est_xyt = got
        if got is None:
            self._unc = _NAN
            if est.last_capture_s is None:
                self._stop(_EV_STALE, "no pose")
            else:
                self._stop(_EV_STALE, "pose estimate invalid")
            return None
        self._unc = got[3]
        return got

    def _own_frame(
        self, now: float, pose: object, pose_capture_s: object
    ) -> tuple[float, float, float, float]:
        """Stage 6's input with ``shared_frame``: this robot's latest camera pose (axle centre,
        heading) and its age at ``now``, for the safety filter's shared-frame plane."""
        ox: object
        oy: object
        oth: object
        ot: object
        if isinstance(pose, tuple):
            ox, oy, oth, ot = pose
        else:
            ps: Any = pose
            ox, oy, oth, ot = ps
        oc = ot if pose_capture_s is None else pose_capture_s
        cap_t = oc if type(oc) is float else _real(oc)
        return (
            ox if type(ox) is float else _real(ox),
            oy if type(oy) is float else _real(oy),
            oth if type(oth) is float else _real(oth),
            now - cap_t,
        )

    def _saturate(self, wr: float, wl: float, th: float) -> tuple[float, float, bool]:
        """Stage 9: ``|omega| <= max_wheel_radps`` keeping the turn (``saturate_wheels``,
        counted); if the reference velocity that leaves (eqs 7, 14-15) is outside the safety
        filter's constraints, one factor on both wheels instead (``u`` scales by a factor in
        (0, 1]: safe, see safety_filter.py). ``(omega_r, omega_l, saturated)``."""
        wmax = self._wmax
        nwmax = self._wmax_neg
        # (fast path: inside the limits; also False for NaN)
        if wr <= wmax and wr >= nwmax and wl <= wmax and wl >= nwmax:
            return wr, wl, False
        swr, swl, sat = saturate_wheels(wr, wl, wmax)
        if not sat:
            return swr, swl, False
        self._saturated += 1
        flt = self._filter
        if self._filter_on and flt.in_range and _isfinite(wr + wl):
            sv, sw = twist_from_wheels_raw(swr, swl, self._half_track, self._wheel_r)
            ux, uy = ref_point_velocity(sv, sw, th, self._l)
            if not flt.admissible(ux, uy):
                k = wmax / max(abs(wr), abs(wl))
                # (wr * k can round one ulp beyond wmax: power 1 + 2e-16 is an invalid wheels
                # message; clamp, a change of one ulp)
                swr = min(wmax, max(-wmax, wr * k))
                swl = min(wmax, max(-wmax, wl * k))
                flt.count_rescaled()
        return swr, swl, True
