"""A neighbour's motion as it publishes and enforces it: the motion claim (issue 30, realtime).

Stdlib only, pure (time is passed in). Three parts, one concern:

* :class:`MotionLimiter`, in every robot's firmware when ``SafetyFilterParams.accel_bound_mps2``
  ``A > 0``: the last stage of every tick, in every mode (tracking, IDLE, HOLD, an e-stop, a
  lost pose, an internal error). It changes the body twist ``b = (v, l omega)`` of the wheel
  command (eq 8 inverted; ``v`` the forward speed, ``omega`` the turn rate, ``l`` the reference
  offset) by at most ``A`` times the time elapsed since the previous tick:
  ``|b_k - b_{k-1}| <= A (t_k - t_{k-1})``. The wheel box (``|omega_wheel| <= max``) is convex
  and holds both ends, so the limited twist needs no new saturation. What it publishes with each
  command is a :class:`Claim`: the tick time, the reference-point velocity ``u = R(theta) b``
  the wheels give (eq 16), ``omega`` and ``A``.
* :func:`motion_view`, on the receiving side: from a neighbour's recent claims (its local
  clock), the capture time of its latest pose and ``now``, what the safety filter needs: how far
  its reference point has moved since the capture, within which radius, its velocity over the
  next tick and the growth of that velocity's uncertainty. None when the claims are missing,
  stale or absurd: then the filter keeps the worst case ``V a`` (``neighbour_speed_mps``).
* :func:`append_claimed`, the barrier row against a neighbour with a view.

The model (what the limiter guarantees, hence what a receiver may assume). With the wheels
following the command within the tick (a motor lag ``tau`` adds ``A tau``) the reference point
moves at ``u(t) = R(theta(t)) b(t)`` with ``b`` piecewise constant. For ``t`` after a claim
``(t_u, u_c, omega_c)``, with ``tau = t - t_u``:

    |b(t) - b_c| <= A tau                              (the limiter, tick by tick)
    |theta(t) - theta_c| <= |omega_c| tau + A tau^2 / (2 l)   (omega = b_y / l)
    |u(t) - u_c| <= |R(theta(t))(b(t) - b_c)| + |R(theta(t)) - R(theta_c)| |b_c|
                 <= e(tau) = e0 + (A + |u_c| |omega_c|) tau + A |u_c| tau^2 / (2 l)

with ``e0 = HEADING_TOL_RAD * |u_c|`` for the publisher's heading error (its estimate of
``theta`` converts ``b`` to ``u_c``). Only forward from a claim (an older velocity cannot be
bounded by a newer one: the twist steps at the ticks), so the receiver integrates from the
newest claim at or before the pose's capture ``t_cap``:

    shift  s = u_c1 (now - t_cap)
    radius R = integral of e(t - t_u1) over [t_cap, now]      (the reference point at now is
                                                                within R of p_cap + s)
    next tick: velocity u_c* (the newest claim), within e(now + dt - t_u*) of the truth.

Then the row (full responsibility: each robot answers for itself against the other's bounded
motion, so a cooperative pair needs no reciprocity and no common clock) is

    h = |p - (p_cap + s)| - (Ds + 2 l + R + rho + rho_j),   n . u >= -gamma h + n . u_c* + e

and the discrete-time step of ``safety_filter.py`` goes through: the neighbour's reference
point at ``now + dt`` is within ``R + e dt`` of ``p_cap + s + u_c* dt`` (``e`` grows with
``tau``; the row uses its value at the end of the tick), so ``|p_i(t + dt) - p_j(t + dt)| >=
|p_i - p_hat| + dt n . (u_i - u_c*) - R - e dt >= D + (1 - gamma dt) h``. It holds for any
neighbour motion the bound allows: an honest neighbour that swerves, brakes (at most ``A``:
its e-stop ramps) or turns, and a lying one that stays within what it published. Ages are on
the receiver's clock (``robot_agent.core.clocksync``: a remote time mapped to the local clock
reads late by the link's least delay, never early); :data:`CLOCK_TOL_S` is added to every
interval for that and for tick jitter.

What a claim does not cover (docs/defaults.md, "Neighbour motion"): a robot whose firmware
stops running (a crash, a power cut: its wheels coast or brake as the motor driver does; its
claims stop, so within ``claim_max_age_s`` its neighbours fall back to ``V a``) and a robot
that is carried or pushed (the movers of ``coordinator/core/movers.py``: not cooperative).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Final, NamedTuple

from .params import AgentConfig
from .qp import _TOL

__all__ = [
    "CLOCK_TOL_S",
    "HEADING_TOL_RAD",
    "Claim",
    "MotionLimiter",
    "MotionView",
    "append_claimed",
    "claim_is_sane",
    "motion_view",
    "view_is_sane",
]

HEADING_TOL_RAD: Final = 0.05
"""Heading error (rad) of the publisher's own estimate (it converts its body twist to the
reference-point velocity it claims): 10-50 x what the estimator holds with a camera."""
CLOCK_TOL_S: Final = 0.002
"""Added to every interval of the model (s): a remote time on the local clock reads late by the
link's least one-way delay (microseconds on one host, under a millisecond on a LAN)."""
DEAD_RECKON_S: Final = 0.5
"""A robot publishes a claim while moving only if its heading is at most this old (s): a
dead-reckoned one (ticks without a pose) drifts from the truth, and the claim's heading
allowance is :data:`HEADING_TOL_RAD`; at rest the claim (zero) needs no heading."""
MAX_ACCEL_MPS2: Final = 100.0
"""A claimed bound above this (m/s^2) is absurd (rejected): ``SafetyFilterParams``'s range."""

