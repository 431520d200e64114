"""The estimator's arithmetic: the exact arc of the unicycle (``propagate_pose``, paper eq 9 over
constant ``(v, omega)``), the odometry chain and the correction frames of ``Estimator``: plain
functions over explicit arguments (the chain's nodes, an anchor, the noise variances), no state.
``Estimator`` (estimator.py) owns the nodes and the anchors and calls these.

Odometry chain and correction frame (the ``odom`` / ``map`` pair of ROS REP 105)
===============================================================================

The twists (segments of constant ``(v, omega)``) are integrated once, in an arbitrary *odometry
frame*, into a chain of **nodes**: a node is the start of a segment, with the dead-reckoned pose
there and the running sums the variances need (distance, turn, process noise)::

    node     = (t, ox, oy, oth, D, TU, Q, v, omega, measured, q_m, q_s)   (class _Node)
    state    = (ox, oy, oth, D, TU, Q)
    chain(t) = the state of the node at or before t, advanced along its segment's arc

``D`` is the distance travelled since the chain's origin, ``TU`` the sum of ``|omega dt| / 2``,
``Q`` the sum of the position process noise ``q_m |v| dt + q_s dt``; a propagation from ``t_a``
to ``t_b`` adds the differences ``D(t_b) - D(t_a)`` etc. Before the first node the robot stands
still (with the commanded-speed noise rate).

Each fused camera pose is an **anchor**: the posterior (x, y, theta, P, Pth) at its capture time
in the world, the measurement, and the *correction frame* that maps the chain onto the world
from that capture on (a rotation by ``A`` and a translation)::

    anchor   = (t, x, y, th, P, Pth, zx, zy, zth, cos A, sin A, tx, ty, A, D, TU, Q)  (_Anchor)
    world(t) = R(A) chain(t) + (tx, ty),  theta = chain_theta(t) + A     (t >= anchor.t)

(one flat object: the correction frame ``(cos A, sin A, tx, ty, A)`` and the chain's running sums
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
from typing import Final, final

_isfinite: Final = math.isfinite
_PI: Final = math.pi
_NEG_PI: Final = -math.pi
_TWO_PI: Final = 2.0 * math.pi

# A capture time within this of a node (both float sums of ticks) is taken at the node: at most
# nanometres of motion.
_TINY_S: Final = 1e-9

# chain state at a time: (ox, oy, oth, D, TU, Q)
_State = tuple[float, float, float, float, float, float]


@final
class _Node:
    """A node of the chain: the start ``t`` of a segment of twist ``(v, w)`` (``measured``:
    the encoders', else the commanded one; position noise rates ``qm`` (m^2/m), ``qs``
    (m^2/s)) and the chain's state there, ``(ox, oy, oth, d, tu, q)``. Immutable by
    convention. A small class, not a tuple: compiled, its floats are stored unboxed in one
    object (no float object to allocate, read or free per field)."""

    __slots__ = ("d", "measured", "oth", "ox", "oy", "q", "qm", "qs", "t", "tu", "v", "w")

    def __init__(self, t: float, ox: float, oy: float, oth: float, d: float, tu: float,
                 q: float, v: float, w: float, measured: bool, qm: float,
                 qs: float) -> None:  # fmt: skip
        self.t = t
        self.ox = ox
        self.oy = oy
        self.oth = oth
        self.d = d
        self.tu = tu
        self.q = q
        self.v = v
        self.w = w
        self.measured = measured
        self.qm = qm
        self.qs = qs


@final
class _Anchor:
    """An anchor (see the module docstring): the posterior ``(x, y, th, pp, ppth)`` at its
    capture time ``t``, the measurement ``(zx, zy, zth)``, the correction frame ``(c, s, tx,
    ty, fa)`` (``c = cos fa``, ``s = sin fa``) and the chain's sums ``(d, tu, q)`` at ``t``.
    Immutable by convention; a small class for the reason of ``_Node``."""

    __slots__ = ("c", "d", "fa", "pp", "ppth", "q", "s", "t", "th", "tu", "tx", "ty", "x", "y",
                 "zth", "zx", "zy")  # fmt: skip

    def __init__(self, t: float, x: float, y: float, th: float, pp: float, ppth: float,
                 zx: float, zy: float, zth: float, c: float, s: float, tx: float, ty: float,
                 fa: float, d: float, tu: float, q: float) -> None:  # fmt: skip
        self.t = t
        self.x = x
        self.y = y
        self.th = th
        self.pp = pp
        self.ppth = ppth
        self.zx = zx
        self.zy = zy
        self.zth = zth
        self.c = c
        self.s = s
        self.tx = tx
        self.ty = ty
        self.fa = fa
        self.d = d
        self.tu = tu
        self.q = q


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
    v = n.v
    h = n.w * dt * 0.5
    vdt = v * dt
    if -0.1 < h < 0.1:  # _sinc inlined
        h2 = h * h
        chord = vdt * (1.0 - h2 * (1.0 / 6.0 - h2 * (1.0 / 120.0)))
    else:
        chord = vdt * (_sin(h) / h)
    mid = n.oth + h
    d = vdt if v >= 0.0 else -vdt  # (-v * dt: the same bits)
    return (n.ox + chord * _cos(mid), n.oy + chord * _sin(mid), mid + h, n.d + d,
            n.tu + (h if h >= 0.0 else -h), n.q + (n.qm * d + n.qs * dt))  # fmt: skip


def last_at_or_before(times: list[float], t: float) -> int:
    """The index of the last of ``times`` (ascending) at or before ``t``, -1 if none: the same
    as ``bisect_right(times, t) - 1``, scanning back from the newest (a camera pose is a few
    ticks old and never older than ``max_latency_s``: a few steps; compiled, a native loop
    instead of a call of ``bisect`` over boxed floats)."""
    i = len(times) - 1
    while i >= 0 and times[i] > t:
        i -= 1
    return i


def chain_at(nodes: list[_Node], node_t: list[float], still_q_s: float, t: float) -> _State:
    """The chain's state at ``t`` (see the module docstring): the node at or before ``t``
    (``node_t`` holds the nodes' start times, ascending) advanced along its segment's arc;
    before every node the robot stands still, accruing ``still_q_s`` (m^2/s, the commanded-speed
    rate) of position noise."""
    i = len(node_t) - 1
    lim = t + _TINY_S
    if i >= 0 and node_t[i] > lim:
        i = bisect_right(node_t, lim) - 1
    if i < 0:  # before any known twist: standing still
        if not node_t:
            return 0.0, 0.0, 0.0, 0.0, 0.0, still_q_s * t
        n = nodes[0]
        return n.ox, n.oy, n.oth, n.d, n.tu, n.q + still_q_s * (t - n.t)
    n = nodes[i]
    dt = t - n.t
    if dt < _TINY_S:
        return n.ox, n.oy, n.oth, n.d, n.tu, n.q
    return _arc(n, dt)


def make_anchor(
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
    """The anchor of the posterior ``(x, y, th, pp, ppth)`` at ``t`` (measurement ``(zx, zy,
    zth)``) on chain state ``st``: its correction frame maps ``st`` onto the posterior."""
    ox, oy, oth, d_, tu, q = st
    a = th - oth
    c = _cos(a)
    s = _sin(a)
    return _Anchor(t, x, y, th, pp, ppth, zx, zy, zth,
                   c, s, x - (c * ox - s * oy), y - (s * ox + c * oy), a, d_, tu, q)  # fmt: skip


def prior(
    a: _Anchor, t: float, st: _State, q_rad2: float, q_thm: float, q_ths: float
) -> tuple[float, float, float, float, float]:
    """The prediction: anchor ``a`` propagated to ``t`` (chain state ``st`` there) through its
    correction frame, ``(x, y, theta, P, Pth)``; ``q_rad2`` (2 x ``theta_var_per_rad``: TU sums
    ``|omega dt| / 2``), ``q_thm``, ``q_ths``: the heading's process noise rates."""
    ox, oy, oth, d_, tu, q = st
    c = a.c
    s = a.s
    ppth = a.ppth
    dist = d_ - a.d
    return (c * ox - s * oy + a.tx, s * ox + c * oy + a.ty, oth + a.fa,
            a.pp + (q - a.q) + ppth * dist * dist,
            ppth + q_rad2 * (tu - a.tu) + q_thm * dist
            + q_ths * (t - a.t))  # fmt: skip


def correct(
    px: float,
    py: float,
    pth: float,
    pp: float,
    ppth: float,
    r_pos: float,
    r_th: float,
    t: float,
    zx: float,
    zy: float,
    zth: float,
    st: _State,
) -> _Anchor:
    """The correction: the Kalman update of the prior ``(px, py, pth, pp, ppth)`` at ``t`` with
    the measurement ``(zx, zy, zth)`` of variances ``r_pos`` (m^2, per axis) and ``r_th``
    (rad^2), the heading innovation wrapped; the posterior's anchor on chain state ``st``."""
    sv = pp + r_pos
    k = pp / sv if sv > 0.0 else 1.0
    sv = ppth + r_th
    kt = ppth / sv if sv > 0.0 else 1.0
    d = zth - pth
    if not -_PI < d <= _PI:
        d = _wrap(d)
    th = pth + kt * d
    if not -_PI < th <= _PI:
        th = _wrap(th)
    return make_anchor(t, px + k * (zx - px), py + k * (zy - py), th, (1.0 - k) * pp,
                       (1.0 - kt) * ppth, zx, zy, zth, st)  # fmt: skip
