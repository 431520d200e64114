"""The estimator's arithmetic: the exact arc of the unicycle (``propagate_pose``, paper eq 9 over
constant ``(v, omega)``), the odometry chain and the correction frames of ``Estimator``, as the
base class ``_EstimatorMath``.

Odometry chain and correction frame (the ``odom`` / ``map`` pair of ROS REP 105)
===============================================================================

The twists (segments of constant ``(v, omega)``) are integrated once, in an arbitrary *odometry
frame*, into a chain of **nodes**: a node is the start of a segment, with the dead-reckoned pose
there and the running sums the variances need (distance, turn, process noise)::

    node     = (t, state, v, omega, measured, q_m, q_s),  state = (ox, oy, oth, D, TU, Q)
    chain(t) = the state of the node at or before t, advanced along its segment's arc

``D`` is the distance travelled since the chain's origin, ``TU`` the sum of ``|omega dt| / 2``,
``Q`` the sum of the position process noise ``q_m |v| dt + q_s dt``; a propagation from ``t_a``
to ``t_b`` adds the differences ``D(t_b) - D(t_a)`` etc. Before the first node the robot stands
still (with the commanded-speed noise rate).

Each fused camera pose is an **anchor**: the posterior (x, y, theta, P, Pth) at its capture time
in the world, the measurement, and the *correction frame* that maps the chain onto the world
from that capture on (a rotation by ``A`` and a translation)::

    anchor   = (t, x, y, th, P, Pth, zx, zy, zth, cos A, sin A, tx, ty, A, D, TU, Q)
    world(t) = R(A) chain(t) + (tx, ty),  theta = chain_theta(t) + A     (t >= anchor.t)

(one flat tuple: the correction frame ``(cos A, sin A, tx, ty, A)`` and the chain's running sums
``D, TU, Q`` at the capture inline). The unicycle's motion over a twist is the same in any rigid
frame, so this is the pose a propagation from the anchor gives (equal to rounding). The estimate
at ``now`` is then one arc (from the newest node) and a rigid transform, whatever the camera
latency; a camera pose's prior is the chain at its capture time (usually a node: no arc) through
the frame before it. A change of the twists from ``t`` on rebuilds the nodes from ``t`` and
re-fuses the anchors after it (the oldest kept anchor is re-based: same posterior, frame
recomputed on the new chain); a late camera pose re-fuses the anchors after it. Live and batch
runs do the same operations in the same order.
"""

from __future__ import annotations

import math
from bisect import bisect_right
from math import cos as _cos  # (imported, not assigned: mypyc compiles these to C calls)
from math import sin as _sin

from robot_agent.core.params import EstimatorParams

_isfinite = math.isfinite
_PI = math.pi
_NEG_PI = -math.pi
_TWO_PI = 2.0 * math.pi

# A capture time within this of a node (both float sums of ticks) is taken at the node: at most
# nanometres of motion.
_TINY_S = 1e-9

# chain state at a time: (ox, oy, oth, D, TU, Q)
_State = tuple[float, float, float, float, float, float]
# node tuple fields: (t, state, v, omega, measured, q_m, q_s)
_Node = tuple[float, _State, float, float, bool, float, float]
# anchor tuple fields (flat): (t, x, y, th, P, Pth, zx, zy, zth, cos A, sin A, tx, ty, A, D, TU,
# Q): the posterior, the measurement, the correction frame and the chain's sums at t
_Anchor = tuple[
    float, float, float, float, float, float, float, float, float,
    float, float, float, float, float, float, float, float,
]  # fmt: skip


def _wrap(a: float) -> float:
    """Angle to (-pi, pi] (finite input)."""
    r = (_PI - a) % _TWO_PI
    if not r < _TWO_PI:
        r = 0.0
    return _PI - r


