"""A replan's bridge on the followed plan (pure: no clock).

The paper's global coordinator "creates no-collision trajectories of the virtual leader"; a
replan at run time must keep that while the new plan is computed. The straight bridge
(``replan.Bridge``) holds the leader's heading for at least ``BRIDGE_S``: asked while the
formation rounds an obstacle, that straight line leaves the followed plan, where the formation
may fit in no heading (the planner then answers "no way" and the leader stops).
:class:`PlanBridge` instead keeps the leader ON the plan it follows (a run-time plan, or a
``kind = "plan"`` script), the collision-free trajectory already checked, as a fixed function of
the time ``e`` since the ask ``t0_s``:

* its progress on the followed plan advances at the rate ``r0`` the leader had at the ask (the
  team's wait is not applied on a bridge, as on the straight one) for ``hold_s``:
  ``tau(e) = tau0 + r0 e``, the leader is the plan's state at ``tau`` with its speed and turn
  rate times ``r0`` (eqs 1-2 along the planned path);
* ``hold_s`` is at least the least bridge, and is lengthened (on the :data:`STEP_S` grid) until
  the plan is on a straight piece of its path: the new plan then starts where the leader goes
  straight, along its heading, at its speed (``planner.plan`` leaves along the start heading),
  so position, heading, speed AND turn rate are continuous at the switch;
* after ``hold_s`` the rate falls to 0 at ``brake_per_s`` (a late realtime plan: the leader
  brakes to a stop on the followed path).

:func:`bridge_on_plan` says whether such a bridge may be used: the followed plan must go on
beyond the bridge's stop, not squeeze within it (a bridge keeps the nominal formation), and the
formation's slots along it (to its stop) must clear the obstacles added at run time; else it
says why not (the coordinator then brakes on the straight bridge, and the reason is in the
status's ``plan_why``). :func:`clear_to_end`: whether the whole rest of the followed plan is
still clear; then a replan that finds no way from the bridge's end does not stop the leader:
it goes on along the followed plan from where the bridge is (the plan it had is still a
collision-free trajectory of the new world).
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Mapping, Sequence
from typing import Any, Final

import numpy as np

from coordinator.core.trajectory import LeaderState, wrap_angle

from .timed import NOMINAL_Q, TimedPlan
from .world import PlanWorld

__all__ = ["BLOCKED", "MAX_HOLD_S", "STEP_S", "PlanBridge", "bridge_on_plan", "clear_to_end"]

BLOCKED: Final = "the followed plan is blocked within the bridge"

STEP_S: Final = 0.005
"""Grid of the bridge's hold (s): the same as the straight bridge's sub-step."""
MAX_HOLD_S: Final = 6.0
"""Longest hold waiting for a straight piece (s); beyond it the bridge ends where the least hold
does, on the curve (the new plan then leaves along the tangent)."""
DEPARTURE_M: Final = 0.4
"""Longest straight departure of a plan asked from a bridge on the followed plan (m): the
planner's own."""
MIN_DEPARTURE_M: Final = 0.1
"""Shortest such departure (m): nearer the corner point the planner's own departures are
used (a corner right after the start leaves no room for its arc)."""
_STRAIGHT_AHEAD_M: Final = 0.01
"""The hold ends at least this far (m) into a straight piece (past its first timing sample)."""


class PlanBridge:
    """The leader on the followed plan while a plan is computed (module docstring): a fixed
    function of the time since ``t0_s``."""

    __slots__ = ("brake_per_s", "followed", "hold_s", "rate", "t0_s", "tau0_s")

    def __init__(
        self,
        followed: TimedPlan,
        tau0_s: float,
        rate: float,
        t0_s: float,
        *,
        least_s: float,
        brake_per_s: float,
    ) -> None:
        self.followed = followed
        self.tau0_s = tau0_s
        self.rate = min(max(rate, 0.0), 1.0)
        self.t0_s = t0_s
        self.brake_per_s = brake_per_s
        self.hold_s = _hold_s(followed, tau0_s, self.rate, least_s)

    def progress(self, e_s: float) -> tuple[float, float]:
        """(plan time on the followed plan, rate) at ``e_s`` after the ask."""
        r0, hold = self.rate, self.hold_s
        if e_s <= hold:
            return self.tau0_s + r0 * e_s, r0
        b = e_s - hold
        t_stop = r0 / self.brake_per_s
        if b >= t_stop:
            b = t_stop
        return self.tau0_s + r0 * hold + r0 * b - 0.5 * self.brake_per_s * b * b, r0 - (
            self.brake_per_s * b
        )

    @property
    def stop_tau_s(self) -> float:
        """The plan time where the bridge stops if no plan is switched in."""
        return self.progress(self.hold_s + self.rate / self.brake_per_s)[0]

    @property
    def v_join_mps(self) -> float:
        """The speed at the end of the hold (the new plan starts with it)."""
        return self.state_at(self.t0_s + self.hold_s).v_mps

    def departure_m(self, now_s: float) -> float | None:
        """How far (m) the new plan asked at ``now_s`` may leave straight along its heading
        and stay on the followed route: to the corner point of the followed path ahead (the
        route's vertex its arc rounds), at most :data:`DEPARTURE_M`; None when the bridge is on
        a curve there."""
        s_end = self.followed.where(self.progress(max(0.0, now_s - self.t0_s))[0])[0]
        pieces = self.followed.result.pieces
        i = max(0, bisect.bisect_right([p.s0 for p in pieces], s_end) - 1)
        p = pieces[i]
        if p.kappa != 0.0:
            return None
        d = p.s0 + p.length - s_end
        if i + 1 < len(pieces) and pieces[i + 1].kappa != 0.0:
            arc = pieces[i + 1]
            d += math.tan(0.5 * arc.length * abs(arc.kappa)) / abs(arc.kappa)
        return min(DEPARTURE_M, d) if d >= MIN_DEPARTURE_M else None

    def state_at(self, now_s: float) -> LeaderState:
        """The leader at ``now_s`` (>= ``t0_s``; earlier reads as ``t0_s``)."""
        tau, r = self.progress(max(0.0, now_s - self.t0_s))
        x, y, th, v, w = self.followed.state(tau)
        return LeaderState(now_s, x, y, wrap_angle(th), r * v, r * w)


