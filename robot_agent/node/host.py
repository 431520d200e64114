"""``formation agent-host``: the firmware of many robots in one process (for simulation at scale).

Usage::

    formation agent-host --ids r1..r100 [--name NAME] [--scenario NAME|FILE] [--fleet demo]
                         [--lockstep] [--rate-hz 50] [zenoh options]

The command line and bootstrap are :mod:`robot_agent.node.host_main`; this module is the node.

A workstation simulating hundreds of robots cannot afford one process (and ~40 MB, and one Zenoh
session) per robot; a real robot runs ``formation agent``. This process runs one
:class:`~robot_agent.node.agent.AgentNode` per robot, each with its own
:class:`~robot_agent.core.firmware.Firmware` exactly as ``formation agent`` runs it (same setpoint
choice, same safe states, same lockstep rules), and each robot keeps its own liveliness token
``formation/<fleet>/alive/robot/<id>``, so the coordinator, the plant and the fault tools see
ordinary robots. What is shared is the I/O, batched (bus_schemas, docs/scale.md):

* in: ``formation/<fleet>/poses`` (:class:`~bus_schemas.PoseBatch`, every robot's pose, which is
  both the own pose of each hosted robot and the neighbours for repulsion), ``setpoints``
  (:class:`~bus_schemas.SetpointBatch` from a coordinator started with ``--batch``), ``estop``,
  and ``clock`` in lockstep. One decode per message for all robots, not one per robot.
* out: ``formation/<fleet>/host/<name>/wheels`` (:class:`~bus_schemas.WheelsBatch`, the commands of
  one control step, chunks of :data:`~bus_schemas.BATCH_CHUNK`) and ``host/<name>/status``
  (:class:`~bus_schemas.StatusBatch`, 5 Hz).
* repulsion and safety filter: each robot's neighbours come from one spatial hash of the latest
  frame (``robot_agent.core.host_grid``: cells of the larger of the repulsion influence distance
  ``d0`` and the safety filter's ``neighbour_range_m``), so a query costs the robots in 3 x 3
  cells, not N; the neighbours are passed in frame order, the order ``formation agent`` sees
  them, so the firmware sums the same terms in the same order.

Realtime: the robots whose poses are in a frame chunk are stepped when it arrives (the
on-pose loop of ``formation agent``) and their commands go out in batches; a ``--rate-hz``
watchdog steps every robot that was not stepped for a period, so stale data still drives HOLD.
The watchdog runs when the oldest step falls due (not on a fixed grid) and steps
:data:`WATCHDOG_CHUNK` robots per turn of the event loop, so a frame that arrives meanwhile is
served first (its robots are then no longer due). ``host_main`` turns the automatic garbage
collection off in realtime: the host collects when a watchdog round ends, between two frames
(:meth:`HostNode.collect_garbage`), never inside a frame's steps.
Lockstep: on ``clock`` k every robot steps at ``t_k`` (``AgentNode.clock_step``) and one batch
(``tick: k``) answers; a repeated clock gets the same batch again.

E-stop as latched fleet state (``robot_agent.core.estop``, docs/faults.md): every hosted robot keeps
its own latch. Like ``formation agent``, the host asks the coordinators for the latched state
before it subscribes to anything that moves its robots (so robots of a host that starts or is
respawned under an e-stop come up in ESTOP), again when it resumes from a stop, and every
``ESTOP_REFRESH_S`` in realtime, together with the engagements the other agents hold
(the handlers are the host's :class:`~robot_agent.node.host_estop.HostEstop` part); while a
hosted robot holds an engagement, the host answers ``estop/held/<host>`` with every hosted
robot's (its :class:`~robot_agent.node.estop_shell.EstopWitness`).

The host owns its parts as the agent does: one
:class:`~robot_agent.core.neighbour_table.NeighbourTable` for all its robots (the frames' poses,
the other robots' modes from :class:`~robot_agent.node.peer_status.PeerStatusInputs`), read
through the spatial hash; the e-stop query, witness and handlers; its fault counters
(:class:`runtime.Faults`: a bad message is counted against every hosted robot's firmware).

Bad input is counted in the host's ``faults`` (:class:`runtime.Faults`) and against every hosted
robot's firmware (``rejected`` in the status batch) and logged at most once a second; it never
stops the loop. SIGINT/SIGTERM: exits within a second,
session closed (``runtime.transport.run_node``). Prints ``agent-host <name> ready`` once its
subscriptions and every robot's token are declared.
"""

from __future__ import annotations

