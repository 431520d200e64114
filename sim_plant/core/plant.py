"""Ground-truth plant: n differential-drive robots, vectorised over robots.

Theory of operation
-------------------
The plant holds the *true* pose of every robot, ``[x_m, y_m, theta_rad]`` per row, and the true
wheel speeds ``[omega_r, omega_l]`` in rad/s. Nothing in here is a measurement: sensors
(:mod:`sim_plant.core.sensors`) read :attr:`Plant.truth` and add their own noise and delay.

One :meth:`Plant.step` advances sim time by ``dt_s`` with the wheel command held constant over the
step (zero-order hold, as a motor driver updated once per control tick):

1. Sanitise the command: a robot whose command holds NaN/inf gets ``(0, 0)`` (counted in
   :attr:`Plant.nonfinite_count`); with ``wheel_limit`` each wheel is clamped independently to
   ``+-max_wheel_radps`` (a motor cannot exceed its speed; the turn-preserving scaling is the
   firmware's job, not the motor's). A robot with at least one clamped wheel adds one to
   :attr:`Plant.clamp_count`.
2. Motor lag (optional, ``motor_tau_s > 0``): each wheel is a first-order lag towards its command,
   discretised exactly, ``w(t0+s) = c + (w(t0) - c) exp(-s / tau)``. The pose is integrated with
   the exact *mean* wheel speed over the (sub-)interval, so the heading change and the distance
   travelled are exact; only the shape of the path inside one step is approximated by an arc.
   With ``motor_tau_s == 0`` the wheels follow the command instantly.
3. Exact unicycle integration (paper eq. 9) of the body twist from the standard differential-drive
   kinematics (paper eq. 7 corrected, see docs/paper-errata.md)::

       v = R (omega_r + omega_l) / 2,   omega = R (omega_r - omega_l) / (2 L)

   over the step: an arc when ``omega != 0``, a straight line when ``omega == 0``. Both cases are
   one formula, the chord ``v dt sinc(omega dt / 2)`` along the mid-step heading, which is exact
   for constant ``(v, omega)`` and smooth through ``omega = 0``. Theta is wrapped to (-pi, pi].

Disturbances model a person interfering with the arena:

* :meth:`Plant.teleport` puts a robot down at a new pose instantly.
* :meth:`Plant.drag` carries a robot: from ``t_start_s`` for ``duration_s`` its position moves
  linearly by ``(dx_m, dy_m)`` while its heading is kept and its wheels have no effect on the pose
  (the motors keep running in the air and their lag state still evolves). After the drag the
  wheels act again. A step that straddles the start or the end of a drag is split exactly: wheels
  before, carried in between, wheels after.

The core is pure: no clock is read (time only advances by the ``dt_s`` passed in) and there is no
randomness.

Small fleets
------------
For a handful of robots numpy's per-call overhead (~1 us per ufunc) costs far more than the
arithmetic, so up to :data:`SMALL_N` robots the common step (no drag, every command finite and
within the wheel limit) runs in plain Python on tuples (:meth:`Plant._step_small`), with exactly
the operations of the vectorised path in the same order (``math.sin``/``cos`` give the same bits
as ``np.sin``/``cos``, float ``%`` the same as ``np.mod``), so both paths give bit-identical
states; the tests check it. The tuples are then the current state and the arrays are rebuilt only
when something asks for them (:attr:`Plant.truth`, a drag, a teleport, ...).
:meth:`Plant.truth_rows` reads the state without building an array. The small-fleet loop keeps
typed float locals and calls ``math.sin``/``cos`` directly, so that the compiled build
(``sim_plant.core._accel``) runs it on C doubles (the same operations, the same bits).
"""

from __future__ import annotations

import math
import sys
from typing import Any, Final

import numpy as np
import numpy.typing as npt

from sim_plant.core.carry import Carries
from sim_plant.core.commands import CommandGuard
from sim_plant.core.encoders import _check_finite_scalar
from sim_plant.core.kinematics import (
    FloatArray,
    GeometryLike,
    PoseRow,
    PoseRows,
    unicycle_integrate,
    wrap_angles,
)