_hypot: Final = math.hypot
_isfinite: Final = math.isfinite


class Claim(NamedTuple):
    """One published command of a robot: what it enforces from ``t_s`` on.

    Attributes:
        t_s: the tick time (s) on the clock of whoever holds the claim (the publisher's own,
            or the receiver's after ``clocksync``).
        ux_mps, uy_mps: the reference-point velocity the command gives (m/s, world frame).
        omega_radps: its turn rate (rad/s).
        accel_mps2: the bound its limiter enforces on the body twist (m/s^2).
    """

    t_s: float
    ux_mps: float
    uy_mps: float
    omega_radps: float
    accel_mps2: float


MotionView = tuple[float, float, float, float, float, float, float, float, float]
"""``(sx, sy, r_m, ux, uy, tau_s, e0, e1, e2)``: the reference point's shift since the capture
and its radius (m), the velocity over the next tick (m/s), the newest claim's age at now (s)
and the coefficients of its velocity error ``e(tau) = e0 + e1 tau + e2 tau^2`` (m/s)."""


def claim_is_sane(c: Claim, vmax_mps: float) -> bool:
    """Finite, a speed at most twice ``vmax_mps`` (a reference point is a little faster than
    the axle), a bound in ``(0, MAX_ACCEL_MPS2]`` and a turn rate below 100 rad/s."""
    t, ux, uy, w, a = c
    return (
        _isfinite(t + ux + uy + w + a)
        and _hypot(ux, uy) <= 2.0 * vmax_mps
        and 0.0 < a <= MAX_ACCEL_MPS2
        and abs(w) < 100.0
    )


def _coefficients(c: Claim, l_m: float) -> tuple[float, float, float]:
    speed = _hypot(c.ux_mps, c.uy_mps)
    a = c.accel_mps2
    return HEADING_TOL_RAD * speed, a + speed * abs(c.omega_radps), a * speed / (2.0 * l_m)