def _sinc(h: float) -> float:
    """sin(h) / h, 1 at 0 (a series below |h| = 0.1: relative error < 3e-10)."""
    if -0.1 < h < 0.1:
        h2 = h * h
        return 1.0 - h2 * (1.0 / 6.0 - h2 * (1.0 / 120.0))
    return _sin(h) / h


def propagate_pose(
    x: float, y: float, theta: float, v: float, omega: float, dt: float
) -> tuple[float, float, float]:
    """Exact unicycle integration (eq 9) of a constant twist over ``dt`` s; theta not wrapped."""
    h = omega * dt * 0.5
    chord = v * dt * _sinc(h)
    mid = theta + h
    return x + chord * _cos(mid), y + chord * _sin(mid), mid + h


def _arc(n: _Node, dt: float) -> _State:
    """The chain ``dt`` s after node ``n`` (its segment's twist held): eq 9, and the sums."""
    _, st, v, w, _, qm, qs = n
    ox, oy, oth, d_, tu, q = st
    h = w * dt * 0.5
    vdt = v * dt
    if -0.1 < h < 0.1:  # _sinc inlined
        h2 = h * h
        chord = vdt * (1.0 - h2 * (1.0 / 6.0 - h2 * (1.0 / 120.0)))
    else:
        chord = vdt * (_sin(h) / h)
    mid = oth + h
    d = vdt if v >= 0.0 else -vdt  # (-v * dt: the same bits)
    return (ox + chord * _cos(mid), oy + chord * _sin(mid), mid + h, d_ + d,
            tu + (h if h >= 0.0 else -h), q + (qm * d + qs * dt))  # fmt: skip


