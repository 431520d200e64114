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
piece's rates (kept as running sums along the odometry chain, see below),

with ``q_m, q_s`` the odometry or commanded rates of ``EstimatorParams`` depending on the
segment's source. A camera pose then updates each axis with the Kalman gain
``K = P / (P + R)`` (``R`` the measurement variance; ``K = 1`` when both are 0), the heading
innovation wrapped to (-pi, pi]: ``x += K (z - x)``, ``P = (1 - K) P``.

**Odometry chain and correction frames** (estimator_math.py). The twists are integrated once,
segment by segment, into a dead-reckoned *chain* in an odometry frame; each fused camera pose
leaves an *anchor*: the posterior at its capture time, the measurement, and the rigid
correction frame that maps the chain onto the world from then on (the ``odom`` -> ``map``
transform of ROS REP 105). The unicycle's motion is the same in any rigid frame, so propagating
an anchor to a later time is the chain there through that frame: one arc per tick and one
transform, however old the camera pose is.

**Late measurements: replay.** A pose that arrives after younger ones (it was delayed longer) is
fused at its own capture time: the estimator predicts it through the frame of the anchor just
before it, updates, then re-fuses every younger measurement in capture order. The result is the
one a batch filter gets by processing all measurements in capture order (the arithmetic is the
same, so equal to rounding; the tests check it). Odometry for an interval that already holds an
anchor triggers the same replay from there. History is bounded to ``history_s``: older
measurements are rejected.

**The estimate at now.** ``estimate(now_s)`` is the chain at ``now`` through the newest
anchor's frame; this is the pose the controller uses. It is *valid* while the newest camera
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
from math import cos as _cos  # (imported, not assigned: mypyc compiles these to C calls)
from math import sin as _sin
from math import sqrt as _sqrt
from typing import Any

from robot_agent.core.estimator_math import (
    _NEG_PI,
    _PI,
    _TINY_S,
    _Anchor,
    _arc,
    _isfinite,
    _Node,
    _wrap,
    chain_at,
    correct,
    last_at_or_before,
    make_anchor,
    prior,
    propagate_pose,
)
from robot_agent.core.params import EstimatorParams

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