def _hold_s(followed: TimedPlan, tau0_s: float, rate: float, least_s: float) -> float:
    """The hold (module docstring): ``least_s`` on the :data:`STEP_S` grid, lengthened to the
    next straight piece of the followed path when the least hold ends on a curve."""
    least = math.ceil(least_s / STEP_S - 1e-9) * STEP_S
    if rate <= 0.0:
        return least
    r = followed.result
    s_end = followed.where(tau0_s + rate * least)[0]
    pieces = r.pieces
    i = max(0, bisect.bisect_right([p.s0 for p in pieces], s_end) - 1)
    if pieces[i].kappa == 0.0 and s_end >= pieces[i].s0 + _STRAIGHT_AHEAD_M:
        return least
    lines = [p.s0 for p in pieces[i:] if p.kappa == 0.0]
    if not lines:
        return least  # curved to the goal: leave along the tangent
    s_m = r.s_m
    k = int(np.searchsorted(s_m, lines[0] + _STRAIGHT_AHEAD_M))
    if k >= len(s_m):
        return least
    steps = math.ceil((float(r.t_s[k]) - tau0_s) / rate / STEP_S - 1e-9)
    hold = max(least, steps * STEP_S)
    return hold if hold <= MAX_HOLD_S else least


def bridge_on_plan(
    bridge: PlanBridge,
    offsets_m: Sequence[tuple[float, float]],
    added: Sequence[Mapping[str, Any]],
    slot_radius_m: float,
) -> str | None:
    """Why ``bridge`` may not be used (module docstring), or None: the followed plan ends or
    squeezes before the bridge stops, or a slot along it (nominal ``offsets_m`` in the leader's
    frame) comes within ``slot_radius_m`` of an obstacle of ``added`` (the run's)."""
    f = bridge.followed
    tau_stop = bridge.stop_tau_s
    if tau_stop >= f.duration_s:
        return "the followed plan ends within the bridge"
    r = f.result
    s0 = f.where(bridge.tau0_s)[0]
    s1 = f.where(tau_stop)[0]
    k0 = max(0, int(np.searchsorted(r.s_m, s0)) - 1)
    k1 = min(len(r.s_m) - 1, int(np.searchsorted(r.s_m, s1)) + 1)
    if float(np.max(r.q[k0 : k1 + 1])) > NOMINAL_Q:
        return "the followed plan squeezes within the bridge"
    if not added:
        return None
    x, y, th = r.x_m[k0 : k1 + 1], r.y_m[k0 : k1 + 1], r.theta_rad[k0 : k1 + 1]
    c, s = np.cos(th), np.sin(th)
    pts = [np.stack([x + c * ox - s * oy, y + s * ox + c * oy], axis=1) for ox, oy in offsets_m]
    world = PlanWorld(list(added), None)
    if float(world.clearance(np.concatenate(pts), slot_radius_m + 0.01).min()) < slot_radius_m:
        return BLOCKED
    return None


def clear_to_end(
    followed: TimedPlan,
    tau0_s: float,
    added: Sequence[Mapping[str, Any]],
    slot_radius_m: float,
) -> bool:
    """Whether the rest of the followed plan from ``tau0_s`` keeps every slot (its planned
    squeeze included, every 3 cm of the path) ``slot_radius_m`` clear of the obstacles
    ``added`` at run time: then a replan that finds no way keeps it instead of stopping."""
    if not added:
        return True
    r = followed.result
    k0 = max(0, int(np.searchsorted(r.t_s, tau0_s)) - 1)
    idx = [*range(k0, len(r.t_s), 6), len(r.t_s) - 1]
    pts: list[tuple[float, float]] = []
    nominal = [(float(a), float(b)) for a, b in r.footprint.nominal_m]
    for k in idx:
        x, y, th = float(r.x_m[k]), float(r.y_m[k]), float(r.theta_rad[k])
        offs = followed.slot_offsets(float(r.t_s[k]))
        rows = nominal if offs is None else [(o[0], o[1]) for o in offs]
        c, s = math.cos(th), math.sin(th)
        pts.extend((x + c * ox - s * oy, y + s * ox + c * oy) for ox, oy in rows)
    world = PlanWorld(list(added), None)
    return float(world.clearance(np.array(pts), slot_radius_m + 0.01).min()) >= slot_radius_m
