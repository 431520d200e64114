"""The virtual leader as a state the coordinator advances each tick (issue 28): the scripted
trajectory, an operator's teleop twist with a deadman, live goals and paths, and a leader that
waits for its team. Pure: no clock, no I/O; time is ``now_s``.

Theory of operation
-------------------
The leader is a unicycle (paper eqs 1-2: ``xdot = v cos(theta)``, ``ydot = v sin(theta)``,
``thetadot = omega``) in one of these modes:

=========  ================================================================  =================
mode       what drives it                                                    left by
=========  ================================================================  =================
script     the scenario's trajectory sampled at a *progress time* ``tau``    a teleop, goal or
           that advances at the progress rate ``r`` in [0, 1]                path command
teleop     the operator's twist, integrated with speed, turn-rate and        a goal or path
           acceleration limits; the deadman zeroes it (below)                command
goal/path  a pursuit of the waypoints (the goal is a one-point path),        arrival (-> stop),
           through the same limited integrator; or, a goal planned around    another command
           obstacles (coordinator.core.planning.replan), a bridge and then
           the timed plan at a progress advancing at the rate ``r``
stop       holding where it stopped (v = omega = 0)                          any command
=========  ================================================================  =================

**Continuity.** Every mode other than ``script`` integrates the unicycle from the state the
leader is in, with ``|dv| <= max_accel_mps2 dt`` and ``|domega| <= max_turn_accel_radps2 dt``
per tick, so a command never makes the position or the velocity jump. The published ``v_mps``,
``omega_radps`` are the ones integrated (the step is the exact arc of constant ``v``, ``omega``),
so the slots' feed-forward (eqs 3-5 differentiated) is consistent with their positions. A live
goal or path starts from the leader's current state: the join is continuous by construction.
The scripted trajectory is sampled at ``tau`` and its velocity scaled by ``r`` (``d tau / dt =
r``), so a slowing rate slows the leader along the same path; the rate itself changes by at most
``wait_rate_slew_per_s`` per second (a bounded deceleration, never a step of the velocity).

**Bits.** With no command and the rate at 1 throughout, ``tau = now_s - t0_s`` exactly, so the
leader is ``trajectory.sample(now_s - t0_s)`` bit for bit, as before issue 28: lockstep equals
the in-process simulator, and a standby's origin check (coordinator.core.election) still holds.
Commands are queued by the shell and applied at a tick boundary (:meth:`LeaderCore.step` takes
what arrived since the last tick), so the same inputs at the same ticks give the same bits.

**Deadman.** A teleop twist is obeyed for at most ``deadman_s`` (default :data:`DEADMAN_S`)
after it was received; then the targets are zero and the leader decelerates to a stop within its
acceleration limits: it is stopped at most ``deadman_s + max_speed/max_accel`` (and the turn
``max_turn/max_turn_accel``) after the last command.

**Hostile input.** A command with a non-finite number, a speed or turn rate beyond
:data:`ABSURD_FACTOR` times the limit, a path with too many or coincident points, or a goal out
of the arena is refused and counted in :attr:`LeaderCore.rejects` by reason; the leader is not
touched. A twist within that bound but above the limit is clamped (counted as ``clamped``).

**Waiting for the team** (:class:`TeamWait`). The target rate falls linearly from 1 at a worst
tracking error of ``wait_err_full_m`` to 0 at ``wait_err_stop_m``, and is 0 while an assigned
robot is held (e-stopped, or its pose stale while it keeps its slot). A robot that holds the
formation back for longer than ``wait_drop_s`` is dropped from the wait (the leader goes on
without it) until its error is back under ``wait_err_full_m``.

The limits (:class:`LeaderConfig`, :class:`WaitSetting`, :data:`DEADMAN_S`) are in
``coordinator.core.leader_config`` (re-exported here): this module is compiled with the
coordinator's tick (coordinator/core/_accel.py), that one is not (docs/architecture.md).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Final, Protocol

from bus_schemas.messages_fields import LeaderMode  # the modes as the leader message names them
from coordinator.core.leader_config import DEADMAN_S, LeaderConfig, WaitSetting
from coordinator.core.leader_state import Sampler
from coordinator.core.trajectory import LeaderState, Trajectory, sampler, wrap_angle

if TYPE_CHECKING:  # the planning layer imports numpy; the leader takes its objects as given
    from coordinator.core.planning.timed import TimedPlan


class Bridge(Protocol):
    """The motion while a plan is computed (coordinator.core.planning.replan.Bridge)."""

    def state_at(self, now_s: float) -> LeaderState: ...


__all__ = [
    "ABSURD_FACTOR",
    "DEADMAN_S",
    "MAX_PATH_POINTS",
    "LeaderConfig",
    "LeaderCore",
    "LeaderMode",
    "TeamWait",
    "WaitSetting",
    "integrate_unicycle",
]

ABSURD_FACTOR: Final = 10.0
"""A twist beyond this multiple of a limit is refused, not clamped: it is garbage, not haste."""
MAX_PATH_POINTS: Final = 256
"""Most waypoints a live path may have."""
_STOPPED_MPS: Final = 1e-9
# The modes as module constants: compiled (coordinator/core/_accel.py), a Final constant is a C
# static, where ``LeaderMode.SCRIPT`` is an attribute lookup on the enum class (0.1 us) each time.
_SCRIPT: Final = LeaderMode.SCRIPT
_TELEOP: Final = LeaderMode.TELEOP
_GOAL: Final = LeaderMode.GOAL
_PATH: Final = LeaderMode.PATH
_STOP: Final = LeaderMode.STOP


def integrate_unicycle(
    x: float, y: float, theta: float, v_mps: float, omega_radps: float, dt_s: float
) -> tuple[float, float, float]:
    """The pose after ``dt_s`` at constant ``v_mps``, ``omega_radps``: the exact arc of eqs 1-2
    (a straight step when the turn is negligible)."""
    dth = omega_radps * dt_s
    if abs(dth) < 1e-9:
        mid = theta + 0.5 * dth
        return x + v_mps * dt_s * math.cos(mid), y + v_mps * dt_s * math.sin(mid), theta + dth
    r = v_mps / omega_radps
    th1 = theta + dth
    return x + r * (math.sin(th1) - math.sin(theta)), y - r * (math.cos(th1) - math.cos(theta)), th1


def _toward(value: float, target: float, step: float) -> float:
    """``value`` moved toward ``target`` by at most ``step`` (>= 0)."""
    if target > value + step:
        return value + step
    if target < value - step:
        return value - step
    return target


def _clamp(value: float, bound: float) -> float:
    return -bound if value < -bound else bound if value > bound else value


class TeamWait:
    """The progress rate a leader that waits for its team may run at (module docstring)."""

    def __init__(self, config: LeaderConfig) -> None:
        self.config = config
        self._blocking_since: dict[str, float] = {}
        self.dropped: set[str] = set()
        """Robots the leader no longer waits for (held back the formation too long)."""
        self.worst_m = 0.0
        self.worst_robot: str | None = None
        self.held: tuple[str, ...] = ()

    def target_rate(
        self, now_s: float, errors_m: Mapping[str, float], held: Iterable[str] = ()
    ) -> float:
        """The rate in [0, 1] for tracking errors ``errors_m`` (robot -> m, the assigned robots)
        and the ``held`` robots among them, at ``now_s``."""
        cfg = self.config
        held_set = {r for r in held if r in errors_m}
        for rid in [r for r in self._blocking_since if r not in errors_m]:
            del self._blocking_since[rid]
        self.dropped.intersection_update(errors_m)
        worst, worst_robot = 0.0, None
        rate = 1.0
        for rid, err in errors_m.items():
            err = err if math.isfinite(err) else math.inf
            if rid in self.dropped:
                if err <= cfg.wait_err_full_m and rid not in held_set:
                    self.dropped.discard(rid)  # caught up: waited for again
                else:
                    continue
            if rid in held_set:
                r = 0.0
            elif err <= cfg.wait_err_full_m:
                r = 1.0
            elif err >= cfg.wait_err_stop_m:
                r = 0.0
            else:
                r = (cfg.wait_err_stop_m - err) / (cfg.wait_err_stop_m - cfg.wait_err_full_m)
            if r < 1.0:
                since = self._blocking_since.setdefault(rid, now_s)
                if now_s - since > cfg.wait_drop_s:
                    self.dropped.add(rid)
                    del self._blocking_since[rid]
                    continue
            else:
                self._blocking_since.pop(rid, None)
            if err > worst or worst_robot is None:
                worst, worst_robot = err, rid
            rate = min(rate, r)
        self.worst_m, self.worst_robot = worst, worst_robot
        self.held = tuple(sorted(held_set))
        return rate


@dataclass(frozen=True)
class _Twist:
    v_mps: float
    omega_radps: float
    rx_s: float


@dataclass(frozen=True)
class _Route:
    points: tuple[tuple[float, float], ...]
    heading: float | None
    goal: bool


class LeaderCore:
    """The virtual leader's state and its update (module docstring)."""

    def __init__(
        self,
        trajectory: Trajectory,
        config: LeaderConfig | None = None,
        *,
        t0_s: float = 0.0,
        trajectory_kind: str = "",
        arena: tuple[float, float, float, float] | None = None,
    ) -> None:
        self._trajectory = trajectory
        # its compiled sampler (None: sampled through its own method); set with the trajectory
        self._sampler: Sampler | None = sampler(trajectory)
        self._config = config if config is not None else LeaderConfig()
        self._trajectory_kind = trajectory_kind
        self.arena = arena
        """(xmin, ymin, xmax, ymax) in m: goals and path points outside are refused."""
        self.t0_s = t0_s
        self.mode = _SCRIPT
        self.rate = 1.0
        """The progress rate applied at the last step (1: full speed)."""
        self.progress_s = 0.0
        """Trajectory time ``tau`` of the scripted trajectory (s)."""
        self.target_index = 0
        """Next waypoint of a goal or path."""
        self.rejects: dict[str, int] = {}
        self.commands = 0
        self.superseded = 0
        self.wait = TeamWait(self.config)
        self.state: LeaderState | None = None
        self._pending: list[Any] = []
        self._twist: _Twist | None = None
        self._route: _Route | None = None
        self._anchored = False  # tau integrates (the rate left 1, or a state was adopted)
        self._last_now: float | None = None
        self._deadman_tripped = False
        self._script_waits = self._config.waits(_SCRIPT, trajectory_kind)
        """:meth:`waits` in mode script (the config and the trajectory's kind are fixed)."""
        self.bridge: Bridge | None = None
        """The motion while a plan is computed (coordinator.core.planning.replan), or None."""
        self.plan: TimedPlan | None = None
        """The run-time plan followed (at plan time ``progress_s``), or None."""
        self.new_goal: tuple[float, float, float | None] | None = None
        """A goal applied at the last step (the planner takes it: :meth:`take_new_goal`)."""

    @property
    def config(self) -> LeaderConfig:
        """The leader's limits and wait setting (fixed for the leader's life)."""
        return self._config

    @property
    def trajectory(self) -> Trajectory:
        """The scenario's trajectory (the script; a new one brings its own sampler)."""
        return self._trajectory

    @trajectory.setter
    def trajectory(self, trajectory: Trajectory) -> None:
        self._trajectory = trajectory
        self._sampler = sampler(trajectory)

    @property
    def trajectory_kind(self) -> str:
        """The scenario trajectory's kind (``"plan"``: a planned one; fixed)."""
        return self._trajectory_kind

    def _sample(self, tau: float) -> LeaderState:
        """``self.trajectory.sample(tau)``: through its compiled sampler when it has one (the
        same function of the same floats: the same bits; ``tau`` as the float ``sample`` takes
        it), else, or for a time that is not finite (its ``ValueError``), its own method."""
        sp = self._sampler
        if sp is not None and not (math.isinf(tau) or math.isnan(tau)):
            return sp.sample(float(tau))
        return self._trajectory.sample(tau)

    # -- commands (queued; applied at the next step) ---------------------------------------

    def _refuse(self, reason: str) -> str:
        self.rejects[reason] = self.rejects.get(reason, 0) + 1
        return reason

    def command_twist(self, v_mps: float, omega_radps: float, rx_s: float) -> str | None:
        """A teleop twist received at ``rx_s``; returns the refusal reason, or None."""
        cfg = self.config
        if not all(_finite(v) for v in (v_mps, omega_radps, rx_s)):
            return self._refuse("nonfinite")
        if (
            abs(v_mps) > ABSURD_FACTOR * cfg.max_speed_mps
            or abs(omega_radps) > ABSURD_FACTOR * cfg.max_turn_radps
        ):
            return self._refuse("absurd")
        if abs(v_mps) > cfg.max_speed_mps or abs(omega_radps) > cfg.max_turn_radps:
            self.rejects["clamped"] = self.rejects.get("clamped", 0) + 1
        v = _clamp(float(v_mps), cfg.max_speed_mps)
        w = _clamp(float(omega_radps), cfg.max_turn_radps)
        self._queue(_Twist(v, w, float(rx_s)))
        return None

    def command_goal(self, x: float, y: float, heading: float | None = None) -> str | None:
        """Drive to ``(x, y)`` (m), then turn to ``heading`` (rad) if given."""
        if heading is not None and not _finite(heading):
            return self._refuse("nonfinite")
        why = self._check_points([(x, y)])
        if why is not None:
            return self._refuse(why)
        h = None if heading is None else wrap_angle(float(heading))
        self._queue(_Route(((float(x), float(y)),), h, goal=True))
        return None

    def command_path(
        self, points: Sequence[tuple[float, float]], heading: float | None = None
    ) -> str | None:
        """Drive through ``points`` (m) from where the leader is."""
        if heading is not None and not _finite(heading):
            return self._refuse("nonfinite")
        why = self._check_points(points)
        if why is not None:
            return self._refuse(why)
        pts = tuple((float(x), float(y)) for x, y in points)
        h = None if heading is None else wrap_angle(float(heading))
        self._queue(_Route(pts, h, goal=False))
        return None

    def command_stop(self) -> None:
        """Stop where the leader is (decelerating within the limits)."""
        self._queue(_STOP)

    def _check_points(self, points: Sequence[tuple[float, float]]) -> str | None:
        if not 1 <= len(points) <= MAX_PATH_POINTS:
            return "path_length"
        for p in points:
            if len(p) != 2 or not all(_finite(c) for c in p):
                return "nonfinite"
            if self.arena is not None:
                xmin, ymin, xmax, ymax = self.arena
                if not (xmin <= p[0] <= xmax and ymin <= p[1] <= ymax):
                    return "outside_arena"
        for a, b in itertools.pairwise(points):
            if math.hypot(b[0] - a[0], b[1] - a[1]) < 1e-6:
                return "coincident_points"
        return None

    def _queue(self, cmd: object) -> None:
        self.commands += 1
        if self._pending:
            self.superseded += len(self._pending)
            self._pending.clear()  # the latest command of a tick wins (a burst is one command)
        self._pending.append(cmd)

    # -- takeover --------------------------------------------------------------------------

    def adopt(
        self,
        now_s: float,
        state: LeaderState,
        mode: LeaderMode,
        progress_s: float,
        rate: float,
        target_index: int,
    ) -> None:
        """Continue from the state another coordinator instance last published (a takeover):
        the same position, velocity, mode, progress and rate; a goal or path continues from
        ``target_index`` of the route this instance received itself (if none: stop)."""
        vals = (now_s, state.x, state.y, state.theta, state.v_mps, state.omega_radps, progress_s)
        if not all(_finite(v) for v in vals) or not 0.0 <= rate <= 1.0:
            raise ValueError("adopt: a non-finite or out-of-range leader state")
        self.state = state
        self.mode = LeaderMode(mode)
        self.progress_s = progress_s
        self.rate = rate
        self.target_index = max(0, int(target_index))
        self._anchored = True
        self._last_now = now_s
        self.bridge = self.plan = None  # a planned goal is planned again from here (replan.py)
        if self.mode in (_GOAL, _PATH):
            routes = [c for c in self._pending if isinstance(c, _Route)]
            if self._route is None and routes:
                self._route = routes[-1]
            if self._route is None or self.target_index >= len(self._route.points):
                self.mode = _STOP
        self._pending = [c for c in self._pending if isinstance(c, _Twist)]
        if self.mode is not _TELEOP:
            self._pending.clear()

    def remember(self) -> None:
        """A standby: keep what the commands received say (the route, the twist) without
        applying them, so a takeover continues them (:meth:`adopt`)."""
        for cmd in self._pending:
            if isinstance(cmd, _Route):
                self._route = cmd
            elif isinstance(cmd, _Twist):
                self._twist = cmd

    # -- the tick --------------------------------------------------------------------------

    @property
    def deadman(self) -> bool:
        """True when the leader is under teleop and the last twist is older than the deadman
        (as of the last step)."""
        return self.mode is _TELEOP and self._deadman_tripped

    @property
    def scripted(self) -> bool:
        """The leader is the scenario's trajectory at ``now - t0``, as it has been since the start
        (no command, no wait, no adoption): a pure function of time, which a standby can check
        against the trajectory (coordinator.core.election)."""
        return self.mode is _SCRIPT and not self._anchored

    def waits(self) -> bool:
        """Does the leader wait for its team in its current mode (the scenario's setting)?"""
        if self.mode is _SCRIPT:  # (every tick of a script: the answer of __init__)
            return self._script_waits
        return self.config.waits(self.mode, self.trajectory_kind)

    def step(self, now_s: float, target_rate: float = 1.0) -> LeaderState:
        """Advance to ``now_s`` (s) and return the leader's state there. ``target_rate`` in [0, 1]:
        what the team allows (:class:`TeamWait`); ignored unless :meth:`waits`."""
        if self._pending:
            self._apply_pending()
        last = self._last_now
        self._last_now = now_s
        if (
            self.mode is _SCRIPT
            and not self._anchored
            and (target_rate == 1.0 or not self._script_waits)
        ):  # the scenario's script at full speed: exactly trajectory.sample(now - t0)
            tau = self.progress_s = now_s - self.t0_s
            s = self.state = self._sample(tau)
            return s
        dt = 0.0 if last is None else max(0.0, now_s - last)
        cfg = self.config
        want = target_rate if self.waits() and _finite(target_rate) else 1.0
        want = 0.0 if want < 0.0 else 1.0 if want > 1.0 else want
        rate = _toward(self.rate, want, cfg.wait_rate_slew_per_s * dt)
        self.rate = rate
        if self.mode is _SCRIPT:
            if rate != 1.0:
                self._anchored = True
            if self._anchored:
                self.progress_s += rate * dt
                tau = self.progress_s
            else:
                tau = self.progress_s = now_s - self.t0_s
            s = self._sample(tau)
            if rate != 1.0:
                s = LeaderState(s.t, s.x, s.y, s.theta, rate * s.v_mps, rate * s.omega_radps)
            self.state = s
            return s
        if self.bridge is not None:  # a plan is computed: the bridge, a function of time
            b = self.bridge.state_at(now_s)
            # the bridge does not wait for the team (at most BRIDGE_S at the join speed); the
            # plan starts at full rate from the bridge's speed and the wait slews from there
            self.rate = 1.0
            self.state = LeaderState(now_s - self.t0_s, b.x, b.y, b.theta, b.v_mps, b.omega_radps)
            return self.state
        if self.plan is not None:
            return self._follow(self.plan, rate * dt)
        prev = self.state
        assert prev is not None  # a non-script mode starts from a state
        v_t, w_t = self._targets(prev, now_s)
        v_t, w_t = rate * v_t, rate * w_t
        v = _toward(prev.v_mps, v_t, cfg.max_accel_mps2 * dt)
        w = _toward(prev.omega_radps, w_t, cfg.max_turn_accel_radps2 * dt)
        if abs(v) < _STOPPED_MPS:
            v = 0.0
        if abs(w) < _STOPPED_MPS:
            w = 0.0
        x, y, th = integrate_unicycle(prev.x, prev.y, prev.theta, v, w, dt)
        self.state = LeaderState(now_s - self.t0_s, x, y, wrap_angle(th), v, w)
        if self.mode in (_GOAL, _PATH) and self._arrived(self.state):
            self.mode = _STOP
            self._route = None
        return self.state

    def _follow(self, plan: TimedPlan, dtau: float) -> LeaderState:
        """The leader on the run-time plan, progress advanced by ``dtau`` (rate x dt)."""
        self.progress_s += dtau
        x, y, th, v, w = plan.state(self.progress_s)
        r = self.rate
        assert self._last_now is not None
        self.state = LeaderState(self._last_now - self.t0_s, x, y, wrap_angle(th), r * v, r * w)
        if self.progress_s >= plan.duration_s and self.mode is _GOAL:
            self.mode = _STOP  # at rest on the goal: arrived (the plan stays, for
            self._route = None  # the squeeze it ends in: the slots do not jump)
        return self.state

    # -- run-time plans (coordinator.core.planning.replan drives these) ---------------------

    @property
    def goal_point(self) -> tuple[float, float, float | None] | None:
        """The goal (x, y, heading) of the route in mode goal, or None."""
        route = self._route
        if self.mode is not _GOAL or route is None or not route.goal:
            return None
        return (*route.points[-1], route.heading)

    def take_new_goal(self) -> tuple[float, float, float | None] | None:
        """The goal applied at the last step, once (None if none)."""
        goal, self.new_goal = self.new_goal, None
        return goal

    def begin_bridge(self, bridge: Bridge) -> None:
        """Leave the current motion for ``bridge`` (it starts from :attr:`state`)."""
        self.bridge = bridge
        self.plan = None
        self._anchored = True
        if self.mode not in (_GOAL, _SCRIPT):
            self.mode = _GOAL
        if self.mode is _SCRIPT:  # a planned script replanned to its goal
            self.mode = _GOAL

    def follow_plan(
        self, plan: TimedPlan, t_switch_s: float, progress_s: float = 0.0, rate: float = 1.0
    ) -> None:
        """Follow ``plan`` from ``t_switch_s`` (before the step of the tick at or after it), at
        plan time ``progress_s`` and progress rate ``rate`` there (a new plan: its start at full
        rate; the followed plan kept after a replan found no way: where its bridge is)."""
        self.bridge = None
        self.plan = plan
        self.mode = _GOAL
        self.progress_s = progress_s
        self.rate = rate
        self._last_now = t_switch_s  # the step integrates the progress from the switch time

    def no_way(self) -> None:
        """No plan: decelerate to a stop from where the leader is, within its limits."""
        self.bridge = self.plan = None
        self.mode = _STOP
        self._route = None

    def squeezed(self) -> bool:
        """The formation is squeezed on the run-time plan here (a replan waits for the end)."""
        plan = self.plan
        return plan is not None and plan.squeezed_at(self.progress_s)

    def _apply_pending(self) -> None:
        pending, self._pending = self._pending, []
        if pending:
            self.bridge = self.plan = None  # an operator's command replaces a run-time plan
        for cmd in pending:
            if self.state is None:  # before the first tick: start from the script's start
                self.state = self.trajectory.sample(0.0)
            if isinstance(cmd, _Twist):
                self._twist = cmd
                self.mode = _TELEOP
            elif isinstance(cmd, _Route):
                self._route = cmd
                self.target_index = 0
                self.mode = _GOAL if cmd.goal else _PATH
                if cmd.goal:
                    self.new_goal = (*cmd.points[-1], cmd.heading)
            elif cmd is _STOP:
                self.mode = _STOP

    def _targets(self, s: LeaderState, now_s: float) -> tuple[float, float]:
        """The (v, omega) the leader steers toward in a non-script mode."""
        cfg = self.config
        if self.mode is _TELEOP:
            tw = self._twist
            self._deadman_tripped = tw is None or not (now_s - tw.rx_s <= cfg.deadman_s)
            if self._deadman_tripped or tw is None:
                return 0.0, 0.0
            return tw.v_mps, tw.omega_radps
        self._deadman_tripped = False
        route = self._route
        if self.mode is _STOP or route is None:
            return 0.0, 0.0
        pts = route.points
        i = self.target_index
        while i < len(pts) - 1 and math.hypot(pts[i][0] - s.x, pts[i][1] - s.y) <= cfg.lookahead_m:
            i += 1
        self.target_index = i
        tx, ty = pts[i]
        dist = math.hypot(tx - s.x, ty - s.y)
        if self._at_goal(s):
            if route.heading is None:
                return 0.0, 0.0
            err = wrap_angle(route.heading - s.theta)
            # brake the turn so it ends at the heading: |omega| <= sqrt(2 alpha |err|)
            w_cap = min(cfg.max_turn_radps, math.sqrt(2.0 * cfg.max_turn_accel_radps2 * abs(err)))
            return 0.0, math.copysign(w_cap, err) if abs(err) > cfg.heading_tol_rad else 0.0
        remaining = dist + sum(
            math.hypot(b[0] - a[0], b[1] - a[1])
            for a, b in zip(pts[i:], pts[i + 1 :], strict=False)
        )
        err = wrap_angle(math.atan2(ty - s.y, tx - s.x) - s.theta)
        # brake so the leader stops at the last point: v <= sqrt(2 a d)
        v_cap = min(cfg.max_speed_mps, math.sqrt(2.0 * cfg.max_accel_mps2 * remaining))
        v = v_cap * max(0.0, math.cos(err)) ** 2  # turn first when facing away
        w = _clamp(1.5 * err, cfg.max_turn_radps)
        return v, w

    def _at_goal(self, s: LeaderState) -> bool:
        """At the last point of the route: within ``goal_tol_m``, or just past it (it is behind
        the leader, within 4 ``goal_tol_m``: stop rather than turn around for millimetres)."""
        route = self._route
        if route is None:
            return True
        if self.target_index < len(route.points) - 1:
            return False
        tx, ty = route.points[-1]
        dist = math.hypot(tx - s.x, ty - s.y)
        tol = self.config.goal_tol_m
        if dist <= tol:
            return True
        behind = abs(wrap_angle(math.atan2(ty - s.y, tx - s.x) - s.theta)) > 0.5 * math.pi
        return behind and dist <= 4.0 * tol

    def _arrived(self, s: LeaderState) -> bool:
        route = self._route
        if route is None:
            return True
        if not self._at_goal(s) or abs(s.v_mps) > 1e-3:
            return False
        if route.heading is not None:
            if abs(wrap_angle(route.heading - s.theta)) > self.config.heading_tol_rad:
                return False
            return abs(s.omega_radps) <= 1e-3
        return True


def _finite(value: object) -> bool:
    return not isinstance(value, bool) and isinstance(value, int | float) and math.isfinite(value)