import asyncio
import contextlib
import gc
import math
import os
import socket
import time
from collections.abc import Iterable, Sequence
from typing import Final

import runtime as rt
from bus_schemas import (
    BATCH_CHUNK,
    Clock,
    DecodeError,
    PoseBatch,
    RejectCounts,
    SetpointBatch,
    StatusBatch,
    WheelsBatch,
    decode,
    encode,
    keys,
)
from robot_agent.core.clocksync import ClockOffsets
from robot_agent.core.firmware import Mode, WheelCommand
from robot_agent.core.firmware import Pose as FwPose
from robot_agent.core.firmware import Setpoint as FwSetpoint
from robot_agent.core.host_grid import NeighbourGrid
from robot_agent.core.lockstep import Replay
from robot_agent.core.neighbour_table import NeighbourTable
from robot_agent.core.params import AgentConfig
from robot_agent.core.safety_filter import Neighbour, SafetyFilter
from robot_agent.node.agent import AgentNode, Publish, clock_wheels
from robot_agent.node.estop_shell import EstopQuery, EstopWitness
from robot_agent.node.host_estop import HostEstop
from robot_agent.node.host_status import StatusRow, status_batches, status_row
from robot_agent.node.movers_input import MoversInput
from robot_agent.node.peer_status import PeerStatusInputs
from runtime.lifecycle import gc_generation
from runtime.sdnotify import Notifier
from runtime.timers import run_timers

__all__ = ["MAX_HOSTED", "HostNode"]

MAX_HOSTED: Final = 4096
"""Robots one host runs at most."""
MAX_TRACKED: Final = 20000
"""Distinct robot positions kept for repulsion (a flood of made-up ids cannot grow memory)."""
REALTIME_CHUNK: Final = 32
"""Realtime: commands per published WheelsBatch (sent as soon as that many robots stepped).
Tried in session 5: 50 (two puts a frame for 100 robots instead of four): p50 up (half the
robots then wait for the whole frame), p99 no better on the shared machine (docs/scale.md)."""
WATCHDOG_CHUNK: Final = 32
"""Realtime: robots one turn of the watchdog timer steps before it yields to the event loop,
so a pose frame that arrives meanwhile waits for at most that many steps, not the fleet's."""
STATUS_STEP: Final = 25
"""Realtime: robots whose status one turn of the event loop takes (``HostNode.publish_status``)."""
WATCHDOG_YIELD_S: Final = 0.0002
"""Realtime: the watchdog's pause between two chunks (s). A real wait, not ``sleep(0)``: the loop
blocks in its selector, so Zenoh's thread gets the GIL and hands over a frame that arrived
during the chunk, and the frame's handler runs before the next chunk (after ``sleep(0)`` the
next chunk would be queued first)."""

GC_MAX_GAP_S: Final = 0.5
"""Realtime with manual collections (:attr:`HostNode.manual_gc`): the longest time without one."""


