"""``formation coordinator``: virtual leader, slots, role assignment and setpoints as a process.

Usage::

    formation coordinator --scenario NAME|FILE [--name main] [--fleet demo] [--rate-hz 50]
                          [--lockstep] [zenoh options]

A thin asyncio shell over :class:`coordinator.core.coordinator.CoordinatorCore`, built from the
scenario by
``scenario.assemble`` (the assembly ``formation/sim/simulate.py`` uses too); the standby election
is :mod:`coordinator.core.election` (on the bus: the node's :class:`~coordinator.node.election_io.
ElectionIO` part), the lockstep
rules :mod:`robot_agent.core.lockstep`; what a tick publishes is encoded by
:mod:`coordinator.node.outputs`, the latched e-stop is held by
:mod:`coordinator.node.estop_source`. It
prints exactly one line ``coordinator ready`` on stdout once its session is open, its subscriptions
and its liveliness token ``formation/<fleet>/alive/coordinator/<name>`` are declared, and exits
0 within a second of SIGINT/SIGTERM.

Theory of operation: docs/process-shells.md (inputs, outputs, realtime and lockstep).
"""

from __future__ import annotations

import asyncio
import os
import socket
import time
from collections import deque
from collections.abc import Mapping
from typing import Any, Final

import runtime as rt
from bus_schemas import (
    Clock,
    CoordinatorStatus,
    DecodeError,
    Fault,
    Heartbeat,
    Pose,
    PoseBatch,
    RejectCounts,
    decode,
    encode,
    keys,
    to_map,
)
from coordinator.core.coordinator import CoordinatorOutput, pose_stale_s
from coordinator.core.election import Election, Takeover
from coordinator.core.operator_script import OperatorScript
from coordinator.node.election_io import MAX_ROBOTS, ElectionIO
from coordinator.node.estop_source import EstopSource
from coordinator.node.fault_schedule import FaultNotices, slot_messages
from coordinator.node.operator_io import OperatorInputs, reshape_fields
from coordinator.node.outputs import TickOutputs
from coordinator.node.plan_worker import PLAN_WAIT_S, PlanWorker
from robot_agent.core.estop import EstopLatch
from robot_agent.core.lockstep import Arrivals, Replay
from runtime.timers import STATUS_PERIOD_S  # every node reports at the one rate
from scenario import Scenario
from scenario.assemble import coordinator_core
from scenario.preflight import path_conflicts

__all__ = ["CoordinatorNode"]

HEARTBEAT_PERIOD_S: Final = 0.1
"""Heartbeat period (s): a standby learns the active's state (``leader_t0``, epoch) from it, and
an instance resuming from a hang learns from it that it was replaced."""
POSITION_LIMIT_M: Final = 1.0e4
"""A pose farther than this from the origin (m, per axis) is rejected: it can only be garbage,
and squared distances of absurd positions overflow the assignment's costs."""