def motion_view(
    claims: Sequence[Claim],
    capture_s: float,
    now_s: float,
    l_m: float,
    vmax_mps: float,
    max_age_s: float,
) -> MotionView | None:
    """The filter's view of a neighbour from its claims (oldest first, receiver's clock), the
    capture time of its latest pose and now (module docstring); None (the worst case) if the
    newest claim is missing, absurd, in the future or older than ``max_age_s``, or no claim
    at or before the capture is kept."""
    if not claims:
        return None
    newest = claims[-1]
    tau = now_s - newest.t_s
    if not (claim_is_sane(newest, vmax_mps) and -CLOCK_TOL_S <= tau <= max_age_s):
        return None
    base = None
    for c in reversed(claims):
        if c.t_s <= capture_s:
            base = c
            break
    if base is None or not claim_is_sane(base, vmax_mps):
        return None
    a = now_s - capture_s
    if a < 0.0:  # (a capture in the future is age 0: robot_agent.core.neighbours)
        a = 0.0
    e0, e1, e2 = _coefficients(base, l_m)
    t0 = capture_s - base.t_s
    t1 = t0 + a + CLOCK_TOL_S
    r = e0 * (t1 - t0) + e1 * (t1 * t1 - t0 * t0) / 2.0 + e2 * (t1**3 - t0**3) / 3.0
    e0, e1, e2 = _coefficients(newest, l_m)
    tau = max(tau, 0.0) + CLOCK_TOL_S
    return (base.ux_mps * a, base.uy_mps * a, r, newest.ux_mps, newest.uy_mps, tau, e0, e1, e2)


def view_is_sane(view: object) -> bool:
    """A :data:`MotionView` as :func:`motion_view` makes them: nine finite numbers, the radius,
    the claim's age and the error coefficients >= 0 (anything else: the worst case)."""
    if not isinstance(view, tuple) or len(view) != 9:
        return False
    try:
        sx, sy, r, ux, uy, tau, e0, e1, e2 = (float(v) for v in view)
    except (TypeError, ValueError):
        return False
    return (
        _isfinite(sx + sy + r + ux + uy + tau + e0 + e1 + e2)
        and r >= 0.0
        and tau >= 0.0
        and e0 >= 0.0
        and e1 >= 0.0
        and e2 >= 0.0
    )


def append_claimed(
    px: float,
    py: float,
    qx: float,
    qy: float,
    view: MotionView,
    dd: float,
    gamma: float,
    dt_s: float,
    cap: float,
    cons: list[tuple[float, float, float]],
) -> float:
    """Append the row against a neighbour whose reference point was ``(qx, qy)`` at the
    capture (``dd``: ``Ds + 2 l`` plus the own and its uncertainty beyond the noise budget;
    ``dt_s``: this tick's length, the command is held that long) if it can bind a command of
    speed ``cap``; returns its barrier value ``h`` (module docstring)."""
    sx, sy, r, ux, uy, tau, e0, e1, e2 = view
    tau += dt_s
    err = e0 + e1 * tau + e2 * tau * tau
    dx = px - qx - sx
    dy = py - qy - sy
    d = _hypot(dx, dy)
    if d > 0.0:
        nx = dx / d
        ny = dy / d
    else:
        nx, ny = 1.0, 0.0
    h = d - dd - r
    b = -gamma * h + nx * ux + ny * uy + err
    if b > -cap - _TOL:
        cons.append((nx, ny, b))
    return h


