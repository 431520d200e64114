"""``formation plant``: the simulated robots, camera and radio link as a process.

Usage::

    formation plant --scenario NAME|FILE [--fleet demo] [--seed N] [--lockstep]
                    [--lockstep-timeout 2.0] [--physics-hz 100] [--duration S] [--wait-robots]
                    [zenoh options]

A thin asyncio shell over :class:`sim_plant.core.plant.Plant`,
:class:`sim_plant.core.sensors.Camera`,
:class:`sim_plant.core.sensors.CommandLink` and
:class:`sim_plant.core.accounting.SeparationMonitor`, built
from the scenario by ``scenario.assemble_plant`` (the assembly ``formation/sim/simulate.py``
uses: one ``numpy.random.default_rng(seed)`` shared by camera and link, the same order of random
draws), so
a lockstep run over the bus reproduces the in-process run. It prints exactly one line
``plant ready`` once its session is open, its subscriptions and its liveliness token
``formation/<fleet>/alive/plant`` are declared, and exits 0 within a second of SIGINT/SIGTERM,
or after ``--duration`` (sim time in lockstep, wall time in realtime).

Theory of operation: docs/process-shells.md (inputs, outputs, realtime and lockstep).
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import threading
import time
from collections import deque
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any, Final

import numpy as np
import numpy.typing as npt

import runtime as rt
from bus_schemas import (
    MAX_LIST_LEN,
    Clock,
    PlantStatus,
    RejectCounts,
    encode,
    keys,
    to_map,
)
from robot_agent.core.lockstep import tick_time
from runtime.timers import STATUS_PERIOD_S  # every node reports at the one rate
from scenario import Scenario
from scenario.assemble_plant import apply_scheduled, plant_models
from sim_plant.core.accounting import SeparationMonitor
from sim_plant.core.encoders import WheelEncoders
from sim_plant.core.plant import Plant
from sim_plant.core.sensors import Camera, CommandLink
from sim_plant.node.faults import PlantFaults
from sim_plant.node.inputs import _DRAG, LinkCmd, PlantInputs
from sim_plant.node.outputs import PlantOutputs

__all__ = ["PlantNode"]

REANNOUNCE_S: Final = 0.25
"""Lockstep: while waiting for answers the clock is published again this often (s)."""
WAIT_ROBOTS_S: Final = 30.0
"""--wait-robots gives up after this long (s)."""


@dataclass
class _Sim:
    """The numpy cores of one run (built when the run starts: realtime needs its t0)."""

    plant: Plant
    camera: Camera
    link: CommandLink[LinkCmd]
    monitor: SeparationMonitor
    t0_s: float


class PlantNode:
    """State of the plant; Zenoh-free apart from the ``publish`` callable. It owns its parts:
    :attr:`inputs` (:class:`PlantInputs`: the input handlers and what arrived), :attr:`outputs`
    (:class:`PlantOutputs`: truth and camera-frame publication, the realtime latency
    bookkeeping) and :attr:`faults` (rejected inputs, internal errors).

    Handlers never raise. In realtime everything runs on the event loop. In lockstep the run is
    a thread of its own (:meth:`run_lockstep_blocking`): it publishes the clock, sleeps until
    the input handlers (on Zenoh's thread, in the order the session received the samples) say
    the tick's last answer is in (:attr:`PlantInputs.wake`) and steps; the event loop keeps the
    status and the tokens. Every one of them holds :attr:`guard` while it touches the node's
    state.
    """

    def __init__(
        self,
        scenario: Scenario,
        fleet: str,
        publish: Any,
        *,
        seed: int | None = None,
        lockstep: bool = False,
        lockstep_timeout_s: float = 2.0,
        physics_hz: float = 100.0,
        duration_s: float | None = None,
        batch: bool = False,
        log: rt.NodeLog | None = None,
        poses: bool = True,
        wanted: Callable[[str, rt.QoS], bool] | None = None,
    ) -> None:
        self.scenario = scenario
        self.batch = batch
        self.poses = poses  # False: a real tracker (formation camera) publishes the poses
        self.fleet = keys.check_fleet(fleet)
        self.seed = scenario.seed if seed is None else seed
        self.lockstep = lockstep
        self.lockstep_timeout_s = lockstep_timeout_s
        self.physics_period_s = 1.0 / physics_hz
        self.duration_s = duration_s
        self.log = log if log is not None else rt.NodeLog("plant")
        self._publish = publish
        self.faults = rt.Faults(self.log)  # every drop by "<message>-<reason>" (status "rejects")
        # lockstep: the tick thread, Zenoh's thread (the inputs) and the event loop share the
        # state; each holds this while it touches it (realtime: everything on the loop)
        self.guard: contextlib.AbstractContextManager[Any] = (
            threading.RLock() if lockstep else contextlib.nullcontext()
        )
        self.halt = threading.Event()  # the lockstep thread stops (SIGINT/SIGTERM)

        self.ids: list[str] = list(scenario.robot_ids)
        self.n = len(self.ids)
        self.index = {rid: i for i, rid in enumerate(self.ids)}
        self.rng = np.random.default_rng(self.seed)
        self.sim: _Sim | None = None
        # lockstep with encoder emulation: the readings of the current tick, relayed in its clock
        self.encoders: WheelEncoders | None = None
        self.clock_enc: list[tuple[float, float]] | None = None

        self.clock_key = keys.clock_key(fleet)
        self.leader_key = keys.leader_key(fleet)
        self.disturbance_key = keys.disturbance_key(fleet)
        self.fault_key = keys.fault_key(fleet)
        self.wheels_pattern = keys.all_wheels_pattern(fleet)
        self.host_wheels_pattern = keys.all_host_wheels_pattern(fleet)
        self.alive_robots_pattern = keys.alive_robots_pattern(fleet)
        self.alive_coordinators_pattern = keys.alive_coordinators_pattern(fleet)
        self.status_key = keys.plant_status_key(fleet)
        self.alive_key = keys.alive_plant_key(fleet)

        # the wheel speeds the physics applies (what the link delivered)
        self.applied: npt.NDArray[np.float64] = np.zeros((self.n, 2))
        self.clock_tracking: tuple[str, ...] = ()  # what the current clock carries
        self.clock_claims: list[tuple[str, tuple[float, float, float, float, float]]] = []
        self.scheduled = deque(scenario.disturbances)
        self.timeouts = 0
        self.state = "waiting"
        self.tick = -1
        self.sim_t = 0.0
        self.scripted = PlantFaults()  # scripted faults' notices (sim_plant.node.faults)
        self.inputs = PlantInputs(
            self.ids,
            lockstep=lockstep,
            faults=self.faults,
            current_tick=lambda: self.tick,
            send=self._send,
            stop_wheels=self._stop_wheels,
            offline=lambda: self.scripted.offline,
            guard=self.guard,
        )
        # lockstep: what the tick thread publishes under the guard waits here and is put after
        # it lets go (PlantNode._emit)
        self._outbox: list[tuple[str, bytes, rt.QoS]] | None = None
        # (lockstep: each robot's truth and pose only while ``wanted`` says someone reads it)
        self.outputs = PlantOutputs(
            self.ids,
            self.fleet,
            self._emit,
            batch=batch,
            poses=poses,
            lockstep=lockstep,
            wanted=wanted,
        )

    # -- bookkeeping ---------------------------------------------------------------------------

    def _now(self) -> float:
        return self.sim_t if self.lockstep else time.monotonic()

    @property
    def rejects(self) -> RejectCounts:
        """Inputs rejected so far, by ``<message>-<reason>`` (status ``rejects``)."""
        return self.faults.rejects

    @property
    def rejected(self) -> int:
        """Inputs rejected so far."""
        return self.faults.rejected

    @property
    def internal_errors(self) -> int:
        """Internal errors caught by the handlers and loops."""
        return self.faults.internal_errors

    def _send(self, i: int, cmd: LinkCmd, pose_t: float | None, rx_s: float) -> None:
        """Realtime: robot ``i``'s command into the link now (PlantInputs)."""
        if self.sim is not None:
            self.sim.link.send(rx_s, i, cmd)
            self.outputs.command_answered(i, pose_t, rx_s)

    def _stop_wheels(self, i: int) -> None:
        """Robot ``i``'s agent is gone (PlantInputs.drop_agent): its wheels stop at once."""
        self.applied[i] = 0.0

    def build(self, t0_s: float) -> _Sim:
        """Build plant, camera, link and monitor as formation/sim/simulate.py does, at ``t0_s``."""
        plant, camera, link, monitor = plant_models(self.scenario, self.rng, t0_s)
        self.sim = _Sim(plant, camera, link, monitor, t0_s)
        cfg = self.scenario.plant
        if self.lockstep and cfg.encoder_counts_per_rev > 0.0:  # after the models: same draws
            self.encoders = WheelEncoders(
                self.n, cfg.encoder_counts_per_rev, cfg.encoder_slip_std, self.rng
            )
        return self.sim

    def _apply_disturbances(self, sim: _Sim, t_s: float) -> None:
        """Scheduled disturbances due at ``t_s`` (simulator's rule), then those from the bus."""
        plant = sim.plant
        elapsed = t_s - sim.t0_s
        while self.scheduled and self.scheduled[0].t_s <= elapsed + 1e-9:
            d = self.scheduled.popleft()
            i = self.index[d.robot]
            try:
                apply_scheduled(plant, i, d, sim.camera, sim.t0_s)
                self.log.info(f"t={t_s:.3f} s: scheduled {d.kind} of {d.robot}")
            except (ValueError, IndexError) as exc:
                self.faults.internal("scheduled disturbance", exc)
        bus = self.inputs.bus_disturbances
        while bus:
            m = bus.popleft()
            i = self.index[m.robot]
            try:
                if m.kind == _DRAG:
                    plant.drag(i, m.dx, m.dy, m.duration_s)
                else:
                    assert m.x is not None and m.y is not None  # the schema's RequiredWhen rule
                    plant.teleport(i, m.x, m.y, m.theta)
                self.log.info(f"t={t_s:.3f} s: {m.kind} of {m.robot} from the bus")
            except (ValueError, IndexError) as exc:
                self.faults.reject("disturbance", str(exc))

    def sense(self, sim: _Sim, t_s: float) -> npt.NDArray[np.float64]:
        """Lockstep tick: publish truth (every tick, so a collector's rows are the simulator's
        ticks), capture a frame if due, publish the frames due; returns truth."""
        truth = sim.plant.truth
        self.outputs.publish_truth(t_s, truth)
        if self.encoders is not None:  # mean wheel speeds over the last tick, as measured
            self.clock_enc = self.encoders.read(t_s, sim.plant.wheel_angles())
        sim.camera.capture(t_s, truth)
        self.outputs.publish_due_frames(sim.camera, t_s)
        return truth

    def _deliver(self, sim: _Sim, t_s: float) -> None:
        gen = self.inputs.generation
        for i, (g, wr, wl) in sim.link.poll(t_s):
            if g == gen[i]:
                self.applied[i, 0] = wr
                self.applied[i, 1] = wl

    def on_fault(self, rx: rt.Received) -> None:
        """A scripted fault's notice (sim_plant.node.faults); never raises."""
        with self.guard:
            try:
                self.scripted.on_fault(self, rx.payload)
                self.inputs.wake.set()  # (a robot kept out may be the answer the wait lacks)
            except Exception as exc:
                self.faults.internal("on_fault", exc)

    # -- lockstep ------------------------------------------------------------------------------

    def _emit(self, key: str, payload: bytes, qos: rt.QoS) -> None:
        """Publish now, or (the lockstep tick thread, holding the guard) once it let go of it:
        a lockstep put blocks while Zenoh's queue is full, and the thread that empties the
        queue may be the one waiting for the guard in an input handler (``formation up
        --lockstep`` runs Zenoh on one thread, ``runtime.transport.LOCKSTEP_ZENOH_RUNTIME``)."""
        outbox = self._outbox
        if outbox is None:
            self._publish(key, payload, qos)
        else:
            outbox.append((key, payload, qos))

    @contextlib.contextmanager
    def _guarded(self) -> Iterator[None]:
        """The tick thread's work under the guard; what it emits then is put, in order, once
        the guard is let go (dropped if the work raised)."""
        outbox: list[tuple[str, bytes, rt.QoS]] = []
        with self.guard:
            self._outbox = outbox
            try:
                yield
            finally:
                self._outbox = None
        for key, payload, qos in outbox:
            self._publish(key, payload, qos)

    def _publish_clock(self, k: int, t_s: float) -> None:
        enc = self.clock_enc
        if enc is None:
            robots = wr = wl = None
        else:  # the encoder readings of this tick (within a list's bound)
            m = min(self.n, MAX_LIST_LEN)
            robots = tuple(self.ids[:m])
            wr = tuple(float(e[0]) for e in enc[:m])
            wl = tuple(float(e[1]) for e in enc[:m])
        msg = Clock(
            t=t_s,
            seq=self.outputs.next_seq(self.clock_key),
            tick=k,
            tracking=self.clock_tracking,
            **_claim_fields(self.clock_claims),
            enc_robots=robots,
            enc_wr=wr,
            enc_wl=wl,
        )
        self._emit(self.clock_key, encode(msg), rt.QOS_CRITICAL)

    def _wait_answers(self, k: int, t_s: float) -> bool:
        """Until tick ``k``'s answers are in (or the timeout: counted, lost agents dropped),
        announcing the clock again every :data:`REANNOUNCE_S`; False when halted. The tick
        thread sleeps without the guard; :attr:`PlantInputs.wake` wakes it."""
        inputs, guard, wake = self.inputs, self.guard, self.inputs.wake
        start = time.monotonic()
        deadline = start + self.lockstep_timeout_s
        next_announce = start + REANNOUNCE_S
        while True:
            with guard:
                if inputs.answered(k):
                    return True
            if self.halt.is_set():
                return False
            now = time.monotonic()
            if now >= deadline:
                with guard:
                    self.timeouts += 1
                    missing = inputs.missing(k)
                    self.log.limited(
                        "timeout",
                        f"tick {k}: no answer from {', '.join(missing)} within "
                        f"{self.lockstep_timeout_s:g} s; going on ({self.timeouts} timeouts)",
                    )
                    inputs.drop_lost(missing)
                return True
            if now >= next_announce:
                with self._guarded():
                    self._publish_clock(k, t_s)
                next_announce = now + REANNOUNCE_S
            wake.wait(min(deadline, next_announce) - now)
            wake.clear()  # (then answered() again: a wake after the wait is not lost)

    def run_lockstep_blocking(self) -> bool:
        """The lockstep loop, on the calling thread until the duration or :attr:`halt`; True
        when ``--duration`` ended it."""
        guard = self.guard
        with guard:
            sim = self.build(0.0)
        dt = self.scenario.dt_s
        ticks = None if self.duration_s is None else round(self.duration_s / dt) + 1
        k = 0
        while not self.halt.is_set() and (ticks is None or k < ticks):
            try:
                with self._guarded():  # (truth, frames, clock: put after the guard)
                    t = tick_time(k, dt)
                    self.tick = k
                    self.sim_t = t
                    self.scripted.apply_tick(self, sim, k, t)
                    self._apply_disturbances(sim, t)
                    truth = self.sense(sim, t)
                    self.clock_tracking = self.inputs.tracking_answers(k - 1)
                    self.clock_claims = self.inputs.claim_answers(k - 1)
                    self._publish_clock(k, t)
                if not self._wait_answers(k, t):
                    break
                with guard:
                    gen, cmd = self.inputs.generation, self.inputs.last_cmd
                    for i in range(self.n):
                        sim.link.send(t, i, (gen[i], float(cmd[i, 0]), float(cmd[i, 1])))
                    self._deliver(sim, t)
                    sim.monitor.update(t, truth)
                    sim.plant.step(dt, self.applied)
            except Exception as exc:  # a bug: log it, keep the clock going
                with guard:
                    self.faults.internal("lockstep tick", exc)
            k += 1
        return ticks is not None and k >= ticks

    async def run_lockstep(self, stop: asyncio.Event) -> bool:
        """The lockstep loop on a thread of its own (:meth:`run_lockstep_blocking`) while the
        event loop serves the rest; ``stop`` halts it. True when ``--duration`` ended it."""
        relay = asyncio.ensure_future(self._wake_on_stop(stop))
        try:
            return await asyncio.to_thread(self.run_lockstep_blocking)
        finally:
            relay.cancel()
            self.halt.set()  # (cancelled: the thread ends at its next look)
            self.inputs.wake.set()

    # -- realtime ------------------------------------------------------------------------------

    async def run_realtime(self, stop: asyncio.Event) -> bool:
        """The realtime loop; True when ``--duration`` ended it."""
        t0 = time.monotonic()
        sim = self.build(t0)
        end = math.inf if self.duration_s is None else t0 + self.duration_s
        period = self.physics_period_s
        next_phys = t0
        latency = sim.camera.latency_s
        deliveries: deque[float] = deque()
        while not stop.is_set():
            now = time.monotonic()
            if now >= end:
                return True
            try:
                self.sim_t = now
                if now > sim.plant.t_s:
                    sim.plant.step(now - sim.plant.t_s, self.applied)
                self._apply_disturbances(sim, now)
                self._deliver(sim, now)
                truth = sim.plant.truth
                if sim.camera.capture(now, truth):
                    self.outputs.publish_truth(now, truth)
                    deliveries.append(now + latency)
                self.outputs.publish_due_frames(sim.camera, now)
                while deliveries and deliveries[0] <= now + 1e-9:
                    deliveries.popleft()
                if now >= next_phys:
                    sim.monitor.update(now, truth)
                    self.tick += 1
                    next_phys += period
                    if next_phys <= now:
                        next_phys = now + period
            except Exception as exc:
                self.faults.internal("realtime step", exc)
                next_phys = time.monotonic() + period
            wake = min(next_phys, sim.camera.next_frame_t, end)
            if deliveries:
                wake = min(wake, deliveries[0])
            await asyncio.sleep(max(0.0, wake - time.monotonic()))
        return False

    # -- start, status -------------------------------------------------------------------------

    async def wait_for_fleet(self, stop: asyncio.Event, timeout_s: float = WAIT_ROBOTS_S) -> bool:
        """Until every scenario robot's token and a coordinator's are present; False on timeout."""
        inputs = self.inputs
        start = time.monotonic()
        said = ""
        while not stop.is_set():
            missing = [r for r in self.ids if r not in inputs.alive]
            if not inputs.coordinators:
                missing.append("a coordinator")
            if not missing:
                self.log.info("every robot and a coordinator are alive: starting")
                return True
            text = ", ".join(missing)
            if text != said:
                self.log.info(f"waiting for {text} (up to {timeout_s:g} s)")
                said = text
            remaining = start + timeout_s - time.monotonic()
            if remaining <= 0:
                self.log.info(f"gave up after {timeout_s:g} s: still no {text}")
                return False
            inputs.changed.clear()
            try:
                async with asyncio.timeout(min(remaining, 0.5)):
                    await inputs.changed.wait()
            except TimeoutError:
                pass
        return False

    def status(self) -> PlantStatus:
        """The status message (bus_schemas.PlantStatus)."""
        sim = self.sim
        min_sep = sim.monitor.min_separation_m if sim is not None else math.inf
        return PlantStatus(
            t=max(self._now(), 0.0),
            seq=self.outputs.next_seq(self.status_key),
            mode="lockstep" if self.lockstep else "realtime",
            state=self.state,
            tick=max(self.tick, 0),
            sim_t=self.sim_t - (sim.t0_s if sim is not None else 0.0),
            timeouts=self.timeouts,
            alive=tuple(sorted(self.inputs.alive)),
            coordinators=tuple(sorted(self.inputs.coordinators)),
            link_sent=sim.link.sent if sim is not None else 0,
            link_dropped=sim.link.dropped if sim is not None else 0,
            min_separation_m=min_sep if math.isfinite(min_sep) else None,
            collisions=sim.monitor.collision_count if sim is not None else 0,
            frames=self.outputs.frames_published,
            batch=self.batch,
            ignored=self.inputs.ignored,
            rejected=self.rejected,
            rejects=self.rejects.as_dict(),
            internal_errors=self.internal_errors,
            rx=dict(self.inputs.rx),
        )

    def status_map(self) -> dict[str, Any]:
        """The status as its wire map (what :meth:`publish_status` encodes)."""
        return to_map(self.status())

    def publish_status(self) -> None:
        """Publish the status; never raises."""
        with self.guard:
            try:
                self._publish(self.status_key, encode(self.status()), rt.QOS_TELEMETRY)
            except Exception as exc:
                self.faults.internal("status", exc)

    async def status_loop(self, stop: asyncio.Event) -> None:
        """Publish the status at 5 Hz until ``stop``."""
        while not stop.is_set():
            self.publish_status()
            await asyncio.sleep(STATUS_PERIOD_S)

    async def run(self, stop: asyncio.Event, wait_robots: bool) -> int:
        """Wait for the fleet (optionally), run until stop or the duration; exit status."""
        status = asyncio.ensure_future(self.status_loop(stop))
        relay = asyncio.ensure_future(self._wake_on_stop(stop))
        try:
            if wait_robots and not await self.wait_for_fleet(stop):
                return 0 if stop.is_set() else 1
            if stop.is_set():
                return 0
            self.state = "running"
            self.log.info(
                f"running {'lockstep' if self.lockstep else 'realtime'}, "
                f"{self.n} robots, seed {self.seed}"
            )
            finished = (
                await self.run_lockstep(stop) if self.lockstep else await self.run_realtime(stop)
            )
            if finished:
                self.state = "done"
                self.publish_status()
                self.log.info(
                    f"done: {self.tick + 1} ticks, {self.timeouts} lockstep timeouts, "
                    f"{self.faults.rejected} rejected"
                )
            return 0
        finally:
            status.cancel()
            relay.cancel()

    async def _wake_on_stop(self, stop: asyncio.Event) -> None:
        """On SIGINT/SIGTERM: halt the lockstep thread, wake the waits (answers, fleet)."""
        await stop.wait()
        self.halt.set()
        self.inputs.touch()


def _claim_fields(
    claims: list[tuple[str, tuple[float, float, float, float, float]]],
) -> dict[str, Any]:
    """``Clock``'s ``claim_*`` columns of the relayed claims (none: the fields absent)."""
    if not claims:
        return {}
    cols = list(zip(*(c for _, c in claims), strict=True))
    return {
        "claim_robots": tuple(rid for rid, _ in claims),
        "claim_t": tuple(cols[0]),
        "claim_ux": tuple(cols[1]),
        "claim_uy": tuple(cols[2]),
        "claim_w": tuple(cols[3]),
        "claim_accel": tuple(cols[4]),
    }
