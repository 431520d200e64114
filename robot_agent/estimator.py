"""Pose estimator of one robot: wheel odometry between camera frames, latency compensation.

Theory of operation
===================

Pure core, stdlib only: no clock is read, every call gets its time (the shell's one local clock,
the same as ``Firmware.step``'s ``now_s``).

**Motion model (paper eq 9).** The robot is a unicycle driven by a piecewise-constant twist
``(v, omega)``. The estimator keeps a short history of *segments* ``(t_start, v, omega,
measured)``: a segment's twist holds from its start to the next segment's start. Two sources:

* ``add_command(t_s, v, omega)``: the twist the firmware commanded, assumed to act from ``t_s``
  (the firmware passes ``now + actuation_delay_s``) on. Used where nothing better is known.
* ``add_odometry(t0_s, t1_s, v, omega)``: the mean twist the wheel encoders measured over
  ``[t0, t1)`` (eq 7 from the encoder wheel speeds). It replaces every segment from ``t0`` on
  (the commanded guesses for that interval) and holds from ``t0`` until the next segment.

Over each piece of constant twist the pose is integrated exactly (the arc: chord
``v dt sin(h) / h`` along the mid-piece heading ``theta + h``, ``h = omega dt / 2``), the same
formula as the simulated plant.

**Measurement model.** A camera pose ``z = (x, y, theta)`` captured at ``t`` (local clock) is
the true pose at ``t`` plus white noise of standard deviation ``meas_pos_std_m`` per axis and
``meas_theta_std_rad``.

**Fusion (EKF-lite).** Position and heading each carry one scalar variance, ``P`` (m^2, the
same for x and y) and ``Pth`` (rad^2); cross-covariances are not kept. Propagating over a
piece of length ``d = |v| dt``, turn ``|omega dt|`` and duration ``dt``::

    P   += q_m * d + q_s * dt + Pth * d^2     (heading error swings the path sideways)
    Pth += q_rad * |omega dt| + q_thm * d + q_ths * dt

over one propagation (from a camera pose to the next one, or to ``now``): ``d``, the turn and
``dt`` are the sums over its pieces of constant twist, ``q_m d`` and ``q_s dt`` the sums of each
piece's rates.

with ``q_m, q_s`` the odometry or commanded rates of ``EstimatorParams`` depending on the
segment's source. A camera pose then updates each axis with the Kalman gain
``K = P / (P + R)`` (``R`` the measurement variance; ``K = 1`` when both are 0), the heading
innovation wrapped to (-pi, pi]: ``x += K (z - x)``, ``P = (1 - K) P``.

**Late measurements: replay.** Each fused camera pose leaves an *anchor*: the posterior at its
capture time together with the measurement. A pose that arrives after younger ones (it was
delayed longer) is fused at its own capture time: the estimator propagates from the anchor just
before it, updates, then re-fuses every younger measurement in capture order. The result is the
one a batch filter gets by processing all measurements in capture order (the arithmetic is the
same, so equal to rounding; the tests check it). Odometry for an interval that already holds an
anchor triggers the same replay from there. History is bounded to ``history_s``: older
measurements are rejected.

**The estimate at now.** ``estimate(now_s)`` propagates the newest anchor to ``now`` through
the segments; this is the pose the controller uses. It is *valid* while the newest camera
capture is at most ``max_dropout_odom_s`` old when encoder speeds arrived within
``odom_timeout_s``, else ``max_dropout_cmd_s``, and while the uncertainty
``n_sigma * sqrt(P)`` stays within ``max_uncertainty_m``. The firmware holds otherwise.
The uncertainty is what the safety filter adds to the robot's radius.

**Rejections** (each counted, and the firmware adds them to its own rejected count):
non-finite values; capture after ``now + future_tolerance_s``; capture older than
``max_latency_s`` or than the history; a second, different pose with the capture time of one
already fused (a repeated identical pose is ignored silently); a pose farther than
``gate_m + n_sigma * sqrt(P + R)`` from the prediction (implausible jump); ``reset_after``
implausible poses in a row re-initialise the estimate at the last one (the robot was carried or
put down elsewhere), counted in ``resets``. Non-finite or backwards odometry is rejected too.
"""