class CoordinatorNode:
    """State and handlers of the coordinator; Zenoh-free apart from the ``publish`` callable.

    Handlers run on the event loop and never raise.
    """

    def __init__(
        self,
        scenario: Scenario,
        name: str,
        fleet: str,
        publish: Any,
        *,
        lockstep: bool = False,
        standby: bool = False,
        batch: bool = False,
        log: rt.NodeLog | None = None,
    ) -> None:
        self.scenario = scenario
        self.batch = batch
        self.name = keys.check_name(name)
        self.fleet = keys.check_fleet(fleet)
        self.lockstep = lockstep
        self.core = coordinator_core(scenario)
        # the in-process simulator's rule (coordinator.core.coordinator.pose_stale_s); the robots
        # have
        # encoders when the scenario's plant emulates them
        self.stale_pose_s = pose_stale_s(
            scenario.agent, odometry=scenario.plant.encoder_counts_per_rev > 0.0
        )
        # Realtime: one late pose (a loaded machine) must not re-assign a robot whose token is
        # alive (issue 13 item 7): it keeps its slot while its pose is younger than the
        # estimator's odometry dropout bound (its firmware may still be tracking; with stale
        # data it holds, so keeping the slot moves nobody); liveliness removes a gone robot at
        # once. Lockstep keeps the sim-time rule of formation/sim/simulate.py (no wall clock).
        self.hold_pose_s = max(self.stale_pose_s, scenario.agent.estimator.max_dropout_odom_s)
        # Realtime: a stop of this process (runtime.stall) makes an active instance step down.
        self.stall = rt.StallDetector(gap_s=rt.HANG_GAP_NO_LEASE_S)
        self.log = log if log is not None else rt.NodeLog(f"coordinator {name}")
        # issue 14: the coordinator does not plan around obstacles; it says when a slot's path
        # crosses one (a pure check, coordinator/core/path_check.py), once, at start
        self.path_warnings = [c.message() for c in path_conflicts(scenario)]
        for w in self.path_warnings:
            self.log.info(f"warning: {w}")
        self._publish = publish
        self._order = {rid: i for i, rid in enumerate(scenario.robot_ids)}
        # what a tick publishes, encoded (coordinator.node.outputs: keys, QoS, sequence numbers)
        self.outputs = TickOutputs(
            self.fleet, self._order, lockstep=lockstep, batch=batch, log=self.log
        )
        self.leader_key = self.outputs.leader_key
        self.assignment_key = self.outputs.assignment_key
        self.setpoints_key = self.outputs.setpoints_key
        self.sp_qos = self.outputs.sp_qos
        self.leader_qos = self.outputs.leader_qos
        self.data_qos = self.outputs.data_qos
        self.clock_key = keys.clock_key(fleet)
        self.status_key = keys.coordinator_status_key(fleet, name)
        self.heartbeat_key = keys.heartbeat_key(fleet, name)
        self.alive_key = keys.alive_coordinator_key(fleet, name)
        self.poses_pattern = keys.all_poses_pattern(fleet)
        self.poses_key = keys.poses_key(fleet)
        self.alive_pattern = keys.alive_robots_pattern(fleet)

        self.alive: set[str] = set()
        # robot id -> [x_m, y_m, theta_rad, pose_t, rx_s]; rx_s None while pending (lockstep)
        self.poses: dict[str, list[Any]] = {}
        self._pending: Arrivals[str] = Arrivals()  # lockstep: poses since the last clock
        self.faults = rt.Faults(self.log)  # rejects by "<message>-<reason>" (status "rejects")
        self.rx: dict[str, int] = {
            "pose": 0, "poses": 0, "clock": 0, "alive": 0, "estop": 0, "leader": 0,
        }  # fmt: skip
        # lockstep: a robot's token lost while the run goes on is a fault event only (the
        # plant owns sim time and waits for its answers; membership never follows a lease)
        self.token_losses = 0
        self._reassign_pending = False  # a re-assignment queued after vanished tokens
        self.reassign_coalesced = 0  # vanished tokens that joined a queued re-assignment
        self.ticks = 0
        self.tick_s: deque[float] = deque(maxlen=250)  # compute + publish time of recent ticks
        self.t0_s: float | None = 0.0 if lockstep else None
        self.last: CoordinatorOutput | None = None
        # lockstep: the last clock and the outputs that answered it (realtime: the last tick's)
        self._replay: Replay[list[tuple[str, bytes, rt.QoS]]] = Replay()
        self._replay.answer = []
        self.sim_t = 0.0

        # -- election (module docstring, *Standby*; the decisions are coordinator.core.election's):
        # a standby checks every origin against the leader messages it observes
        self.election = Election(self.name, active=not standby, position_at=self.core.leader_xy)
        self.election_io = ElectionIO(
            self.election,
            lockstep=lockstep,
            faults=self.faults,
            rx=self.rx,
            now=self._now,
            publish_heartbeat=self.publish_heartbeat,
            take_over=self._take_over,
        )
        self.heartbeats_pattern = keys.all_heartbeats_pattern(fleet)
        self.coordinators_pattern = keys.alive_coordinators_pattern(fleet)

        # -- the latched e-stop state (robot_agent.core.estop): every instance, active or standby,
        # keeps it from the estop messages and answers queries on the estop key with it
        # scripted faults ([[fault]], coordinator.node.fault_schedule): the active instance runs
        # the schedule and publishes the notices; operators' requests arrive on the same key
        self.scripted = FaultNotices(scenario, self.fleet, lockstep=lockstep)
        self.fault_key = self.scripted.key
        self.estop_key = keys.estop_key(fleet)
        self.estop_source = EstopSource(
            self.estop_key, self._now, self.faults.reject, self.faults.internal, self.log
        )
        # -- the operator's teleop, goals and paths, and the leader's continuation (issue 28)
        self.operator = OperatorInputs(
            self.fleet,
            self.core,
            safety_m=scenario.agent.safety_distance_m,
            lockstep=lockstep,
            now=self._now,
            is_active=lambda: self.active,
            robots=lambda: self.alive,
            reject=self.faults.reject,
            internal=self.faults.internal,
            log=self.log,
        )
        self._takeovers_seen = 0
        # the scenario's scripted operator commands ([[operator]]), played as the in-process
        # simulator plays them (coordinator.core.operator_script)
        self.operator_script = (
            OperatorScript(scenario.operator, scenario.agent.safety_distance_m)
            if scenario.operator
            else None
        )
        # -- run-time plans computed off the tick (issue 27, coordinator.node.plan_worker)
        self.plan_worker = PlanWorker(self.log)
        self.core.replanner.adaptive = not lockstep  # realtime: slow plans switch later

    # -- bookkeeping ---------------------------------------------------------------------------

    def _now(self) -> float:
        """This node's clock: sim time in lockstep, ``time.monotonic()`` in realtime."""
        return self.sim_t if self.lockstep else time.monotonic()

    def _next_seq(self, key: str) -> int:
        return self.outputs.next_seq(key)

    @property
    def estop(self) -> EstopLatch:
        """The latched e-stop scopes (coordinator.node.estop_source)."""
        return self.estop_source.latch

    @property
    def estop_answer(self) -> tuple[bytes, ...]:
        """What a query on the ``estop`` key is answered with."""
        return self.estop_source.answer

    @property
    def active(self) -> bool:
        """This instance ticks and publishes (the election's decision)."""
        return self.election.active

    @property
    def epoch(self) -> int:
        return self.election.epoch

    @property
    def rejects(self) -> RejectCounts:
        """Inputs rejected so far, by ``<message>-<reason>`` (status ``rejects``)."""
        return self.faults.rejects

    @property
    def rejected(self) -> int:
        """Inputs rejected so far (every drop counted, by reason in :attr:`rejects`)."""
        return self.faults.rejected

    @property
    def internal_errors(self) -> int:
        """Internal errors caught by the handlers."""
        return self.faults.internal_errors

    # -- inputs --------------------------------------------------------------------------------

    def on_alive(self, key: str, alive: bool) -> None:
        """Liveliness of an agent token appeared (``alive``) or vanished."""
        try:
            self.rx["alive"] += 1
            parsed = keys.parse_alive_key(key)
            if parsed is not None and parsed[1] == "coordinator" and parsed[2] is not None:
                self.election_io.on_peer_alive(parsed[2], alive)
                return
            if parsed is None or parsed[1] != "robot" or parsed[2] is None:
                return
            rid = parsed[2]
            if alive:
                if rid not in self.alive and len(self.alive) < MAX_ROBOTS:
                    self.alive.add(rid)
                    self.log.info(f"robot {rid} alive")
            elif rid in self.alive and self.lockstep:
                # A fault event only: in lockstep membership never follows a wall-clock lease
                # (an agent paused past it under load still answers the plant's clocks when it
                # resumes, and the result must be that of the unpaused run; issue 13 item 7).
                self.token_losses += 1
                self.log.info(f"robot {rid}'s token is gone (lockstep: kept, a fault event)")
            elif rid in self.alive:
                self.alive.discard(rid)
                self.poses.pop(rid, None)  # its last pose must not be reused if it comes back
                self.log.info(f"robot {rid} gone")
                if self.active and not self.lockstep and self.t0_s is not None:
                    self._reassign_soon()
        except Exception as exc:
            self.faults.internal("on_alive", exc)

    def _reassign_soon(self) -> None:
        """Re-assign now, not at the next tick (issue 4: the robots left learn their slots
        within 50 ms), once per burst: an agent host's tokens vanish together and a tick per
        token (300 robots) held the loop ~0.75 s. Without a running loop: at once."""
        if self._reassign_pending:
            self.reassign_coalesced += 1
            return
        try:
            asyncio.get_running_loop().call_soon(self._reassign)
            self._reassign_pending = True
        except RuntimeError:
            self.tick(time.monotonic())

    def _reassign(self) -> None:
        self._reassign_pending = False
        if self.active and not self.lockstep and self.t0_s is not None:
            self.tick(time.monotonic())  # (tick counts its own errors)

    def on_estop(self, rx: rt.Received) -> None:
        """An operator's ``estop``: latch or release its scope (coordinator.node.estop_source)."""
        self.rx["estop"] += 1
        self.estop_source.on_estop(rx)

    def on_pose(self, rx: rt.Received) -> None:
        """A measured pose ``robot/<id>/pose``."""
        try:
            self.rx["pose"] += 1
            parsed = keys.parse_robot_key(rx.key)
            if parsed is None or parsed[2] != keys.POSE:
                self.faults.reject("pose", f"not a pose key: {rx.key[:100]!r}", "bad_key")
                return
            rid = parsed[1]
            msg = decode(rx.payload, Pose)
            if isinstance(msg, DecodeError):
                self.faults.reject("pose", msg)
                return
            if msg.robot is not None and msg.robot != rid:
                self.faults.reject("pose", f"robot {msg.robot!r} on {rid}'s key", "misaddressed")
                return
            rx_s: float | None = None if self.lockstep else rx.rx_s
            why = self._store_pose(rid, msg.x, msg.y, msg.theta, msg.t, rx_s)
            if why is not None:
                self.faults.reject("pose", why, "implausible")
        except Exception as exc:
            self.faults.internal("on_pose", exc)

    def _store_pose(
        self, rid: str, x: float, y: float, theta: float, t: float, rx_s: float | None
    ) -> str | None:
        """Keep robot ``rid``'s pose (``rx_s`` None: pending until the next clock); returns why
        it was refused, or None. The newest arrival wins (no stamp comparison: one bogus future
        stamp must not lock the real poses out)."""
        if abs(x) > POSITION_LIMIT_M or abs(y) > POSITION_LIMIT_M:
            return f"position beyond {POSITION_LIMIT_M:g} m"
        if rid not in self.poses and len(self.poses) >= MAX_ROBOTS:
            return "too many robots"
        self.poses[rid] = [x, y, theta, t, rx_s]
        if rx_s is None:
            self._pending.add(rid)
        return None

    def on_poses(self, rx: rt.Received) -> None:
        """A batched pose frame (``--batch``, and every lockstep run: the plant publishes its
        frames as batches there): each entry as if it came on its robot's key."""
        try:
            self.rx["poses"] += 1
            msg = decode(rx.payload, PoseBatch)
            if isinstance(msg, DecodeError):
                self.faults.reject("poses", msg)
                return
            rx_s: float | None = None if self.lockstep else rx.rx_s
            store, stamp = self._store_pose, msg.stamp
            refused = [
                why
                for rid, x, y, th in zip(msg.robots, msg.x, msg.y, msg.theta, strict=True)
                if (why := store(rid, x, y, th, stamp, rx_s)) is not None
            ]
            if refused:
                self.faults.reject(
                    "poses", f"{len(refused)} entries refused, e.g. {refused[0]}", "implausible"
                )
        except Exception as exc:
            self.faults.internal("on_poses", exc)

    def on_clock(self, rx: rt.Received) -> None:
        """Lockstep clock k: tick at clock.t and publish, leader last."""
        try:
            self.rx["clock"] += 1
            msg = decode(rx.payload, Clock)
            if isinstance(msg, DecodeError):
                self.faults.reject("clock", msg)
                return
            if not self.active:
                self.sim_t = msg.t
                return
            again = self._replay.repeat(msg.tick)
            if again is not None:  # the plant re-announced: answer again
                for key, payload, qos in again:
                    self._publish(key, payload, qos)
                return
            t_k = msg.t
            self.sim_t = t_k
            for rid in self._pending.take():
                entry = self.poses.get(rid)
                if entry is not None and entry[4] is None:
                    entry[4] = t_k
            self._replay.last_tick = msg.tick
            self.tick(t_k, tick=msg.tick)
        except Exception as exc:
            self.faults.internal("on_clock", exc)

    # -- the tick ------------------------------------------------------------------------------

    def fresh_poses(self, now_s: float) -> dict[str, tuple[float, float, float]]:
        """Poses of alive robots received within ``stale_pose_s`` (lockstep) or ``hold_pose_s``
        (realtime) of ``now_s``, in robot order."""
        lim = self.stale_pose_s if self.lockstep else self.hold_pose_s
        big = len(self._order)
        out: dict[str, tuple[float, float, float]] = {}
        for rid in sorted(self.alive, key=lambda r: (self._order.get(r, big), r)):
            e = self.poses.get(rid)
            if e is not None and e[4] is not None and -lim <= now_s - e[4] <= lim:
                out[rid] = (e[0], e[1], e[2])
        return out

    def fresh_objects(
        self, now_s: float, counted: Mapping[str, object]
    ) -> dict[str, tuple[float, float]] | None:
        """Tracked bodies the core does not count as robots (issue 30): the fresh poses (as
        ``fresh_poses``) of ids not in the scenario's fleet, e.g. a camera tag on a cart, and of
        the fleet's robots left out of ``counted`` (the poses the core counts: a robot whose
        agent is dead or hung, or a scripted fault's offline robot). The core makes a moving one
        a mover (coordinator.core.movers): a dead robot's wheels are stopped, so it moves only
        when it is carried or pushed, and the others must then see its velocity and make room.
        None if there is none."""
        lim = self.stale_pose_s if self.lockstep else self.hold_pose_s
        out: dict[str, tuple[float, float]] = {}
        for rid in sorted(self.poses):
            e = self.poses[rid]
            if rid in counted or e[4] is None:
                continue
            if rid not in self._order and rid in self.alive:
                continue
            if not -lim <= now_s - e[4] <= lim:
                continue
            out[rid] = (e[0], e[1])
        return out or None

    def tick(self, now_s: float, tick: int | None = None) -> CoordinatorOutput | None:
        """Run the core at ``now_s`` and publish its outputs (see the module docstring).

        Only the active instance ticks. In realtime a tick that finds the loop stalled for more
        than ``stall.gap_s`` steps down instead (the token may have expired meanwhile)."""
        try:
            if not self.active:
                return None
            if not self.lockstep:
                stalled = self.stall.stalled_for(time.monotonic())
                if stalled is not None:
                    self.election_io.step_down(f"this process was stopped for {stalled:.2f} s")
                    return None
            if self.t0_s is None:
                self.t0_s = now_s
                self.core.t0_s = now_s
            if self.election.leader_t0 != self.t0_s:
                self.election.observe_t0(self.t0_s)
            if self.election.takeovers != self._takeovers_seen:  # continue the leader (issue 28)
                self._takeovers_seen = self.election.takeovers
                self.operator.took_over(now_s, self.t0_s)
                if self.operator_script is not None:
                    self.operator_script.skip_until(now_s - self.t0_s)
            replanner = self.core.replanner
            if replanner.setup is not None:  # a plan done (realtime), or due (lockstep: wait)
                due = self.lockstep and replanner.due(now_s) is not None
                self.plan_worker.poll(replanner, PLAN_WAIT_S if due else None)
            started = time.perf_counter()
            poses = self.fresh_poses(now_s)
            if self.scripted.state.offline():  # a scripted kill: its robot counts as gone
                poses = self.scripted.counted(poses)
            if self.operator_script is not None:
                for cmd, why in self.operator_script.play(
                    self.core, now_s - self.t0_s, now_s, len(poses)
                ):
                    self.faults.reject("operator", f"scripted {cmd} refused: {why}", f"{cmd}-{why}")
            held = self.operator.held(self.estop, poses) if self.core.leader.waits() else ()
            out = self.core.tick(now_s, poses, held, self.fresh_objects(now_s, poses))
            request = replanner.take_request() if replanner.setup is not None else None
            if request is not None:
                self.plan_worker.submit(request)
            self.ticks += 1
            self.last = out
            outputs = self.outputs.encode_tick(
                out, now_s, tick, self.t0_s or 0.0, self.leader_extra()
            )
            if self.scripted.live:
                outputs = self.with_faults(outputs, out, poses, now_s - (self.t0_s or 0.0), tick)
            for key, payload, qos in outputs:
                self._publish(key, payload, qos)
            self._replay.answer = outputs
            self.tick_s.append(time.perf_counter() - started)
            return out
        except Exception as exc:
            self.faults.internal("tick", exc)
            return None

    def _take_over(self, now_s: float, takeover: Takeover) -> None:
        """The election made this instance active at ``now_s`` (``ElectionIO.elect``): continue
        the previous instance's trajectory (realtime) with the incumbents it assigned."""
        if takeover.leader_t0 is not None and not self.lockstep:
            # Continue the same trajectory: the virtual leader is a pure function of time and
            # t0 is on the same clock (time.monotonic() of this host, see docs/faults.md).
            self.t0_s = takeover.leader_t0
            self.core.t0_s = takeover.leader_t0
        peer = self.election_io.peer_assignment
        seed = {rid: slot for rid, slot in peer.items() if rid in self.alive}
        self.core.assigner.seed_incumbent(seed)
        self.core.assignment = dict(seed)
        continued = takeover.leader_t0 is not None
        self.log.info(
            f"active (epoch {takeover.epoch}): took over with the trajectory origin "
            f"{'of the previous instance' if continued else 'at this tick'} and "
            f"{len(seed)} incumbents"
        )
        self.publish_heartbeat()
        if not self.lockstep:
            self.tick(now_s)

    def leader_extra(self) -> dict[str, Any]:
        """The ``leader`` message's issue-28 fields: what a standby needs to continue it."""
        ld = self.core.leader
        extra: dict[str, Any] = {"mode": ld.mode.value}
        if not ld.scripted:  # absent: the script at t - leader_t0 (what the election checks)
            extra["progress_s"] = ld.progress_s
            extra["rate"] = ld.rate
        if ld.mode in (ld.mode.GOAL, ld.mode.PATH):
            extra["target"] = min(ld.target_index, 1023)
        if ld.mode is ld.mode.TELEOP:
            extra["deadman"] = ld.deadman
        if self.core.shape is not None:
            extra["shape"] = self.core.shape
        reshaping = self.core.reshaping
        if reshaping is not None:  # and what a standby needs to continue it (issue 28)
            extra["reshape"] = reshaping
            extra.update(reshape_fields(self.core.reshaper.state()))
        return extra

    def with_faults(
        self,
        outputs: list[tuple[str, bytes, rt.QoS]],
        out: CoordinatorOutput,
        counted: dict[str, tuple[float, float, float]],
        run_t_s: float,
        tick: int | None,
    ) -> list[tuple[str, bytes, rt.QoS]]:
        """A tick's outputs with the scripted faults (coordinator.node.fault_schedule): no
        setpoints while it counts as killed; the notices due next before the leader (lockstep,
        where the leader is last) or after everything (realtime)."""
        if self.scripted.setpoints_withheld(run_t_s):
            sp = self.setpoints_key
            outputs = [o for o in outputs if o[0] != sp and not o[0].endswith("/setpoint")]
            if self.batch:  # the slots still go out (recorders read them from the setpoints)
                slots = slot_messages(self.outputs, out, self._now(), tick)
                outputs = [*slots, *outputs]
        notices = self.scripted.after_tick(out, counted, run_t_s, tick, self._now())
        for n in notices:
            self.log.info(f"t={run_t_s:.3f} s: fault notice {decode(n[1], Fault)}")
        if not notices:
            return outputs
        if self.lockstep:
            return [*outputs[:-1], *notices, outputs[-1]]
        return [*outputs, *notices]

    def on_fault(self, rx: rt.Received) -> None:
        """An operator's ``fault`` request (``formation fault ... --at T``): scheduled."""
        try:
            if not self.active:
                return
            why = self.scripted.on_request(rx.payload)
            if why is not None:
                self.faults.reject("fault", why)
        except Exception as exc:
            self.faults.internal("on_fault", exc)

    # -- periodic ------------------------------------------------------------------------------

    def status(self, now_s: float) -> CoordinatorStatus:
        """The status message (bus_schemas.CoordinatorStatus)."""
        last = self.last
        tick_ms = sorted(self.tick_s)
        return CoordinatorStatus(
            t=max(now_s, 0.0),
            seq=self._next_seq(self.status_key),
            name=self.name,
            mode="lockstep" if self.lockstep else "realtime",
            role="active" if self.active else "standby",
            epoch=self.epoch,
            takeovers=self.election.takeovers,
            stepdowns=self.election.stepdowns,
            ticks=self.ticks,
            alive=tuple(sorted(self.alive)),
            assignment=dict(last.assignment) if last is not None else {},
            leader=last.leader_robot if last is not None else None,
            rejected=self.rejected,
            rejects=self.faults.rejects.as_dict(),
            internal_errors=self.faults.internal_errors,
            rx=dict(self.rx),
            pid=os.getpid(),
            host=_HOST,
            tick_p50_ms=1e3 * tick_ms[len(tick_ms) // 2] if tick_ms else None,
            tick_max_ms=1e3 * tick_ms[-1] if tick_ms else None,
            **self.estop_source.status(),
            **self.plan_status(),
        )

    def plan_status(self) -> dict[str, Any]:
        """The status's run-time plan fields (docs/planning.md), absent before any plan."""
        rp = self.core.replanner
        st = rp.stats
        if rp.state is None and not st.plans and not rp.enabled:
            return {}  # no obstacle anywhere: goals are driven straight (nothing is planned)
        return {
            "plan": None if rp.state is None else rp.state.value,
            "plan_why": None if rp.why is None else rp.why[:255],
            "plans": st.plans,
            "replans": st.replans,
            "plan_ms": st.plan_ms,
            "plan_clearance_m": st.min_clearance_m,
            "plan_late": st.late,
            "obstacles": len(rp.obstacles),
            "stuck": tuple(sorted(rp.stuck.stuck)),
        }

    def status_map(self, now_s: float) -> dict[str, Any]:
        """The status as its wire map (what :meth:`publish_status` encodes)."""
        return to_map(self.status(now_s))

    def publish_status(self) -> None:
        """Publish the status and (every call) nothing else; never raises."""
        try:
            now = self.sim_t if self.lockstep else time.monotonic()
            self._publish(self.status_key, encode(self.status(now)), rt.QOS_TELEMETRY)
        except Exception as exc:
            self.faults.internal("status", exc)

    def publish_heartbeat(self) -> None:
        """Publish the heartbeat (``leader_t0`` = the trajectory's time origin); never raises."""
        try:
            now = self.sim_t if self.lockstep else time.monotonic()
            hb = Heartbeat(
                t=max(now, 0.0),
                seq=self._next_seq(self.heartbeat_key),
                name=self.name,
                active=self.active,
                epoch=self.epoch,
                leader_t0=self.t0_s if self.t0_s is not None else 0.0,
            )
            self._publish(self.heartbeat_key, encode(hb), rt.QOS_TELEMETRY)
        except Exception as exc:
            self.faults.internal("heartbeat", exc)

    async def run(self, stop: asyncio.Event, rate_hz: float) -> None:
        """Until ``stop``: the realtime tick loop (not in lockstep), status and heartbeat."""
        period = 1.0 / rate_hz
        now = time.monotonic()
        # A primary listens before it speaks (realtime): an instance already active (a standby
        # that took over while this one was still starting, on a starved machine) is heard
        # within the settle time, and the split-brain rule steps this one down before its first
        # tick, so the robots never get a second virtual leader with another origin.
        next_tick = now + self.election.settle_s if self.active and not self.lockstep else now
        next_status = now
        next_hb = now
        self.election.start(self.sim_t if self.lockstep else now)
        if not self.lockstep:
            self.stall.watch_sigcont()  # a late loop is no stop (runtime.stall)
        self.stall.turned(now)
        while not stop.is_set():
            now = time.monotonic()
            if not self.active:
                self.election_io.elect(self.sim_t if self.lockstep else now)
            if not self.lockstep and now >= next_tick:
                self.tick(now)
                next_tick += period
                if next_tick <= now:  # fell behind: resynchronise
                    next_tick = now + period
            if now >= next_status:
                self.publish_status()
                next_status = max(next_status + STATUS_PERIOD_S, now)
            if now >= next_hb:
                self.publish_heartbeat()
                next_hb = max(next_hb + HEARTBEAT_PERIOD_S, now)
            wake = min(next_status, next_hb)
            if not self.lockstep:
                wake = min(wake, next_tick)
            turned = time.monotonic()
            self.stall.turned(turned)
            await asyncio.sleep(max(0.0, wake - turned))
        self.plan_worker.close()


_HOST: Final = socket.gethostname()[:255] or "unknown"
