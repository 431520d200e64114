"""The closed loop in one process, over the same cores as the distributed runtime (no Zenoh).

Per control tick (``dt_s``), in this order:
0. scripted faults due at this tick fire (``[[fault]]``, :mod:`scenario.faults`), with their
   in-process meaning (:class:`FaultPlay`): a killed, paused or cut-off robot is *offline* (the
   coordinator no longer counts it, as when its liveliness token vanishes, and the plant stops
   its wheels); a killed or paused agent's firmware does not step, a cut-off one steps on the
   inputs it had; an e-stop latches the firmware of its scope; a killed coordinator's outputs
   stop until its hot standby takes over (``takeover_s``); a camera loss occludes the robot;
1. scheduled disturbances start (drag / teleport the truth);
2. the camera captures truth at its own rate and delivers noisy poses after its latency;
3. the coordinator core runs on the latest measured poses (virtual leader, slots, assignment);
4. each robot's firmware steps on its latest pose, its neighbours' poses and the setpoint the
   coordinator computed on the PREVIOUS tick: the lockstep rules of ``robot_agent.core.lockstep``
   (tick time, setpoint delay), the same code the distributed nodes run, so a run over Zenoh in
   lockstep equals this one bit for bit (docs/runtime.md);
5. wheel commands go through the lossy, delayed command link;
6. the plant integrates the wheel speeds that arrived (truth).

The separation monitor (collisions, minimum separation) only reads the truth, so it runs over the
whole logged truth at the end (``SeparationMonitor.update_many``, the same result as one update
per tick).

Speed: the loop runs each component's small-fleet path (plain Python on tuples where numpy's
per-call overhead would dominate; bit-identical to the vectorised paths, which large fleets use),
keeps per-tick records as flat lists of numbers (:class:`formation.sim.ticklog.TickLog`: the tick's
tuples and commands are freed at once, not kept for the collector to walk), converted to arrays
every few hundred ticks and joined at the end. The cyclic garbage collector is paused over the loop
(:class:`formation.sim.collector.CollectorPause`: the loop makes no reference cycles, and an
automatic collection would walk the growing log again and again); its youngest generation is
collected every ``YOUNG_EVERY_TICKS`` ticks. This module and the plant, camera and link it drives
also run compiled (mypyc) when ``make accel`` built them: the same sources, the same bits
(``sim_plant.core._accel``). ``bench/bench_sim.py`` measures it.

Everything random comes from one seeded generator, so a seed gives the same run.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from coordinator.core.coordinator import CoordinatorOutput, pose_stale_s
from coordinator.core.operator_script import OperatorScript
from formation.outputs.runlog import RunLog
from formation.sim.collector import YOUNG_EVERY_TICKS, CollectorPause
from formation.sim.ticklog import TickLog
from robot_agent.core.firmware import Firmware, Mode, Pose, Setpoint, WheelCommand
from robot_agent.core.lockstep import SETPOINT_DELAY_TICKS, SetpointWindow, tick_time
from robot_agent.core.neighbour_index import NEIGHBOUR_CELL_M, NeighbourIndex
from robot_agent.core.neighbour_select import select_min_entries
from robot_agent.core.neighbours import ClaimRing, mover, neighbours_at
from robot_agent.core.safety_filter import Neighbour
from scenario import Scenario
from scenario.assemble import coordinator_core
from scenario.assemble_plant import apply_scheduled, plant_models
from scenario.faults import FaultAction, FaultScheduler, FleetFaults, fleet_view
from scenario.preflight import path_conflicts
from sim_plant.core.encoders import WheelEncoders
from sim_plant.core.sensors import Camera

# Build the firmware's NamedTuple inputs without the generated __new__ frame (hot path; the
# firmware builds its WheelCommand the same way).
_tuple_new = tuple.__new__


@dataclass
class SimResult:
    log: RunLog
    wall_s: float
    firmware_status: dict[str, Any]
    interrupted: bool = False  # ``stop`` was set: the log holds the ticks run before it
    movers: dict[str, Any] = field(default_factory=dict)
    """Scenario ``[[mover]]`` bodies (issue 30): id -> array ``(ticks, 2)`` of the body's centre
    (m) at each logged tick, the same ticks as ``log.t_s``."""

    @property
    def realtime_factor(self) -> float:
        sim_s = float(self.log.t_s[-1] - self.log.t_s[0]) if self.log.t_s.size > 1 else 0.0
        return sim_s / self.wall_s if self.wall_s > 0 else math.inf


PROGRESS_EVERY_TICKS = 500  # how often run() calls its progress callback
_ZERO_CMD = WheelCommand(0.0, 0.0, 0.0, 0.0, Mode.IDLE, None, False)  # a dead agent's "command"


class FaultPlay:
    """The scenario's ``[[fault]]`` entries played in-process (module docstring, step 0)."""

    def __init__(self, scenario: Scenario, firmwares: list[Firmware]) -> None:
        self.ids = list(scenario.robot_ids)
        self.index = {rid: i for i, rid in enumerate(self.ids)}
        self.scheduler = FaultScheduler(scenario.faults)
        self.state = FleetFaults()
        self.firmwares = firmwares
        self.l_m = scenario.agent.geometry.ref_offset_m
        self.tol_m = scenario.settle_tol_m
        self.offline: set[int] = set()  # robot indices the coordinator and plant drop
        self.frozen: set[int] = set()  # killed or paused: the firmware does not step
        # a cut-off robot's inputs (pose, rx, capture), frozen at its first step after the cut
        self.cut_inputs: dict[int, tuple[Any, float, float | None] | None] = {}
        self.leader: str | None = None
        self.in_formation = False
        self.sent: list[dict[str, Any]] = []

    def fire(self, k: int, t_s: float, camera: Camera) -> None:
        """Apply the faults due at tick ``k`` (time ``t_s``)."""
        for act in self.scheduler.due(t_s, leader=self.leader, in_formation=self.in_formation):
            self._apply(act, t_s, camera)
            self.sent.append({**act.as_dict(), "tick": k})

    def _apply(self, act: FaultAction, t_s: float, camera: Camera) -> None:
        st = self.state
        st.apply(act)
        i = self.index.get(act.robot) if act.robot is not None else None
        if act.kind == "camera_loss" and i is not None:
            camera.occlude(i, t_s, t_s + (act.duration_s or 0.0))
        elif act.kind in ("estop", "release"):
            for j, rid in enumerate(self.ids):
                fw = self.firmwares[j]
                if st.stopped(rid):
                    fw.engage_estop()
                else:
                    fw.release_estop()
        elif act.kind == "cut_link" and i is not None and i not in self.cut_inputs:
            self.cut_inputs[i] = None  # taken at its firmware's step (_faulted_step)
        elif act.kind == "restore_link" and i is not None:
            self.cut_inputs.pop(i, None)
        self.offline = {self.index[r] for r in st.offline()}
        self.frozen = {self.index[r] for r in st.killed | st.paused}

    def coordinator_input(
        self, fresh: dict[str, tuple[float, float, float]]
    ) -> dict[str, tuple[float, float, float]]:
        """The poses the coordinator counts: an offline robot's liveliness is gone."""
        if not self.offline:
            return fresh
        gone = {self.ids[i] for i in self.offline}
        return {r: q for r, q in fresh.items() if r not in gone}

    def objects(
        self,
        fresh: dict[str, tuple[float, float, float]],
        counted: dict[str, tuple[float, float, float]],
        bodies: dict[str, tuple[float, float]] | None,
    ) -> dict[str, tuple[float, float]] | None:
        """The tracked bodies the coordinator is given (as the coordinator node's
        ``fresh_objects``): the scenario's visible ``bodies`` and every offline robot with a
        fresh pose. Its wheels are stopped, so it moves only when carried or pushed: then it is
        a mover (coordinator.core.movers) and the others make room and see its velocity."""
        if len(counted) == len(fresh):
            return bodies
        out = dict(bodies) if bodies else {}
        for rid, q in fresh.items():
            if rid not in counted:
                out[rid] = (q[0], q[1])
        return out

    def observe(
        self, out: CoordinatorOutput, counted: dict[str, tuple[float, float, float]]
    ) -> None:
        """After the coordinator's tick on the poses it ``counted``: who leads, and whether
        every robot is in formation (the condition ``when = "in_formation"``;
        :func:`scenario.faults.fleet_view`, the coordinator node's rule too)."""
        self.leader, self.in_formation = fleet_view(
            out.assignment, out.rows, out.slot_ids, counted, self.l_m, self.tol_m
        )


