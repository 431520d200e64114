"""``formation agent``: the firmware of one robot as a process (a thin asyncio shell over Firmware).

Usage::

    formation agent --id r1 [--scenario NAME|FILE | --config ROBOT.toml] [--fleet demo]
                    [--lockstep] [--loop on-pose|fixed] [--rate-hz 50] [zenoh options]
    formation agent --check-config ROBOT.toml      # prints OK or the problems; exit 0 / 1

It prints exactly one line ``agent <id> ready`` on stdout once its Zenoh session is open, its
subscriptions are declared and its liveliness token ``formation/<fleet>/alive/robot/<id>`` is
declared; it exits 0 within a second of SIGINT/SIGTERM (``runtime.transport.run_node``).

The node owns its parts: the neighbour table (:mod:`robot_agent.core.neighbour_table`: the other
robots' poses from the pose frames, their modes from :class:`~robot_agent.node.peer_status.
PeerStatusInputs`), the e-stop query and witness (:mod:`robot_agent.node.estop_shell`, put on the
bus by :mod:`robot_agent.node.agent_estop`) and its fault counters (:class:`runtime.Faults`).

Theory of operation: docs/process-shells.md (inputs, outputs, realtime and lockstep).
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import os
import socket
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Final, Literal

import runtime as rt
from bus_schemas import (
    Clock,
    DecodeError,
    Estop,
    Pose,
    PoseBatch,
    RejectCounts,
    Setpoint,
    Status,
    Wheels,
    decode,
    encode,
    keys,
)
from robot_agent.core.clocksync import ClockOffsets
from robot_agent.core.estop import EstopLatch
from robot_agent.core.firmware import Firmware, Mode, WheelCommand
from robot_agent.core.firmware import Pose as FwPose
from robot_agent.core.firmware import Setpoint as FwSetpoint
from robot_agent.core.lockstep import Replay, SetpointWindow
from robot_agent.core.neighbour_motion import Claim
from robot_agent.core.neighbour_table import NeighbourTable
from robot_agent.core.params import AgentConfig
from robot_agent.core.safety_filter import Neighbour
from robot_agent.node.agent_faults import AgentFaults
from robot_agent.node.estop_shell import EstopQuery, EstopWitness
from robot_agent.node.motor_output import MotorOutput
from robot_agent.node.movers_input import MoversInput
from robot_agent.node.peer_status import PeerStatusInputs, clearance_or_none, filter_counters
from robot_agent.node.status_twist import estimator_twist
from runtime.sdnotify import Notifier
from runtime.timers import run_timers

__all__ = ["MAX_NEIGHBOURS", "AgentNode", "LoopMode", "NeighbourFn", "Publish", "clock_wheels"]

LoopMode = Literal["on-pose", "fixed"]
MAX_NEIGHBOURS: Final = 1024
"""Distinct neighbour ids kept (a flood of made-up ids cannot grow memory without bound)."""


# ---------------------------------------------------------------------------------------------
# The agent
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class _SetpointIn:
    """A received, valid setpoint: firmware form, role, receive time and lockstep tick."""

    sp: FwSetpoint
    role: str
    rx_s: float
    tick: int | None


Publish = Callable[[str, bytes, rt.QoS], None]
NeighbourFn = Callable[["AgentNode", float], list[Neighbour]]
"""``neighbours(node, now_s)``: an agent host's neighbour lookup for one of its robots."""


def clock_wheels(msg: Clock) -> dict[str, tuple[float, float]]:
    """The emulated encoder speeds a lockstep clock carries, by robot (empty without)."""
    if msg.enc_robots is None or msg.enc_wr is None or msg.enc_wl is None:
        return {}
    return {r: (a, b) for r, a, b in zip(msg.enc_robots, msg.enc_wr, msg.enc_wl, strict=True)}


