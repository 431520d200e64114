"""Run-time planning: goals planned around obstacles, replans when the world changes or a robot
is stuck, switched in at a tick boundary without a jump (issue 27, item 5). Pure: no clock.

Theory of operation
-------------------
A plan takes tens to hundreds of milliseconds (``planner.plan``), several 20 ms ticks, so it is
computed OFF the tick (the node shell's worker process; the in-process simulator at once) and
switched in later. What the leader does meanwhile must be known when the plan is asked, so the
plan can start exactly where the leader will be:

1. **Bridge.** When a plan is wanted at tick time ``t_b`` while the leader follows a plan (a
   run-time plan or a ``kind = "plan"`` script) that goes on clear of the run's obstacles
   beyond the bridge, the leader stays ON it: a ``plan_bridge.PlanBridge``, the followed plan
   at a progress advancing at the rate it had, a fixed function of the time since ``t_b``,
   held until a straight piece of the path (the paper's coordinator "creates no-collision
   trajectories of the virtual leader": it keeps the one it has while the next is computed).
   Otherwise (no followed plan; a followed plan that ends or squeezes within the bridge) it
   leaves its mode for a straight :class:`Bridge` (braking at once, ``v_join = 0``, when the
   followed plan is blocked within the bridge: said in ``plan_why``), a fixed function of the
   time since ``t_b``: from its state there (position,
   heading, speed ``v0``, turn rate ``w0``) the speed goes to ``v_join = clip(v0, 0, cruise)``
   at the leader's acceleration limit and the turn rate to 0 at its turn-acceleration limit
   (``leader.integrate_unicycle`` on fixed :data:`BRIDGE_STEP_S` sub-steps), for
   ``hold_s = max(BRIDGE_S, time to get there)``; after ``hold_s`` it brakes to a stop. The
   join of the bridge is continuous (it starts from the leader's state), and so is its end.
   The switch is at the end of the hold, or (realtime only: ``adaptive``) later when the
   last plan took longer than :data:`BRIDGE_S` / 1.5: then the plan starts on the braking
   tail, slower or at rest.
2. **Request.** The plan is asked from the bridge's state at ``t_switch = t_b + hold_s``: a
   straight motion at ``v_join`` along the heading, which ``planner.plan`` continues
   (``v_start_mps``: the plan leaves along the heading at that speed; ``start_nominal``: from
   the nominal formation; ``departure_m``: after a bridge on the followed plan, the straight
   departure ends at most at the followed route's next corner point). The request
   (:class:`PlanRequest`) is plain data: the world (the scenario's obstacles, the operator's,
   the stuck markers), the formation's offsets, the goal; :func:`solve` is a deterministic
   function of it.
3. **Switch.** At the first tick at or after ``t_switch`` the leader follows the plan at plan
   time ``now - t_switch`` (and then at a progress that advances at the team-wait rate, as the
   script does). Position, speed and turn rate are continuous: the plan starts where the bridge
   is at ``t_switch``, with its speed, going straight. In LOCKSTEP the node waits for the
   answer before that tick (:meth:`Replanner.due`), so the switch happens at a tick fixed by the
   command's tick whatever the planning took: lockstep stays equal to the in-process simulator,
   which plans at once. In REALTIME a plan not ready at ``t_switch`` is *late* (counted): the
   bridge goes on (braking after ``hold_s``) and the plan is asked again from the bridge's
   state one ``hold_s`` later; the late answer is dropped.
4. **No way** (``NoPlan``): the leader decelerates to a stop within its limits (mode ``stop``)
   and :attr:`Replanner.state` is ``no_way`` with the planner's one line in
   :attr:`Replanner.why`; unless the bridge was on the followed plan and all of its rest is
   still clear of the run's obstacles (:attr:`Replanner.keep_followed`): then the leader goes
   on along it from where the bridge is (``following``, ``plan_why`` "... (kept the followed
   plan)").

What makes a plan wanted: a goal (``formation goal``) when the world has an obstacle (an open
field keeps the leader's straight pursuit, coordinator.core.leader); an obstacle added, moved
or removed while a goal is being followed (or a ``kind = "plan"`` script, replanned to its
goal); a robot taken as stuck (:class:`StuckWatch`); a standby's takeover of a planned goal. A
replan is deferred while the formation is squeezed in a passage (the new plan starts from the
nominal formation: it is asked as soon as the squeeze is over).

**Stuck** (:class:`StuckWatch`): a robot assigned a slot, not held (e-stop), whose tracking
error has stayed above :data:`STUCK_ERR_M` without shrinking by :data:`STUCK_PROGRESS_M` for
:data:`STUCK_S` while the leader is driven to a planned goal. Something the map does not know
holds it there: a marker disc (the body radius) is put where its reference point is and the
goal is replanned from the leader's state with the rest of the formation clear of that place
(the leader's wait for its team still slows it for the robot, coordinator.core.leader); the
marker goes when the robot is no longer stuck (and a goal that had no way is tried again).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Final

from bus_schemas.messages_status import PlanState
from coordinator.core.leader import integrate_unicycle
from coordinator.core.trajectory import LeaderState, wrap_angle

from .footprint import Footprint
from .limits import SlotLimits
from .plan_bridge import PlanBridge
from .planner import PlanResult, plan
from .search import NoPlan
from .world import PlanWorld

__all__ = [
    "BRIDGE_S",
    "BRIDGE_STEP_S",
    "MAX_RUNTIME_OBSTACLES",
    "STUCK_ERR_M",
    "STUCK_PROGRESS_M",
    "STUCK_S",
    "Bridge",
    "PlanRequest",
    "PlanSetup",
    "PlanState",
    "ReplanStats",
    "Replanner",
    "StuckWatch",
    "obstacle_table",
    "solve",
]

BRIDGE_S: Final = 0.5
"""Least bridge before a plan is switched in (s): room for the plan's computation (50-250 ms on
one core, bench/bench_plan.py) on a loaded host."""
BRIDGE_STEP_S: Final = 0.005
"""Sub-step of the bridge's integration (s): the bridge is the same function of time for every
tick rate."""
STUCK_ERR_M: Final = 0.15
STUCK_PROGRESS_M: Final = 0.02
STUCK_S: Final = 5.0
MAX_RUNTIME_OBSTACLES: Final = 256
"""Most obstacles the operator may add at run time (more is refused, counted)."""


def _toward(value: float, target: float, step: float) -> float:
    if target > value + step:
        return value + step
    if target < value - step:
        return value - step
    return target


class Bridge:
    """The leader's motion while a plan is computed (module docstring, step 1): a fixed function
    of the time since ``t0_s``."""

    __slots__ = ("_cursor", "_n", "accel_mps2", "hold_s", "start", "t0_s", "turn_accel_radps2")

    def __init__(
        self,
        start: LeaderState,
        t0_s: float,
        *,
        cruise_mps: float,
        accel_mps2: float,
        turn_accel_radps2: float,
        least_s: float = BRIDGE_S,
    ) -> None:
        self.start = start
        self.t0_s = t0_s
        self.accel_mps2 = accel_mps2
        self.turn_accel_radps2 = turn_accel_radps2
        v_join = min(max(start.v_mps, 0.0), cruise_mps)
        settle = max(
            abs(start.v_mps - v_join) / accel_mps2, abs(start.omega_radps) / turn_accel_radps2
        )
        steps = math.ceil(max(least_s, settle) / BRIDGE_STEP_S - 1e-9)
        self.hold_s = steps * BRIDGE_STEP_S
        self._n = 0  # sub-steps integrated into the cursor
        self._cursor = (start.x, start.y, start.theta, start.v_mps, start.omega_radps, v_join)

    @property
    def v_join_mps(self) -> float:
        """The speed the bridge holds until ``hold_s`` (and the plan starts with)."""
        return self._cursor[5]

    def _sub(
        self, c: tuple[float, float, float, float, float, float], t_s: float, dt: float
    ) -> tuple[float, float, float, float, float, float]:
        """One sub-step of ``dt`` from cursor ``c`` at bridge time ``t_s``."""
        x, y, th, v, w, v_join = c
        target = v_join if t_s < self.hold_s - 1e-12 else 0.0
        v = _toward(v, target, self.accel_mps2 * dt)
        w = _toward(w, 0.0, self.turn_accel_radps2 * dt)
        x, y, th = integrate_unicycle(x, y, th, v, w, dt)
        return x, y, th, v, w, v_join

    def state_at(self, now_s: float) -> LeaderState:
        """The leader at ``now_s`` (>= ``t0_s``; earlier reads as ``t0_s``)."""
        e = max(0.0, now_s - self.t0_s)
        n = int(e / BRIDGE_STEP_S + 1e-9)
        if n < self._n:  # asked for an earlier time: integrate again from the start
            s = self.start
            self._n = 0
            self._cursor = (s.x, s.y, s.theta, s.v_mps, s.omega_radps, self._cursor[5])
        c = self._cursor
        while self._n < n:
            c = self._sub(c, self._n * BRIDGE_STEP_S, BRIDGE_STEP_S)
            self._n += 1
        self._cursor = c
        rest = e - n * BRIDGE_STEP_S
        if rest > 1e-12:
            c = self._sub(c, n * BRIDGE_STEP_S, rest)
        x, y, th, v, w, _ = c
        return LeaderState(now_s, x, y, wrap_angle(th), v, w)


@dataclass(frozen=True)
class PlanSetup:
    """What every run-time plan of a run shares (the scenario's): its obstacle tables and arena
    (``world.PlanWorld``'s form), the slot disc radius, the least slot separation of a squeeze,
    the hard and soft least slot distances (m), the slots' limits, the cruise speed (m/s), the
    robots' body radius (m, the stuck marker) and the leader's acceleration limits."""

    obstacles: tuple[Mapping[str, Any], ...]
    arena: Mapping[str, float] | None
    slot_radius_m: float
    min_separation_m: float
    min_pair_m: float
    soft_pair_m: float
    limits: SlotLimits
    cruise_mps: float
    body_radius_m: float
    accel_mps2: float
    turn_accel_radps2: float


@dataclass(frozen=True)
class PlanRequest:
    """One plan to compute (plain data, picklable; :func:`solve`): ``id`` (increasing),
    ``reason``, the switch time ``t_switch_s`` (the tick clock), the start pose and speed (the
    bridge's at ``t_switch_s``), the goal, the obstacles (the scenario's and the run's), the
    formation's body-frame offsets and the shared setup."""

    id: int
    reason: str
    t_switch_s: float
    start: tuple[float, float, float]
    v_start_mps: float
    goal: tuple[float, float]
    goal_heading: float | None
    obstacles: tuple[Mapping[str, Any], ...]
    offsets_m: tuple[tuple[float, float], ...]
    setup: PlanSetup
    departure_m: float | None = None
    """The straight departure (m) that stays on the followed route (a bridge on the followed
    plan: ``plan_bridge.PlanBridge.departure_m``), or None: the planner's own choice."""


def solve(req: PlanRequest) -> PlanResult | str:
    """The plan of ``req``, or the one line why there is none (never raises for a bad map)."""
    s = req.setup
    try:
        world = PlanWorld(list(req.obstacles), s.arena)
        fp = Footprint(req.offsets_m, s.slot_radius_m, s.min_separation_m)  # type: ignore[arg-type]
        return plan(
            world,
            fp,
            req.start,
            req.goal,
            goal_heading=req.goal_heading,
            cruise_mps=s.cruise_mps,
            limits=s.limits,
            min_pair_m=s.min_pair_m,
            soft_pair_m=s.soft_pair_m,
            v_start_mps=req.v_start_mps,
            start_nominal=True,  # replans are asked with the formation nominal (not squeezed)
            departure_m=req.departure_m,
        )
    except (NoPlan, ValueError) as exc:
        return f"no plan: {exc}"


def obstacle_table(
    shape: str,
    *,
    x: float | None = None,
    y: float | None = None,
    radius_m: float | None = None,
    xs: Sequence[float] | None = None,
    ys: Sequence[float] | None = None,
) -> dict[str, Any]:
    """An operator's obstacle as a ``PlanWorld`` table (a filled polygon or a disc); raises
    ``ValueError`` naming what is wrong (a degenerate polygon, a missing field)."""
    if shape == "circle":
        if x is None or y is None or radius_m is None:
            raise ValueError("a circle needs x, y and radius_m")
        table: dict[str, Any] = {"kind": "circle", "x": x, "y": y, "radius_m": radius_m}
    elif shape == "polygon":
        if xs is None or ys is None or len(xs) != len(ys):
            raise ValueError("a polygon needs xs and ys of the same length")
        table = {"kind": "polygon", "points": [[a, b] for a, b in zip(xs, ys, strict=True)]}
    else:
        raise ValueError(f"shape must be circle or polygon, got {shape!r}")
    PlanWorld([table], None)  # the planner's own checks (>= 3 points, area, not crossing)
    return table


@dataclass
class ReplanStats:
    """What the run-time planner did (the status's and metrics' names, docs/planning.md)."""

    plans: int = 0
    """Plans switched in or found to have no way (the first for a goal and every replan)."""
    replans: int = 0
    plan_ms: float | None = None
    """Compute time of the last plan (ms; measured by the shell that ran it)."""
    min_clearance_m: float | None = None
    """Least planned clearance of the plan being followed (m)."""
    late: int = 0
    events: list[dict[str, Any]] = field(default_factory=list)
    """One record per plan switched in or refused: ``t_s``, ``reason``, ``ok``, ``why``,
    ``plan_ms`` (its compute time as the shell measured it, None if unknown), ``length_m``,
    ``min_clearance_m``, ``path`` (the leader's waypoints)."""


class StuckWatch:
    """Which assigned robots are stuck (module docstring): a pure detector fed each tick."""

    def __init__(self) -> None:
        self._since: dict[str, tuple[float, float]] = {}  # robot -> (since_s, least error)
        self.stuck: set[str] = set()

    def update(
        self, now_s: float, errors_m: Mapping[str, float], held: Sequence[str] | set[str]
    ) -> set[str]:
        """Robots newly stuck at ``now_s`` (``errors_m``: robot -> tracking error, m)."""
        new: set[str] = set()
        for rid in [r for r in self._since if r not in errors_m or r in held]:
            del self._since[rid]
        self.stuck.intersection_update(errors_m)
        for rid, err in errors_m.items():
            if rid in held or not math.isfinite(err) or err <= STUCK_ERR_M:
                self._since.pop(rid, None)
                self.stuck.discard(rid)
                continue
            since, least = self._since.setdefault(rid, (now_s, err))
            if err < least - STUCK_PROGRESS_M:  # progress: start again
                self._since[rid] = (now_s, err)
                self.stuck.discard(rid)
            elif now_s - since >= STUCK_S and rid not in self.stuck:
                self.stuck.add(rid)
                new.add(rid)
        return new


class Replanner:
    """The run-time planner's state (module docstring): the operator's obstacles, the goal, the
    request in flight and its answer, the figures. Owned by the coordinator core."""

    def __init__(self, setup: PlanSetup | None) -> None:
        self.setup = setup
        self.obstacles: dict[str, dict[str, Any]] = {}
        """The operator's obstacles by id (PlanWorld tables)."""
        self.markers: dict[str, dict[str, Any]] = {}
        """Stuck markers by robot id."""
        self.goal: tuple[float, float, float | None] | None = None
        self.state: PlanState | None = None
        self.why: str | None = None
        self.stats = ReplanStats()
        self.stuck = StuckWatch()
        self.rejects: dict[str, int] = {}
        self._want: str | None = None  # the reason a plan is wanted
        self._request: PlanRequest | None = None
        self._taken = False  # the shell has the request
        self._answer: PlanResult | str | None = None
        self._answer_ms: float | None = None  # the compute time of ``_answer``
        self._next_id = 1
        self._goal_plans = 0  # plans made for the current goal (the first is not a replan)
        self.late_streak = 0
        """Late answers in a row: the next ask keeps the bridge and waits twice as long."""
        self.keep_followed = False
        """The request in flight keeps the followed plan if it finds no way (:meth:`request`)."""
        self.adaptive = False
        """Realtime: the switch waits 1.5 plan times when plans take longer than the bridge
        (never in lockstep or in-process: the switch tick must not depend on a clock)."""

    # -- inputs ------------------------------------------------------------------------------

    @property
    def enabled(self) -> bool:
        """Goals are planned: there is a setup and the world has an obstacle."""
        s = self.setup
        return s is not None and bool(s.obstacles or self.obstacles or self.markers)

    def set_goal(
        self, x: float, y: float, heading: float | None, reason: str = "goal", *, first: bool = True
    ) -> bool:
        """A goal the leader took (or a planned script's goal at a replan: ``first`` False):
        plan to it if the world has obstacles. True if a plan is wanted."""
        self.goal = (x, y, heading)
        self._goal_plans = 0 if first else 1
        self._request = self._answer = None  # an answer for the goal before is dropped
        if not self.enabled:
            self.state = None
            return False
        self._want = reason
        return True

    def clear_goal(self) -> None:
        """The leader left the planned goal (another command): nothing more to plan."""
        self.goal = None
        self._want = None
        self._request = None
        self._answer = None
        if self.state in (PlanState.PLANNING, PlanState.FOLLOWING):
            self.state = None

    def obstacle(self, action: str, oid: str, table: dict[str, Any] | None) -> str | None:
        """Add, move or remove the operator's obstacle ``oid``; returns the refusal reason
        (``exists``, ``unknown``, ``too_many``), or None (a replan is wanted if a goal is
        followed)."""
        if action == "add":
            if oid in self.obstacles:
                return self._refuse("exists")
            if len(self.obstacles) >= MAX_RUNTIME_OBSTACLES:
                return self._refuse("too_many")
        elif oid not in self.obstacles:
            return self._refuse("unknown")
        if action == "remove":
            del self.obstacles[oid]
        else:
            assert table is not None
            self.obstacles[oid] = table
        verb = {"add": "added", "move": "moved", "remove": "removed"}[action]
        if self.goal is not None:
            self._want = f"obstacle {oid} {verb}"
        return None

    def _refuse(self, reason: str) -> str:
        self.rejects[reason] = self.rejects.get(reason, 0) + 1
        return reason

    def robots_stuck(
        self,
        now_s: float,
        errors_m: Mapping[str, float],
        held: Sequence[str] | set[str],
        where: Mapping[str, tuple[float, float]],
        slot_of: Mapping[str, tuple[float, float]],
    ) -> None:
        """Feed the stuck watch; a robot newly stuck gets a marker and wants a replan."""
        if self.setup is None or self.goal is None:
            return
        new = self.stuck.update(now_s, errors_m, held)
        for rid in sorted(r for r in self.markers if r not in self.stuck.stuck):
            del self.markers[rid]  # free again: its marker goes
            if self.state is PlanState.NO_WAY:  # it was what blocked the way: try again
                self._want = f"{rid} free"
        for rid in sorted(new):
            p = where.get(rid)
            if p is None or rid not in slot_of:
                continue
            self.markers[rid] = {
                "kind": "circle", "x": p[0], "y": p[1], "radius_m": self.setup.body_radius_m,
            }  # fmt: skip
            self._want = f"stuck {rid}"

    # -- the shell's side ---------------------------------------------------------------------

    def take_request(self) -> PlanRequest | None:
        """The request to compute now (once; None if none is new)."""
        if self._request is None or self._taken:
            return None
        self._taken = True
        return self._request

    def deliver(self, request_id: int, answer: PlanResult | str, plan_ms: float | None) -> bool:
        """The answer to request ``request_id`` (a stale one is dropped: False; its compute
        time still counts as the last plan's)."""
        if plan_ms is not None:
            self.stats.plan_ms = plan_ms
        if self._request is None or self._request.id != request_id or self._answer is not None:
            return False
        self._answer = answer
        self._answer_ms = plan_ms
        return True

    def due(self, now_s: float) -> PlanRequest | None:
        """The request whose switch is due at ``now_s`` and that has no answer yet (a lockstep
        shell waits for it before the tick)."""
        r = self._request
        if r is not None and self._answer is None and now_s >= r.t_switch_s:
            return r
        return None

    # -- the tick -----------------------------------------------------------------------------

    def switch(self, now_s: float) -> tuple[PlanResult | str, float] | None:
        """Before the leader's step at ``now_s``: the answer to switch in now (a plan, or why
        there is none) and its switch time, or None. A realtime plan not ready at its switch
        time is late: counted and wanted again (from the bridge, which goes on)."""
        r = self._request
        if r is None or now_s < r.t_switch_s:
            return None
        answer = self._answer
        if answer is None:
            self.stats.late += 1
            self.late_streak += 1
            self._want = r.reason  # asked again from the same bridge, later (bridge_least_s)
            self._request = None
            return None
        self.late_streak = 0
        self._request, self._answer = None, None
        self.stats.plans += 1
        if self._goal_plans > 0:
            self.stats.replans += 1
        self._goal_plans += 1
        ok = not isinstance(answer, str)
        event: dict[str, Any] = {
            "t_s": now_s, "reason": r.reason, "ok": ok, "plan_ms": self._answer_ms,
        }  # fmt: skip
        if isinstance(answer, str) and self.keep_followed:
            self.state, self.why = PlanState.FOLLOWING, f"{r.reason} (kept the followed plan)"
            event.update(why=answer, kept=True)
        elif isinstance(answer, str):
            self.state, self.why = PlanState.NO_WAY, answer
            event["why"] = answer
        else:
            self.state, self.why = PlanState.FOLLOWING, r.reason
            self.stats.min_clearance_m = answer.stats.min_clearance_m
            event.update(
                length_m=answer.stats.length_m,
                min_clearance_m=answer.stats.min_clearance_m,
                path=[list(p) for p in answer.waypoints],
            )
        self.stats.events.append(event)
        return answer, r.t_switch_s

    def wanted(self) -> str | None:
        """Why a plan is wanted now (None: none)."""
        return self._want if self.setup is not None and self.goal is not None else None

    def bridge_least_s(self) -> float:
        """The least hold of a new bridge, or (after a late answer: the bridge is kept) the wait
        before the next switch (s): :data:`BRIDGE_S`, or 1.5 times the last plan's compute time
        when that is longer, doubled for every late answer in a row (at most 16 times)."""
        least = BRIDGE_S
        if self.adaptive and self.stats.plan_ms is not None:
            least = max(least, 1.5e-3 * self.stats.plan_ms)
        return least * 2.0 ** min(self.late_streak, 4)

    def request(
        self,
        now_s: float,
        bridge: Bridge | PlanBridge,
        offsets_m: Sequence[tuple[float, float]],
        t_switch_s: float | None = None,
        *,
        note: str | None = None,
        keep_followed: bool = False,
    ) -> PlanRequest:
        """Ask the plan for the wanted reason from ``bridge``, to switch in at ``t_switch_s``
        (default: the end of the bridge's hold); ``note``: how the bridge departs from the
        usual, said after the reason (``plan_why``); ``keep_followed``: the bridge is on the
        followed plan and all of its rest is still clear (``plan_bridge.clear_to_end``): no way
        keeps it (the caller resumes it) instead of stopping."""
        assert self.setup is not None and self.goal is not None
        self.keep_followed = keep_followed
        reason = self._want or "goal"
        if note is not None:
            reason = f"{reason} ({note})"
        self._want = None
        t_sw = bridge.t0_s + bridge.hold_s if t_switch_s is None else t_switch_s
        s = bridge.state_at(t_sw)
        gx, gy, gh = self.goal
        req = PlanRequest(
            id=self._next_id,
            reason=reason,
            t_switch_s=t_sw,
            start=(s.x, s.y, s.theta),
            v_start_mps=s.v_mps,
            goal=(gx, gy),
            goal_heading=gh,
            obstacles=(
                *self.setup.obstacles,
                *(self.obstacles[k] for k in sorted(self.obstacles)),
                *(self.markers[k] for k in sorted(self.markers)),
            ),
            offsets_m=tuple((float(a), float(b)) for a, b in offsets_m),
            setup=self.setup,
            departure_m=bridge.departure_m(t_sw) if isinstance(bridge, PlanBridge) else None,
        )
        self._next_id += 1
        self._request, self._taken, self._answer = req, False, None
        self.state, self.why = PlanState.PLANNING, reason
        return req

    def blocked(self, remaining_xy: Sequence[tuple[float, float]], reach_m: float) -> str | None:
        """While a replan waits for a squeeze to end: why the leader must stop at once (the goal
        or the rest of its path within ``reach_m`` of an obstacle added at run time), or None."""
        assert self.setup is not None and self.goal is not None
        added = [*self.obstacles.values(), *self.markers.values()]
        if not added:
            return None
        world = PlanWorld(added, None)
        gx, gy, _ = self.goal
        import numpy as np

        if world.clearance(np.array([[gx, gy]]), 1.0)[0] < self.setup.slot_radius_m:
            return f"no plan: goal ({gx:g}, {gy:g}) is inside an obstacle"
        if len(remaining_xy) and world.clearance(np.array(remaining_xy), reach_m).min() < reach_m:
            return "no plan: an obstacle on the path while the formation is squeezed in a passage"
        return None

    def stop_now(self, why: str, now_s: float) -> None:
        """No way found without planning (:meth:`blocked`): the leader stops (the caller)."""
        self._want = None
        self._request = self._answer = None
        self.state, self.why = PlanState.NO_WAY, why
        self.stats.events.append({"t_s": now_s, "reason": "blocked", "ok": False, "why": why})

    def arrived(self) -> None:
        """The leader reached the planned goal."""
        if self.state is PlanState.FOLLOWING:
            self.state = PlanState.ARRIVED
        self.goal = None
        self._want = None
