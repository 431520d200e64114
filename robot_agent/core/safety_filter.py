"""Barrier-certificate safety filter on the reference-point velocity (last before eq 16).

Stdlib only, pure (time is passed in), one instance per robot. Each robot filters its own
command with what it knows (decentralised, as the paper's agents are): the positions of the other
robots, static obstacles (circles, segments; a polygon is its edges) and the arena rectangle.

Model and notation
==================
``p`` is this robot's reference point (eqs 10-11), ``c = p - l (cos theta, sin theta)`` its axle
centre, ``l`` the reference offset, ``r_b`` the body radius. Eq 16 gives the reference point
exactly the commanded velocity ``u`` (``p' = u``: the single integrator under the unicycle,
Robotarium's ``si_to_uni``), so the filter works on ``u`` and every barrier is a function of
``p``. ``Ds = 2 r_b + margin`` is the least centre distance between two robots; a robot's centre
keeps ``r_b + margin`` from an obstacle's surface and from the arena walls. ``rho`` is the extra
radius for this robot's own pose uncertainty beyond the noise the margin already pays for:
``rho = max(0, rho_own - beta)`` with ``rho_own`` the larger of ``extra_radius_m`` and the
estimator's ``pose_uncertainty_m`` and ``beta = noise_budget_m`` (see "Noise model" below);
``rho_j = max(0, radius_m - beta)`` likewise for a neighbour's own uncertainty.

Barriers (all distances, ``h >= 0`` is safe)::

    obstacle (circle centre o, radius r):  h = |p - o| - (r + r_b + margin + l + rho)
    segment (closest point q on it):       h = |p - q| - (r_seg + r_b + margin + l + rho)
    arena wall (x >= x_min, ...):          h = p_x - (x_min + r_b + margin + l + rho), ...
    neighbour j, not cooperative:          h = |p - c_j| - (Ds + l + rho + V a_j + rho_j)
    neighbour j, cooperative:              h = |p - p_j| - (Ds + 2 l + rho + V a_j + rho_j)

where ``c_j`` is the neighbour's measured centre, ``p_j = c_j + l (cos theta_j, sin theta_j)``
its reference point, ``a_j`` the age of that measurement (capped at ``max_age_s``), ``V`` the
neighbour top speed and ``rho_j`` its own extra radius. The obstacle and wall rows are built by
``robot_agent.core.safety_world``, the neighbour rows by ``robot_agent.core.safety_neighbours``;
this
module gathers them and solves.

Noise model (what ``margin`` pays for, so nothing is paid twice). A measured or estimated
position is within its uncertainty radius of the truth: ``r = 3 sigma`` of the camera noise for
a raw camera pose (``beta = noise_budget_m``, 9 mm for 3 mm per axis), ``rho_own`` for this
robot's estimate (the estimator's ``n_sigma * sqrt(P)``; below ``beta`` in steady state, as
fusing camera poses only shrinks their noise; above it while the camera is lost), ``radius_m``
for a neighbour that reports one. The margin holds ``beta`` for EACH of the two positions of a
pair (``2 beta <= margin``, enforced by ``SafetyFilterParams``): a neighbour's raw camera
position (``radius_m = 0``) has always been covered that way, and this robot's own position now
is too, so only an uncertainty beyond ``beta`` inflates a barrier. Then with ``h >= 0`` on the
positions the filter has, the TRUE centres keep ``|c_i - c_j| >= Ds - r_i - r_j + (r_i - beta)+
+ (r_j - beta)+ >= Ds - 2 beta = 2 r_b + (margin - 2 beta)`` (0.172 m with the defaults, bodies
touch at 0.15 m), and a true centre keeps ``r_b + margin - beta`` from an obstacle or a wall.
Adding the full ``rho_own`` on top of the margin (as before) counted this robot's noise twice: on
the anchor task with 60 ms latency and 3 mm noise it moved the formation's steady state 6-7 mm
further into the barrier (bench/bench_estimator.py, docs/benchmarks.md).

Why ``h >= 0`` keeps the BODIES apart (the offset l): ``|p - c| = l``, so by the triangle
inequality ``|c - o| >= |p - o| - l`` and ``|c_i - c_j| >= |p_i - c_j| - l >=
|p_i - p_j| - 2 l``. Hence ``h >= 0`` in the circle row gives ``|c - o| >= r + r_b + margin``
(centre clear of the surface by a body plus margin), in the neighbour rows ``|c_i - c_j| >= Ds``
(with the measured positions; the inflation ``V a_j`` covers where the neighbour can have gone
since), and in the wall row ``c_x >= p_x - l >= x_min + r_b + margin``. The segment row is the
same argument with the distance to a convex set.

The filter: ``u* = argmin |u - u_nom|^2`` subject to, for every barrier in range,
``n . u >= b`` with ``n = grad h`` (a unit vector) and

    b = -gamma * h                          obstacle, segment, wall, non-cooperative neighbour
        + n . v_j                           (non-cooperative neighbour with known velocity v_j)
    b = -gamma * h / 2                      cooperative neighbour (reciprocal, half each)

and ``|u| <= |u_nom|``: it never increases speed, except when some ``b > 0`` (the robot is
already inside a boundary, or a neighbour with a known velocity comes at it): then it may use
up to ``max_ref_speed_mps`` to get out. Discrete-time proof of invariance (the loop
holds ``u`` for one tick ``dt``): every ``h`` above is a distance to a convex set minus a
constant, hence a CONVEX function of ``p`` (of ``(p_i, p_j)`` for the pair row), so it lies
above its tangent: ``h(p + u dt) >= h(p) + dt n . u >= h(p) (1 - gamma dt) >= 0`` whenever
``h(p) >= 0`` and ``gamma dt <= 1`` (the filter lowers gamma to ``1 / dt`` on long ticks). For a
cooperative pair both robots run this filter and each contributes ``>= -gamma h / 2``, so the
pair's ``h`` obeys the same inequality (the reciprocal barrier of Wang, Ames and Egerstedt,
2017, the scheme of Robotarium's barrier certificates). Against a stationary or non-cooperative
neighbour, an obstacle or a wall the robot takes the full responsibility (``b = -gamma h``,
plus the neighbour's known velocity). A neighbour is treated as cooperative only when the shell
says so (``Neighbour.cooperative``: a fresh status says it is TRACKING with this firmware) and
its heading is known; even then, if it stops (e-stop, HOLD), ``n . u_i >= -gamma h / 2`` alone
still gives ``h(t + dt) >= (1 - gamma dt / 2) h >= 0``: halving only slows the approach, the
safety against a robot that stands still does not depend on it moving away. What is assumed:
the reference point moves at ``u`` during the tick (exact for eq 16 up to the heading change
within a tick, second order in dt, covered by ``margin_m``), a non-cooperative neighbour moves
at its given velocity (0 if none given) and a cooperative one runs this filter.

Shared-frame plane (``shared_frame``, issue 16): for a cooperative pair measured in the same
camera frame, a plane split between the two robots replaces the ``V a_j`` inflation; its
constraint, proof and conditions are in ``robot_agent.core.safety_plane``.

Solving: the QP is two-dimensional, so its optimum has at most two active constraints; the
filter enumerates the candidates exactly (``u_nom`` itself; the projection on each constraint
line; each pair of lines' intersection; each line's intersections with the speed circle) and
keeps the feasible one nearest to ``u_nom``. If none is feasible (already deep inside a
boundary, or pinched between constraints that ask for more than the cap) the robot LEAVES as
well as it can instead of freezing: "Leaving a barrier" below. The work is ``O(m^3)`` in the
``m`` constraints in range (typically 0-2; ``m = 0`` returns ``u_nom`` untouched: the identity
when nothing is near).

Leaving a barrier (the robot is inside, ``h < 0``: a start inside, noise, a neighbour's
inflation grown with its age, a neighbour turning in place, a pair switching barriers)
=====================================================================================
Then ``b = -share gamma h > 0`` and the robot may use the cap ``max_ref_speed_mps``. While
``b <= cap`` the constraint alone is feasible (``u = b n``) and the proof above gives
``h(t + dt) >= (1 - gamma dt) h(t)``: ``|h|`` shrinks geometrically (a pair: both robots).
When the demands cannot all be met (the old fallback stopped: two robots inside each other's
barrier by more than ``2 cap / gamma`` = 5 cm stood still forever, infeasible at every tick):

* one constraint, ``b > cap``: ``u = cap n``. By convexity ``h(p + u dt) >= h(p) + dt n . u =
  h(p) + cap dt > h(p)``: ``h`` strictly increases, at the largest rate any command of speed
  ``<= cap`` can give (``n . u <= |u| <= cap``), so this is the least-violation command; for a
  cooperative pair each robot adds ``cap dt`` (the pair row is convex in ``(p_i, p_j)``), and
  once ``b <= cap`` the geometric decay above takes over. From ``h_0 < 0`` a cooperative pair
  alone is within ``eps`` of its boundary after at most ``(|h_0| - H)+ / (2 cap) + dt ln(min(
  |h_0|, H) / eps) / (-ln(1 - gamma dt))`` seconds with ``H = 2 cap / gamma`` (a
  non-cooperative barrier: ``H = cap / gamma`` and ``cap`` instead of ``2 cap``), whatever the
  nominal command asks (tests/unit/formation/test_safety_recovery.py checks this bound).
* several constraints, none feasible (``robot_agent.core.qp.solve_qp_relaxed``): every constraint
  with ``b <= 0`` (a barrier that is safe and not approached: the ones the invariance proof
  needs) is kept EXACTLY; every "get out" demand ``b_k > 0`` is scaled by one common factor
  ``s``, the largest in ``[0, 1]`` for which ``F(s) = {|u| <= cap, n_k . u >= s b_k (b_k > 0),
  n_k . u >= b_k (b_k <= 0)}`` is not empty, and the QP is solved on ``F(s)``. ``F(0)`` holds
  ``u = 0`` (so this never fails), and ``F`` shrinks as ``s`` grows (``u`` in ``F(s1)`` gives
  ``(s / s1) u`` in ``F(s)`` for ``s <= s1``: the ``b <= 0`` rows hold for any ``t u``, ``t in
  [0, 1]``), so bisection finds ``s`` (to 1e-6, from below: ``F(s)`` is never empty). Every
  violated barrier then gets ``n_k . u >= s b_k >= 0``: by the same convexity bound it never
  decreases through this robot's command, strictly increases if ``s > 0`` (the largest common
  fraction of the demanded rates: least violation in the max-min sense), and the robot stops
  only when ``F(s) = {0}``. On EVERY constraint this is at least what the stop (``u = 0``)
  gave, so no barrier is worse off than before; the one kind of ``b > 0`` row with ``h >= 0``
  (a non-cooperative neighbour with a known velocity coming at it) is relaxed too, as no
  command keeps it when the set is infeasible. A robot pinched between opposite demands
  (``s = 0``) keeps the sideways part of its command (``n_k . u >= 0``), so it slides out or
  the deadlock tie-break moves it; until then its barriers wait on its neighbours (a
  cooperative one answers only its half, ``|h|`` decaying geometrically toward 0).

Why the non-cooperative distance stays below the cooperative one (a decision): a pair that
kept the non-cooperative row (``|p_i - c_j| >= Ds + l``) while one robot hung can be inside
the cooperative row (``|p_i - p_j| >= Ds + 2 l``) when it resumes. Making the first imply the
second needs ``Ds + 3 l`` (``|p_i - p_j| >= |p_i - c_j| - l``): 0.34 m instead of 0.24 m
against every stopped, held, booting or silent robot, which the formations and narrow passages
pay for, and it would still not keep robots out of barriers: a neighbour's inflation ``V a_j``
grows with its age while nothing can move, its reference point moves by up to ``2 l`` when it
turns in place, its ``radius_m`` grows when its camera is lost, scenarios start robots inside.
Leaving a barrier has to work anyway (above); with it, the switch costs a short retreat.

Wheel saturation after eq 16: ``admissible(ux, uy)`` tells the firmware whether the reference
velocity of the saturated wheels still meets the constraints; when it does not, the firmware
scales both wheels by one factor instead (the twist, and so ``u``, scales by ``s in (0, 1]``):
``n . (s u) >= b`` holds for every ``b <= 0`` (either ``n . u >= 0`` or ``n . s u >= n . u``).

What the filter costs a formation (a design rule, measured by ``bench/bench_estimator.py
--diagnose``): a cooperative neighbour leaves a robot's command untouched in steady state only
if their reference points are at least ``Ds + 2 l + V a + (rho_own - beta)+ + (rho_j - beta)+ +
2 s / gamma`` apart, ``s`` being the speed at which the robot's nominal command approaches the
neighbour's MEASURED reference point: the reciprocal half ``gamma h / 2`` allows no more, even
when the neighbour moves away as fast (a follower chasing its leader; the filter cannot count
on that: the leader may stop at any time, and a stopped neighbour must stay an obstacle).
Below that the filter holds the robot back until ``h`` is that large. On the Robotarium task
(triangle b = 0.3 m, this project's 0.075 m bodies: ``Ds + 2 l`` = 0.29 m) 60 ms of camera
latency alone (``V a`` = 0.2 m/s x 66 ms = 13 mm) puts the slots inside the barrier, and the
followers approach the leader's measured point at 43-55 mm/s (``2 s / gamma`` = 9-11 mm).

With the shared-frame plane (above) the same pair needs, for the robot with split ``s_i``,
``s_i H >= s a + s / gamma_i + noise``: its own approach over the frame's age ``a`` instead of
``V a``, and the whole gap at ``convoy_gain`` times the gain when it is the one behind in a
convoy. On the anchor task with 60 ms latency that leaves 10 - 2.8 - 1.8 = 5.4 mm for the
neighbour's 3 mm camera noise (1.28 mm RMS instead of 12.6; 1.68 mm with the plain gain, 5.4 mm
with equal halves; ``bench/bench_estimator.py --what-if``), with a filter that is safe against
a neighbour stopping dead and needs no bound on its speed or acceleration.

Deadlock tie-break: ``robot_agent.core.deadlock`` (when the filter holds a robot with no progress,
its
nominal command turns right, then left, for a while; the one other place the command can be
faster than the nominal one).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any, Final

from robot_agent.core.deadlock import Deadlock
from robot_agent.core.params import AgentConfig
from robot_agent.core.qp import (
    _TOL,
    _sqrt,
    solve_qp,
    solve_qp_relaxed,
)
from robot_agent.core.safety_neighbours import NeighbourBarriers
from robot_agent.core.safety_types import Neighbour, SafetyFilterStatus
from robot_agent.core.safety_world import WorldBarriers

__all__ = [
    "Neighbour",
    "SafetyFilter",
    "SafetyFilterStatus",
    "solve_qp",
]

_hypot: Final = math.hypot
_NAN: Final = math.nan
_INF: Final = math.inf
# a barrier below -1 um at the input counts as a violation (not rounding)
_VIOLATION_M: Final = 1e-6


class SafetyFilter:
    """One robot's safety filter and its deadlock tie-break (see the module docstring)."""

    __slots__ = (
        "_active",
        "_budget",
        "_cons",
        "_deadlock",
        "_evasions",
        "_gamma",
        "_gamma_slow",
        "_has_world",
        "_infeasible",
        "_last_t",
        "_min_h",
        "_n_nb",
        "_neighbours",
        "_push_m",
        "_rejected",
        "_rescaled",
        "_shared",
        "_ticks",
        "_vcap",
        "_violations",
        "_world",
        "enabled",
        "safety_distance_m",
    )

    def __init__(self, config: AgentConfig) -> None:
        g = config.geometry
        p = config.safety_filter
        self.enabled = p.enabled
        self.safety_distance_m = 2.0 * g.body_radius_m + p.margin_m
        clear = g.body_radius_m + p.margin_m + g.ref_offset_m  # p to an obstacle / a wall
        self._gamma = p.gamma_per_s
        self._gamma_slow = min(p.gamma_per_s, 1.0 / config.safety.max_dt_s)
        self._budget = p.noise_budget_m
        # how far evade() may push into a neighbour's barrier when pinned: 90 % of what the
        # margin holds beyond both positions' noise (centres keep > 2 r_b: module docstring)
        self._push_m = 0.9 * max(0.0, p.margin_m - 2.0 * p.noise_budget_m)
        self._vcap = config.gains.max_ref_speed_mps
        self._neighbours = NeighbourBarriers(config)
        self._world = WorldBarriers(config, clear)
        self._has_world = self._world.present
        self._deadlock = Deadlock(p, self._vcap)
        self._shared = p.shared_frame
        self._last_t = -math.inf  # now_s of the last filter() call (was TRACKING then)
        self._cons: list[tuple[float, float, float]] = []
        self._ticks = 0
        self._active = 0
        self._violations = 0
        self._infeasible = 0
        self._rescaled = 0
        self._rejected = 0
        self._evasions = 0
        self._n_nb = 0  # rows from neighbours at the head of the last constraints() list
        self._min_h = math.inf

    # ------------------------------------------------------------------ public API

    def status(self) -> SafetyFilterStatus:
        """Snapshot of the counters."""
        return SafetyFilterStatus(
            ticks=self._ticks,
            active_ticks=self._active,
            violations=self._violations,
            infeasible=self._infeasible,
            tiebreaks=self._deadlock.tiebreaks,
            tiebreak_active=self._deadlock.active,
            rescaled=self._rescaled,
            rejected=self._rejected + self._neighbours.rejected,
            min_clearance_m=self._min_h,
            constraints=len(self._cons),
        )

    @property
    def neighbour_range_m(self) -> float:
        """The farthest centre-to-centre distance (m) at which a neighbour can constrain this
        robot (any age up to ``max_age_s``, a neighbour radius up to 0.1 m, any command up to
        ``max_ref_speed_mps``; with ``shared_frame``, the plane's range too): a shell that
        pre-selects neighbours by distance must pass at least every neighbour within this
        range."""
        return self._neighbours.range_m(self._vcap, self._gamma_slow, self._shared)

    @property
    def plane_use(self) -> tuple[int, int, int]:
        """How the shared-frame plane was used since construction (``shared_frame``; for
        tests and diagnostics): ``(pairs, bound, other_frame)``, the cooperative neighbours in
        range the plane handled, the plane constraints among them that could bind (in reach:
        appended), and the cooperative neighbours in range, this robot having a frame, that
        were measured in another frame (the inflated barrier instead)."""
        nb = self._neighbours
        return nb.plane_pairs, nb.plane_bound, nb.other_frame

    @property
    def in_range(self) -> bool:
        """Some constraint was in range on the last ``filter`` call."""
        return bool(self._cons)

    def admissible(self, ux: float, uy: float) -> bool:
        """Whether ``u`` meets the constraints of the last ``filter`` call."""
        for ax, ay, b in self._cons:  # noqa: SIM110 (a plain loop: faster than all())
            if ax * ux + ay * uy < b - _TOL:
                return False
        return True

    @property
    def evasions(self) -> int:
        """Ticks on which ``evade`` moved a robot that was not tracking (issue 30)."""
        return self._evasions

    def count_rescaled(self) -> None:
        """The firmware rescaled saturated wheels uniformly to stay admissible."""
        self._rescaled += 1

    def reset_deadlock(self) -> None:
        """Forget deadlock timing (the robot left TRACKING)."""
        self._deadlock.reset()

    def _rho(self, extra_radius_m: float) -> float:
        """This robot's own uncertainty that inflates a barrier: only what is beyond the
        margin's noise budget (module docstring); 0 for a NaN."""
        rho = extra_radius_m - self._budget
        if not rho > 0.0:  # also NaN
            rho = 0.0
        return rho

    def _gamma_for(self, dt_s: float) -> float:
        """The barrier gain of a tick of ``dt_s`` (0 = unknown): lowered to ``1 / dt_s`` if
        larger (``gamma dt <= 1``, the invariance proof of the module docstring)."""
        gamma = self._gamma
        if not 0.0 < dt_s * gamma <= 1.0:
            gamma = 1.0 / dt_s if dt_s * self._gamma_slow > 1.0 else self._gamma_slow
        return gamma

    def reach_box_m(self, extra_radius_m: float, dt_s: float) -> float:
        """The half-width (m) of the box around the reference point outside which ``filter``
        (``extra_radius_m``, ``dt_s``: its arguments; no ``frame``) skips a neighbour entry of
        eight fields with no radius and no velocity without reading more of it: the bound its
        neighbour rows test first (``NeighbourBarriers.quick_m``, the same floats), for
        ``robot_agent.core.neighbour_select``. Not valid with the shared-frame plane, whose
        bound may be larger."""
        reach = (self._vcap + _TOL) / self._gamma_for(dt_s)
        return self._neighbours.quick_m(self._rho(extra_radius_m), reach)

    def constraints(
        self,
        px: float,
        py: float,
        cap: float,
        neighbours: Sequence[Any],
        obstacles: Sequence[tuple[float, float, float]] = (),
        extra_radius_m: float = 0.0,
        dt_s: float = 0.0,
        frame: tuple[float, float, float, float] | None = None,
    ) -> list[tuple[float, float, float]]:
        """The constraints ``(ax, ay, b)`` (``a . u >= b``) in range of a command of speed
        ``cap`` at reference point ``(px, py)``; updates the violation / clearance counters.
        ``dt_s`` is the tick (0 = unknown): gamma is lowered to ``1 / dt_s`` if larger.
        ``frame``: this robot's own latest camera pose ``(x, y, theta, age_s)`` when the
        shared-frame plane may be used (``filter`` passes it only with ``shared_frame`` on and
        when this robot was TRACKING on the previous tick); None: never."""
        rho = self._rho(extra_radius_m)
        gamma = self._gamma_for(dt_s)
        cons: list[tuple[float, float, float]] = []
        # A constraint n.u >= b can bind a command of speed <= cap only if b > -cap, that is
        # h < (cap + n.v) / (share * gamma): the reach beyond the boundary.
        reach = (cap + _TOL) / gamma
        min_h = self._neighbours.append(
            px, py, cap, reach, gamma, rho, dt_s, frame, neighbours, cons, _INF
        )
        self._n_nb = len(cons)
        if obstacles or self._has_world:
            min_h, bad = self._world.append(px, py, reach, gamma, rho, obstacles, cons, min_h)
            self._rejected += bad
        if min_h < -_VIOLATION_M:
            self._violations += 1
        if min_h < self._min_h:
            self._min_h = min_h
        return cons

    def filter(
        self,
        now_s: float,
        px: float,
        py: float,
        ux: float,
        uy: float,
        ex: float = 0.0,
        ey: float = 0.0,
        neighbours: Sequence[Any] = (),
        obstacles: Sequence[tuple[float, float, float]] = (),
        extra_radius_m: float = 0.0,
        dt_s: float = 0.0,
        frame: tuple[float, float, float, float] | None = None,
    ) -> tuple[float, float]:
        """The safe reference-point velocity nearest to ``(ux, uy)`` (m/s).

        Args:
            now_s: local clock (s), for the deadlock timer only.
            px, py: this robot's reference point (m), eqs 10-11.
            ux, uy: nominal reference-point velocity (m/s).
            ex, ey: tracking error, setpoint minus reference point (m): the goal direction of
                the deadlock tie-break.
            neighbours: ``(x, y)`` tuples or ``Neighbour``s (axle centres).
            obstacles: extra circles ``(x, y, radius_m)`` given per tick (besides the
                configured ``world``).
            extra_radius_m: this robot's own position uncertainty (m), added to every barrier.
            dt_s: this tick's length (s), 0 if unknown; see ``constraints``.
            frame: this robot's own latest camera pose ``(x, y, theta, age_s)`` (axle centre,
                heading, age on the same clock as the neighbours' ages), for the shared-frame
                plane; ignored unless ``shared_frame`` is on and this robot was TRACKING (this
                method was called) on the previous tick.

        Returns:
            ``(ux, uy)``: ``|u| <= |u_nom|`` except during a tie-break or to leave a boundary
            (``b > 0``; module docstring). When the constraints are infeasible, the
            least-violation command ("Leaving a barrier"; it does not meet the constraints, so
            ``admissible`` refuses a saturated turn and the firmware scales the wheels
            uniformly: ``n . (k u) >= 0`` still).
        """
        self._ticks += 1
        if not self.enabled:
            self._cons = []
            return ux, uy
        deadlock = self._deadlock
        # Deadlock.steer's common case inlined for speed (a call costs more than its body):
        # steer was called on the previous tick (within 0.5 s) and no tie-break is under way, so
        # it would only record now_s and return (ux, uy) unchanged. Else the full method.
        if 0.0 < now_s - deadlock._last_now <= 0.5 and not now_s < deadlock._tb_until:
            deadlock._last_now = now_s
            tiebreak = False
        else:
            ux, uy, tiebreak = deadlock.steer(now_s, ux, uy, ex, ey)
        if frame is not None:
            # the neighbours see this robot as cooperative iff it was TRACKING on the previous
            # tick, that is iff this method was called then: only then may it use the plane
            last = self._last_t
            if not (dt_s > 0.0 and now_s - last <= 1.5 * dt_s and self._shared):
                frame = None
        self._last_t = now_s
        cons = self.constraints(
            px, py, self._vcap, neighbours, obstacles, extra_radius_m, dt_s, frame
        )
        self._cons = cons
        if not cons:
            fx, fy = ux, uy
            # Deadlock.observe's case with nothing in range and no tie-break streak, inlined
            # for speed: it would only forget the stuck window
            if tiebreak or deadlock._tb_streak:
                deadlock.observe(now_s, ex, ey, False, tiebreak)
            else:
                deadlock._stuck_since = _NAN
            return fx, fy
        if len(cons) == 1:  # the common case, in closed form (same result as solve_qp)
            ax, ay, b = cons[0]
            dot = ax * ux + ay * uy
            if dot >= b - _TOL:
                fx, fy = ux, uy
            else:
                t = b - dot
                fx = ux + t * ax
                fy = uy + t * ay
                # the speed cap: |u_nom|, or max_ref_speed when it must move away (inside a
                # boundary / approached: b > 0), computed only here where it is used
                cap = self._vcap if b > 0.0 else _hypot(ux, uy)
                cap2 = cap * cap
                if fx * fx + fy * fy > cap2 * (1.0 + 1e-12) + 1e-18:
                    r2 = cap2 - b * b
                    if r2 < 0.0:  # asks for more than cap away: out along n at the cap
                        # (module docstring, "Leaving a barrier": h strictly increases)
                        fx = cap * ax
                        fy = cap * ay
                        self._infeasible += 1
                    else:  # the end of the chord nearest the projection
                        r = _sqrt(r2) if ax * uy - ay * ux >= 0.0 else -_sqrt(r2)
                        fx = b * ax - r * ay
                        fy = b * ay + r * ax
                self._active += 1
        else:
            cap = _hypot(ux, uy)
            for con in cons:
                if con[2] > 0.0:  # must move away (inside a boundary / approached): may speed up
                    cap = self._vcap
                    break
            fx, fy, feasible = solve_qp(ux, uy, cons, cap)
            if not feasible:  # the least-violation fallback (module docstring)
                fx, fy, _, _ = solve_qp_relaxed(ux, uy, cons, cap)
                self._infeasible += 1
            if fx != ux or fy != uy:
                self._active += 1
        if not tiebreak:  # (observe does nothing during a tie-break with something in range)
            deadlock.observe(now_s, ex, ey, True, False)
        return fx, fy

    def evade(
        self,
        px: float,
        py: float,
        neighbours: Sequence[Any] = (),
        obstacles: Sequence[tuple[float, float, float]] = (),
        extra_radius_m: float = 0.0,
        dt_s: float = 0.0,
    ) -> tuple[float, float]:
        """The filter with a ZERO nominal command, for a robot that is not tracking (HOLD,
        IDLE; issue 30, "Movers"): ``(0, 0)`` while every barrier holds and nothing comes at
        it (every ``b <= 0``: standing still keeps them, the invariance proof of the module
        docstring with ``u = 0``); else the least-norm command that meets the "get out"
        demands (``b > 0``: a body or a neighbour with a known velocity approaching, or the
        robot already inside a boundary), at up to ``max_ref_speed_mps``, and when they cannot
        all be met the least-violation command ("Leaving a barrier"). So a robot that stopped
        trying to reach a slot still gets out of the way of a body carried at it.

        Unlike ``filter`` it runs no deadlock tie-break, does not count a filter tick and does
        not mark this robot as having been TRACKING (the shared-frame plane's condition): a
        robot in HOLD is a non-cooperative neighbour to the others, and answers for itself.
        ``admissible`` then refers to these constraints (the firmware's saturation stage)."""
        if not self.enabled:
            self._cons = []
            return 0.0, 0.0
        cons = self.constraints(
            px, py, self._vcap, neighbours, obstacles, extra_radius_m, dt_s, None
        )
        self._cons = cons
        for con in cons:
            if con[2] > 0.0:
                break
        else:  # no demand: u = 0 meets every constraint (exactly the old HOLD output)
            return 0.0, 0.0
        cap = self._vcap
        if len(cons) == 1:  # closed form: b n, or the cap along n
            ax, ay, b = cons[0]
            if b > cap:
                self._infeasible += 1
                b = cap
            fx, fy = b * ax, b * ay
        else:
            fx, fy, feasible = solve_qp(0.0, 0.0, cons, cap)
            if not feasible:
                # Pinned (a body at it, other robots behind): push into the others' barriers
                # by up to ``_push_m``, so that they in turn get out of the way (their own rows
                # see this robot inside and they evade), instead of waiting for the body
                push = self._gamma * self._push_m
                soft = [
                    (ax, ay, b - push if k < self._n_nb else b)
                    for k, (ax, ay, b) in enumerate(cons)
                ]
                fx, fy, feasible = solve_qp(0.0, 0.0, soft, cap)
                if not feasible:
                    fx, fy, _, _ = solve_qp_relaxed(0.0, 0.0, soft, cap)
                    self._infeasible += 1
        if fx != 0.0 or fy != 0.0:
            self._evasions += 1
        return fx, fy