class _EstimatorMath:
    """The chain and anchor internals of :class:`robot_agent.core.estimator.Estimator` (its base
    class); the state is declared here and set by ``Estimator.__init__``."""

    __slots__ = (
        "_anch",
        "_anch_t",
        "_cmd_q",
        "_first_is_init",
        "_gated_run",
        "_head",
        "_node_t",
        "_nodes",
        "_p",
        "_q_rad2",
        "_q_thm",
        "_q_ths",
        "_r_pos",
        "_r_th",
        "replayed",
    )
    _p: EstimatorParams
    _r_pos: float
    _r_th: float
    _cmd_q: tuple[float, float]
    _q_rad2: float  # 2 x theta_var_per_rad (TU sums |omega dt| / 2)
    _q_thm: float
    _q_ths: float
    _nodes: list[_Node]
    _node_t: list[float]
    _anch: list[_Anchor]
    _anch_t: list[float]
    _gated_run: int
    _first_is_init: bool
    # (t, node, state): the chain at t computed from that node (the last estimate's); reused
    # when a segment starts at t
    _head: tuple[float, _Node, _State] | None
    replayed: int

    # ------------------------------------------------------------------ the chain

    def _chain_at(self, t: float) -> _State:
        """The chain's state at ``t`` (see the module docstring)."""
        nt = self._node_t
        i = len(nt) - 1
        lim = t + _TINY_S
        if i >= 0 and nt[i] > lim:
            i = bisect_right(nt, lim) - 1
        if i < 0:  # before any known twist: standing still
            qs = self._cmd_q[1]
            if not nt:
                return 0.0, 0.0, 0.0, 0.0, 0.0, qs * t
            n = self._nodes[0]
            ox, oy, oth, d_, tu, q = n[1]
            return ox, oy, oth, d_, tu, q + qs * (t - n[0])
        n = self._nodes[i]
        dt = t - n[0]
        if dt < _TINY_S:
            return n[1]
        return _arc(n, dt)

    def _start_segment(self, t_s: float, v: float, w: float, measured: bool) -> None:
        """Append a segment starting at ``t_s`` (after every node) with its node."""
        head = self._head
        nodes = self._nodes
        if head is not None and head[0] == t_s and nodes and head[1] is nodes[-1]:
            st = head[2]
        else:
            st = self._chain_at(t_s)
        qm, qs = self._p_rates(measured)
        nodes.append((t_s, st, v, w, measured, qm, qs))
        self._node_t.append(t_s)

    def _p_rates(self, measured: bool) -> tuple[float, float]:
        p = self._p
        if measured:
            return p.odom_pos_var_per_m, p.odom_pos_var_per_s
        return self._cmd_q

    def _truncate(self, t_s: float) -> None:
        """Drop every segment starting at or after ``t_s``."""
        nodes = self._nodes
        nt = self._node_t
        while nt and nt[-1] >= t_s:
            nt.pop()
            nodes.pop()
        self._head = None

    # ------------------------------------------------------------------ anchors

    def _anchor(
        self,
        t: float,
        x: float,
        y: float,
        th: float,
        pp: float,
        ppth: float,
        zx: float,
        zy: float,
        zth: float,
        st: _State,
    ) -> _Anchor:
        """The anchor of the posterior ``(x, y, th, pp, ppth)`` at ``t`` on chain state ``st``:
        its correction frame maps ``st`` onto the posterior."""
        ox, oy, oth, d_, tu, q = st
        a = th - oth
        c = _cos(a)
        s = _sin(a)
        return (t, x, y, th, pp, ppth, zx, zy, zth,
                c, s, x - (c * ox - s * oy), y - (s * ox + c * oy), a, d_, tu, q)  # fmt: skip

    def _prior(self, a: _Anchor, t: float, st: _State) -> tuple[float, float, float, float, float]:
        """Anchor ``a`` propagated to ``t`` (chain state ``st``): (x, y, theta, P, Pth)."""
        ox, oy, oth, d_, tu, q = st
        at, _, _, _, app, ppth, _, _, _, c, s, tx, ty, fa, ad, atu, aq = a
        dist = d_ - ad
        return (c * ox - s * oy + tx, s * ox + c * oy + ty, oth + fa,
                app + (q - aq) + ppth * dist * dist,
                ppth + self._q_rad2 * (tu - atu) + self._q_thm * dist
                + self._q_ths * (t - at))  # fmt: skip

    def _init(self, t_s: float, x: float, y: float, theta: float) -> None:
        st = self._chain_at(t_s)
        self._anch.append(self._anchor(t_s, x, y, theta, self._r_pos, self._r_th, x, y, theta, st))
        self._anch_t.append(t_s)
        self._gated_run = 0
        self._first_is_init = True

    def _fuse(self, a: _Anchor, t_s: float, zx: float, zy: float, zth: float) -> _Anchor:
        """Kalman update of anchor ``a``'s prediction at ``t_s`` with a measurement."""
        st = self._chain_at(t_s)
        px, py, pth, pp, ppth = self._prior(a, t_s, st)
        sv = pp + self._r_pos
        k = pp / sv if sv > 0.0 else 1.0
        sv = ppth + self._r_th
        kt = ppth / sv if sv > 0.0 else 1.0
        d = zth - pth
        if not -_PI < d <= _PI:
            d = _wrap(d)
        th = pth + kt * d
        if not -_PI < th <= _PI:
            th = _wrap(th)
        return self._anchor(t_s, px + k * (zx - px), py + k * (zy - py), th, (1.0 - k) * pp,
                            (1.0 - kt) * ppth, zx, zy, zth, st)  # fmt: skip

    def _refuse(self, later: list[_Anchor]) -> None:
        """Fuse the measurements of ``later`` again, in order, after the newest anchor."""
        anch = self._anch
        anch_t = self._anch_t
        for b in later:
            anch.append(self._fuse(anch[-1], b[0], b[6], b[7], b[8]))
            anch_t.append(b[0])

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
            anch[0] = self._anchor(a[0], a[1], a[2], a[3], a[4], a[5], a[6], a[7], a[8],
                                   self._chain_at(a[0]))  # fmt: skip
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
        cutoff = now_s - self._p.history_s
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
