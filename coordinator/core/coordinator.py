"""The coordinator's pure tick: virtual leader -> slots -> role assignment -> setpoints.

One call per control tick, time passed in. The in-process simulator and the Zenoh coordinator
process both run exactly this, so they make the same decisions from the same poses.

**Approach of a newly assigned robot** (issue 13: spares never sprint). A robot that gets a slot
while the formation is already running (a spare replacing a dead robot, a robot back after its
pose was stale) and whose reference point is farther than :data:`APPROACH_JOIN_M` from that slot
is not given the slot itself, which would make its controller saturate toward a far target.
Its setpoint is an *approach point* that starts at its reference point and moves with the slot's
velocity plus at most :data:`APPROACH_SPEED_MPS` toward the slot, with that velocity as the
feed-forward, until it reaches the slot; from then on the robot tracks the slot as every other
one. Robots assigned at the start (the paper's convergence from the start poses) and robots
that move from one slot to another (the refill after a death) go straight to their slot. The
rule is here, in the core, so the in-process simulator and the Zenoh coordinator share it:
:attr:`CoordinatorOutput.approach` holds the approach setpoints and
:meth:`CoordinatorOutput.setpoint_for` applies them.

The tick is on the simulator's hot path (one call per 20 ms tick of sim time, and the sim runs
some thousand times faster than real time), so it works on plain floats and tuples: the slots are
computed by :func:`~coordinator.core.formation.slot_rows` (the trigonometry once per heading),
the assignment by :meth:`RoleAssigner.update_ordered` (given the rigid formation's least slot
spacing, it proves in O(n) that the incumbents hold instead of running the rule:
``coordinator.core.matching.kept_by_spacing``), and the :class:`SlotState` objects of
:attr:`CoordinatorOutput.slots` are only built if someone asks for them. Every shortcut returns
the bits of the full computation (``bench/bench_coordinator.py --against`` compares the outputs
of two trees).
"""

from __future__ import annotations

import math
from collections.abc import Collection, Mapping, Sequence
from dataclasses import replace
from types import MappingProxyType
from typing import Any, Final

from coordinator.core.assignment import RoleAssigner
from coordinator.core.formation import (
    FormationSpec,
    SlotRow,
    SlotState,
    morphed_slot_rows,
    slot_rows,
    states_from_rows,
)
from coordinator.core.leader import LeaderConfig, LeaderCore, LeaderMode
from coordinator.core.movers import MoverDetector, MoverParams, MoverRow
from coordinator.core.planning.plan_bridge import (
    BLOCKED,
    PlanBridge,
    bridge_on_plan,
    clear_to_end,
)
from coordinator.core.planning.replan import Bridge, PlanSetup, PlanState, Replanner
from coordinator.core.planning.timed import TimedPlan
from coordinator.core.planning.trajectory import PlannedTrajectory
from coordinator.core.reshape import blended_rows
from coordinator.core.reshaping import Reshaper
from coordinator.core.trajectory import LeaderState, Trajectory, make_trajectory, wrap_angle
from robot_agent.core.params import AgentConfig

__all__ = [
    "APPROACH_JOIN_M",
    "APPROACH_SPEED_MPS",
    "CoordinatorCore",
    "CoordinatorOutput",
    "pose_stale_s",
]

APPROACH_SPEED_MPS: Final = 0.1
"""Closing speed (m/s, relative to its slot) of a newly assigned robot's approach point: 40 % of
the firmware's reference-speed clamp (``TrackingGains.max_ref_speed_mps``, 0.25 m/s), so the
slot's own speed (the paper's leaders: 0.02-0.1 m/s), the PID's correction and the turn toward
the slot fit under the wheel limit instead of saturating it."""
APPROACH_JOIN_M: Final = 0.05
"""A newly assigned robot whose reference point is this close to its slot goes straight to it."""


def pose_stale_s(agent: AgentConfig, *, odometry: bool) -> float:
    """How long (s, receive time) the coordinator keeps a robot whose pose stopped coming: the
    one rule of the in-process simulator and the Zenoh coordinator.

    ``safety.stale_pose_s``, or, with the estimator enabled, at least the estimator's dropout
    bound (``max_dropout_odom_s`` when the robots have wheel encoders, ``odometry``, else
    ``max_dropout_cmd_s``): the robots ride through camera dropouts on their estimators, so the
    coordinator keeps a robot (and its slot) as long as its firmware may still be tracking.
    """
    stale = agent.safety.stale_pose_s
    est = agent.estimator
    if est.enabled:
        stale = max(stale, est.max_dropout_odom_s if odometry else est.max_dropout_cmd_s)
    return stale