from __future__ import annotations

import math
from bisect import bisect_right
from dataclasses import dataclass
from typing import Any

from .estimator_math import (  # noqa: F401  (moved to estimator_math.py; re-exported)
    _PI,
    _TINY_S,
    _TWO_PI,
    _Anchor,
    _cos,
    _EstimatorMath,
    _isfinite,
    _Segment,
    _sin,
    _sinc,
    _sqrt,
    _wrap,
    propagate_pose,
)
from .params import EstimatorParams

__all__ = ["Estimator", "EstimatorStatus", "propagate_pose"]


@dataclass(frozen=True, slots=True)
class EstimatorStatus:
    """Counters and state of the estimator (for status messages and logs)."""

    initialised: bool
    last_capture_s: float | None
    accepted: int
    replayed: int
    rejected_nonfinite: int
    rejected_future: int
    rejected_old: int
    rejected_duplicate: int
    rejected_implausible: int
    rejected_odometry: int
    resets: int
    anchors: int
    segments: int

    @property
    def rejected(self) -> int:
        """All rejected inputs."""
        return (
            self.rejected_nonfinite
            + self.rejected_future
            + self.rejected_old
            + self.rejected_duplicate
            + self.rejected_implausible
            + self.rejected_odometry
        )

    def as_dict(self) -> dict[str, Any]:
        """Plain dict (msgpack / JSON friendly)."""
        return {
            "initialised": self.initialised,
            "last_capture_s": self.last_capture_s,
            "accepted": self.accepted,
            "replayed": self.replayed,
            "rejected": self.rejected,
            "rejected_nonfinite": self.rejected_nonfinite,
            "rejected_future": self.rejected_future,
            "rejected_old": self.rejected_old,
            "rejected_duplicate": self.rejected_duplicate,
            "rejected_implausible": self.rejected_implausible,
            "rejected_odometry": self.rejected_odometry,
            "resets": self.resets,
        }