class MotionLimiter:
    """One robot's enforcement of its motion bound ``accel_mps2`` (module docstring).

    Args:
        accel_mps2: the bound ``A`` (> 0).
        wheel_radius_m, half_track_m, ref_offset_m: the robot's geometry (eq 8, eqs 10-11).
        max_wheel_radps: the wheel limit (a limited command is rounded back into it).
    """

    __slots__ = (
        "_a",
        "_bv",
        "_bw",
        "_dr_s",
        "_half_track",
        "_l",
        "_last_t",
        "_r",
        "_th",
        "_wmax",
        "claim",
        "limited",
    )

    def __init__(
        self,
        accel_mps2: float,
        wheel_radius_m: float,
        half_track_m: float,
        ref_offset_m: float,
        max_wheel_radps: float = math.inf,
    ) -> None:
        if not (0.0 < accel_mps2 <= MAX_ACCEL_MPS2):
            raise ValueError(f"accel_mps2 must be in (0, {MAX_ACCEL_MPS2}], got {accel_mps2!r}")
        self._a = accel_mps2
        self._r = wheel_radius_m
        self._half_track = half_track_m
        self._l = ref_offset_m
        self._wmax = max_wheel_radps
        self._bv = 0.0  # the previous command's body twist (v, l omega): at rest before the first
        self._bw = 0.0
        self._last_t = math.nan
        self._th = math.nan  # heading at the previous tick (dead-reckoned when not given)
        self._dr_s = 0.0  # how long the heading has been dead-reckoned
        self.claim: Claim | None = None
        """The claim of the last tick's command (None while the heading is unknown)."""
        self.limited = 0
        """Ticks on which the bound changed the command."""

    @classmethod
    def of(cls, config: AgentConfig) -> MotionLimiter | None:
        """The limiter ``config`` asks for (``safety_filter.accel_bound_mps2``), None if 0."""
        a_max = config.safety_filter.accel_bound_mps2
        if not a_max > 0.0:
            return None
        g = config.geometry
        return cls(a_max, g.wheel_radius_m, g.half_track_m, g.ref_offset_m, g.max_wheel_radps)

    def limit(self, now_s: float, wr: float, wl: float, th: float) -> tuple[float, float]:
        """The wheel command ``(wr, wl)`` (rad/s, within the wheel limits) of the tick at
        ``now_s``, its body-twist change bounded by ``A`` times the time since the previous
        tick (none on the first tick, or if the clock did not advance); ``th`` the heading
        the tick used (NaN: unknown, dead-reckoned from the last one). Sets :attr:`claim`
        (None while the heading is unknown, or dead-reckoned longer than
        :data:`DEAD_RECKON_S` while moving)."""
        last = self._last_t
        elapsed = now_s - last if now_s > last else 0.0  # (NaN last: the first tick)
        if not _isfinite(elapsed):
            elapsed = 0.0
        self._last_t = now_s if _isfinite(now_s) else last
        r = self._r
        l_m = self._l
        bv = 0.5 * r * (wr + wl)
        bw = l_m * r * (wr - wl) / (2.0 * self._half_track)
        pv = self._bv
        pw = self._bw
        dv = bv - pv
        dw = bw - pw
        step = _hypot(dv, dw)
        room = self._a * elapsed
        if not step <= room:  # (also NaN: keep the previous twist)
            k = room / step if step > 0.0 and _isfinite(step) else 0.0
            bv = pv + k * dv
            bw = pw + k * dw
            # the twist back to wheels (eq 8): on the segment between two commands within the
            # box, hence within it (up to rounding, which the clamp takes back: an ulp)
            w = bw / l_m
            wmax = self._wmax
            wr = min(max((bv + self._half_track * w) / r, -wmax), wmax)
            wl = min(max((bv - self._half_track * w) / r, -wmax), wmax)
            self.limited += 1
        omega = bw / l_m
        if _isfinite(th):
            self._dr_s = 0.0
        else:  # (a tick without a pose: HOLD's evasion on an estimate, an e-stop's ramp)
            th = self._th + self._omega_prev() * elapsed
            self._dr_s += elapsed
        self._th = th
        self._bv = bv
        self._bw = bw
        if _isfinite(th) and (self._dr_s <= DEAD_RECKON_S or (bv == 0.0 and bw == 0.0)):
            c = math.cos(th)
            s = math.sin(th)
            self.claim = Claim(now_s, c * bv - s * bw, s * bv + c * bw, omega, self._a)
        else:
            self.claim = None
        return wr, wl

    def held_wheels(self) -> tuple[float, float]:
        """The wheels of the previous command's twist (held: no change at all)."""
        w = self._bw / self._l
        wmax = self._wmax
        r = self._r
        wr = min(max((self._bv + self._half_track * w) / r, -wmax), wmax)
        wl = min(max((self._bv - self._half_track * w) / r, -wmax), wmax)
        return wr, wl

    def _omega_prev(self) -> float:
        return self._bw / self._l