class CoordinatorOutput:
    """One tick's decisions (read-only).

    ``leader``: the virtual leader's state; ``slots``: every slot's :class:`SlotState` in the
    formation's definition order; ``assignment``: robot id -> slot; ``changed``: the assignment
    differs from the previous tick's. The same numbers without objects: ``theta`` (rad, the
    formation heading shared by every slot) and ``rows``, ``(x, y, vx, vy)`` (m, m/s) per slot in
    definition order; ``slot_ids`` gives the slot of each row.
    """

    __slots__ = (
        "_approach",
        "_assignment",
        "_by_id",
        "_changed",
        "_leader",
        "_movers",
        "_rows",
        "_slot_ids",
        "_slots",
        "_spec",
        "_theta",
    )

    _approach: Mapping[str, SlotRow]
    _assignment: dict[str, int]
    _by_id: Mapping[int, SlotState] | None
    _changed: bool
    _leader: LeaderState
    _movers: tuple[MoverRow, ...]
    _rows: list[SlotRow]
    _slot_ids: tuple[int, ...]
    _slots: list[SlotState] | None
    _spec: FormationSpec | None
    _theta: float

    def __init__(
        self,
        leader: LeaderState,
        slots: Sequence[SlotState],
        assignment: dict[str, int],
        changed: bool,
        spec: FormationSpec | None = None,
        theta: float = 0.0,
        rows: list[SlotRow] | None = None,
        approach: Mapping[str, SlotRow] | None = None,
        movers: tuple[MoverRow, ...] = (),
    ) -> None:
        """From the slots' states; or, with ``rows`` (and ``spec``, ``theta``; ``slots``
        unread), from their numbers (:meth:`from_rows`)."""
        self._leader = leader
        self._assignment = assignment
        self._changed = changed
        self._by_id = None
        self._approach = _NO_APPROACH if approach is None else approach
        self._movers = movers
        if rows is not None and spec is not None:
            self._slots = None
            self._spec = spec
            self._theta = theta
            self._rows = rows
            self._slot_ids = spec.slot_ids
            return
        slot_list = list(slots)
        self._slots = slot_list
        self._spec = None
        self._theta = slot_list[0].theta if slot_list else wrap_angle(leader.theta)
        self._rows = [(s.x, s.y, s.vx, s.vy) for s in slot_list]
        self._slot_ids = tuple(s.slot for s in slot_list)

    @classmethod
    def from_rows(
        cls,
        leader: LeaderState,
        spec: FormationSpec,
        theta: float,
        rows: list[SlotRow],
        assignment: dict[str, int],
        changed: bool,
        approach: Mapping[str, SlotRow] | None = None,
        movers: tuple[MoverRow, ...] = (),
    ) -> CoordinatorOutput:
        """Build from :func:`~coordinator.core.formation.slot_rows` output without making the
        :class:`SlotState` objects (they are made on first access to :attr:`slots`)."""
        return cls(leader, (), assignment, changed, spec, theta, rows, approach, movers)

    @property
    def leader(self) -> LeaderState:
        return self._leader

    @property
    def slots(self) -> list[SlotState]:
        """Every slot's state, definition order (built once, on first access)."""
        slots = self._slots
        if slots is None:
            assert self._spec is not None
            slots = self._slots = states_from_rows(self._spec, self._theta, self._rows)
        return slots

    @property
    def assignment(self) -> dict[str, int]:
        """Robot id -> slot id."""
        return self._assignment

    @property
    def changed(self) -> bool:
        """The assignment differs from the previous tick's."""
        return self._changed

    @property
    def theta(self) -> float:
        """Formation heading (rad, wrapped), the ``theta`` of every slot."""
        return self._theta

    @property
    def rows(self) -> list[SlotRow]:
        """``(x, y, vx, vy)`` (m, m/s) of every slot, definition order (do not modify)."""
        return self._rows

    @property
    def slot_ids(self) -> tuple[int, ...]:
        """Slot id of each entry of :attr:`rows` / :attr:`slots`."""
        return self._slot_ids

    @property
    def approach(self) -> Mapping[str, SlotRow]:
        """Robot id -> ``(x, y, vx, vy)`` of its approach setpoint, for the newly assigned
        robots still on their way to their slot (module docstring); the others track their
        slot's row."""
        return self._approach

    @property
    def movers(self) -> tuple[MoverRow, ...]:
        """The moving obstacles now (coordinator.core.movers): ``(id, x, y, vx, vy)`` (m, m/s;
        the centre and its velocity over the detector's window), fleet robots and tracked
        objects, by id; the robots' filters take them as non-cooperative neighbours with that
        velocity (robot_agent.core.neighbours.with_movers)."""
        return self._movers

    def setpoint_for(self, robot: str) -> SlotState | None:
        """Robot ``robot``'s setpoint: its slot's state, or its approach point on the way."""
        slot = self._assignment.get(robot)
        if slot is None:
            return None
        state = self.slots_by_id[slot]
        row = self._approach.get(robot)
        if row is not None:
            state = replace(state, x=row[0], y=row[1], vx=row[2], vy=row[3])
        return state

    @property
    def slots_by_id(self) -> Mapping[int, SlotState]:
        """Slot id -> state (a read-only view, built once)."""
        by_id = self._by_id
        if by_id is None:
            by_id = self._by_id = MappingProxyType({s.slot: s for s in self.slots})
        return by_id

    @property
    def leader_robot(self) -> str | None:
        for rid, slot in self._assignment.items():
            if slot == 0:
                return rid
        return None

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, CoordinatorOutput):
            return NotImplemented
        return (
            self._leader == other._leader
            and self.slots == other.slots
            and self._assignment == other._assignment
            and self._changed == other._changed
            and dict(self._approach) == dict(other._approach)
            and self._movers == other._movers
        )

    __hash__ = None  # type: ignore[assignment]  # mutable assignment dict inside

    def __repr__(self) -> str:
        return (
            f"CoordinatorOutput(leader={self._leader!r}, slots={self.slots!r}, "
            f"assignment={self._assignment!r}, changed={self._changed!r})"
        )