def run(  # noqa: PLR0915 (the in-process loop: one tick's stages in their order)
    scenario: Scenario,
    seed: int | None = None,
    duration_s: float | None = None,
    stop: threading.Event | None = None,
    progress: Callable[[float, float], None] | None = None,
) -> SimResult:
    """Run ``scenario`` in-process for ``duration_s`` (default: the scenario's) of sim time.

    ``seed`` overrides the scenario's seed. The returned ``wall_s`` is the wall-clock time of the
    loop and of building the log arrays at the end. ``stop`` (e.g. set by a SIGINT handler) ends
    the run early, between two ticks: the result holds the ticks run so far (at least one) and
    ``interrupted`` is True. ``progress(t_s, duration_s)``, if given, is
    called every :data:`PROGRESS_EVERY_TICKS` ticks (it must not touch the run's state).
    """
    seed = scenario.seed if seed is None else seed
    duration = scenario.duration_s if duration_s is None else duration_s
    rng = np.random.default_rng(seed)
    ids = list(scenario.robot_ids)
    n = len(ids)
    index = {rid: i for i, rid in enumerate(ids)}
    geom = scenario.agent.geometry
    l_m = geom.ref_offset_m

    coord = coordinator_core(scenario)
    plant, camera, link, monitor = plant_models(scenario, rng)
    encoders = (
        WheelEncoders(
            n, scenario.plant.encoder_counts_per_rev, scenario.plant.encoder_slip_std, rng
        )
        if scenario.plant.encoder_counts_per_rev > 0.0
        else None
    )
    wheel_meas: list[tuple[float, float]] | None = None
    firmwares = [Firmware(scenario.agent) for _ in ids]

    dt = scenario.dt_s
    ticks = round(duration / dt) + 1
    slot_ids = list(coord.formation.slot_ids)
    slot_row = {s: k for k, s in enumerate(slot_ids)}
    # how long the coordinator keeps a robot whose pose stopped coming (with the estimator:
    # its dropout bound), the Zenoh coordinator's rule too
    stale = pose_stale_s(scenario.agent, odometry=encoders is not None)

    # Per-robot state of the loop. poses[i] is robot i's latest measured pose, as its firmware
    # sees it; xyt[i] the same (x, y, theta) as the coordinator sees it.
    poses: list[Pose | None] = [None] * n
    xyt: list[tuple[float, float, float] | None] = [None] * n
    pose_rx = [-math.inf] * n
    pose_objs: list[Any] = poses  # the same lists, read without unboxing (see t_obj below)
    rx_objs: list[Any] = pose_rx
    pose_cap: list[float | None] = [None] * n
    applied: list[tuple[float, float]] = [(0.0, 0.0)] * n
    neighbours: list[Any] = [[] for _ in ids]  # robot i's list (or view) of the tick
    view_min = select_min_entries()  # lists this long or longer are views (neighbour_index)
    tracking = [False] * n  # robot j's firmware was TRACKING on the previous tick
    # motion claims (rule 4 of robot_agent.core.neighbours): the previous ticks' commands
    sfp = scenario.agent.safety_filter
    rings = [ClaimRing() for _ in ids] if sfp.accel_bound_mps2 > 0.0 else None
    vmax = geom.max_speed_mps
    pending = list(scenario.disturbances)
    fresh: dict[str, tuple[float, float, float]] = {}
    oldest_rx = math.inf  # earliest receive time among the poses in `fresh`
    outputs: SetpointWindow[CoordinatorOutput] = SetpointWindow()  # the coordinator's outputs

    slot_of_changes: list[tuple[int, list[int]]] = []

    faults = FaultPlay(scenario, firmwares) if scenario.faults else None
    # scripted operator commands ([[operator]], issue 28): played into the core before its tick,
    # as the coordinator node does; a reshape may change the slots, so the rows are looked up
    # by the slot ids of each output and logged by slot id
    script = (
        OperatorScript(scenario.operator, scenario.agent.safety_distance_m)
        if scenario.operator
        else None
    )
    # what the log keeps per tick, as flat lists (converted to arrays once, at the end)
    ticklog = TickLog(keyed=script is not None)
    row_ids: tuple[int, ...] = coord.formation.slot_ids
    # scenario movers (issue 30): a body of radius R is a neighbour whose extra radius makes
    # the barrier's centre distance R + body + margin (the filter subtracts the noise budget)
    bodies = scenario.movers
    body_tracks: list[list[tuple[float, float]]] = [[] for _ in bodies]
    budget = scenario.agent.safety_filter.noise_budget_m
    body_extra = [budget + max(0.0, m.radius_m - geom.body_radius_m) for m in bodies]
    seen_bodies: dict[str, tuple[float, float]] = {}

    # run-time plans (issue 27): a plan the core asks is solved at once, before the next tick
    # (the lockstep node waits for it before its switch tick: the same leader, bit for bit)
    replanner = coord.replanner
    steps = [fw.step_positional for fw in firmwares]
    tracking_mode = Mode.TRACKING
    robots = list(zip(range(n), ids, steps, strict=True))
    # module globals read once: a compiled loop would look each up in the module's dict at
    # every use (the firmware's NamedTuple types and the constructor that skips their __new__)
    new_tuple: Any = _tuple_new
    pose_type: Any = Pose
    setpoint_type: Any = Setpoint
    wc: tuple[Any, ...]  # a WheelCommand, its items read natively when compiled
    wall0 = time.perf_counter()
    interrupted = False
    collector = CollectorPause()
    try:
        for k in range(ticks):
            if k and stop is not None and stop.is_set():
                interrupted = True
                break
            t = tick_time(k, dt)
            # the tick's time, the poses and their receive times as Python objects (Any): the
            # compiled loop passes them to the firmware's functions as they are, where a typed
            # float would be unboxed and boxed again at each call (the same values)
            t_obj: Any = t
            if progress is not None and k % PROGRESS_EVERY_TICKS == 0:
                progress(t, duration)
            if k % YOUNG_EVERY_TICKS == 0:
                collector.collect_young()  # a cycle dropped since the last call is freed now
            # 0. scripted faults
            if faults is not None:
                faults.fire(k, t, camera)
            # 1. disturbances
            while pending and pending[0].t_s <= t + 1e-9:
                d = pending.pop(0)
                apply_scheduled(plant, index[d.robot], d, camera)
            truth = plant.truth_rows()
            if encoders is not None:  # mean wheel speeds over the last tick, as measured
                wheel_meas = encoders.read(t, plant.wheel_angles())
            # 2. camera
            camera.capture(t, truth)
            delivered: list[Any] = camera.poll(t)  # (Any: its tuples are not unboxed)
            if delivered:
                meas: tuple[Any, ...]  # (i, stamp, x, y, theta), its numbers passed on as
                for meas in delivered:  # they are (a tuple: its items read natively)
                    seen: int = meas[0]  # (an int: the lists below are indexed natively)
                    x, y, th, stamp = meas[2], meas[3], meas[4], meas[1]
                    poses[seen] = new_tuple(pose_type, (x, y, th, stamp))
                    pose_cap[seen] = stamp  # capture time, on the loop's (sim) clock
                    xyt[seen] = (x, y, th)
                    rx_objs[seen] = t_obj
            # every other robot's latest measured pose received within NEIGHBOUR_STALE_S, for
            # repulsion and the safety filter, with its age now (capture to this tick) and whether
            # it was TRACKING on the previous tick (then it runs the same filter: cooperative); the
            # rule of robot_agent.core.neighbours, which the Zenoh agents and hosts use too
            # (one call for the fleet: robot_agent.core.neighbours.neighbours_at)
            pts = neighbours_at(
                pose_objs, rx_objs, t, tracking, rings, l_m, vmax, sfp.claim_max_age_s
            )
            # the coordinator's movers of the previous tick (received with its setpoints): not
            # cooperative, with their velocity (rule 4 of robot_agent.core.neighbours)
            prev_out = outputs.for_clock(k)
            movers = prev_out.movers if prev_out is not None else ()
            if movers:
                for mid, _, _, mvx, mvy in movers:
                    jm = index.get(mid)
                    if jm is not None:
                        seen_nb = pts[jm]
                        if seen_nb is not None:
                            pts[jm] = mover(seen_nb, mvx, mvy)
            # scenario movers (issue 30): the bodies at t; a visible one is seen like a robot
            # (no velocity, age 0) by every robot's filter, after the robots, and as a tracked
            # object by the coordinator; an invisible one (an untracked person) only by the logs
            seen_tail: list[Any] = []
            if bodies:
                seen_bodies = {}
                for b, (mover_body, track) in enumerate(zip(bodies, body_tracks, strict=True)):
                    bx, by, _, _ = mover_body.state(t)
                    track.append((bx, by))
                    if mover_body.visible:
                        seen_bodies[mover_body.id] = (bx, by)
                        extra = body_extra[b]
                        nb = _tuple_new(Neighbour, (bx, by, math.nan, 0.0, 0.0, 0.0, False, extra))
                        for mid, _, _, mvx, mvy in movers:
                            if mid == mover_body.id:
                                nb = mover(nb, mvx, mvy)
                        seen_tail.append(nb)
            # every robot's list: the others' entries in order, then the bodies; where the
            # firmware selects from it (compiled, long lists), a view of one grid of the tick's
            # entries (each firmware reads only the entries near it: neighbour_index)
            if n - 1 + len(seen_tail) >= view_min:
                neighbours = NeighbourIndex(pts, NEIGHBOUR_CELL_M).views(seen_tail)
            elif None in pts:
                for i in range(n):
                    neighbours[i] = [q for j, q in enumerate(pts) if j != i and q is not None]
                    if seen_tail:
                        neighbours[i].extend(seen_tail)
            else:  # every robot's list is the others' entries in order: a copy less one
                for i in range(n):
                    others = pts.copy()
                    del others[i]
                    if seen_tail:
                        others.extend(seen_tail)
                    neighbours[i] = others
            # 3. coordinator on the measured poses that are fresh (the set changes only when a pose
            # arrives or one goes stale)
            if delivered or t - oldest_rx > stale:
                fresh = {}
                oldest_rx = math.inf
                for i, q in enumerate(xyt):
                    if q is not None and t - pose_rx[i] <= stale:
                        fresh[ids[i]] = q
                        if pose_rx[i] < oldest_rx:
                            oldest_rx = pose_rx[i]
            objects = seen_bodies if bodies else None
            if faults is None:
                if script is not None:
                    script.play(coord, t, t, len(fresh))
                out = coord.tick(t, fresh, (), objects)  # by position (see step below)
                if replanner.setup is not None:
                    _plan_now(replanner)
            else:
                counted = faults.coordinator_input(fresh)
                if script is not None:
                    script.play(coord, t, t, len(counted))
                out = coord.tick(t, counted, (), faults.objects(fresh, counted, objects))
                if replanner.setup is not None:
                    _plan_now(replanner)
                faults.observe(out, counted)
            # 4. firmware, on the setpoints of the previous tick (received at that tick's time)
            t_prev = tick_time(k - SETPOINT_DELAY_TICKS, dt)
            t_prev_obj: Any = t_prev  # (as t_obj; the rows below likewise)
            cmds: list[WheelCommand] = []
            if prev_out is not None:
                if prev_out.slot_ids is not row_ids:  # a reshape changed the rows
                    row_ids = prev_out.slot_ids
                    slot_row = {sid: r for r, sid in enumerate(row_ids)}
                prev_asg = prev_out.assignment
                prev_rows: list[Any] = prev_out.rows
                prev_theta: Any = prev_out.theta
                # newly assigned robots on their way (core)
                prev_approach: Mapping[str, Any] = prev_out.approach
            else:
                prev_asg = {}
                prev_approach = {}
            approaching = len(prev_approach) > 0  # (usually none: no lookup per robot)
            for i, rid, step in robots:
                if faults is not None and (i in faults.frozen or i in faults.cut_inputs):
                    if faults.cut_inputs.get(i, 0) is None:  # the pose it had when cut off
                        faults.cut_inputs[i] = (poses[i], pose_rx[i], pose_cap[i])
                    cmds.append(_faulted_step(faults, i, t, step))
                    continue
                sp = None
                slot = prev_asg.get(rid)
                if slot is not None:
                    row: Any = prev_approach.get(rid) if approaching else None  # (x, y, vx, vy)
                    if row is None:
                        row = prev_rows[slot_row[slot]]
                    # a tuple (SlotRow): typed so, its items are read natively when compiled
                    r4: tuple[Any, ...] = row if isinstance(row, tuple) else tuple(row)
                    # the Setpoint's seven fields in one tuple (no list built to unpack the row)
                    sp = new_tuple(
                        setpoint_type, (r4[0], r4[1], r4[2], r4[3], prev_theta, slot, t_prev_obj)
                    )
                # (by position: Firmware.step's keyword arguments cost more than the call
                # across two compiled groups)
                cmds.append(
                    step(
                        t_obj,
                        poses[i],
                        rx_objs[i],
                        sp,
                        t_prev_obj,
                        neighbours[i],
                        pose_cap[i],
                        None if wheel_meas is None else wheel_meas[i],
                    )
                )
            # each robot's mode and wheels (omega_r, omega_l), in one pass over the commands
            cmd_objs: list[Any] = cmds
            tracking = []
            wheels: list[Any] = []
            for wc in cmd_objs:
                tracking.append(wc[4] is tracking_mode)
                wheels.append((wc[0], wc[1]))
            if rings is not None:
                for ring, fw in zip(rings, firmwares, strict=True):
                    claim = fw.motion_claim
                    if claim is not None and (not ring.claims or ring.claims[-1] is not claim):
                        ring.add(claim)
            # 5. command link
            link.send_all(t, wheels)
            link.poll_into(t, applied)  # applied[i]: the wheels robot i received last
            if faults is not None:  # the plant stops an offline robot's wheels
                for i in faults.offline:
                    applied[i] = (0.0, 0.0)
            # record the tick (truth at t, before integrating to t + dt)
            leader = out.leader
            ticklog.record(truth, leader.x, leader.y, leader.theta, out.rows, out.slot_ids, cmds)
            if out.changed or k == 0:
                asg = out.assignment
                slot_of_changes.append((k, [asg.get(rid, -1) for rid in ids]))
            if faults is None or not faults.state.coordinator_down(t):
                outputs.add(k, out)
            # 6. plant
            plant.step(dt, applied)
    finally:
        collector.resume()
    log = ticklog.runlog(ids, slot_ids, dt, slot_of_changes, l_m)
    # The separation accounting reads only the truth and feeds nothing back into the loop, so it
    # runs once over the logged truth, vectorised over ticks (the same events and minimum as
    # one update per tick).
    monitor.update_many(log.t_s, log.truth)
    wall = time.perf_counter() - wall0

    log.min_separation_m = float(monitor.min_separation_m)
    log.collisions = [_event_dict(e, ids) for e in monitor.collisions]
    log.body_radius_m = geom.body_radius_m  # safety accounting (formation.outputs.metrics)
    log.safety_distance_m = scenario.agent.safety_distance_m
    log.world = scenario.agent.world
    log.filter_counts = {
        rid: fw.safety_filter.status().as_dict() for rid, fw in zip(ids, firmwares, strict=True)
    }
    log.meta = {
        "scenario": scenario.name,
        "seed": seed,
        "dt_s": dt,
        "mode": "in-process",
        "wall_s": wall,
        "link": {"sent": link.sent, "dropped": link.dropped},
        "path_warnings": [c.message() for c in path_conflicts(scenario, duration)],
    }
    log.meta["faults"] = [] if faults is None else faults.sent
    log.meta["faults_pending"] = [] if faults is None else faults.scheduler.pending()
    log.meta["disturbances"] = [
        {"t_s": d.t_s, "kind": d.kind, "robot": d.robot} for d in scenario.disturbances
    ]
    if script is not None:
        log.meta["operator"] = {"applied": script.applied, "rejects": dict(script.rejects)}
        log.reshapes = [
            {"kind": r["kind"], "slots": r["slots"], "start_s": r["started_s"],
             "end_s": r["started_s"] + r["transition_s"], "complete": True}
            for r in coord.reshapes
        ]  # fmt: skip
    if replanner.stats.plans or replanner.stats.events:
        from formation.outputs.plan_view import planner_counts, replan_events

        log.replans = replan_events(replanner.stats.events)
        log.meta["planner"] = planner_counts(replanner.stats)
    if interrupted:
        log.meta["interrupted"] = True
    status = {rid: _status_dict(fw) for rid, fw in zip(ids, firmwares, strict=True)}
    tracks = {
        m.id: np.asarray(tr, dtype=float).reshape(-1, 2)
        for m, tr in zip(bodies, body_tracks, strict=True)
    }
    return SimResult(
        log=log, wall_s=wall, firmware_status=status, interrupted=interrupted, movers=tracks
    )


