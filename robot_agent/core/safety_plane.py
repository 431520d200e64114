"""The safety filter's shared-frame plane (``SafetyFilterParams.shared_frame``, issue 16).

Stdlib only, pure. :class:`robot_agent.core.safety_filter.SafetyFilter` calls
:meth:`SharedFramePlane.constraint` for a cooperative neighbour measured in the same camera frame
as this robot's own latest camera pose; the notation (``p``, ``c``, ``l``, ``Ds``, ``rho``,
``beta``, ``gamma``) is the filter's module docstring's.

The inflation ``V a_j`` pays for where a neighbour may have gone since its pose was captured:
13 mm for a 66 ms old pose at 0.2 m/s, more than the whole slack of a formation spaced 10 mm
beyond ``Ds + 2 l``. For a cooperative pair measured in the SAME camera frame both robots can
instead answer for their own motion since that frame, which each knows, and nobody needs a
bound on the other's speed. Notation for robot i and neighbour j: ``q_i``, ``q_j`` the reference
points (eqs 10-11) of the two camera poses of the frame (the anchors: stale and noisy, it does
not matter),
``d = |q_i - q_j|``, ``n = (q_i - q_j) / d``, ``H = d - D`` with ``D = Ds + 2 l``, the split
``s_i = 1/2 + x``, ``s_j = 1/2 - x`` in [0, 1], ``A = min(H, convoy_gap_m)``, and::

    G_i = n . (p_i - q_i) + s_i A + (H - A) / 2 - (rho_own - beta)+
    constraint:  n . u_i >= -gamma_i G_i,   gamma_i = min(gamma (1 + (k - 1) (2 s_i - 1)+), 1 / dt)

(the plane ``n . p = n . q_i - s_i A - (H - A)/2`` split between the two anchors; ``p_i`` is
this robot's reference point now, from its estimate). Proof of ``|c_i - c_j| >= Ds - 2 beta``:

1. *Complementary.* Robot j computes from the same frame ``n_j = -n``, the same ``d`` and
   ``H``, and ``s_j = 1 - s_i``: every operation on the pair's data is antisymmetric (negations
   and differences are exact in floating point; the split's two sums differ by rounding only,
   1e-16 of the gap). So ``G_i + G_j = n . (p_i - p_j) - D - excess_i - excess_j`` for any
   anchors: their noise and age cancel; each robot pays its own uncertainty beyond ``beta``.
2. *Each side.* ``G_i`` is affine in ``p_i`` (the anchors are fixed during the frame), so
   ``G_i(t + dt) = G_i + dt n . u_i >= (1 - gamma_i dt) G_i`` for either sign of ``G_i`` (when
   it is negative the constraint asks ``n . u_i >= gamma_i |G_i|``: move away), and
   ``gamma_i dt <= 1`` keeps ``G_i >= 0``. The gain is each side's own affair (the pair needs
   only both sides non-negative): the side that holds more of the gap (``s_i > 1/2``, the one
   behind in a convoy) closes on it at up to ``k = convoy_gain`` times gamma (2.5: 25 /s, still
   ``gamma dt <= 1`` at 30 Hz), as a robot alone before a wall could; with equal halves it is
   the reciprocal barrier's ``gamma H / 2`` each. A robot that stops dead (e-stop, HOLD, power
   cut) keeps its ``G``, which is no less when ``G >= 0``: with ``s`` in [0, 1] no robot counts
   on the other moving away, so stopping stays safe.
3. *The pair.* Hence ``S = G_i + G_j >= 0`` is invariant, and with the truth within
   ``max(beta, rho)`` of each estimate, ``|c_i - c_j| >= |p_i - p_j| - 2 l >= n . (p_i - p_j) -
   2 l >= Ds - 2 beta`` as in "Noise model".
4. *A new frame* replaces ``n`` by ``n'``; at the same positions both ``n . r - D`` and
   ``n' . r - D`` (``r = p_i - p_j``) are lower bounds of ``|r| - D``, the new one short by
   ``|r| (1 - cos angle(n', r)) <= delta^2 / (2 |r|)``, ``delta = |(q_i - q_j) - r|``: the
   anchors' noise, the estimates' error and the motion since the frame, at most ``4 beta + 2 V
   frame_max_age_s`` (76 mm with the defaults at 0.2 m/s: <= 10 mm at ``|r| = D``; with
   1-sigma noise and the anchor task's motion < 0.1 mm). A negative ``S`` recovers at rate
   gamma (step 2), so with a new frame every ``T_c`` the loss cannot pile up beyond
   ``e^(-gamma T_c) / (1 - e^(-gamma T_c))`` (2.5 at 30 Hz) times one: a second-order term
   like the heading change within a tick, paid by the part of ``margin_m`` beyond the two noise
   budgets (22 mm, sized for the latency and the tick of motion that the plane does not pay),
   except for 3-sigma noise aligned against the pair on every frame in a row.

It costs a robot its own approach toward the neighbour during the frame's age (a follower
chasing its leader at 43 mm/s: 2.8 mm in 66 ms) instead of ``V a``. The split: ``x =
convoy_share (c_i - c_j) g`` with ``c_i = -h_i . n`` (how much i heads toward j, ``h`` the unit
heading of the camera pose), ``c_j = h_j . n`` and ``g = (h_i . h_j - cos a0) / (1 - cos a0)``
clamped to [0, 1] (``a0 = convoy_angle_rad``): in a convoy (parallel headings, one behind the
other) the robot behind gets the gap, as the one ahead drives away from it; side by side or
crossing, half each. Only ``A`` (the first ``convoy_gap_m`` of the gap) is split unevenly, so a
far neighbour stays out of range for both. Any split is safe (step 1); this one decides only who
may use the gap.

Both robots must use the plane or neither (they are then in the reciprocal barrier above):
the plane is used only if ``shared_frame`` is on, the neighbour is cooperative with a heading,
this robot was TRACKING on the previous tick too (the neighbour's view of it: ``filter`` checks
that it was called then), the neighbour's age equals this robot's own camera pose's age (the
same capture: in-process and in lockstep a frame reaches every robot at the same tick, so both
robots see the match, or both a mismatch, e.g. one camera lost), that age is at most
``frame_max_age_s`` and the anchors differ. In realtime two robots can be on different frames
at the same moment: the realtime shells turn ``shared_frame`` off (``AgentConfig.realtime``).
What breaks it, as it breaks the reciprocal barrier: a robot flagged cooperative that moves
without its filter (carried by hand, coasting toward the other after a power cut).
"""