class HostNode:
    """Many :class:`AgentNode` sharing one session's batched I/O; Zenoh-free apart from
    ``publish``. Handlers take one :class:`runtime.transport.Received`, run on the event
    loop and never raise.

    Args:
        name: host name in the keys (``[A-Za-z0-9_-]+``).
        robot_ids: the robots this host runs.
        fleet: fleet name.
        config: firmware parameters (every robot the same).
        publish: ``publish(key, payload, qos)``.
        lockstep: step on ``clock`` only.
        rate_hz: realtime watchdog timer rate.
        log: where to log.
    """

    def __init__(
        self,
        name: str,
        robot_ids: Sequence[str],
        fleet: str,
        config: AgentConfig,
        publish: Publish,
        *,
        lockstep: bool = False,
        rate_hz: float = 50.0,
        log: rt.NodeLog | None = None,
    ) -> None:
        self.name = keys.check_name(name)
        self.fleet = keys.check_fleet(fleet)
        self.lockstep = lockstep
        self.period_s = 1.0 / rate_hz
        self.log = log if log is not None else rt.NodeLog(f"agent-host {name}")
        self._publish = publish
        self.hostname = socket.gethostname()[:255] or "unknown"
        self.pid = os.getpid()
        if len(robot_ids) > MAX_HOSTED:
            raise ValueError(f"at most {MAX_HOSTED} robots per host")
        self.nodes: dict[str, AgentNode] = {}
        quiet = rt.NodeLog(f"agent-host {name}", min_interval_s=5.0)
        for rid in robot_ids:
            self.nodes[rid] = AgentNode(
                rid, fleet, config, publish, lockstep=lockstep, loop_mode="fixed",
                rate_hz=rate_hz, log=quiet, neighbour_fn=self._neighbours_of,
                publish_wheels=False,
            )  # fmt: skip
        self.order = list(self.nodes)
        # a bad message reached every hosted robot: each firmware counts it
        self.faults = rt.Faults(self.log, on_reject=self._firmware_reject)
        # every robot's latest pose (robot_agent.core.neighbour_table) and the cooperative rule:
        # lockstep, what the clock relays; realtime, the hosted robots' own modes and the others'
        # status messages (peer_status)
        self.neighbour_table = NeighbourTable(
            lockstep=lockstep, max_robots=MAX_TRACKED, local_tracking=self._hosted_tracking
        )
        # neighbours are looked up in 3 x 3 cells: a cell must cover the repulsion's d0 and the
        # safety filter's range
        self.cell_m = max(
            config.repulsion.influence_m, SafetyFilter(config).neighbour_range_m, 1e-3
        )
        self.grid = NeighbourGrid(
            self.cell_m, self.neighbour_table.cooperative, self.neighbour_table.seen
        )

        self.poses_key = keys.poses_key(fleet)
        self.setpoints_key = keys.setpoints_key(fleet)
        self.estop_key = keys.estop_key(fleet)
        self.clock_key = keys.clock_key(fleet)
        self.wheels_key = keys.host_wheels_key(fleet, name)
        self.status_key = keys.host_status_key(fleet, name)
        self.wheels_qos = rt.QOS_CRITICAL if lockstep else rt.QOS_CONTROL

        self.clocks = ClockOffsets()  # realtime: the pose frames' clock on this host's
        self.rx: dict[str, int] = {
            "poses": 0, "setpoints": 0, "estop": 0, "clock": 0, "status": 0, "movers": 0,
        }  # fmt: skip
        # the coordinator's moving obstacles (issue 30), for every hosted robot's neighbours
        self.movers_key = keys.movers_key(fleet)
        self.movers_in = MoversInput(lockstep=lockstep, reject=self.faults.reject)
        self.peer_status = PeerStatusInputs(
            self.neighbour_table,
            self.rx,
            self.faults.reject,
            self.faults.internal,
            own_key=self.status_key,
        )
        self.batches = 0
        self.sim_t = 0.0
        self._replay: Replay[list[bytes]] = Replay()  # lockstep: the last clock's batches
        self._seq_wheels = 0
        self._seq_status = 0
        self._status_rows: list[StatusRow] = []  # the status round under way (publish_status)
        self._status_t = 0.0
        self.stall = rt.StallDetector()  # realtime: stops of this process (runtime.stall)
        # the latched e-stop (robot_agent.core.estop): the query of the latched state, the
        # witness answering with the engagements held (robot_agent.node.estop_shell, put on the
        # bus by host_main) and the handlers applying both to every hosted robot
        self.estop_query = EstopQuery(self.faults.internal)
        self.witness = EstopWitness(self.faults.internal)
        self.estop = HostEstop(
            self.nodes,
            self.witness,
            self.rx,
            self.faults,
            step_now=None if lockstep else self._step_now,
        )
        # Held by the loop's entry points (e-stop, status) while they touch this state. A
        # lockstep host runs its per-tick handlers on a thread of its own
        # (runtime.bridge.TickPump) and sets a lock here that the pump holds too.
        self.guard: contextlib.AbstractContextManager[object] = contextlib.nullcontext()
        # realtime: the process turned the automatic garbage collection off (host_main) and the
        # host collects after each watchdog round, between two frames (collect_garbage)
        self.manual_gc = False
        self.gc_rounds = 0
        self.gc_s = -math.inf

    # -- the loop's e-stop entry points (HostEstop's, under the guard) ---------------------------

    def on_estop(self, rx: rt.Received) -> None:
        """An ``estop`` message (:meth:`HostEstop.on_estop`)."""
        with self.guard:
            self.estop.on_estop(rx)

    def on_estop_state(self, payloads: Sequence[bytes], token: int = 0) -> None:
        """The coordinators' latched state (:meth:`HostEstop.on_estop_state`)."""
        with self.guard:
            self.estop.on_estop_state(payloads, token)

    def on_estop_held(self, payloads: Sequence[bytes], token: int = 0) -> None:
        """The engagements other agents hold (:meth:`HostEstop.on_estop_held`)."""
        with self.guard:
            self.estop.on_estop_held(payloads, token)

    # -- bookkeeping ---------------------------------------------------------------------------

    def _firmware_reject(self, text: str) -> None:
        for node in self.nodes.values():
            node.firmware.reject(text)

    @property
    def rejects(self) -> RejectCounts:
        """Messages dropped by this host, by ``<message>-<reason>``."""
        return self.faults.rejects

    @property
    def rejected(self) -> int:
        """Messages dropped by this host (each counted by every hosted robot's firmware too)."""
        return self.faults.rejected

    @property
    def internal_errors(self) -> int:
        """Internal errors caught by the handlers."""
        return self.faults.internal_errors

    def check_resume(self, now_s: float) -> bool:
        """Realtime: a stop of the whole process (:mod:`runtime.stall`) -> every robot drops its
        setpoint and pose; True while the quarantine lasts (as ``AgentNode.check_resume``)."""
        if self.lockstep:
            return False
        stopped = self.stall.resume(now_s)
        if stopped is not None:
            for node in self.nodes.values():
                node.setpoint = None
                node.pose = None
            self.neighbour_table.clear()
            self.grid.invalidate()
            self.log.info(f"resumed after {stopped:.2f} s stopped: holding until fresh data")
            self.estop_query.request(now_s)  # an e-stop engaged or released meanwhile
        return self.stall.quarantined(now_s)

    # -- neighbours ----------------------------------------------------------------------------

    def _hosted_tracking(self, rid: str) -> bool | None:
        """A hosted robot's own mode (rule 3 in realtime); None for a robot not hosted here."""
        node = self.nodes.get(rid)
        return None if node is None else node.firmware.mode is Mode.TRACKING

    def _neighbours_of(self, node: AgentNode, now_s: float) -> list[Neighbour]:
        """``node``'s neighbours at ``now_s`` as its safety filter and repulsion see them
        (:meth:`robot_agent.core.host_grid.NeighbourGrid.neighbours_of`)."""
        pose = node.pose
        if pose is None:
            return []
        return self.grid.neighbours_of(node.robot_id, pose.x, pose.y, now_s)

    # -- inputs --------------------------------------------------------------------------------

    def on_poses(self, rx: rt.Received) -> None:
        """A pose frame (chunk): own poses of hosted robots, everyone's position for repulsion;
        realtime: step the hosted robots of this chunk now and publish their batch."""
        try:
            self.rx["poses"] += 1
            if self.check_resume(rx.rx_s):
                return
            msg = decode(rx.payload, PoseBatch)
            if isinstance(msg, DecodeError):
                self.faults.reject("poses", msg)
                return
            rx_s: float | None
            store = self.neighbour_table.store
            nodes = self.nodes
            stamp = msg.stamp
            if self.lockstep:  # sim time: one clock for every node; received at the next clock
                cap, rx_s, now = stamp, None, self.sim_t
            else:
                cap = self.clocks.capture_to_local(rx.key, msg.t, stamp, rx.rx_s)
                rx_s = now = rx.rx_s
            mine: list[AgentNode] = []
            for rid, x, y, th in zip(msg.robots, msg.x, msg.y, msg.theta, strict=True):
                if store(rid, x, y, th, cap, rx_s, now) is None:
                    continue  # the table is full of current robots
                node = nodes.get(rid)
                if node is not None:
                    node.rx["pose"] += 1
                    node.take_pose(FwPose(x, y, th, stamp), cap, rx_s)
                    if rx_s is not None:
                        mine.append(node)
            self.grid.invalidate()
            self.neighbour_table.end_frame()
            if mine:
                now = time.monotonic()
                self._publish_steps((n, n.step(now)) for n in mine)
        except Exception as exc:
            self.faults.internal("on_poses", exc)

    def on_movers(self, rx: rt.Received) -> None:
        """The coordinator's moving obstacles (``formation/<fleet>/movers``, issue 30)."""
        try:
            self.rx["movers"] += 1
            self.movers_in.on_payload(rx.payload, rx.rx_s)
        except Exception as exc:
            self.faults.internal("on_movers", exc)

    def on_setpoints(self, rx: rt.Received) -> None:
        """A setpoint batch: each hosted robot's entry as if it came on its own key."""
        try:
            self.rx["setpoints"] += 1
            if self.check_resume(rx.rx_s):
                return
            msg = decode(rx.payload, SetpointBatch)
            if isinstance(msg, DecodeError):
                self.faults.reject("setpoints", msg)
                return
            nodes = self.nodes
            th, t, tick = msg.theta, msg.t, msg.tick
            rows = zip(msg.robots, msg.slot, msg.role, msg.x, msg.y, msg.vx, msg.vy, strict=True)
            for rid, slot, role, x, y, vx, vy in rows:
                node = nodes.get(rid)
                if node is not None:
                    node.rx["setpoint"] += 1
                    node.accept_setpoint(FwSetpoint(x, y, vx, vy, th, slot, t), role, rx.rx_s, tick)
        except Exception as exc:
            self.faults.internal("on_setpoints", exc)

    def on_fault(self, rx: rt.Received) -> None:
        """A scripted fault's notice, for each robot of the host (robot_agent.node.agent_faults:
        a killed robot of a host stops stepping for good; the host lives on)."""
        for n in self.nodes.values():
            n.on_fault(rx)

    def on_clock(self, rx: rt.Received) -> None:
        """Lockstep clock k: every robot steps at t_k; one batch with ``tick: k`` answers."""
        try:
            self.rx["clock"] += 1
            msg = decode(rx.payload, Clock)
            if isinstance(msg, DecodeError):
                self.faults.reject("clock", msg)
                return
            k, t_k = msg.tick, msg.t
            again = self._replay.repeat(k)
            if again:
                for payload in again:  # re-announced clock
                    self._publish(self.wheels_key, payload, self.wheels_qos)
                return
            self.sim_t = t_k
            self.neighbour_table.relay(msg.tracking or ())
            enc = clock_wheels(msg)
            for n in self.nodes.values():
                n.clock_wheels = enc.get(n.robot_id)
            self.neighbour_table.settle(t_k)
            self.grid.invalidate()
            self.grid.set_movers(self.movers_in.for_clock(k))
            self._replay.record(k, [])
            nodes = self.nodes.values()
            self._replay.answer = self._publish_steps(
                ((n, n.clock_step(k, t_k)) for n in nodes), tick=k
            )
        except Exception as exc:
            self.faults.internal("on_clock", exc)

    # -- outputs -------------------------------------------------------------------------------

    def _step_now(self, robots: Iterable[AgentNode]) -> None:
        """Realtime: step ``robots`` now and publish their commands (an engaged e-stop)."""
        now = time.monotonic()
        self.grid.set_movers(self.movers_in.at(now))
        self._publish_steps((n, n.step(now)) for n in robots)

    def _publish_steps(
        self,
        steps: Iterable[tuple[AgentNode, WheelCommand | None]],
        tick: int | None = None,
    ) -> list[bytes]:
        """Publish the commands of ``steps`` as WheelsBatch chunks; returns the payloads.

        ``steps`` is consumed lazily (a generator that steps the firmware): in realtime a chunk
        of :data:`REALTIME_CHUNK` commands goes out as soon as it is complete, so the first
        robots' commands do not wait for the last robots' steps; lockstep sends fewer, larger
        chunks (:data:`~bus_schemas.BATCH_CHUNK`): the plant waits for all of them anyway."""
        size = BATCH_CHUNK if self.lockstep else REALTIME_CHUNK
        payloads: list[bytes] = []
        rows: list[tuple[str, WheelCommand]] = []
        for n, cmd in steps:
            if cmd is not None:
                rows.append((n.robot_id, cmd))
                if len(rows) == size:
                    payloads.append(self._publish_chunk(rows, tick))
                    rows = []
        if rows:
            payloads.append(self._publish_chunk(rows, tick))
        self.batches += len(payloads)
        return payloads

    def _publish_chunk(self, chunk: list[tuple[str, WheelCommand]], tick: int | None) -> bytes:
        """Publish one WheelsBatch of ``chunk``; returns its payload."""
        now = self.sim_t if self.lockstep else time.monotonic()
        self._seq_wheels += 1
        payload = encode(
            WheelsBatch(
                t=max(now, 0.0),
                seq=self._seq_wheels,
                robots=tuple(r for r, _ in chunk),
                omega_r=tuple(c.omega_r for _, c in chunk),
                omega_l=tuple(c.omega_l for _, c in chunk),
                power_r=tuple(c.power_r for _, c in chunk),
                power_l=tuple(c.power_l for _, c in chunk),
                pose_t=tuple(-1.0 if c.pose_t is None else c.pose_t for _, c in chunk),
                tick=tick,
                mode=tuple(str(c.mode) for _, c in chunk),
            )
        )
        self._publish(self.wheels_key, payload, self.wheels_qos)
        return payload

    def step_due(self, now_s: float, limit: int | None = None) -> int:
        """Realtime watchdog: step (and publish) the robots not stepped for a period, at most
        ``limit`` of them (frame order); returns how many were due."""
        lim = self.period_s * 0.999
        due = [n for n in self.nodes.values() if now_s - n.last_step_s >= lim]
        chunk = due if limit is None else due[:limit]
        if chunk:
            self.grid.set_movers(self.movers_in.at(now_s))
            self._publish_steps((n, n.step(now_s)) for n in chunk)
            for n in chunk:  # a step that failed is not retried before a period
                if n.last_step_s < now_s:
                    n.last_step_s = now_s
        return len(due)

    def status_batches(self, now_s: float) -> list[StatusBatch]:
        """The status of every hosted robot, in chunks."""
        return self._status_messages(now_s, [self._status_row(r, now_s) for r in self.order])

    def _status_row(self, rid: str, now_s: float) -> StatusRow:
        return status_row(rid, self.nodes[rid].firmware, now_s)

    def _status_messages(self, now_s: float, rows: list[StatusRow]) -> list[StatusBatch]:
        out = status_batches(rows, max(now_s, 0.0), self._seq_status, self.pid, self.hostname)
        self._seq_status += len(out)
        return out

    def publish_status(self) -> float | None:
        """One piece of a status round (never raises). Realtime: the status of
        :data:`STATUS_STEP` robots per call (~20 us per robot), the batches published once every
        robot's is taken, so a frame never waits for a whole fleet's status; returns when to go
        on (``runtime.timers``) while the round is not complete. Lockstep: all at once."""
        with self.guard:
            return self._publish_status()

    def _publish_status(self) -> float | None:
        try:
            rows = self._status_rows
            if not rows:  # a new round
                now = self.sim_t if self.lockstep else time.monotonic()
                self._status_t = now
                if not self.lockstep and self.estop_query.due(now):
                    self.estop_query.request(now)
            start = len(rows)
            end = len(self.order) if self.lockstep else start + STATUS_STEP
            rows.extend(self._status_row(r, self._status_t) for r in self.order[start:end])
            if len(rows) < len(self.order):
                return time.monotonic() + WATCHDOG_YIELD_S
            self._status_rows = []
            for msg in self._status_messages(self._status_t, rows):
                self._publish(self.status_key, encode(msg), rt.QOS_TELEMETRY)
        except Exception as exc:
            self._status_rows = []
            self.faults.internal("status", exc)
        return None

    def control_timer(self, now: float) -> float:
        """Realtime timer: the watchdog step of at most :data:`WATCHDOG_CHUNK` robots not
        stepped for a period. Returns when it wants to run again (``runtime.timers``): at once
        while more robots are due, after the event loop has served what arrived meanwhile (a
        pose frame steps its robots first: it never waits for the whole fleet's watchdog
        step), else when the next robot falls due (at most a period from now)."""
        lim = self.period_s * 0.999
        try:
            due = self.step_due(now, WATCHDOG_CHUNK)
            if due > WATCHDOG_CHUNK:
                return time.monotonic() + WATCHDOG_YIELD_S
            if self.manual_gc and (due or now - self.gc_s >= GC_MAX_GAP_S):
                self.collect_garbage(now)
            oldest = min(n.last_step_s for n in self.nodes.values())
        except Exception as exc:
            self.faults.internal("step_due", exc)
            return now + self.period_s
        after = time.monotonic()
        return min(max(oldest + lim, after), after + self.period_s)

    def collect_garbage(self, now_s: float) -> None:
        """One collection at the end of a watchdog round (:attr:`manual_gc`): the youngest
        generation, now and then the older ones (:func:`runtime.lifecycle.gc_generation`).
        With 30 Hz frames and a 50 Hz watchdog a round ends ~25 ms after a frame and ~8 ms
        before the next, so a collection no longer lands inside a frame's steps (automatic
        collections did, at any allocation: ~0.25 ms for the youngest, ~2 ms for the middle
        generation on this machine). Also when no round ended for :data:`GC_MAX_GAP_S`
        (frames as fast as the watchdog leave no robot due)."""
        self.gc_s = now_s
        self.gc_rounds += 1
        gc.collect(gc_generation(self.gc_rounds))

    async def run(self, stop: asyncio.Event, notifier: Notifier | None = None) -> None:
        """Timers until ``stop``: the realtime watchdog step and the 5 Hz status."""
        await run_timers(self, stop, notifier)
