"""Deadlock tie-break of the safety filter (``robot_agent.core.safety_filter``): stdlib only, pure
(time is passed in), one instance per robot, owned by its ``SafetyFilter``.

Deadlock tie-break: with a constraint in range and more than ``stuck_error_m`` of tracking
error, an error that has not shrunk by ``stuck_speed_mps * stuck_time_s`` within
``stuck_time_s`` (zero progress, whether the filter or a potential-field minimum holds the
robot, and also when it only trails a moving robot that blocks its way) triggers a tie-break
of ``tiebreak_time_s``: the nominal command is replaced by one toward the setpoint rotated
``tiebreak_angle_rad`` to the RIGHT (clockwise), at ``max(|u_nom|, tiebreak_speed_mps)``, and
filtered as usual. Every robot turns right, so two robots head-on pass each other (each keeps
the other on its left), and a robot blocked by a stationary one goes around it clockwise.
After two tie-breaks in a row that did not bring the robot within ``stuck_error_m`` of its
setpoint, the next two turn LEFT (a dead end on the right, e.g. a gap too narrow between a
pillar and a wall), then right again, and so on: still deterministic. It is the one place the
command can be faster than the nominal one besides leaving a boundary (at most
``tiebreak_speed_mps`` when the nominal is slower); it is counted.

The tie-break never weakens the filter: the command it makes is the nominal one the filter then
filters as usual (``SafetyFilter.filter``), so every barrier of the filter's proof still holds.
"""

from __future__ import annotations

import math
from typing import Final

from robot_agent.core.params import SafetyFilterParams

__all__ = ["Deadlock"]

_hypot: Final = math.hypot
_NAN: Final = math.nan


class Deadlock:
    """Stuck detection and tie-break timing of one robot (see the module docstring)."""

    __slots__ = (
        "_last_now",
        "_params",
        "_stuck_e",
        "_stuck_error",
        "_stuck_since",
        "_tb_cos",
        "_tb_sin",
        "_tb_speed",
        "_tb_streak",
        "_tb_until",
        "_vcap",
        "tiebreaks",
    )

    def __init__(self, params: SafetyFilterParams, vcap_mps: float) -> None:
        self._params = params
        self._vcap = vcap_mps  # the fastest reference-point command (max_ref_speed_mps)
        self._stuck_error = params.stuck_error_m
        self._tb_cos = math.cos(params.tiebreak_angle_rad)
        self._tb_sin = math.sin(params.tiebreak_angle_rad)
        self._tb_speed = params.tiebreak_speed_mps
        self._last_now = _NAN
        self._stuck_since = _NAN
        self._stuck_e = math.inf
        self._tb_until = -math.inf
        self._tb_streak = 0
        self.tiebreaks = 0  # tie-breaks started so far

    @property
    def active(self) -> bool:
        """A tie-break was under way at the last ``steer``."""
        return self._last_now < self._tb_until

    def reset(self) -> None:
        """Forget deadlock timing (the robot left TRACKING)."""
        self._stuck_since = _NAN
        self._tb_until = -math.inf

    def steer(
        self, now_s: float, ux: float, uy: float, ex: float, ey: float
    ) -> tuple[float, float, bool]:
        """The nominal command of this tick: ``(ux, uy)`` itself, or during a tie-break one
        toward the setpoint (error ``(ex, ey)``) turned right (or left); the bool says which."""
        last = self._last_now
        self._last_now = now_s
        if not (0.0 < now_s - last <= 0.5):  # first call, or the loop left TRACKING for a while
            self._stuck_since = _NAN
            if not now_s - last <= 0.5:
                self._tb_until = -math.inf
        tiebreak = False
        if now_s < self._tb_until:
            e = _hypot(ex, ey)
            tiebreak = e > self._stuck_error
        if tiebreak:
            gx = ex / e
            gy = ey / e
            c = self._tb_cos
            s = self._tb_sin
            speed = _hypot(ux, uy)
            if speed < self._tb_speed:
                speed = self._tb_speed
            if speed > self._vcap:
                speed = self._vcap
            # the goal direction rotated clockwise (to the right) by the tie-break angle; after
            # two tie-breaks that did not get the robot home, two to the left, and so on
            if (self._tb_streak - 1) // 2 % 2:
                s = -s
            ux = speed * (gx * c + gy * s)
            uy = speed * (gy * c - gx * s)
        return ux, uy, tiebreak

    def observe(self, now_s: float, ex: float, ey: float, in_range: bool, tiebreak: bool) -> None:
        """After filtering: ``in_range`` = some constraint was in range, ``tiebreak`` = what
        ``steer`` said. Starts a tie-break when something is in range and the tracking error has
        not shrunk by ``stuck_speed_mps * stuck_time_s`` within ``stuck_time_s``."""
        if not tiebreak and (in_range or self._tb_streak):
            p = self._params
            since = self._stuck_since
            e = _hypot(ex, ey)
            if e <= p.stuck_error_m:
                self._stuck_since = _NAN
                self._tb_streak = 0
            elif not in_range:
                self._stuck_since = _NAN
            elif since != since or e < self._stuck_e - p.stuck_speed_mps * p.stuck_time_s:
                self._stuck_since = now_s  # (re)start the window: progress was made
                self._stuck_e = e
            elif now_s - since >= p.stuck_time_s:
                self._tb_until = now_s + p.tiebreak_time_s
                self.tiebreaks += 1
                self._tb_streak += 1
                self._stuck_since = _NAN
        elif not in_range:
            self._stuck_since = _NAN