from __future__ import annotations

import math
from typing import Final

from robot_agent.core.params import AgentConfig
from robot_agent.core.qp import _TOL

__all__ = ["SharedFramePlane"]

_hypot: Final = math.hypot


class SharedFramePlane:
    """The plane's constants for one robot (module docstring), from its configuration."""

    __slots__ = ("_cgain", "_convoy", "_cos0", "_d_coop", "_gap", "_l", "bound")

    def __init__(self, config: AgentConfig) -> None:
        g = config.geometry
        p = config.safety_filter
        self._l = g.ref_offset_m
        self._d_coop = 2.0 * g.body_radius_m + p.margin_m + 2.0 * g.ref_offset_m  # p_i to p_j
        self._convoy = p.convoy_share
        self._cgain = p.convoy_gain - 1.0
        self._cos0 = math.cos(p.convoy_angle_rad)
        self._gap = p.convoy_gap_m
        #: constraints appended by ``constraint`` (in reach: they could bind), for diagnostics
        self.bound = 0

    def constraint(
        self,
        px: float,
        py: float,
        qx: float,
        qy: float,
        th: float,
        pl: tuple[float, float, float, float, float],
        rho: float,
        gamma: float,
        gmax: float,
        cap: float,
        cons: list[tuple[float, float, float]],
    ) -> float | None:
        """The shared-frame plane against a cooperative neighbour measured at ``(qx, qy, th)``
        in this robot's own frame ``pl`` (module docstring); appends its constraint when in
        range and returns ``G``. Every operation on the pair's data is antisymmetric in
        (this robot, the neighbour), so the neighbour, computing the same from the same frame,
        gets the opposite normal, the same ``H`` and the complementary share."""
        qix, qiy, hix, hiy, _ = pl
        hjx = math.cos(th)
        hjy = math.sin(th)
        l_m = self._l
        dx = qix - (qx + l_m * hjx)
        dy = qiy - (qy + l_m * hjy)
        d = _hypot(dx, dy)
        if not 0.0 < d < math.inf:  # coincident (or absurd) anchors, both see it: no plane
            return None
        nx = dx / d
        ny = dy / d
        big_h = d - self._d_coop
        # the convoy split: 1/2 + x for this robot, 1/2 - x for the neighbour (x antisymmetric)
        share = 0.5
        al = hix * hjx + hiy * hjy  # how parallel the headings are (symmetric)
        cos0 = self._cos0
        if al > cos0 and self._convoy > 0.0:
            ci = -(hix * nx + hiy * ny)  # this robot heads toward the neighbour
            cj = hjx * nx + hjy * ny  # the neighbour heads toward this robot
            share += self._convoy * (ci - cj) * ((al - cos0) / (1.0 - cos0))
            share = 0.0 if share < 0.0 else (1.0 if share > 1.0 else share)
        a = big_h if big_h < self._gap else self._gap
        g = nx * (px - qix) + ny * (py - qiy) + share * a + 0.5 * (big_h - a) - rho
        if share > 0.5:  # more of the gap is this side's: it may close on it faster
            gamma *= 1.0 + self._cgain * (2.0 * share - 1.0)
            if gamma > gmax:
                gamma = gmax
        b = -gamma * g
        if b > -cap - _TOL:
            cons.append((nx, ny, b))
            self.bound += 1
        return g
