"""Reference-point tracking law: PID with feed-forward, per axis (paper eqs 21-22).

Per axis ``u = ff + Kp * (e + (1/Ti) * I + Td * edot)`` where ``e = p_v - p_r`` is the error of
the reference point (m), ``I`` its integral (m*s), ``edot`` its derivative (m/s) and ``ff`` the
velocity of the setpoint (m/s). Substituting into ``edot = pdot_v - pdot_r`` gives the ideal
closed loop ``(1 + Kp Td) s^2 + Kp s + Kp/Ti`` per axis: poles -0.2 and -0.01 with the paper's
gains (the printed eqs 23-24 drop the Kp factors).

Firmware habits (PX4 ``PID.cpp``, ArduPilot ``AC_PID``):

* The derivative is the error difference quotient through a first-order low-pass (time
  constant ``d_filter_tau_s``); the first sample after a reset has ``edot = 0``, so a fresh
  start or a resume gives no derivative kick. (The law is implicit in ``edot``; a discrete
  controller must use the previous error.)
* The integral is clamped to ``+-integral_limit_ms``. While the caller says the actuators are
  saturated (``freeze_integrator=True``), and while the controller's own speed cap bound the
  previous output, the integral may only shrink in magnitude (anti-windup).
* A tick with ``dt_s <= 0`` or non-finite ``dt_s`` updates no state and returns
  ``P + I + FF`` from the stored integral (no integration, no derivative).
* New state is committed only if it is finite; a non-finite error returns a safe 0.0 and
  leaves the state untouched.
* ``snapshot()`` returns a ``PIDInfo`` of the last update for logging; it is built on demand
  so the control loop allocates nothing for it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Final

from robot_agent.core.params import TrackingGains

__all__ = ["AxisPID", "PIDInfo", "TrackingController"]

_isfinite: Final = math.isfinite
_INF: Final = math.inf
_hypot: Final = math.hypot


@dataclass(frozen=True, slots=True)
class PIDInfo:
    """Snapshot of one axis after its last update (for logs and the status message).

    Attributes:
        error: last error e (m).
        p_term: Kp * e (m/s).
        i_term: Kp * I / Ti (m/s).
        d_term: Kp * Td * edot (m/s).
        output: p_term + i_term + d_term (m/s), without feed-forward.
        integral_ms: stored integral I (m*s).
        edot_filtered: stored filtered derivative (m/s).
        dt_s: dt of the last update (s); <= 0 or NaN means it integrated nothing.
        frozen: the integrator was frozen (may only shrink) on the last update.
        limited: the integral hit its clamp on the last update.
    """

    error: float = 0.0
    p_term: float = 0.0
    i_term: float = 0.0
    d_term: float = 0.0
    output: float = 0.0
    integral_ms: float = 0.0
    edot_filtered: float = 0.0
    dt_s: float = 0.0
    frozen: bool = False
    limited: bool = False

    def as_dict(self) -> dict[str, float | bool]:
        """Plain dict (msgpack-friendly) of the snapshot."""
        return {
            "error": self.error,
            "p": self.p_term,
            "i": self.i_term,
            "d": self.d_term,
            "out": self.output,
            "integral": self.integral_ms,
            "edot": self.edot_filtered,
            "dt": self.dt_s,
            "frozen": self.frozen,
            "limited": self.limited,
        }


class AxisPID:
    """One axis of eqs 21-22 without the feed-forward: ``Kp*(e + I/Ti + Td*edot_filtered)``."""

    __slots__ = (
        "_edot",
        "_has_prev",
        "_ilim",
        "_integral",
        "_inv_ti",
        "_kp",
        "_kp_inv_ti",
        "_kp_td",
        "_last_d",
        "_last_dt",
        "_last_error",
        "_last_frozen",
        "_last_limited",
        "_prev_error",
        "_tau",
    )

    def __init__(self, gains: TrackingGains) -> None:
        self._kp = float(gains.kp)
        self._inv_ti = 1.0 / gains.ti_s
        self._kp_inv_ti = self._kp * self._inv_ti
        self._kp_td = self._kp * gains.td_s
        self._tau = float(gains.d_filter_tau_s)
        self._ilim = float(gains.integral_limit_ms)
        self._integral = 0.0
        self._edot = 0.0
        self._prev_error = 0.0
        self._has_prev = False
        self._last_error = 0.0
        self._last_d = 0.0
        self._last_dt = 0.0
        self._last_frozen = False
        self._last_limited = False

    @property
    def integral_ms(self) -> float:
        """Stored error integral I (m*s), within +-integral_limit_ms."""
        return self._integral

    def reset(self) -> None:
        """Forget everything: integral, derivative filter, previous error and the snapshot."""
        self._integral = 0.0
        self._last_error = 0.0
        self._last_d = 0.0
        self._last_dt = 0.0
        self._last_frozen = False
        self._last_limited = False
        self.reset_derivative()

    def reset_derivative(self) -> None:
        """Forget the derivative state only; the next update has edot = 0 (no kick)."""
        self._edot = 0.0
        self._prev_error = 0.0
        self._has_prev = False

    def update(self, error: float, dt_s: float, freeze_integrator: bool = False) -> float:
        """Advance one tick with error ``error`` (m) after ``dt_s`` (s); return the PID part (m/s).

        ``freeze_integrator=True`` lets the integral only shrink in magnitude this tick.
        """
        if not _isfinite(error):
            return 0.0
        kp = self._kp
        integ = self._integral
        if not (0.0 < dt_s < _INF):  # zero, negative, NaN or inf: no state update
            self._last_error = error
            self._last_d = 0.0
            self._last_dt = dt_s
            self._last_frozen = freeze_integrator
            self._last_limited = False
            return kp * error + self._kp_inv_ti * integ

        if self._has_prev:
            raw = (error - self._prev_error) / dt_s
            edot = self._edot + (dt_s / (self._tau + dt_s)) * (raw - self._edot)
        else:
            edot = 0.0

        cand = integ + error * dt_s
        ilim = self._ilim
        limited = False
        if cand > ilim:
            cand = ilim
            limited = True
        elif cand < -ilim:
            cand = -ilim
            limited = True
        if freeze_integrator and abs(cand) > abs(integ):
            cand = integ

        d = self._kp_td * edot
        out = kp * error + self._kp_inv_ti * cand + d
        if _isfinite(out + edot):  # commit only finite state (PX4 PID.cpp)
            self._integral = cand
            self._edot = edot
            self._prev_error = error
            self._has_prev = True
        else:  # overflow somewhere: keep the old state, fall back to P + stored I
            d = 0.0
            out = kp * error + self._kp_inv_ti * integ
        self._last_error = error
        self._last_d = d
        self._last_dt = dt_s
        self._last_frozen = freeze_integrator
        self._last_limited = limited
        return out

    def snapshot(self) -> PIDInfo:
        """``PIDInfo`` of the last update."""
        # The I term of the last update always used the integral as stored after it.
        p = self._kp * self._last_error
        i = self._kp_inv_ti * self._integral
        return PIDInfo(
            error=self._last_error,
            p_term=p,
            i_term=i,
            d_term=self._last_d,
            output=p + i + self._last_d,
            integral_ms=self._integral,
            edot_filtered=self._edot,
            dt_s=self._last_dt,
            frozen=self._last_frozen,
            limited=self._last_limited,
        )


class TrackingController:
    """Eqs 21-22 on both axes with feed-forward and a cap on the commanded speed.

    ``update`` returns the commanded reference-point velocity ``(xdot_r, ydot_r)`` in m/s, its
    norm capped at ``max_ref_speed_mps`` (direction kept). When the cap bound the previous
    output the integrators are frozen on this tick (anti-windup with a one-tick lag, as the
    integrator can only know about saturation it has already seen).
    """

    __slots__ = ("_ilim", "_kp", "_kp_inv_ti", "_kp_td", "_l_dt", "_l_dx", "_l_dy", "_l_ex",
                 "_l_ey", "_l_freeze", "_l_limx", "_l_limy", "_l_pending", "_limited", "_tau",
                 "_vmax", "_vmax2_in", "_x", "_y", "last_valid")  # fmt: skip

    def __init__(self, gains: TrackingGains) -> None:
        self._x = AxisPID(gains)
        self._y = AxisPID(gains)
        # the gains both axes share, for the inlined per-tick path of ``update``
        ax = self._x
        self._kp = ax._kp
        self._kp_inv_ti = ax._kp_inv_ti
        self._kp_td = ax._kp_td
        self._tau = ax._tau
        self._ilim = ax._ilim
        self._vmax = float(gains.max_ref_speed_mps)
        self._vmax2_in = 0.99 * self._vmax * self._vmax  # (see the end of update)
        self._limited = False
        # ex, ey, d_x, d_y, dt, frozen, limited_x, limited_y of the last inlined update, not
        # yet written into the axes' snapshot fields while _l_pending (attributes, not a tuple:
        # compiled, unboxed floats instead of six objects a tick)
        self._l_pending = False
        self._l_ex = self._l_ey = self._l_dx = self._l_dy = self._l_dt = 0.0
        self._l_freeze = self._l_limx = self._l_limy = False
        #: False if the last update had non-finite input or output and returned (0, 0).
        self.last_valid = True

    def _sync(self) -> None:
        """Write the last inlined update's snapshot fields into the axes."""
        if self._l_pending:
            self._l_pending = False
            dt_s = self._l_dt
            freeze = self._l_freeze
            for pid, e, d, lim in (
                (self._x, self._l_ex, self._l_dx, self._l_limx),
                (self._y, self._l_ey, self._l_dy, self._l_limy),
            ):
                pid._last_error = e
                pid._last_d = d
                pid._last_dt = dt_s
                pid._last_frozen = freeze
                pid._last_limited = lim

    @property
    def x(self) -> AxisPID:
        """The x-axis PID."""
        self._sync()
        return self._x

    @property
    def y(self) -> AxisPID:
        """The y-axis PID."""
        self._sync()
        return self._y

    @property
    def speed_limited(self) -> bool:
        """True if the speed cap bound the last output."""
        return self._limited

    def reset(self) -> None:
        """Reset both axes (integral and derivative) and the speed-cap flag."""
        self._l_pending = False
        self._x.reset()
        self._y.reset()
        self._limited = False

    def reset_derivative(self) -> None:
        """Reset the derivative state of both axes only (keeps the integrals)."""
        self._sync()
        self._x.reset_derivative()
        self._y.reset_derivative()

    def update(  # noqa: PLR0915 (both PID axes inline, on the compiled hot path)
        self,
        ex: float,
        ey: float,
        ff_vx: float,
        ff_vy: float,
        dt_s: float,
        freeze_integrator: bool = False,
    ) -> tuple[float, float]:
        """One tick: errors (m), feed-forward (m/s), ``dt_s`` (s) -> ``(xdot_r, ydot_r)`` (m/s).

        Non-finite input (or values so large, ~1e308, that their sum overflows) returns
        ``(0.0, 0.0)`` with ``last_valid = False`` and leaves the state untouched; a non-finite
        output (overflow) also returns ``(0.0, 0.0)``, the stored state staying finite.
        """
        # (finite: x - x is 0.0 for a finite x only; the tests without a call, as below)
        s = ex + ey + ff_vx + ff_vy
        if s - s != 0.0:
            self.last_valid = False
            return 0.0, 0.0
        freeze = freeze_integrator or self._limited
        if 0.0 < dt_s < _INF:
            # ``AxisPID.update`` of both axes inlined (the per-tick path: the same operations in
            # the same order, so the same bits; tests/unit/robot_agent/test_agent_tracking.py
            # checks it); the
            # errors are finite (their sum is)
            kp = self._kp
            kp_inv_ti = self._kp_inv_ti
            kp_td = self._kp_td
            ilim = self._ilim
            alpha = dt_s / (self._tau + dt_s)
            # --- x axis
            pidx = self._x
            integ = pidx._integral
            if pidx._has_prev:
                edot0 = pidx._edot
                edot = edot0 + alpha * ((ex - pidx._prev_error) / dt_s - edot0)
            else:
                edot = 0.0
            cand = integ + ex * dt_s
            limx = False
            if cand > ilim:
                cand = ilim
                limx = True
            elif cand < -ilim:
                cand = -ilim
                limx = True
            if freeze and abs(cand) > abs(integ):
                cand = integ
            dx = kp_td * edot
            out = kp * ex + kp_inv_ti * cand + dx
            s = out + edot
            if s - s == 0.0:  # commit only finite state (PX4 PID.cpp)
                pidx._integral = cand
                pidx._edot = edot
                pidx._prev_error = ex
                pidx._has_prev = True
            else:  # overflow somewhere: keep the old state, fall back to P + stored I
                dx = 0.0
                out = kp * ex + kp_inv_ti * integ
            ux = ff_vx + out
            # --- y axis
            pidy = self._y
            integ = pidy._integral
            if pidy._has_prev:
                edot0 = pidy._edot
                edot = edot0 + alpha * ((ey - pidy._prev_error) / dt_s - edot0)
            else:
                edot = 0.0
            cand = integ + ey * dt_s
            limy = False
            if cand > ilim:
                cand = ilim
                limy = True
            elif cand < -ilim:
                cand = -ilim
                limy = True
            if freeze and abs(cand) > abs(integ):
                cand = integ
            dy = kp_td * edot
            out = kp * ey + kp_inv_ti * cand + dy
            s = out + edot
            if s - s == 0.0:  # commit only finite state (PX4 PID.cpp)
                pidy._integral = cand
                pidy._edot = edot
                pidy._prev_error = ey
                pidy._has_prev = True
            else:  # overflow somewhere: keep the old state, fall back to P + stored I
                dy = 0.0
                out = kp * ey + kp_inv_ti * integ
            uy = ff_vy + out
            # the axes' snapshot fields, written into them only when read (``_sync``)
            self._l_ex = ex
            self._l_ey = ey
            self._l_dx = dx
            self._l_dy = dy
            self._l_dt = dt_s
            self._l_freeze = freeze
            self._l_limx = limx
            self._l_limy = limy
            self._l_pending = True
        else:
            self._l_pending = False
            ux = ff_vx + self._x.update(ex, dt_s, freeze)
            uy = ff_vy + self._y.update(ey, dt_s, freeze)
        # well inside the cap (1 % below it in the square: far beyond any rounding of the sum
        # or of hypot), hypot is finite and below the cap: the output is (ux, uy) as below,
        # known without the call
        if ux * ux + uy * uy < self._vmax2_in:
            self.last_valid = True
            self._limited = False
            return ux, uy
        speed = _hypot(ux, uy)
        if speed - speed != 0.0:  # not finite
            self.last_valid = False
            return 0.0, 0.0
        self.last_valid = True
        vmax = self._vmax
        if speed > vmax:
            k = vmax / speed
            self._limited = True
            return ux * k, uy * k
        self._limited = False
        return ux, uy

    def snapshot(self) -> tuple[PIDInfo, PIDInfo]:
        """``(PIDInfo x, PIDInfo y)`` of the last update."""
        self._sync()
        return self._x.snapshot(), self._y.snapshot()