class Estimator:
    """Pose of one robot's axle centre at ``now`` (see the module docstring). It owns its state:
    the odometry chain's nodes, the anchors, the counters; the arithmetic over them is the
    plain functions of estimator_math.py."""

    __slots__ = (
        "_anch",
        "_anch_t",
        "_b_cmd",
        "_b_odom",
        "_cmd_q",
        "_first_is_init",
        "_fut_tol",
        "_gate",
        "_gate2",
        "_gated_run",
        "_h_d",
        "_h_oth",
        "_h_ox",
        "_h_oy",
        "_h_q",
        "_h_tu",
        "_head_nt",
        "_head_t",
        "_hist",
        "_last_odom_t",
        "_max_lat",
        "_max_unc",
        "_node_t",
        "_nodes",
        "_nsig",
        "_odom_q",
        "_odom_to",
        "_p",
        "_q_rad2",
        "_q_thm",
        "_q_ths",
        "_r_pos",
        "_r_th",
        "_still_q",
        "accepted",
        "last_reason",
        "rejected_duplicate",
        "rejected_future",
        "rejected_implausible",
        "rejected_nonfinite",
        "rejected_odometry",
        "rejected_old",
        "replayed",
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
        self._still_q = p.cmd_pos_var_per_s  # (standing still before the first twist)
        # 2 x theta_var_per_rad (TU sums |omega dt| / 2; the same bits as q * 2.0 inline)
        self._q_rad2 = p.theta_var_per_rad * 2.0
        self._b_cmd = p.max_dropout_cmd_s
        self._b_odom = p.max_dropout_odom_s
        self._fut_tol = p.future_tolerance_s
        self._gate = p.gate_m
        self._gate2 = p.gate_m * p.gate_m
        self._hist = p.history_s
        self._max_lat = p.max_latency_s
        self._max_unc = p.max_uncertainty_m
        self._nsig = p.n_sigma
        self._odom_to = p.odom_timeout_s
        self._q_thm = p.theta_var_per_m
        self._q_ths = p.theta_var_per_s
        self._nodes: list[_Node] = []
        self._node_t: list[float] = []
        self._anch: list[_Anchor] = []
        self._anch_t: list[float] = []
        # the head: the chain at _head_t (NaN: none) computed from the newest node then (the
        # last estimate's), the state (_h_ox, _h_oy, _h_oth, _h_d, _h_tu, _h_q); reused when a
        # segment starts at _head_t while that node is still the newest. That node is told by
        # its start time, _head_nt: nodes are only appended with later start times or dropped
        # with the head (plain float attributes, not a tuple: compiled, stored unboxed, no
        # tuple and no float objects every tick)
        self._head_t = math.nan
        self._head_nt = math.nan
        self._h_ox = 0.0
        self._h_oy = 0.0
        self._h_oth = 0.0
        self._h_d = 0.0
        self._h_tu = 0.0
        self._h_q = 0.0
        self._last_odom_t = -math.inf
        self._gated_run = 0
        self._first_is_init = False
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
        self._nodes.clear()
        self._node_t.clear()
        self._anch.clear()
        self._anch_t.clear()
        self._head_t = math.nan
        self._last_odom_t = -math.inf
        self._gated_run = 0

    def add_command(self, t_s: float, v_mps: float, omega_radps: float) -> None:
        """The commanded twist acts from ``t_s`` on (replaces guesses from ``t_s`` on)."""
        if not _isfinite(t_s + v_mps + omega_radps):
            return  # the firmware never commands non-finite speeds; nothing to learn
        nt = self._node_t
        nodes = self._nodes
        if nt and t_s <= nt[-1]:
            if nodes[-1].measured and t_s < nt[-1]:
                return  # never overwrite measured odometry with a guess
            self._truncate(t_s)
        elif nodes and nodes[-1].v == v_mps and nodes[-1].w == omega_radps:
            return  # same twist continues: one segment
        self._start_segment(t_s, v_mps, omega_radps, False)
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
        nt = self._node_t
        if nt and nt[-1] >= t0_s:
            self._truncate(t0_s)
        self._start_segment(t0_s, v_mps, omega_radps, True)
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
        if a.t == t_s:
            if a.zx == x and a.zy == y and a.zth == theta:
                return None  # the same pose presented again
            self.rejected_duplicate += 1
            return "second pose with the same capture time"
        # plausibility gate on the position innovation
        st = chain_at(self._nodes, self._node_t, self._still_q, t_s)
        px, py, _, pp, _ = prior(a, t_s, st, self._q_rad2, self._q_thm, self._q_ths)
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
        new = self._fuse(a, t_s, x, y, theta)
        if i < len(anch) - 1:
            self.replayed += 1
            later = anch[i + 1 :]
            del anch[i + 1 :]
            del anch_t[i + 1 :]
            anch.append(new)
            anch_t.append(t_s)
            self._refuse(later)
        else:
            anch.append(new)
            anch_t.append(t_s)
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
        ``estimate(now_s)``, returned. The stages inline the common case (inputs in time
        order): the same operations in the same order as the general methods, so the same bits
        (tests/unit/robot_agent/test_estimator.py checks it).
        """
        if seg_t_s == seg_t_s:  # not NaN
            self._twist_in(now_s, seg_t_s, v_mps, omega_radps, odometry)
        if capture_s is not None:
            self.last_reason = self._pose_in(now_s, capture_s, x, y, theta)
        return self.estimate(now_s)

    def _twist_in(
        self, now_s: float, seg_t_s: float, v_mps: float, omega_radps: float, odometry: bool
    ) -> None:
        """Stage 1 of ``tick``, the motion input (eq 9's twist): ``add_odometry(seg_t_s, now_s,
        v, omega)`` (``odometry``) or ``add_command(seg_t_s, v, omega)``; the common case, a
        new segment after the newest node, inlined (``_start_segment``)."""
        nt = self._node_t
        nodes = self._nodes
        if nt and seg_t_s <= nt[-1]:
            if odometry:
                self.add_odometry(seg_t_s, now_s, v_mps, omega_radps)
            else:
                self.add_command(seg_t_s, v_mps, omega_radps)
        elif odometry or not (nodes and nodes[-1].v == v_mps and nodes[-1].w == omega_radps):
            if odometry:
                qm, qs = self._odom_q
                if now_s > self._last_odom_t:
                    self._last_odom_t = now_s
            else:
                qm, qs = self._cmd_q
            if self._head_t == seg_t_s and nt[-1] == self._head_nt:  # (a head: nodes exist)
                node = _Node(seg_t_s, self._h_ox, self._h_oy, self._h_oth, self._h_d,
                             self._h_tu, self._h_q, v_mps, omega_radps, odometry, qm,
                             qs)  # fmt: skip
            else:
                ox, oy, oth, d_, tu, q = chain_at(nodes, nt, self._still_q, seg_t_s)
                node = _Node(seg_t_s, ox, oy, oth, d_, tu, q, v_mps, omega_radps, odometry, qm,
                             qs)  # fmt: skip
            nodes.append(node)
            nt.append(seg_t_s)
            anch_t = self._anch_t
            if anch_t and anch_t[-1] > seg_t_s:
                self._replay_after(seg_t_s)

    def _pose_in(self, now_s: float, t_s: float, x: float, y: float, theta: float) -> str | None:
        """Stage 2 of ``tick``, the camera pose captured at ``t_s``: ``add_measurement`` (its
        result returned), with the common case inlined: a pose younger than the newest anchor,
        inside the gate (the chain at ``t_s``, the prior through the newest anchor's frame,
        the Kalman update: ``chain_at``, ``prior``, ``correct`` and ``make_anchor``)."""
        nt = self._node_t
        nodes = self._nodes
        anch = self._anch
        anch_t = self._anch_t
        # (finite: x - x is 0.0 for a finite x only; the test without a call)
        if not (anch and anch_t[-1] < t_s <= now_s and now_s - t_s <= self._max_lat
                and (s := now_s + t_s + x + y + theta) - s == 0.0):  # fmt: skip
            return self.add_measurement(now_s, t_s, x, y, theta)
        # (-pi < a <= pi as two plain comparisons with a constant -pi: fewer bytecodes
        # than the chained form, and False for NaN alike)
        if not (theta > _NEG_PI and theta <= _PI):
            theta = _wrap(theta)
        # the chain at t_s (chain_at inlined: usually a node, no arc)
        j = last_at_or_before(nt, t_s + _TINY_S)  # the last node at or before t_s
        if j < 0:
            ox, oy, oth, d_, tu, q = chain_at(nodes, nt, self._still_q, t_s)
        else:
            n = nodes[j]
            if t_s - n.t < _TINY_S:  # (one assignment of six: compiled, no tuple is built)
                ox, oy, oth, d_, tu, q = n.ox, n.oy, n.oth, n.d, n.tu, n.q
            else:
                ox, oy, oth, d_, tu, q = _arc(n, t_s - n.t)
                if j == len(nt) - 1:  # after the newest node: the next segment's start
                    self._set_head(t_s, n.t, ox, oy, oth, d_, tu, q)
        # the prior through the newest anchor's frame (prior inlined)
        a = anch[-1]
        c = a.c
        s = a.s
        ppth = a.ppth
        dist = d_ - a.d
        px = c * ox - s * oy + a.tx
        py = s * ox + c * oy + a.ty
        pth = oth + a.fa
        pp = a.pp + (q - a.q) + ppth * dist * dist
        ppth = (ppth + self._q_rad2 * (tu - a.tu) + self._q_thm * dist
                + self._q_ths * (t_s - a.t))  # fmt: skip
        dx = x - px
        dy = y - py
        rp = self._r_pos
        d2 = dx * dx + dy * dy
        if d2 > self._gate2:  # else inside the gate without its sqrt (g >= gate_m)
            g = self._gate + self._nsig * _sqrt(pp + rp)
            jump = d2 > g * g
        else:
            jump = False
        if jump:
            return self.add_measurement(now_s, t_s, x, y, theta)
        # correct and make_anchor inlined
        self._gated_run = 0
        self.accepted += 1
        sv = pp + rp
        k = pp / sv if sv > 0.0 else 1.0
        sv = ppth + self._r_th
        kt = ppth / sv if sv > 0.0 else 1.0
        d = theta - pth
        if not (d > _NEG_PI and d <= _PI):
            d = _wrap(d)
        th = pth + kt * d
        if not (th > _NEG_PI and th <= _PI):
            th = _wrap(th)
        wx = px + k * (x - px)
        wy = py + k * (y - py)
        fa = th - oth
        c = _cos(fa)
        s = _sin(fa)
        anch.append(_Anchor(t_s, wx, wy, th, (1.0 - k) * pp, (1.0 - kt) * ppth, x, y, theta,
                            c, s, wx - (c * ox - s * oy), wy - (s * ox + c * oy), fa, d_, tu,
                            q))  # fmt: skip
        anch_t.append(t_s)
        if anch_t[0] < now_s - self._hist - 0.25:  # amortised: every ~0.25 s
            self._trim(now_s)
        return None

    def _set_head(self, t_s: float, node_t_s: float, ox: float, oy: float, oth: float,
                  d: float, tu: float, q: float) -> None:  # fmt: skip
        """The head: the chain ``(ox, oy, oth, d, tu, q)`` at ``t_s`` from the newest node,
        started at ``node_t_s``."""
        self._head_t = t_s
        self._head_nt = node_t_s
        self._h_ox = ox
        self._h_oy = oy
        self._h_oth = oth
        self._h_d = d
        self._h_tu = tu
        self._h_q = q

    # ------------------------------------------------------------------ the history

    def _start_segment(self, t_s: float, v: float, w: float, measured: bool) -> None:
        """Append a segment starting at ``t_s`` (after every node) with its node."""
        nodes = self._nodes
        qm, qs = self._odom_q if measured else self._cmd_q
        if self._head_t == t_s and self._node_t[-1] == self._head_nt:  # (a head: nodes exist)
            node = _Node(t_s, self._h_ox, self._h_oy, self._h_oth, self._h_d, self._h_tu,
                         self._h_q, v, w, measured, qm, qs)  # fmt: skip
        else:
            ox, oy, oth, d_, tu, q = chain_at(nodes, self._node_t, self._still_q, t_s)
            node = _Node(t_s, ox, oy, oth, d_, tu, q, v, w, measured, qm, qs)
        nodes.append(node)
        self._node_t.append(t_s)

    def _truncate(self, t_s: float) -> None:
        """Drop every segment starting at or after ``t_s``."""
        nodes = self._nodes
        nt = self._node_t
        while nt and nt[-1] >= t_s:
            nt.pop()
            nodes.pop()
        self._head_t = math.nan

    def _init(self, t_s: float, x: float, y: float, theta: float) -> None:
        """Start the anchors from the camera pose ``(x, y, theta)`` captured at ``t_s``."""
        st = chain_at(self._nodes, self._node_t, self._still_q, t_s)
        self._anch.append(make_anchor(t_s, x, y, theta, self._r_pos, self._r_th, x, y, theta, st))
        self._anch_t.append(t_s)
        self._gated_run = 0
        self._first_is_init = True

    def _fuse(self, a: _Anchor, t_s: float, zx: float, zy: float, zth: float) -> _Anchor:
        """Anchor ``a``'s prediction at ``t_s`` corrected with a measurement: the new anchor."""
        st = chain_at(self._nodes, self._node_t, self._still_q, t_s)
        px, py, pth, pp, ppth = prior(a, t_s, st, self._q_rad2, self._q_thm, self._q_ths)
        return correct(px, py, pth, pp, ppth, self._r_pos, self._r_th, t_s, zx, zy, zth, st)

    def _refuse(self, later: list[_Anchor]) -> None:
        """Fuse the measurements of ``later`` again, in order, after the newest anchor."""
        anch = self._anch
        anch_t = self._anch_t
        for b in later:
            anch.append(self._fuse(anch[-1], b.t, b.zx, b.zy, b.zth))
            anch_t.append(b.t)

    def _replay_after(self, t_s: float) -> None:
        """The twists from ``t_s`` on changed: re-fuse every anchor captured after ``t_s`` (the
        oldest is kept and re-based on the new chain)."""
        anch = self._anch
        anch_t = self._anch_t
        i = bisect_right(anch_t, t_s)
        if i >= len(anch_t):
            return
        if i == 0:
            a = anch[0]
            st = chain_at(self._nodes, self._node_t, self._still_q, a.t)
            anch[0] = make_anchor(a.t, a.x, a.y, a.th, a.pp, a.ppth, a.zx, a.zy, a.zth, st)
            i = 1
            if i >= len(anch_t):
                return
        later = anch[i:]
        del anch[i:]
        del anch_t[i:]
        self.replayed += 1
        self._refuse(later)

    def _trim(self, now_s: float) -> None:
        """Bound the history: anchors older than ``history_s`` (keeping the newest) and the
        nodes before the oldest anchor kept."""
        cutoff = now_s - self._hist
        anch_t = self._anch_t
        n = bisect_right(anch_t, cutoff)
        if n >= len(anch_t):
            n = len(anch_t) - 1
        if n > 0:
            del anch_t[:n]
            del self._anch[:n]
            self._first_is_init = False
        if anch_t:
            j = bisect_right(self._node_t, min(cutoff, anch_t[0])) - 1
            if j > 0:
                del self._node_t[:j]
                del self._nodes[:j]

    # ------------------------------------------------------------------ outputs

    def estimate(self, now_s: float) -> tuple[float, float, float, float] | None:
        """``(x, y, theta, uncertainty_m)`` at ``now_s``, or None when invalid (see module doc);
        stage 3 of ``tick``.

        ``uncertainty_m`` = ``n_sigma * sqrt(P)`` (m), for the safety filter's extra radius.
        The chain at ``now_s`` (usually the newest segment's arc: ``_arc`` inlined) through
        the newest anchor's frame (``prior`` inlined).
        """
        anch = self._anch
        nt = self._node_t
        nodes = self._nodes
        if not anch:
            return None
        a = anch[-1]
        age = now_s - a.t
        bound = self._b_odom if now_s - self._last_odom_t <= self._odom_to else self._b_cmd
        if not age <= bound:  # also False for NaN
            return None
        if age <= 0.0:
            ex, ey, eth, pp = a.x, a.y, a.th, a.pp
        else:
            if nt and nt[-1] <= now_s + _TINY_S:
                n = nodes[-1]
                nt0 = n.t
                dt = now_s - nt0
                ox = n.ox
                oy = n.oy
                oth = n.oth
                d_ = n.d
                tu = n.tu
                q = n.q
                if not dt < _TINY_S:  # _arc(n, dt) inlined
                    v = n.v
                    h = n.w * dt * 0.5
                    vdt = v * dt
                    if -0.1 < h < 0.1:  # _sinc inlined
                        h2 = h * h
                        chord = vdt * (1.0 - h2 * (1.0 / 6.0 - h2 * (1.0 / 120.0)))
                    else:
                        chord = vdt * (_sin(h) / h)
                    mid = oth + h
                    d = vdt if v >= 0.0 else -vdt  # (-v * dt: the same bits)
                    ox = ox + chord * _cos(mid)
                    oy = oy + chord * _sin(mid)
                    oth = mid + h
                    d_ = d_ + d
                    tu = tu + (h if h >= 0.0 else -h)
                    q = q + (n.qm * d + n.qs * dt)
                self._set_head(now_s, nt0, ox, oy, oth, d_, tu, q)
            else:
                ox, oy, oth, d_, tu, q = chain_at(nodes, nt, self._still_q, now_s)
            c = a.c
            s = a.s
            dist = d_ - a.d
            ex = c * ox - s * oy + a.tx
            ey = s * ox + c * oy + a.ty
            eth = oth + a.fa
            pp = a.pp + (q - a.q) + a.ppth * dist * dist
            if not (eth > _NEG_PI and eth <= _PI):
                eth = _wrap(eth)
        u = self._nsig * _sqrt(pp)
        if not u <= self._max_unc:
            return None
        return ex, ey, eth, u

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
            segments=len(self._nodes),
        )

    def twist(self, now_s: float) -> tuple[float, float] | None:
        """``(v_mps, omega_radps)``: the twist of the segment holding at ``now_s`` (eq 9's
        ``(v, omega)``: the encoders' mean where measured, else the commanded one), or None
        before any segment. Read-only (a status, never the control path)."""
        nt = self._node_t
        i = bisect_right(nt, now_s) - 1
        if i < 0:
            return None
        n = self._nodes[i]
        return n.v, n.w

    @property
    def last_capture_s(self) -> float | None:
        """Capture time of the newest fused camera pose (local clock), or None."""
        return self._anch_t[-1] if self._anch_t else None