_NO_APPROACH: Mapping[str, SlotRow] = MappingProxyType({})


class CoordinatorCore:
    """Virtual leader (eqs 1-2, a state advanced each tick: coordinator.core.leader), slots
    (eqs 3-5), greedy/optimal role assignment (eq 6)."""

    def __init__(
        self,
        trajectory: Trajectory,
        formation: FormationSpec,
        assigner: RoleAssigner,
        ref_offset_m: float,
        t0_s: float = 0.0,
        leader: LeaderCore | None = None,
        movers: MoverParams | None = None,
        plan_setup: PlanSetup | None = None,
    ) -> None:
        if not (ref_offset_m > 0 and math.isfinite(ref_offset_m)):
            raise ValueError(f"ref_offset_m must be positive and finite, got {ref_offset_m!r}")
        self.trajectory = trajectory
        self.leader = leader if leader is not None else LeaderCore(trajectory, t0_s=t0_s)
        self.leader.t0_s = t0_s
        # a planned trajectory may squeeze the formation (time-varying slot offsets)
        self._offsets_at = getattr(trajectory, "slot_offsets", None)
        self.reshaper = Reshaper(formation)
        """The settled formation and a runtime reshape over it (coordinator.core.reshaping)."""
        self.assigner = assigner
        self.ref_offset_m = ref_offset_m
        self.errors_m: dict[str, float] = {}
        """Tracking error (m) of each assigned robot at the last tick (reference point to the
        setpoint of the tick before), computed while the leader waits for its team."""
        self.assignment: dict[str, int] = {}
        self.movers = MoverDetector(movers)
        """Robots moving as their wheels cannot (issue 30): no slot while so, theirs kept."""
        self._yielding: frozenset[str] = frozenset()
        self._released: dict[str, tuple[int, float]] = {}
        """Robots whose slot a reshape dropped -> (that slot, until when, s): still counted as
        driven by the mover detector while they brake (a spare that moves is a mover)."""
        self.approach_speed_mps = APPROACH_SPEED_MPS
        self._approach: dict[str, list[float]] = {}  # robot -> approach point [x, y]
        self._running = False  # a tick has assigned robots (later assignments approach)
        self._last_now: float | None = None
        self._row_of: dict[int, int] = {}
        self._row_ids: tuple[int, ...] | None = None  # the slot ids _row_of was built for
        self._last_out: CoordinatorOutput | None = None
        self.replanner = Replanner(plan_setup)
        """Run-time plans: goals around obstacles, replans (coordinator.core.planning.replan)."""

    @property
    def formation(self) -> FormationSpec:
        """The settled formation (the scenario's, or the target of the last reshape over)."""
        return self.reshaper.formation

    @formation.setter
    def formation(self, spec: FormationSpec) -> None:
        self.reshaper.formation = spec

    @property
    def shape(self) -> str | None:
        """The kind of the last reshape asked (None: the scenario's formation)."""
        return self.reshaper.shape

    @property
    def reshapes(self) -> list[dict[str, Any]]:
        """One record per reshape completed (coordinator.core.reshaping)."""
        return self.reshaper.reshapes

    def _rows_by_slot(self, slot_ids: tuple[int, ...]) -> dict[int, int]:
        """Slot id -> row for rows in ``slot_ids`` order (cached for the same tuple)."""
        if slot_ids is not self._row_ids:
            self._row_of = {sid: i for i, sid in enumerate(slot_ids)}
            self._row_ids = slot_ids
        return self._row_of

    @property
    def t0_s(self) -> float:
        """Time origin of the scripted trajectory (s, the tick's clock)."""
        return self.leader.t0_s

    @t0_s.setter
    def t0_s(self, value: float) -> None:
        self.leader.t0_s = value

    @classmethod
    def from_config(
        cls,
        trajectory: Mapping[str, Any],
        formation: Mapping[str, Any],
        method: str,
        hysteresis_m: float,
        tie_tol_m: float,
        ref_offset_m: float,
        t0_s: float = 0.0,
        leader: LeaderConfig | None = None,
        arena: tuple[float, float, float, float] | None = None,
        plan_setup: PlanSetup | None = None,
    ) -> CoordinatorCore:
        kind = str(trajectory["kind"])
        traj_params = {k: v for k, v in trajectory.items() if k != "kind"}
        traj = make_trajectory(kind, traj_params)
        return cls(
            traj,
            FormationSpec.from_dict(dict(formation)),
            RoleAssigner(method=method, hysteresis_m=hysteresis_m, tie_tol_m=tie_tol_m),
            ref_offset_m=ref_offset_m,
            t0_s=t0_s,
            leader=LeaderCore(traj, leader, t0_s=t0_s, trajectory_kind=kind, arena=arena),
            plan_setup=plan_setup,
        )

    def _ref_points(
        self, poses: Mapping[str, tuple[float, float, float]]
    ) -> tuple[list[str], list[tuple[float, float]]]:
        """Reference points (eqs 10-11) of the finite poses: (ids, (x, y) in m), input order.

        The arithmetic of ``robot_agent.core.kinematics.reference_point`` (the same operations
        in the same order, so the same bits:
        ``tests/unit/coordinator/test_coord_reference_points.py``),
        written out: compiled, this loop calls C's ``cos``, ``sin``, ``isinf`` and ``isnan``
        where a call into the firmware's build would box four floats and a tuple per robot."""
        l_m = self.ref_offset_m
        ids: list[str] = []
        xy: list[tuple[float, float]] = []
        for rid, (x, y, th) in poses.items():  # (math.f(...) spelled out: mypyc's C calls)
            xr, yr = x + l_m * math.cos(th), y + l_m * math.sin(th)  # eqs 10-11
            if not (math.isinf(xr) or math.isnan(xr) or math.isinf(yr) or math.isnan(yr)):
                ids.append(rid)
                xy.append((xr, yr))
        return ids, xy

    def reference_points(
        self, poses: Mapping[str, tuple[float, float, float]]
    ) -> dict[str, tuple[float, float]]:
        """Robot axle-centre poses -> reference points (eqs 10-11), skipping non-finite ones."""
        ids, xy = self._ref_points(poses)
        return dict(zip(ids, xy, strict=True))

    def leader_xy(self, t_s: float) -> tuple[float, float]:
        """The virtual leader's position (m) at trajectory time ``t_s`` (now - t0)."""
        state = self.trajectory.sample(t_s)
        return state.x, state.y

    def tick(
        self,
        now_s: float,
        poses: Mapping[str, tuple[float, float, float]],
        held: Collection[str] = (),
        objects: Mapping[str, tuple[float, float]] | None = None,
    ) -> CoordinatorOutput:
        """``poses``: the latest fresh pose of every live robot (axle centre x, y, theta);
        ``held``: robots known to be held (e-stopped): a leader that waits for its team stops
        for them (coordinator.core.leader); ``objects``: tracked bodies that are not counted
        robots (centre x, y; a cart's tag, a dead robot still tracked): moving, they are movers
        (coordinator.core.movers)."""
        ids, xy = self._ref_points(poses)
        ld = self.leader
        rate = 1.0
        if ld.waits() and self._last_out is not None:
            self.errors_m = self._errors(self._last_out, ids, xy)
            rate = ld.wait.target_rate(now_s, self.errors_m, held)
        planning = self.replanner.setup is not None
        if planning:
            self._switch_plan(now_s)
        leader = ld.step(now_s, rate)
        reshaper = self.reshaper
        tr = reshaper.advance(now_s)
        spacing_m = None  # the slots' least spacing, for a rigid formation (RoleAssigner)
        if tr is not None:
            spec = tr.spec
            theta, rows = blended_rows(leader, *reshaper.offsets(now_s))
        else:
            spec = reshaper.formation
            offsets = None  # a planned squeeze, at the plan's own (progress) time
            if self._offsets_at is not None and ld.mode is LeaderMode.SCRIPT:
                offsets = self._offsets_at(ld.progress_s)
            elif ld.plan is not None:  # a run-time plan's squeeze
                offsets = ld.plan.slot_offsets(ld.progress_s)
            if offsets is not None:
                theta, rows = morphed_slot_rows(leader, offsets)
            else:
                theta, rows = slot_rows(spec, leader)
                spacing_m = spec.least_spacing_m
        slot_ids: Sequence[int] = spec.priority_slots
        # (not a comprehension: compiled, that unboxes each row and boxes a copy of it)
        slot_xy = list(map(rows.__getitem__, spec.priority_rows))
        movers = self.movers
        was_yielding = self._yielding
        driven = self._driven(now_s) if self._released else self.assignment
        if movers.update(now_s, poses, driven, held, objects):
            a_ids, a_xy, slot_ids, slot_xy = self._without_movers(ids, xy, slot_ids, slot_xy)
            assignment, changed = self.assigner.update_ordered(
                a_ids, a_xy, slot_ids, slot_xy, spacing_m
            )
        else:
            assignment, changed = self.assigner.update_ordered(
                ids, xy, slot_ids, slot_xy, spacing_m
            )
        refuges: dict[str, SlotRow] | None = None
        self._yielding = movers.yielding
        if self._yielding or was_yielding:
            refuges = self._make_room(assignment, ids, xy, rows, spec.slot_ids, was_yielding)
            changed = assignment != self.assignment
        previous, self.assignment = self.assignment, assignment
        if changed and tr is None and len(previous) > len(assignment):
            self._release(now_s, previous, assignment, spec)
        dt = 0.0 if self._last_now is None else max(0.0, now_s - self._last_now)
        self._last_now = now_s
        approach = None
        if self._approach or (changed and self._running):
            approach = self._approaches(previous, assignment, ids, xy, rows, spec.slot_ids, dt)
        if refuges:
            approach = {**approach, **refuges} if approach else refuges
        self._running = self._running or bool(assignment)
        out = CoordinatorOutput.from_rows(
            leader, spec, theta, rows, assignment, changed, approach, movers.moving()
        )
        self._last_out = out
        if planning and (ld.new_goal is not None or self.replanner.goal is not None):
            # (without a goal, new or followed, _replan has nothing to do)
            self._replan(now_s, held, ids, xy, rows, spec.slot_ids, assignment)
        return out

    def _release(
        self,
        now_s: float,
        previous: Mapping[str, int],
        assignment: Mapping[str, int],
        spec: FormationSpec,
    ) -> None:
        """The robots that lost their slot because a reshape dropped it: driven for a while."""
        grace = self.movers.params.window_s + self.movers.params.hold_s
        for rid, slot in previous.items():
            if rid not in assignment and slot not in spec:
                self._released[rid] = (slot, now_s + grace)

    def _driven(self, now_s: float) -> dict[str, int]:
        """The previous assignment plus the robots released by a reshape that may still be
        braking (coordinator.core.movers: a robot without a slot that moves is a mover)."""
        for rid in [r for r, (_, until) in self._released.items() if now_s > until]:
            del self._released[rid]
        extra = {r: slot for r, (slot, _) in self._released.items() if r not in self.assignment}
        return {**self.assignment, **extra}

    # -- run-time plans (coordinator.core.planning.replan) -------------------------------------

    def obstacle(self, action: str, oid: str, table: dict[str, Any] | None) -> str | None:
        """Add, move or remove the operator's planning obstacle ``oid`` (a ``PlanWorld`` table);
        a goal followed (or a planned script) is replanned from the leader's state at the next
        tick. Returns why it is refused, or None."""
        rp = self.replanner
        if rp.setup is None:
            return "no_planner"
        why = rp.obstacle(action, oid, table)
        traj = self.trajectory
        if (
            why is None
            and rp.goal is None
            and self.leader.mode is LeaderMode.SCRIPT
            and self.leader.trajectory_kind == "plan"
            and self.leader.progress_s < getattr(traj, "duration_s", 0.0)
        ):  # a planned script: replanned to its goal around the new world
            gx, gy = getattr(traj, "goal", (0.0, 0.0))
            rp.set_goal(float(gx), float(gy), getattr(traj, "goal_heading", None),
                        f"obstacle {oid} {action}", first=False)  # fmt: skip
        return why

    def continue_goal(self) -> bool:
        """After a takeover (``LeaderCore.adopt``): a goal the leader was driven to is planned
        again from the adopted state (the bridge joins it without a jump). True if so."""
        goal = self.leader.goal_point
        rp = self.replanner
        if goal is None or rp.setup is None:
            return False
        return rp.set_goal(*goal, "takeover", first=False)

    def _blocked_while_squeezed(self, now_s: float) -> None:
        """The world changed while the formation is squeezed on its plan: stop at once if the
        goal or the rest of the path (the leader within the formation's reach) is blocked."""
        ld, rp = self.leader, self.replanner
        plan = ld.plan
        assert plan is not None and rp.setup is not None
        r = plan.result
        rest = [(float(x), float(y)) for x, y, t in zip(r.x_m, r.y_m, r.t_s, strict=True)
                if t >= ld.progress_s][::10]  # fmt: skip
        offs = self.formation.body_offsets_m
        reach = float(max(math.hypot(a, b) for a, b in offs)) + rp.setup.slot_radius_m
        why = rp.blocked(rest, reach)
        if why is not None:
            rp.stop_now(why, now_s)
            ld.no_way()

    def _switch_plan(self, now_s: float) -> None:
        """Before the leader's step: switch in the plan due now, or stop where there is none."""
        got = self.replanner.switch(now_s)
        if got is None:
            return
        answer, t_switch = got
        bridge = self.leader.bridge
        if (
            isinstance(answer, str)
            and isinstance(bridge, PlanBridge)
            and self.replanner.keep_followed
        ):
            tau, rate = bridge.progress(t_switch - bridge.t0_s)  # no way: the plan it had, on
            self.leader.follow_plan(bridge.followed, t_switch, tau, rate)  # from the bridge
            return
        if isinstance(answer, str):
            self.leader.no_way()
            return
        self.leader.follow_plan(TimedPlan(answer), t_switch)

    def _replan(
        self,
        now_s: float,
        held: Collection[str],
        ids: list[str],
        xy: list[tuple[float, float]],
        rows: list[SlotRow],
        slot_ids: tuple[int, ...],
        assignment: Mapping[str, int],
    ) -> None:
        """After the tick: take a new goal, watch for stuck robots, and start the bridge of a
        wanted plan from the leader's state of this tick (coordinator.core.planning.replan)."""
        ld, rp = self.leader, self.replanner
        goal = ld.take_new_goal()
        if goal is not None:
            rp.set_goal(*goal)
        elif rp.goal is not None and ld.mode is not LeaderMode.GOAL:
            if rp.state is PlanState.FOLLOWING and ld.mode is LeaderMode.STOP:
                rp.arrived()
            elif rp.state is not PlanState.NO_WAY:
                rp.clear_goal()  # the operator took the leader elsewhere
        if rp.goal is not None and self.errors_m:
            row_of = self._rows_by_slot(slot_ids)
            slot_of = {r: rows[row_of[s]][:2] for r, s in assignment.items() if s in row_of}
            where = dict(zip(ids, xy, strict=True))
            rp.robots_stuck(now_s, self.errors_m, set(held), where, slot_of)
        if rp.wanted() is None or ld.state is None:
            return
        if ld.squeezed():  # the replan waits for the end of the passage, unless it must not
            self._blocked_while_squeezed(now_s)
            return
        offsets = [(float(a), float(b)) for a, b in self.formation.body_offsets_m]
        if rp.late_streak and isinstance(ld.bridge, Bridge | PlanBridge):  # late: the same
            rp.request(now_s, ld.bridge, offsets, now_s + rp.bridge_least_s(),  # bridge, later
                       keep_followed=rp.keep_followed)  # fmt: skip
            return
        bridge, note = self._bridge(now_s, offsets)
        keep = False
        if isinstance(bridge, PlanBridge):
            added = [*rp.obstacles.values(), *rp.markers.values()]
            keep = clear_to_end(bridge.followed, bridge.tau0_s, added, rp.setup.slot_radius_m)  # type: ignore[union-attr]
        ld.begin_bridge(bridge)
        # a slow planner: the switch is later, on the bridge's braking tail (a slower start)
        t_switch = now_s + max(bridge.hold_s, rp.bridge_least_s())
        rp.request(now_s, bridge, offsets, t_switch, note=note, keep_followed=keep)

    def _bridge(
        self, now_s: float, offsets: list[tuple[float, float]]
    ) -> tuple[Bridge | PlanBridge, str | None]:
        """The leader's motion while a plan is computed, from its state of this tick, and a
        note for ``plan_why`` when it brakes: on the plan it follows (a run-time plan or a
        planned script) when that plan goes on clear of the run's obstacles
        (coordinator.core.planning.plan_bridge), else the straight bridge; braking at once
        (a straight bridge to rest) when the followed plan is blocked within the bridge."""
        ld, rp = self.leader, self.replanner
        cfg, setup = ld.config, rp.setup
        assert setup is not None and ld.state is not None
        followed = self._followed()
        cruise = setup.cruise_mps
        note = None
        if followed is not None:
            timed, tau = followed
            v_max = max(float(timed.result.v_mps.max()), 1e-3)
            pb = PlanBridge(timed, tau, ld.rate, now_s, least_s=rp.bridge_least_s(),
                            brake_per_s=0.5 * cfg.max_accel_mps2 / v_max)  # fmt: skip
            added = [*rp.obstacles.values(), *rp.markers.values()]
            why = bridge_on_plan(pb, offsets, added, setup.slot_radius_m)
            if why is None:
                return pb, None
            if why == BLOCKED:
                cruise, note = 0.0, f"braking: {why}"
        bridge = Bridge(ld.state, now_s, cruise_mps=cruise, accel_mps2=cfg.max_accel_mps2,
                        turn_accel_radps2=cfg.max_turn_accel_radps2)  # fmt: skip
        return bridge, note

    def _followed(self) -> tuple[TimedPlan, float] | None:
        """The plan the leader follows and its plan time now, or None (not on a plan)."""
        ld = self.leader
        if ld.plan is not None and ld.bridge is None:
            return ld.plan, ld.progress_s
        traj = ld.trajectory
        if ld.mode is LeaderMode.SCRIPT and isinstance(traj, PlannedTrajectory):
            return traj.timed, ld.progress_s - traj.t_start_s
        return None

    def _without_movers(
        self,
        ids: list[str],
        xy: list[tuple[float, float]],
        slot_ids: Sequence[int],
        slot_xy: list[SlotRow],
    ) -> tuple[list[str], list[tuple[float, float]], list[int], list[SlotRow]]:
        """The assignment's input without the movers and without the slots kept for them
        (coordinator.core.movers): a mover and a robot making room for it get no slot, and no
        robot is sent to theirs."""
        movers = self.movers.excluded
        keep = [i for i, rid in enumerate(ids) if rid not in movers]
        kept = set(self.movers.reserved.values())
        free = [k for k, sid in enumerate(slot_ids) if sid not in kept]
        return (
            [ids[i] for i in keep],
            [xy[i] for i in keep],
            [slot_ids[k] for k in free],
            [slot_xy[k] for k in free],
        )

    def _make_room(
        self,
        assignment: dict[str, int],
        ids: list[str],
        xy: list[tuple[float, float]],
        rows: list[SlotRow],
        slot_ids: tuple[int, ...],
        was_yielding: frozenset[str],
    ) -> dict[str, SlotRow]:
        """The robots making room for a mover (coordinator.core.movers) keep the slot they had
        (added to ``assignment``) with a refuge beside the mover's path as their setpoint (the
        returned approach rows, with a feed-forward toward the refuge: ``aside_rows``); one
        that stops yielding far from its slot goes back to it on an approach point (as a newly
        assigned robot does)."""
        movers = self.movers
        reserved = movers.reserved
        row_of = self._rows_by_slot(slot_ids)
        where = dict(zip(ids, xy, strict=True))
        out: dict[str, SlotRow] = {}
        points: dict[str, tuple[float, float]] = {}
        for rid in sorted(self._yielding):
            slot = reserved.get(rid)
            q = where.get(rid)
            if slot is None or q is None or slot not in row_of:  # (a slot a reshape dropped)
                continue
            assignment[rid] = slot
            self._approach.pop(rid, None)
            points[rid] = q
        out.update(movers.aside_rows(points))
        for rid in sorted(was_yielding - self._yielding):
            slot = assignment.get(rid)
            q = where.get(rid)
            if slot is None or q is None or rid in self._approach:
                continue
            sx, sy, _, _ = rows[row_of[slot]]
            if math.hypot(sx - q[0], sy - q[1]) > APPROACH_JOIN_M:
                self._approach[rid] = [q[0], q[1]]
        return out

    # -- runtime reshaping (coordinator.core.reshaping) ----------------------------------------

    def reshape(
        self,
        kind: str,
        spacing_m: float,
        safety_m: float,
        slots: int | None = None,
        robots: int | None = None,
    ) -> str | None:
        """Reshape the formation into ``kind`` with ``slots`` slots (None: as now) ``spacing_m``
        apart, never closer than ``safety_m`` (m) along the way; applied at the next tick.
        Returns why it is refused (``too_many_slots`` beyond ``robots`` alive, ``bad_slots``,
        ``bad_shape``, ``unsafe``), or None. A reshape during a reshape starts from where the
        slots are."""
        return self.reshaper.ask(kind, spacing_m, safety_m, slots, robots)

    @property
    def reshaping(self) -> float | None:
        """Fraction of the running reshape done (None: no reshape running)."""
        return self.reshaper.fraction

    def _errors(
        self, last: CoordinatorOutput, ids: list[str], xy: list[tuple[float, float]]
    ) -> dict[str, float]:
        """Each robot assigned at the last tick: distance (m) from its reference point now to
        the setpoint it was given (its slot, or its approach point)."""
        row_of = self._rows_by_slot(last.slot_ids)
        where = dict(zip(ids, xy, strict=True))
        out: dict[str, float] = {}
        rows, approach = last.rows, last.approach
        for rid, slot in last.assignment.items():
            p = where.get(rid)
            if p is None:
                continue
            row = approach.get(rid) or rows[row_of[slot]]
            out[rid] = math.hypot(row[0] - p[0], row[1] - p[1])
        return out

    def _approaches(
        self,
        previous: Mapping[str, int],
        assignment: Mapping[str, int],
        ids: list[str],
        xy: list[tuple[float, float]],
        rows: list[SlotRow],
        slot_ids: tuple[int, ...],
        dt: float,
    ) -> dict[str, SlotRow] | None:
        """Advance the approach points by ``dt`` and start those of the robots newly assigned
        far from their slot (module docstring); the approach setpoints, or None."""
        row_of = self._rows_by_slot(slot_ids)
        points = self._approach
        for rid in [r for r in points if r not in assignment]:
            del points[rid]
        if self._running:
            where = dict(zip(ids, xy, strict=True))
            for rid, slot in assignment.items():
                if rid in points or rid in previous or rid not in where:
                    continue
                px, py = where[rid]
                sx, sy, _, _ = rows[row_of[slot]]
                if math.hypot(sx - px, sy - py) > APPROACH_JOIN_M:
                    points[rid] = [px, py]
        out: dict[str, SlotRow] = {}
        closing = self.approach_speed_mps
        for rid, p in list(points.items()):
            sx, sy, vx, vy = rows[row_of[assignment[rid]]]
            # the point moves with the slot, and closes in on it at most `closing`
            qx, qy = p[0] + vx * dt, p[1] + vy * dt
            dx, dy = sx - qx, sy - qy
            d = math.hypot(dx, dy)
            if not math.isfinite(d) or d <= closing * dt:
                del points[rid]  # reached: the slot itself from now on
                continue
            ux, uy = dx / d, dy / d
            p[0], p[1] = qx + ux * closing * dt, qy + uy * closing * dt
            out[rid] = (p[0], p[1], vx + ux * closing, vy + uy * closing)
        return out or None