class AgentNode:
    """State and handlers of one agent; Zenoh-free apart from the ``publish`` callable.

    Every handler takes one :class:`runtime.transport.Received` and runs on the event loop;
    none raises (bad input is counted, internal faults are counted and logged).

    Args:
        robot_id: this robot's id.
        fleet: the fleet name.
        config: firmware parameters.
        publish: ``publish(key, payload, qos)``.
        lockstep: step on ``clock`` only (see the module docstring).
        loop_mode: ``"on-pose"`` or ``"fixed"`` (realtime only).
        rate_hz: timer rate (Hz) of the realtime loop.
        motor: the motor seam; None: bus only.
        log: where to log.
        neighbour_fn: an agent host's neighbour lookup (None: this node's own neighbour table).
        publish_wheels: publish each step's wheels (False: an agent host batches them).
    """

    def __init__(
        self,
        robot_id: str,
        fleet: str,
        config: AgentConfig,
        publish: Publish,
        *,
        lockstep: bool = False,
        loop_mode: LoopMode = "on-pose",
        rate_hz: float = 50.0,
        motor: MotorOutput | None = None,
        log: rt.NodeLog | None = None,
        neighbour_fn: NeighbourFn | None = None,
        publish_wheels: bool = True,
    ) -> None:
        self.robot_id = keys.check_robot_id(robot_id)
        self.fleet = keys.check_fleet(fleet)
        # realtime: no shared-frame plane (frames reach robots at different ticks; params.py)
        self.firmware = Firmware(config if lockstep else config.realtime())
        self.lockstep = lockstep
        self.loop_mode: LoopMode = loop_mode
        self.period_s = 1.0 / rate_hz
        self.motor = motor
        self.log = log if log is not None else rt.NodeLog(f"agent {robot_id}")
        self._publish = publish
        self.host = socket.gethostname()[:255] or "unknown"
        self.pid = os.getpid()

        self.pose_key = keys.pose_key(fleet, robot_id)
        self.setpoint_key = keys.setpoint_key(fleet, robot_id)
        self.poses_key = keys.poses_key(fleet)
        self.estop_key = keys.estop_key(fleet)
        self.clock_key = keys.clock_key(fleet)
        self.wheels_key = keys.wheels_key(fleet, robot_id)
        self.status_key = keys.status_key(fleet, robot_id)
        self.alive_key = keys.alive_robot_key(fleet, robot_id)
        # Lockstep: the plant waits for these wheels, so they must arrive (BLOCK) and keep their
        # order relative to the clock (same priority).
        self.wheels_qos = rt.QOS_CRITICAL if lockstep else rt.QOS_CONTROL

        self.pose: FwPose | None = None
        self.pose_rx_s = -math.inf
        # capture time of self.pose on this node's clock (robot_agent.core.clocksync), for the
        # estimator: the pose's t in lockstep (sim time), converted in realtime
        self.pose_capture_s: float | None = None
        self.clocks = ClockOffsets()  # realtime: one offset estimate per source key
        self._pose_pending = False  # lockstep: received since the last clock
        self.setpoint: _SetpointIn | None = None  # realtime: the newest
        self._setpoints: SetpointWindow[_SetpointIn] = SetpointWindow()  # lockstep
        self.role: str | None = None
        # lockstep: this robot's emulated encoder speeds of the current clock (Clock.enc_*)
        self.clock_wheels: tuple[float, float] | None = None

        self.rx: dict[str, int] = {
            "pose": 0, "setpoint": 0, "poses": 0, "estop": 0, "clock": 0, "status": 0,
            "movers": 0,
            "wheels": 0,
        }  # fmt: skip
        # every drop by "<message>-<reason>" (status "rejects"), also counted by the firmware
        self.faults = rt.Faults(self.log, on_reject=self.firmware.reject)
        # the coordinator's moving obstacles (issue 30; robot_agent.node.movers_input)
        self.movers_in = MoversInput(lockstep=lockstep, reject=self.faults.reject)
        self.movers_key = keys.movers_key(fleet)
        # the other robots (robot_agent.core.neighbours): poses from the frames (on_poses),
        # modes from their status messages (realtime) or the clock (lockstep)
        sfp = config.safety_filter
        g = config.geometry
        # motion claims (robot_agent.core.neighbour_motion): realtime, from the other robots'
        # wheels messages (on_wheels); lockstep, relayed by the clock (on_clock)
        self.claims_on = sfp.accel_bound_mps2 > 0.0
        self.neighbour_table = NeighbourTable(
            lockstep=lockstep,
            max_robots=MAX_NEIGHBOURS,
            local_tracking=self._own_tracking,
            motion=(g.ref_offset_m, g.max_speed_mps, sfp.claim_max_age_s)
            if self.claims_on
            else None,
        )
        self.peer_status = PeerStatusInputs(
            self.neighbour_table, self.rx, self.faults.reject, self.faults.internal
        )
        # E-stop as latched fleet state (robot_agent.core.estop): the scopes this robot obeys (with
        # their engagement ids), the query of the latched state and the witness of every
        # engagement seen, answered on estop/held (robot_agent.node.estop_shell).
        self.estop = EstopLatch()
        self.estop_query = EstopQuery(self.faults.internal)
        self.witness = EstopWitness(self.faults.internal)
        self.steps = 0
        self.last_step_s = -math.inf
        self.sim_t = 0.0  # lockstep: t of the last clock
        self._replay: Replay[bytes] = Replay()  # lockstep: the last clock's wheels
        self._seq_wheels = 0
        self._seq_status = 0
        self.stall = rt.StallDetector()  # realtime: stops of this process (runtime.stall)
        # Agent host (robot_agent.node.host): the host publishes the wheels of all its robots in one
        # batch and answers neighbour queries from its shared spatial index.
        self.publish_wheels = publish_wheels
        self.neighbour_fn = neighbour_fn
        self.scripted = AgentFaults(self.robot_id)  # scripted faults, lockstep (agent_faults)
        self.fault_key = keys.fault_key(fleet)
        # Held by the loop's entry points (e-stop, status) while they touch this state. A
        # lockstep agent process runs its per-tick handlers on a thread of its own
        # (runtime.bridge.TickPump) and sets a lock here that the pump holds too.
        self.guard: contextlib.AbstractContextManager[object] = contextlib.nullcontext()

    # -- bookkeeping ---------------------------------------------------------------------------

    def _own_tracking(self, rid: str) -> bool | None:
        """This robot's own mode (its status messages are not a neighbour's)."""
        return self.firmware.mode is Mode.TRACKING if rid == self.robot_id else None

    @property
    def rejects(self) -> RejectCounts:
        """Messages dropped by this node, by ``<message>-<reason>`` (status ``rejects``)."""
        return self.faults.rejects

    @property
    def internal_errors(self) -> int:
        """Internal errors caught by the handlers."""
        return self.faults.internal_errors

    @property
    def rejected(self) -> int:
        """Messages rejected so far (decode errors and misaddressed messages)."""
        return self.firmware.status().rejected_count

    def check_resume(self, now_s: float) -> bool:
        """Realtime: detect a resume after a stop of this process (:mod:`runtime.stall`): drop
        the setpoint and pose and return True while the quarantine lasts (inputs are backlog)."""
        if self.lockstep:
            return False
        stopped = self.stall.resume(now_s)
        if stopped is not None:
            self.setpoint = None
            self.pose = None
            self.log.info(f"resumed after {stopped:.2f} s stopped: holding until fresh data")
            self.estop_query.request(now_s)  # an e-stop engaged or released meanwhile
        return self.stall.quarantined(now_s)

    # -- input handlers (event loop) -----------------------------------------------------------

    def on_pose(self, rx: rt.Received) -> None:
        """Own pose: keep it; realtime on-pose: step now."""
        try:
            self.rx["pose"] += 1
            if self.check_resume(rx.rx_s):
                self.faults.reject("pose", "received during the resume quarantine", "quarantine")
                return
            msg = decode(rx.payload, Pose)
            if isinstance(msg, DecodeError):
                self.faults.reject("pose", msg)
                return
            if msg.robot is not None and msg.robot != self.robot_id:
                self.faults.reject(
                    "pose", f"robot {msg.robot!r} on {self.robot_id}'s key", "misaddressed"
                )
                return
            pose = FwPose(msg.x, msg.y, msg.theta, msg.t)
            if self.lockstep:  # sim time: one clock for every node
                self.take_pose(pose, msg.t, None)
                return
            pub_t = msg.t if msg.pub_t is None else msg.pub_t
            capture_s = self.clocks.capture_to_local(rx.key, pub_t, msg.t, rx.rx_s)
            self.take_pose(pose, capture_s, rx.rx_s)
            if self.loop_mode == "on-pose":
                self.step(time.monotonic())
        except Exception as exc:
            self.faults.internal("on_pose", exc)

    def take_pose(self, pose: FwPose, capture_s: float, rx_s: float | None) -> None:
        """This robot's own measured pose, captured at ``capture_s`` (this node's clock; sim
        time in lockstep) and received at ``rx_s``; ``rx_s`` None: lockstep, pending until the
        next clock. The one writer of the pose (:meth:`on_pose`, :meth:`on_poses`, an agent
        host's frame)."""
        self.pose = pose
        self.pose_capture_s = capture_s
        if rx_s is None:
            self._pose_pending = True
        else:
            self.pose_rx_s = rx_s

    def on_poses(self, rx: rt.Received) -> None:
        """Batched poses: the other robots' poses and capture times, for repulsion and the
        safety filter (``robot_agent.core.neighbours``); in lockstep also this robot's own pose,
        as :meth:`on_pose` takes it (every lockstep node reads the plant's frames as batches)."""
        try:
            self.rx["poses"] += 1
            msg = decode(rx.payload, PoseBatch)
            if isinstance(msg, DecodeError):
                self.faults.reject("poses", msg)
                return
            me = self.robot_id
            store = self.neighbour_table.store
            if self.lockstep:  # sim time: one clock for every node; received at the next clock
                cap, rx_s, now = msg.stamp, None, self.sim_t
            else:
                cap = self.clocks.capture_to_local(rx.key, msg.t, msg.stamp, rx.rx_s)
                rx_s = now = rx.rx_s
            own: tuple[float, float, float] | None = None
            for rid, x, y, th in zip(msg.robots, msg.x, msg.y, msg.theta, strict=True):
                if rid != me:
                    store(rid, x, y, th, cap, rx_s, now)
                elif self.lockstep:
                    own = (x, y, th)
            self.neighbour_table.end_frame()
            if own is not None:  # lockstep: its own pose comes with the frame
                if self.check_resume(rx.rx_s):
                    self.faults.reject(
                        "poses", "own pose received during the resume quarantine", "quarantine"
                    )
                    return
                self.take_pose(FwPose(own[0], own[1], own[2], msg.stamp), msg.stamp, None)
        except Exception as exc:
            self.faults.internal("on_poses", exc)

    def on_wheels(self, rx: rt.Received) -> None:
        """Realtime, with motion bounds: another robot's wheels message carries its motion
        claim (``robot_agent.core.neighbour_motion``), its tick time on the local clock through
        the sender's clock offset (``robot_agent.core.clocksync``)."""
        try:
            self.rx["wheels"] += 1
            parsed = keys.parse_robot_key(rx.key)
            if parsed is None or parsed[1] == self.robot_id:
                return
            msg = decode(rx.payload, Wheels)
            if isinstance(msg, DecodeError):
                self.faults.reject("wheels", msg)
                return
            if msg.ux is None or msg.uy is None or msg.w is None or msg.accel is None:
                return  # (no claim: this robot keeps the worst case for it)
            t = self.clocks.capture_to_local(rx.key, msg.t, msg.t, rx.rx_s)
            claim = Claim(t, msg.ux, msg.uy, msg.w, msg.accel)
            if not self.neighbour_table.note_claim(parsed[1], claim, rx.rx_s):
                self.faults.reject("wheels", "claim not newer or table full", "claim")
        except Exception as exc:
            self.faults.internal("on_wheels", exc)

    def on_setpoint(self, rx: rt.Received) -> None:
        """Own setpoint: keep the newest (realtime) or the last two with their ticks (lockstep)."""
        try:
            self.rx["setpoint"] += 1
            if self.check_resume(rx.rx_s):
                self.faults.reject(
                    "setpoint", "received during the resume quarantine", "quarantine"
                )
                return
            msg = decode(rx.payload, Setpoint)
            if isinstance(msg, DecodeError):
                self.faults.reject("setpoint", msg)
                return
            if msg.robot != self.robot_id:
                self.faults.reject(
                    "setpoint", f"robot {msg.robot!r} on {self.robot_id}'s key", "misaddressed"
                )
                return
            sp = FwSetpoint(msg.x, msg.y, msg.vx, msg.vy, msg.theta, msg.slot, msg.t)
            tick = msg.tick if self.lockstep else None
            self.accept_setpoint(sp, msg.role, rx.rx_s, tick)
        except Exception as exc:
            self.faults.internal("on_setpoint", exc)

    def on_movers(self, rx: rt.Received) -> None:
        """The coordinator's moving obstacles (``formation/<fleet>/movers``, issue 30)."""
        try:
            self.rx["movers"] += 1
            self.movers_in.on_payload(rx.payload, rx.rx_s)
        except Exception as exc:
            self.faults.internal("on_movers", exc)

    def accept_setpoint(self, sp: FwSetpoint, role: str, rx_s: float, tick: int | None) -> None:
        """Keep a valid setpoint: the newest (realtime) or the last two with ticks (lockstep)."""
        if self.lockstep:
            if tick is None:
                self.faults.reject("setpoint", "lockstep setpoint without a valid tick", "no_tick")
                return
            # In lockstep the setpoint's t is the sim time of its tick, which is when
            # simulate.py considers it received.
            self._setpoints.add(tick, _SetpointIn(sp, role, sp.t, tick))
        else:
            self.setpoint = _SetpointIn(sp, role, rx_s, None)

    def on_estop(self, rx: rt.Received) -> None:
        """Fleet or own estop: latch or release that scope (robot_agent.core.estop); the firmware is
        in ESTOP (zero wheels at once in realtime) while the fleet's or this robot's is latched."""
        with self.guard:
            self._on_estop(rx)

    def _on_estop(self, rx: rt.Received) -> None:
        try:
            self.rx["estop"] += 1
            msg = decode(rx.payload, Estop)
            if isinstance(msg, DecodeError):
                self.faults.reject("estop", msg)
                return
            self.witness.message(msg.engage, msg.robot, msg.id)  # answered on estop/held
            if msg.robot is not None and msg.robot != self.robot_id:
                return  # another robot's estop
            self.estop.apply(msg.engage, msg.robot, msg.id)
            self.sync_estop("message")
        except Exception as exc:
            self.faults.internal("on_estop", exc)

    def on_estop_state(self, answers: list[tuple[bool, str | None, int | None]]) -> None:
        """The coordinators' latched e-stop state (a query's ``(engage, robot, id)`` entries,
        any robots'): adds engagements, releases one held here only if the answer saw that
        engagement released (``EstopLatch.merge_answer``). No answer: nothing changes."""
        with self.guard:
            self._on_estop_state(answers)

    def _on_estop_state(self, answers: list[tuple[bool, str | None, int | None]]) -> None:
        try:
            if not answers:
                return
            self.witness.answer(answers)
            mine = [a for a in answers if a[1] is None or a[1] == self.robot_id]
            self.estop.merge_answer(mine)
            self.sync_estop("query answer")
        except Exception as exc:
            self.faults.internal("on_estop_state", exc)

    def sync_estop(self, why: str = "") -> None:
        """Engage or release the firmware's e-stop to match the latched scopes (``why``: what
        changed them, for the log)."""
        stop = self.estop.stopped(self.robot_id)
        latched = self.firmware.status().estop_latched
        src = f" by {why}" if why else ""
        if stop and not latched:
            self.firmware.engage_estop()
            scope = " (fleet)" if self.estop.fleet else ""
            self.log.info(f"estop engaged{scope}{src} t={time.monotonic():.6f}")
            if not self.lockstep:
                self.step(time.monotonic())  # zero wheels now, not at the next tick
        elif latched and not stop:
            self.firmware.release_estop()
            self.log.info(f"estop released{src} t={time.monotonic():.6f}")

    def on_clock(self, rx: rt.Received) -> None:
        """Lockstep clock k: step at t_k and answer with wheels(tick=k)."""
        try:
            self.rx["clock"] += 1
            msg = decode(rx.payload, Clock)
            if isinstance(msg, DecodeError):
                self.faults.reject("clock", msg)
                return
            k = msg.tick
            again = self._replay.repeat(k)
            if again is not None:
                self._publish(self.wheels_key, again, self.wheels_qos)  # re-announced clock
                return
            self.neighbour_table.relay(msg.tracking or ())
            if self.claims_on and msg.claim_robots:
                self._relayed_claims(msg)
            self.clock_wheels = clock_wheels(msg).get(self.robot_id)
            self.clock_step(k, msg.t)
        except Exception as exc:
            self.faults.internal("on_clock", exc)

    def _relayed_claims(self, msg: Clock) -> None:
        """Lockstep: the motion claims the clock relays (the answers to the previous tick, sim
        time: one clock for every node), as the in-process simulator hands them over."""
        rows, ts, uxs = msg.claim_robots, msg.claim_t, msg.claim_ux
        uys, ws, accs = msg.claim_uy, msg.claim_w, msg.claim_accel
        if rows is None or ts is None or uxs is None or uys is None or ws is None or accs is None:
            return  # (the codec's Together rule: all or none)
        note = self.neighbour_table.note_claim
        me = self.robot_id
        for rid, t, ux, uy, w, a in zip(rows, ts, uxs, uys, ws, accs, strict=True):
            if rid != me:
                note(rid, Claim(t, ux, uy, w, a), msg.t)

    def take_arrivals(self, t_k: float) -> None:
        """Lockstep: poses and neighbours received since the last clock count as received at
        ``t_k``."""
        self.sim_t = t_k
        if self._pose_pending:
            self.pose_rx_s = t_k
            self._pose_pending = False
        self.neighbour_table.settle(t_k)

    def on_fault(self, rx: rt.Received) -> None:
        """A scripted fault's notice (robot_agent.node.agent_faults); never raises."""
        try:
            self.scripted.on_fault(self, rx.payload)
        except Exception as exc:
            self.faults.internal("on_fault", exc)

    def clock_step(self, k: int, t_k: float) -> WheelCommand | None:
        """Lockstep tick k at sim time ``t_k``: poses and neighbours received since the last
        clock count as received at ``t_k``, the setpoint of tick k-1 is chosen, one step (none
        while a scripted fault keeps this robot out: robot_agent.node.agent_faults)."""
        try:
            if self.scripted.busy and not self.scripted.at_clock(self, k, t_k):
                return None
            self.take_arrivals(t_k)
            self.setpoint = self._setpoints.for_clock(k)
            self._replay.last_tick = k
            return self.step(t_k, tick=k)
        except Exception as exc:
            self.faults.internal("clock_step", exc)
            return None

    # -- control -------------------------------------------------------------------------------

    def step(self, now_s: float, tick: int | None = None) -> WheelCommand | None:
        """One firmware tick at ``now_s`` (s); publishes wheels and drives the motor seam."""
        try:
            sp = self.setpoint
            cmd = self.firmware.step(
                now_s,
                pose=self.pose,
                pose_rx_s=self.pose_rx_s,
                setpoint=sp.sp if sp is not None else None,
                setpoint_rx_s=sp.rx_s if sp is not None else -math.inf,
                neighbours=(
                    self.neighbour_table.neighbours(
                        now_s,
                        self.movers_in.for_clock(tick)
                        if tick is not None
                        else self.movers_in.at(now_s),
                    )
                    if self.neighbour_fn is None
                    else self.neighbour_fn(self, now_s)
                ),
                pose_capture_s=self.pose_capture_s,
                wheel_speeds=(
                    self.clock_wheels if self.motor is None else self.motor.take_wheel_speeds()
                ),
            )
            if sp is not None:
                self.role = sp.role
            self.steps += 1
            self.last_step_s = now_s
            if self.motor is not None:
                zero = cmd.omega_r == 0.0 and cmd.omega_l == 0.0
                self.motor.command(cmd.omega_r, cmd.omega_l, now_s, zero)
            if not self.publish_wheels:
                return cmd
            self._seq_wheels += 1
            claim = self.firmware.motion_claim
            if claim is not None and claim.t_s != now_s:
                claim = None  # (the bound held the previous tick's claim: none for this one)
            payload = encode(
                Wheels(
                    t=max(now_s, 0.0),
                    seq=self._seq_wheels,
                    omega_r=cmd.omega_r,
                    omega_l=cmd.omega_l,
                    power_r=cmd.power_r,
                    power_l=cmd.power_l,
                    pose_t=cmd.pose_t,
                    tick=tick,
                    saturated=cmd.saturated,
                    mode=str(cmd.mode),
                    ux=None if claim is None else claim.ux_mps,
                    uy=None if claim is None else claim.uy_mps,
                    w=None if claim is None else claim.omega_radps,
                    accel=None if claim is None else claim.accel_mps2,
                )
            )
            self._replay.answer = payload
            self._publish(self.wheels_key, payload, self.wheels_qos)
            return cmd
        except Exception as exc:  # SchemaError (a bug) or a closed session at shutdown
            self.faults.internal("step", exc)
            return None

    def status_message(self, now_s: float) -> Status:
        """The status message for ``now_s`` (s, this node's bus clock)."""
        st = self.firmware.status()
        self._seq_status += 1
        flt = st.safety_filter
        tw = estimator_twist(self.firmware, now_s)
        return Status(
            t=max(now_s, 0.0),
            seq=self._seq_status,
            mode=str(st.mode),
            slot=st.slot,
            pid=self.pid,
            host=self.host,
            rejected=st.rejected_count,
            ex=rt.finite_or_none(st.ex),
            ey=rt.finite_or_none(st.ey),
            role=self.role,
            rx=dict(self.rx),
            robot=self.robot_id,
            rejects=self.faults.rejects.as_dict(),
            filter=None if flt is None else filter_counters(flt),
            min_clearance_m=None if flt is None else clearance_or_none(flt.min_clearance_m),
            v_mps=None if tw is None else tw[0],
            omega_radps=None if tw is None else tw[1],
        )

    def publish_status(self) -> None:
        """Publish one status message (never raises)."""
        with self.guard:
            self._publish_status()

    def _publish_status(self) -> None:
        try:
            now = self.sim_t if self.lockstep else time.monotonic()
            if not self.lockstep and self.estop_query.due(now):
                self.estop_query.request(now)
            self._publish(self.status_key, encode(self.status_message(now)), rt.QOS_TELEMETRY)
        except Exception as exc:
            self.faults.internal("status", exc)

    def control_timer(self, now: float) -> None:
        """Realtime timer tick: step unless an own pose stepped within the period (on-pose)."""
        if self.loop_mode == "fixed" or now - self.last_step_s >= self.period_s * 0.999:
            self.step(now)

    async def run(self, stop: asyncio.Event, notifier: Notifier | None = None) -> None:
        """Timers until ``stop``: the realtime control/watchdog timer and the 5 Hz status."""
        if not self.lockstep:
            self.stall.watch_sigcont()  # a late loop is no stop (runtime.stall)
        await run_timers(self, stop, notifier)