class Estimator(_EstimatorMath):
    """Pose of one robot's axle centre at ``now`` (see the module docstring)."""

    __slots__ = (
        "_b_cmd",
        "_b_odom",
        "_fut_tol",
        "_gate",
        "_hist",
        "_last_odom_t",
        "_max_lat",
        "_max_unc",
        "_nsig",
        "_odom_q",
        "_odom_to",
        "accepted",
        "last_reason",
        "rejected_duplicate",
        "rejected_future",
        "rejected_implausible",
        "rejected_nonfinite",
        "rejected_odometry",
        "rejected_old",
        "resets",
    )

    def __init__(self, params: EstimatorParams | None = None) -> None:
        p = params if params is not None else EstimatorParams()
        if not isinstance(p, EstimatorParams):
            raise TypeError(f"params must be EstimatorParams, got {type(p).__name__}")
        self._p = p
        self._r_pos = p.meas_pos_std_m * p.meas_pos_std_m
        self._r_th = p.meas_theta_std_rad * p.meas_theta_std_rad
        self._odom_q = (p.odom_pos_var_per_m, p.odom_pos_var_per_s)
        self._cmd_q = (p.cmd_pos_var_per_m, p.cmd_pos_var_per_s)
        self._q_rad = p.theta_var_per_rad
        self._b_cmd = p.max_dropout_cmd_s
        self._b_odom = p.max_dropout_odom_s
        self._fut_tol = p.future_tolerance_s
        self._gate = p.gate_m
        self._hist = p.history_s
        self._max_lat = p.max_latency_s
        self._max_unc = p.max_uncertainty_m
        self._nsig = p.n_sigma
        self._odom_to = p.odom_timeout_s
        self._q_thm = p.theta_var_per_m
        self._q_ths = p.theta_var_per_s
        self._seg: list[_Segment] = []
        self._seg_t: list[float] = []
        self._anch: list[_Anchor] = []
        self._anch_t: list[float] = []
        self._last_odom_t = -math.inf
        self._gated_run = 0
        self._first_is_init = False
        # checkpoints (t, x, y, theta, dist, turn, qd, qt) of the propagation from _ck_anchor
        self._ck: list[tuple[float, float, float, float, float, float, float, float]] = []
        self._ck_anchor: _Anchor | None = None
        self.accepted = 0
        #: ``tick``'s camera pose: None when fused (or none given), else the rejection reason
        self.last_reason: str | None = None
        self.replayed = 0
        self.rejected_nonfinite = 0
        self.rejected_future = 0
        self.rejected_old = 0
        self.rejected_duplicate = 0
        self.rejected_implausible = 0
        self.rejected_odometry = 0
        self.resets = 0

    # ------------------------------------------------------------------ inputs

    @property
    def params(self) -> EstimatorParams:
        """The parameters."""
        return self._p

    def reset(self) -> None:
        """Forget everything but the counters (the next camera pose initialises)."""
        self._seg.clear()
        self._seg_t.clear()
        self._anch.clear()
        self._anch_t.clear()
        self._last_odom_t = -math.inf
        self._gated_run = 0
        self._ck.clear()
        self._ck_anchor = None

    def add_command(self, t_s: float, v_mps: float, omega_radps: float) -> None:
        """The commanded twist acts from ``t_s`` on (replaces guesses from ``t_s`` on)."""
        if not _isfinite(t_s + v_mps + omega_radps):
            return  # the firmware never commands non-finite speeds; nothing to learn
        seg_t = self._seg_t
        if seg_t and t_s <= seg_t[-1]:
            if self._seg[-1][3] and t_s < seg_t[-1]:
                return  # never overwrite measured odometry with a guess
            self._truncate(t_s)
        elif self._seg and self._seg[-1][1] == v_mps and self._seg[-1][2] == omega_radps:
            return  # same twist continues: one segment
        else:
            ck = self._ck
            while ck and ck[-1][0] > t_s:  # they assumed the previous twist beyond t_s
                ck.pop()
        qm, qs = self._cmd_q
        self._seg.append((t_s, v_mps, omega_radps, False, qm, qs))
        seg_t.append(t_s)
        anch_t = self._anch_t
        if anch_t and anch_t[-1] > t_s:
            self._replay_after(t_s)

    def add_odometry(self, t0_s: float, t1_s: float, v_mps: float, omega_radps: float) -> bool:
        """Encoders measured the mean twist ``(v, omega)`` over ``[t0_s, t1_s)``.

        Returns False (and counts it) for non-finite values or ``t1_s < t0_s``.
        """
        if not (_isfinite(t0_s + t1_s + v_mps + omega_radps) and t1_s >= t0_s):
            self.rejected_odometry += 1
            return False
        self._truncate(t0_s)
        qm, qs = self._odom_q
        self._seg.append((t0_s, v_mps, omega_radps, True, qm, qs))
        self._seg_t.append(t0_s)
        if t1_s > self._last_odom_t:
            self._last_odom_t = t1_s
        anch_t = self._anch_t
        if anch_t and anch_t[-1] > t0_s:
            self._replay_after(t0_s)
        return True

    def add_measurement(
        self, now_s: float, t_s: float, x: float, y: float, theta: float
    ) -> str | None:
        """Fuse a camera pose captured at ``t_s`` (local clock). Returns None when fused (or
        an exact repeat of a fused pose, ignored), else the rejection reason (counted)."""
        if not _isfinite(now_s + t_s + x + y + theta):
            self.rejected_nonfinite += 1
            return "non-finite pose or capture time"
        if t_s > now_s:
            if t_s > now_s + self._fut_tol:
                self.rejected_future += 1
                return "pose captured in the future"
            t_s = now_s
        if now_s - t_s > self._max_lat:
            self.rejected_old += 1
            return "pose too old"
        if not -_PI < theta <= _PI:
            theta = _wrap(theta)
        anch = self._anch
        anch_t = self._anch_t
        if not anch:
            self._init(t_s, x, y, theta)
            self.accepted += 1
            return None
        if t_s < anch_t[0]:
            if self._first_is_init and now_s - t_s <= self._hist:
                # older than the pose we started from (cold start, arrivals out of order):
                # start from this one and re-fuse the others, as a batch filter would
                later = anch[:]
                anch.clear()
                anch_t.clear()
                self._init(t_s, x, y, theta)
                self._refuse(later)
                self.accepted += 1
                self.replayed += 1
                return None
            self.rejected_old += 1
            return "pose older than the replay history"
        i = len(anch_t) - 1 if t_s > anch_t[-1] else bisect_right(anch_t, t_s) - 1
        a = anch[i]
        if a[0] == t_s:
            if a[6] == x and a[7] == y and a[8] == theta:
                return None  # the same pose presented again
            self.rejected_duplicate += 1
            return "second pose with the same capture time"
        px, py, pth, pp, ppth = self._propagate(a, t_s)
        # plausibility gate on the position innovation
        dx = x - px
        dy = y - py
        g = self._gate + self._nsig * _sqrt(pp + self._r_pos)
        if dx * dx + dy * dy > g * g:
            self._gated_run += 1
            if self._gated_run >= self._p.reset_after:
                self.resets += 1
                self.reset()
                self._init(t_s, x, y, theta)
                self.accepted += 1
                return None
            self.rejected_implausible += 1
            return "implausible pose (jump)"
        self._gated_run = 0
        self.accepted += 1
        if i == len(anch) - 1:  # in capture order: _fuse inlined (hot path)
            sv = pp + self._r_pos
            k = pp / sv if sv > 0.0 else 1.0
            sv = ppth + self._r_th
            kt = ppth / sv if sv > 0.0 else 1.0
            d = theta - pth
            if not -_PI < d <= _PI:
                d = _wrap(d)
            th = pth + kt * d
            if not -_PI < th <= _PI:
                th = _wrap(th)
            anch.append((t_s, px + k * dx, py + k * dy, th, (1.0 - k) * pp, (1.0 - kt) * ppth,
                         x, y, theta))  # fmt: skip
            anch_t.append(t_s)
        else:
            new = self._fuse(t_s, px, py, pth, pp, ppth, x, y, theta)
            self.replayed += 1
            later = anch[i + 1 :]
            del anch[i + 1 :]
            del anch_t[i + 1 :]
            anch.append(new)
            anch_t.append(t_s)
            self._refuse(later)
        if anch_t[0] < now_s - self._hist - 0.25:  # amortised: every ~0.25 s
            self._trim(now_s)
        return None

    def tick(
        self,
        now_s: float,
        seg_t_s: float,
        v_mps: float,
        omega_radps: float,
        odometry: bool,
        capture_s: float | None,
        x: float,
        y: float,
        theta: float,
    ) -> tuple[float, float, float, float] | None:
        """One firmware tick in one call: a twist, a camera pose, then ``estimate(now_s)``.

        The same as ``add_odometry(seg_t_s, now_s, v, omega)`` (``odometry``; the caller has
        checked the values are finite and ``seg_t_s < now_s``) or ``add_command(seg_t_s, v,
        omega)`` (no twist when ``seg_t_s`` is NaN), then ``add_measurement(now_s, capture_s,
        x, y, theta)`` (none when ``capture_s`` is None; its result in ``last_reason``), then
        ``estimate(now_s)``, returned. The common case (inputs in time order) is inlined: the
        arithmetic is the same operations in the same order as the three calls, so the same
        bits (tests/test_estimator.py checks it).
        """
        # --- twist --------------------------------------------------------------------------
        seg_t = self._seg_t
        if seg_t_s == seg_t_s:  # not NaN
            seg = self._seg
            if odometry:
                if seg_t and seg_t[-1] >= seg_t_s:
                    self._truncate(seg_t_s)
                else:
                    ck = self._ck
                    while ck and ck[-1][0] > seg_t_s:
                        ck.pop()
                qm, qs = self._odom_q
                seg.append((seg_t_s, v_mps, omega_radps, True, qm, qs))
                seg_t.append(seg_t_s)
                if now_s > self._last_odom_t:
                    self._last_odom_t = now_s
                anch_t = self._anch_t
                if anch_t and anch_t[-1] > seg_t_s:
                    self._replay_after(seg_t_s)
            elif seg_t and seg_t_s <= seg_t[-1]:
                self.add_command(seg_t_s, v_mps, omega_radps)
            elif not (seg and seg[-1][1] == v_mps and seg[-1][2] == omega_radps):
                ck = self._ck
                while ck and ck[-1][0] > seg_t_s:
                    ck.pop()
                qm, qs = self._cmd_q
                seg.append((seg_t_s, v_mps, omega_radps, False, qm, qs))
                seg_t.append(seg_t_s)
                anch_t = self._anch_t
                if anch_t and anch_t[-1] > seg_t_s:
                    self._replay_after(seg_t_s)
        # --- camera pose ----------------------------------------------------------------------
        anch = self._anch
        if capture_s is not None:
            anch_t = self._anch_t
            t_s = capture_s
            if (
                anch
                and anch_t[-1] < t_s <= now_s
                and now_s - t_s <= self._max_lat
                and _isfinite(now_s + t_s + x + y + theta)
            ):  # in capture order: add_measurement's hot path
                if not -_PI < theta <= _PI:
                    theta = _wrap(theta)
                a = anch[-1]
                ck = self._ck
                j = len(ck) - 1
                if a is self._ck_anchor and j >= 0:
                    lim = t_s + _TINY_S
                    while j >= 0 and ck[j][0] > lim:
                        j -= 1
                if j >= 0 and a is self._ck_anchor and t_s - ck[j][0] < _TINY_S:
                    # the prior at a checkpoint of the last estimate (capture times on ticks):
                    # what _propagate returns from there, without the call
                    _, px, py, pth, dist, turn, qd, qt = ck[j]
                    ppth = a[5]
                    pp = a[4] + (qd + qt + ppth * dist * dist)
                    ppth += (
                        self._q_rad * 2.0 * turn + self._q_thm * dist + self._q_ths * (t_s - a[0])
                    )
                else:
                    px, py, pth, pp, ppth = self._propagate(a, t_s)
                dx = x - px
                dy = y - py
                rp = self._r_pos
                g = self._gate + self._nsig * _sqrt(pp + rp)
                if dx * dx + dy * dy > g * g:
                    self.last_reason = self.add_measurement(now_s, t_s, x, y, theta)
                else:
                    self._gated_run = 0
                    self.accepted += 1
                    sv = pp + rp
                    k = pp / sv if sv > 0.0 else 1.0
                    sv = ppth + self._r_th
                    kt = ppth / sv if sv > 0.0 else 1.0
                    d = theta - pth
                    if not -_PI < d <= _PI:
                        d = _wrap(d)
                    th = pth + kt * d
                    if not -_PI < th <= _PI:
                        th = _wrap(th)
                    anch.append((t_s, px + k * dx, py + k * dy, th, (1.0 - k) * pp,
                                 (1.0 - kt) * ppth, x, y, theta))  # fmt: skip
                    anch_t.append(t_s)
                    if anch_t[0] < now_s - self._hist - 0.25:  # amortised: every ~0.25 s
                        self._trim(now_s)
                    self.last_reason = None
            else:
                self.last_reason = self.add_measurement(now_s, t_s, x, y, theta)
        # --- estimate at now_s (estimate() inlined) -------------------------------------------
        if not anch:
            return None
        a = anch[-1]
        age = now_s - a[0]
        bound = self._b_odom if now_s - self._last_odom_t <= self._odom_to else self._b_cmd
        if not age <= bound:  # also False for NaN
            return None
        if age <= 0.0:
            ex, ey, eth, pp = a[1], a[2], a[3], a[4]
        elif a is self._ck_anchor:
            ex, ey, eth, pp, _ = self._propagate(a, now_s, True)
        else:
            # a fresh anchor (a camera pose every tick: the common case): _propagate(a, now_s,
            # True) inlined, the same operations in the same order
            self._ck_anchor = a
            ck = self._ck
            ck.clear()
            t, ex, ey, eth, pp, ppth, _, _, _ = a
            seg = self._seg
            n = len(seg_t)
            i = bisect_right(seg_t, t) - 1
            dist = turn = qd = qt = 0.0
            while t < now_s:
                if i >= 0:
                    _, v, w, _, qm, qs = seg[i]
                else:  # before any known twist: assume standing still
                    v = w = 0.0
                    qm, qs = self._cmd_q
                nxt = seg_t[i + 1] if i + 1 < n else now_s
                if nxt > now_s:
                    nxt = now_s
                dt = nxt - t
                if dt < _TINY_S:
                    t = nxt
                    i += 1
                    continue
                h = w * dt * 0.5
                if -0.1 < h < 0.1:
                    h2 = h * h
                    chord = v * dt * (1.0 - h2 * (1.0 / 6.0 - h2 * (1.0 / 120.0)))
                else:
                    chord = v * dt * (_sin(h) / h)
                mid = eth + h
                ex += chord * _cos(mid)
                ey += chord * _sin(mid)
                eth = mid + h
                d = v * dt if v >= 0.0 else -v * dt
                dist += d
                turn += h if h >= 0.0 else -h
                qd += qm * d
                qt += qs * dt
                t = nxt
                i += 1
                if t < now_s:  # t only grows and ck was cleared: always after ck[-1]
                    ck.append((t, ex, ey, eth, dist, turn, qd, qt))
            pp += qd + qt + ppth * dist * dist
        if not -_PI < eth <= _PI:
            eth = _wrap(eth)
        u = self._nsig * _sqrt(pp)
        if not u <= self._max_unc:
            return None
        return ex, ey, eth, u

    # ------------------------------------------------------------------ outputs

    def estimate(self, now_s: float) -> tuple[float, float, float, float] | None:
        """``(x, y, theta, uncertainty_m)`` at ``now_s``, or None when invalid (see module doc).

        ``uncertainty_m`` = ``n_sigma * sqrt(P)`` (m), for the safety filter's extra radius.
        """
        anch = self._anch
        if not anch:
            return None
        a = anch[-1]
        age = now_s - a[0]
        bound = self._b_odom if now_s - self._last_odom_t <= self._odom_to else self._b_cmd
        if not age <= bound:  # also False for NaN
            return None
        if age > 0.0:
            x, y, th, pp, _ = self._propagate(a, now_s, True)
            if not -_PI < th <= _PI:
                th = _wrap(th)
        else:
            x, y, th, pp = a[1], a[2], a[3], a[4]
        u = self._nsig * _sqrt(pp)
        if not u <= self._max_unc:
            return None
        return x, y, th, u

    def status(self) -> EstimatorStatus:
        """Counters and state."""
        return EstimatorStatus(
            initialised=bool(self._anch),
            last_capture_s=self._anch_t[-1] if self._anch_t else None,
            accepted=self.accepted,
            replayed=self.replayed,
            rejected_nonfinite=self.rejected_nonfinite,
            rejected_future=self.rejected_future,
            rejected_old=self.rejected_old,
            rejected_duplicate=self.rejected_duplicate,
            rejected_implausible=self.rejected_implausible,
            rejected_odometry=self.rejected_odometry,
            resets=self.resets,
            anchors=len(self._anch),
            segments=len(self._seg),
        )

    @property
    def last_capture_s(self) -> float | None:
        """Capture time of the newest fused camera pose (local clock), or None."""
        return self._anch_t[-1] if self._anch_t else None