__all__ = ["SMALL_N", "Plant"]

BoolArray = npt.NDArray[np.bool_]
WheelRow = tuple[float, float]


#: Largest fleet stepped in plain Python; larger fleets use the vectorised path. The camera uses
#: the same bound. Measured on the 2.5 GHz Xeon of this project (CPython 3.11): a plant step
#: costs 11 us (Python) vs 90 us (numpy) for 4 robots, 125 vs 137 us for 64, 250 vs 176 us for
#: 128; a camera frame 82 vs 94 us for 64 robots, 157 vs 124 us for 128.
SMALL_N = 64

_MAX_FLOAT: Final = sys.float_info.max
# the constants of sim_plant.core.kinematics (the same bits), Final: inlined when compiled
_PI: Final = math.pi
_TWO_PI: Final = 2.0 * math.pi


def _listed(cmd: Any) -> list[Any]:
    """A wheel command that is not a list, as one (an array's rows as lists of floats)."""
    return cmd.tolist() if isinstance(cmd, np.ndarray) else list(cmd)


class Plant:
    """n differential-drive robots: true poses, wheel limits, motor lag, teleport and drag.

    Args:
        x0: initial poses, shape ``(n, 3)``, rows ``[x_m, y_m, theta_rad]`` (finite); theta is
            wrapped to (-pi, pi]. ``n`` may be 0.
        geometry: wheel radius R, half track L and wheel speed limit (``RobotGeometry``).
        motor_tau_s: first-order motor time constant in seconds; 0 means ideal motors.
        wheel_limit: clamp each wheel to ``+-geometry.max_wheel_radps``.
        t0_s: sim time of ``x0`` in seconds.

    Robots are addressed by row index ``i``; :meth:`remove_robot` shifts the rows after ``i``.
    The plant owns the poses and the wheel speeds; it composes the command guard (sanitising
    and its counters, :mod:`sim_plant.core.commands`) and the drag schedule
    (:mod:`sim_plant.core.carry`).
    """

    def __init__(
        self,
        x0: npt.ArrayLike,
        geometry: GeometryLike,
        motor_tau_s: float = 0.0,
        wheel_limit: bool = True,
        t0_s: float = 0.0,
    ) -> None:
        pose = np.array(x0, dtype=np.float64, copy=True)
        if pose.ndim == 1 and pose.size == 0:
            pose = pose.reshape(0, 3)
        if pose.ndim != 2 or pose.shape[1] != 3:
            raise ValueError(f"x0 must have shape (n, 3), got {pose.shape}")
        if not np.all(np.isfinite(pose)):
            raise ValueError("x0 must be finite")
        radius = _check_finite_scalar("geometry.wheel_radius_m", geometry.wheel_radius_m)
        half_track = _check_finite_scalar("geometry.half_track_m", geometry.half_track_m)
        max_w = _check_finite_scalar("geometry.max_wheel_radps", geometry.max_wheel_radps)
        if radius <= 0.0 or half_track <= 0.0 or max_w <= 0.0:
            raise ValueError("wheel radius, half track and max wheel speed must be > 0")
        tau = _check_finite_scalar("motor_tau_s", motor_tau_s)
        if tau < 0.0:
            raise ValueError(f"motor_tau_s must be >= 0, got {motor_tau_s}")

        self._geometry = geometry
        self._radius_m = radius
        self._half_track_m = half_track
        self._motor_tau_s = tau
        self._t_s = _check_finite_scalar("t0_s", t0_s)

        n = pose.shape[0]
        pose[:, 2] = wrap_angles(pose[:, 2])
        self._pose: FloatArray = pose
        self._wheels: FloatArray = np.zeros((n, 2))
        # Cumulative wheel angles (rad): what ideal encoders count (also while carried); flat,
        # per robot the right wheel's then the left's.
        self._angles: list[float] = [0.0] * (2 * n)
        self._carries = Carries(n)
        self._guard = CommandGuard(n, max_w, bool(wheel_limit))
        # Small-fleet state as tuples (see the module docstring). Invariant: when _np_stale the
        # tuples are the state and _pose/_wheels are outdated; otherwise the arrays are the
        # state and the tuples, if not None, a copy of them.
        self._rows: PoseRows | None = None
        self._wrows: tuple[WheelRow, ...] | None = None
        self._np_stale = False
        self._lag_dt = math.nan  # dt the cached lag factors below are for (NaN: none yet)
        self._lag_factor = 0.0
        self._lag_decay = 0.0

    # ------------------------------------------------------------------ properties

    @property
    def n(self) -> int:
        """Number of robots."""
        return int(self._pose.shape[0])

    @property
    def t_s(self) -> float:
        """Current sim time in seconds."""
        return self._t_s

    @property
    def geometry(self) -> GeometryLike:
        """The geometry the plant was built with."""
        return self._geometry

    @property
    def motor_tau_s(self) -> float:
        """Motor time constant in seconds (0 = ideal motors)."""
        return self._motor_tau_s

    @property
    def truth(self) -> FloatArray:
        """Copy of the true poses, ``(n, 3)`` ``[x_m, y_m, theta_rad]``, theta in (-pi, pi]."""
        self._sync_arrays()
        return self._pose.copy()

    def truth_rows(self) -> PoseRows:
        """The true poses as ``(x_m, y_m, theta_rad)`` tuples (immutable; no array is built)."""
        rows = self._rows
        if rows is None:
            rows = self._rows = PoseRows((x, y, th) for x, y, th in self._pose.tolist())
        return rows

    @property
    def wheel_speeds(self) -> FloatArray:
        """Copy of the true wheel speeds, ``(n, 2)`` ``[omega_r, omega_l]`` in rad/s."""
        self._sync_arrays()
        return self._wheels.copy()

    def wheel_angles(self) -> list[tuple[float, float]]:
        """Cumulative angle of each wheel since the start, ``(angle_r, angle_l)`` in rad: the
        integral of the (lagged) wheel speed, what an ideal encoder counts. The wheels turn
        (and count) while the robot is carried, too."""
        a = self._angles
        return [(a[j], a[j + 1]) for j in range(0, len(a), 2)]

    @property
    def body_twist(self) -> FloatArray:
        """``(n, 2)`` ``[v_mps, omega_radps]`` from the current wheel speeds (eq. 7 corrected)."""
        self._sync_arrays()
        v, w = self._twist(self._wheels)
        return np.stack([v, w], axis=1)

    @property
    def carried(self) -> BoolArray:
        """Copy of the mask of robots being carried by a drag right now, ``(n,)`` bool."""
        return self._carries.carried

    @property
    def saturated(self) -> BoolArray:
        """Copy of the mask of robots whose last command had a clamped wheel, ``(n,)`` bool."""
        return self._guard.saturated

    @property
    def clamp_count(self) -> int:
        """Robot-steps in which at least one wheel command was clamped to the limit."""
        return int(self._guard.clamp_counts.sum())

    @property
    def clamp_counts(self) -> npt.NDArray[np.int64]:
        """Per-robot clamp counts, ``(n,)``."""
        return self._guard.clamp_counts

    @property
    def nonfinite_count(self) -> int:
        """Robot-steps whose command held NaN or inf (treated as zero)."""
        return int(self._guard.nonfinite_counts.sum())

    @property
    def nonfinite_counts(self) -> npt.NDArray[np.int64]:
        """Per-robot non-finite command counts, ``(n,)``."""
        return self._guard.nonfinite_counts

    # ------------------------------------------------------------------ state representation

    def _sync_arrays(self) -> None:
        """Make ``_pose``/``_wheels`` current (after small-fleet steps ran on tuples)."""
        if self._np_stale:
            assert self._rows is not None and self._wrows is not None
            n = len(self._rows)
            self._pose = np.array(self._rows, dtype=np.float64).reshape(n, 3)
            self._wheels = np.array(self._wrows, dtype=np.float64).reshape(n, 2)
            self._np_stale = False

    def _arrays_changed(self) -> None:
        """The arrays were modified in place or replaced: the tuples are outdated."""
        self._rows = None
        self._wrows = None

    # ------------------------------------------------------------------ dynamics

    def _twist(self, wheels: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Body twist ``(v_mps, omega_radps)`` from wheel speeds (eq. 7, standard form)."""
        wr = wheels[:, 0]
        wl = wheels[:, 1]
        v = 0.5 * self._radius_m * (wr + wl)
        omega = self._radius_m * (wr - wl) / (2.0 * self._half_track_m)
        return v, omega

    def _mean_wheels(self, cmd: FloatArray, a_s: FloatArray | float, b_s: FloatArray) -> FloatArray:
        """Exact mean wheel speed over ``[a, b]`` seconds into the step (first-order lag)."""
        tau = self._motor_tau_s
        if tau == 0.0:
            return cmd
        w0 = self._wheels
        a = np.broadcast_to(np.asarray(a_s, dtype=np.float64), b_s.shape)
        span = b_s - a
        ea = np.exp(-a / tau)
        eb = np.exp(-b_s / tau)
        # (e^-a/tau - e^-b/tau) * tau / (b - a); for a vanishing span the limit e^-a/tau.
        safe = span > 1e-12
        factor = np.where(safe, (ea - eb) * tau / np.where(safe, span, 1.0), ea)
        return cmd + (w0 - cmd) * factor[:, None]

    def step(self, dt_s: float, wheel_cmd: npt.ArrayLike) -> None:
        """Advance the plant by ``dt_s`` seconds with ``wheel_cmd`` held over the step.

        ``wheel_cmd`` is ``(n, 2)`` ``[omega_r, omega_l]`` in rad/s. ``dt_s == 0`` is a no-op
        (the command is not even looked at); a negative or non-finite ``dt_s`` raises
        ``ValueError`` because it is a bug in the caller's clock, not a disturbance to model.
        """
        dt = float(dt_s)
        if not math.isfinite(dt) or dt < 0.0:
            raise ValueError(f"dt_s must be finite and >= 0, got {dt_s!r}")
        if dt == 0.0:
            return
        # (the wheel angles: two per robot, a list's length, not an array attribute)
        small = not self._carries.any and len(self._angles) <= 2 * SMALL_N
        if small and self._step_small(dt, wheel_cmd):
            return
        self._sync_arrays()
        cmd = self._guard.sanitise(wheel_cmd, self.n)
        ta = self._t_s
        tb = ta + dt

        tau = self._motor_tau_s
        if not self._carries.any:
            # Fast path, no drag anywhere: one segment over the whole step, so the mean-speed
            # factor of the lag, tau (1 - exp(-dt / tau)) / dt, is one scalar for every robot.
            if tau > 0.0:
                mean = cmd + (self._wheels - cmd) * (-tau * math.expm1(-dt / tau) / dt)
            else:
                mean = cmd
            v, w = self._twist(mean)
            self._pose = unicycle_integrate(self._pose, v, w, dt)
        else:
            mean = self._mean_wheels(cmd, 0.0, np.full(self.n, dt))

            def move(
                pose: FloatArray, a_s: FloatArray | float, b_s: FloatArray, span_s: FloatArray
            ) -> FloatArray:
                v, w = self._twist(self._mean_wheels(cmd, a_s, b_s))
                return unicycle_integrate(pose, v, w, span_s)

            self._pose = self._carries.advance(self._pose, ta, tb, dt, move)
        a = self._angles
        for j, (mr, ml) in enumerate(mean.tolist()):
            a[2 * j] += mr * dt
            a[2 * j + 1] += ml * dt

        if tau > 0.0:
            self._wheels = cmd + (self._wheels - cmd) * math.exp(-dt / tau)
        else:
            self._wheels = cmd
        self._t_s = tb
        self._arrays_changed()

    def _step_small(self, dt: float, wheel_cmd: npt.ArrayLike) -> bool:
        """The no-drag step of :meth:`step` in plain Python, for small fleets.

        Same operations in the same order as the vectorised path (``_sanitise`` with nothing to
        clamp or zero, the lag's mean-speed factor, ``_twist``, :func:`unicycle_integrate`,
        :func:`wrap_angles`), so the same bits. Returns False, having changed nothing, when the
        command needs the general path: not ``n`` pairs of real numbers, or a wheel that is
        non-finite or over the limit (to be zeroed / clamped and counted there).
        """
        rows, wrows = self._tuple_state()
        # typed views for the compiled build: a tuple's item and a list's are read natively
        # (PoseRows is a tuple), a pair command (the loop's) is unpacked without an iterator
        prow: tuple[PoseRow, ...] = rows
        cmds: Any = wheel_cmd
        try:
            if len(cmds) != len(rows):
                return False
            clist: list[Any] = cmds if type(cmds) is list else _listed(cmds)
        except TypeError:
            return False
        # Without a wheel limit the largest finite float: the test below then still sends
        # NaN and +-inf the general way.
        guard = self._guard
        lim: float = guard.max_wheel_radps if guard.wheel_limit else _MAX_FLOAT
        lag = self._motor_tau_s > 0.0
        if dt != self._lag_dt:  # the loop's dt is constant: compute the lag factors once
            self._set_lag(dt)
        factor = self._lag_factor
        decay = self._lag_decay
        kv = 0.5 * self._radius_m
        radius = self._radius_m
        track = 2.0 * self._half_track_m
        half_dt = 0.5 * dt
        new_rows: list[PoseRow] = []
        new_w: list[WheelRow] = []
        old_angles = self._angles
        angles: list[float] = []  # the wheel angles after the step (as self._angles)
        # Typed locals and direct math.sin/cos calls: the compiled build (sim_plant.core._accel)
        # keeps them as C doubles; a non-number raises TypeError on the assignment there and on
        # the comparison here.
        cr: float
        cl: float
        try:
            for j in range(len(rows)):  # the lengths are equal (checked above)
                x, y, th = prow[j]
                w0r, w0l = wrows[j]
                c = clist[j]
                if type(c) is tuple and len(c) == 2:
                    pair: tuple[Any, ...] = c
                    cr = pair[0]
                    cl = pair[1]
                else:
                    cr, cl = c
                # False for NaN, for +-inf and beyond the limit: those go the general way to be
                # zeroed or clamped and counted. (Nothing is committed before the loop ends.)
                if not (-lim <= cr <= lim and -lim <= cl <= lim):
                    return False
                if lag:
                    mr = cr + (w0r - cr) * factor
                    ml = cl + (w0l - cl) * factor
                    new_w.append((cr + (w0r - cr) * decay, cl + (w0l - cl) * decay))
                else:
                    mr = cr = float(cr)  # the wheel state holds floats, as the arrays do
                    ml = cl = float(cl)
                    new_w.append((cr, cl))
                angles.append(old_angles[2 * j] + mr * dt)
                angles.append(old_angles[2 * j + 1] + ml * dt)
                v = kv * (mr + ml)  # eq 7 (corrected), as _twist
                half_turn = radius * (mr - ml) / track * half_dt
                ratio = math.sin(half_turn) / half_turn if half_turn != 0.0 else 1.0
                chord = v * dt * ratio  # eq 9, exact arc, as unicycle_integrate
                mid = th + half_turn
                r = (_PI - (mid + half_turn)) % _TWO_PI  # wrap_angles
                new_rows.append(
                    (
                        x + chord * math.cos(mid),
                        y + chord * math.sin(mid),
                        _PI - (r if r < _TWO_PI else 0.0),
                    )
                )
        except (TypeError, ValueError):  # not pairs of real numbers
            return False
        self._guard.none_saturated(len(rows))
        self._angles = angles
        self._rows = PoseRows(new_rows)
        self._wrows = tuple(new_w)
        self._np_stale = True
        self._t_s += dt
        return True

    def _tuple_state(self) -> tuple[PoseRows, tuple[WheelRow, ...]]:
        """The poses and the wheel speeds as tuples (built from the arrays if those are the
        state)."""
        rows = self._rows
        if rows is None:
            rows = self.truth_rows()
        wrows = self._wrows
        if wrows is None:
            wrows = self._wrows = tuple((w[0], w[1]) for w in self._wheels.tolist())
        return rows, wrows

    def _set_lag(self, dt: float) -> None:
        """The lag's factors for steps of ``dt``: the mean of the lag over a step, and its decay
        over a step (0 without lag)."""
        tau = self._motor_tau_s
        lag = tau > 0.0
        self._lag_dt = dt
        self._lag_factor = -tau * math.expm1(-dt / tau) / dt if lag else 0.0
        self._lag_decay = math.exp(-dt / tau) if lag else 0.0

    # ------------------------------------------------------------------ disturbances

    def _index(self, i: int) -> int:
        idx = int(i)
        if not 0 <= idx < self.n:
            raise IndexError(f"robot index {i} out of range for {self.n} robots")
        return idx

    def teleport(self, i: int, x: float, y: float, theta: float | None = None) -> None:
        """Put robot ``i`` down at ``(x_m, y_m)``, heading ``theta`` rad (kept if ``None``).

        Cancels any drag of robot ``i`` (the person let go). Wheel speeds are unchanged.
        """
        idx = self._index(i)
        fx = _check_finite_scalar("x", x)
        fy = _check_finite_scalar("y", y)
        fth = None if theta is None else float(wrap_angles(_check_finite_scalar("theta", theta)))
        self._sync_arrays()
        self._pose[idx, 0] = fx
        self._pose[idx, 1] = fy
        if fth is not None:
            self._pose[idx, 2] = fth
        self._arrays_changed()
        self._carries.clear(idx)

    def drag(
        self,
        i: int,
        dx: float,
        dy: float,
        duration_s: float,
        t_start_s: float | None = None,
    ) -> None:
        """Carry robot ``i`` by ``(dx_m, dy_m)`` over ``duration_s`` seconds from ``t_start_s``.

        ``t_start_s`` defaults to now and may not lie in the past. While carried the position
        moves linearly from where the robot was at ``t_start_s`` to that point plus the offset,
        the heading is kept and the wheels do not move the robot. ``duration_s == 0`` is an
        instant shift at ``t_start_s``. A new drag replaces any pending or running drag of ``i``
        (a running one stops where it is).
        """
        idx = self._index(i)
        ddx = _check_finite_scalar("dx", dx)
        ddy = _check_finite_scalar("dy", dy)
        dur = _check_finite_scalar("duration_s", duration_s)
        if dur < 0.0:
            raise ValueError(f"duration_s must be >= 0, got {duration_s}")
        start = self._t_s if t_start_s is None else _check_finite_scalar("t_start_s", t_start_s)
        if start < self._t_s - 1e-9:
            raise ValueError(f"t_start_s={start} lies before the plant time {self._t_s}")
        start = max(start, self._t_s)
        self._carries.schedule(idx, start, dur, ddx, ddy)

    # ------------------------------------------------------------------ fleet changes

    def add_robot(self, pose: npt.ArrayLike) -> int:
        """Append a robot at ``pose`` ``[x_m, y_m, theta_rad]``, wheels still; returns its index."""
        row = np.array(pose, dtype=np.float64).reshape(3)
        if not np.all(np.isfinite(row)):
            raise ValueError("pose must be finite")
        row[2] = float(wrap_angles(row[2]))
        self._sync_arrays()
        self._arrays_changed()
        self._pose = np.vstack([self._pose, row[None, :]])
        self._wheels = np.vstack([self._wheels, np.zeros((1, 2))])
        self._carries.append()
        self._guard.append()
        self._angles.extend((0.0, 0.0))
        return self.n - 1

    def remove_robot(self, i: int) -> None:
        """Remove robot ``i``; the robots after it move down one index."""
        idx = self._index(i)
        self._sync_arrays()
        self._arrays_changed()
        self._pose = np.delete(self._pose, idx, axis=0)
        self._wheels = np.delete(self._wheels, idx, axis=0)
        self._carries.delete(idx)
        self._guard.delete(idx)
        del self._angles[2 * idx : 2 * idx + 2]