def _plan_now(replanner: Any) -> None:
    """Solve the plan ``replanner`` asks, at once (its compute time measured, for the record
    only: nothing in the loop reads it in-process)."""
    req = replanner.take_request()
    if req is None:
        return
    from coordinator.core.planning.replan import solve  # only when a plan is asked (rare)

    t0 = time.perf_counter()
    answer = solve(req)
    replanner.deliver(req.id, answer, (time.perf_counter() - t0) * 1e3)


def _faulted_step(faults: FaultPlay, i: int, t_s: float, step: Callable[..., Any]) -> Any:
    """Robot ``i`` under a fault: a killed or paused agent does not step (zero wheels, the
    plant's too); a cut-off one steps on the pose it had, with no setpoint or neighbour.
    ``step`` is the robot's ``Firmware.step_positional``."""
    if i in faults.frozen:
        return _ZERO_CMD
    frozen = faults.cut_inputs[i]
    assert frozen is not None
    pose, rx, cap = frozen
    return step(t_s, pose, rx, None, t_s, [], cap, None)  # Firmware.step_positional


def _event_dict(e: Any, ids: list[str]) -> dict[str, Any]:
    if isinstance(e, dict):
        d = dict(e)
    elif hasattr(e, "_asdict"):
        d = dict(e._asdict())
    elif hasattr(e, "__dataclass_fields__"):
        d = {f: getattr(e, f) for f in e.__dataclass_fields__}
    else:
        d = {"event": repr(e)}
    for key in ("i", "j"):
        if key in d and isinstance(d[key], int | np.integer):
            d[key] = ids[int(d[key])]
    return {k: (float(v) if isinstance(v, np.floating) else v) for k, v in d.items()}


def _status_dict(fw: Firmware) -> dict[str, Any]:
    st = fw.status()
    if hasattr(st, "__dataclass_fields__"):
        return {f: _jsonable(getattr(st, f)) for f in st.__dataclass_fields__}
    return {"status": repr(st)}


def _jsonable(v: Any) -> Any:
    if isinstance(v, float | int | str | bool) or v is None:
        return v if not (isinstance(v, float) and not math.isfinite(v)) else None
    return str(v)
