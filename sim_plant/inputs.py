"""The plant process's inputs: wheel commands, disturbances, liveliness, the lockstep leader.

:class:`PlantInputs` holds the input handlers of :class:`sim_plant.node.PlantNode` (which sets
every attribute declared here): each decodes on the event loop, counts a bad message in
``faults`` (:class:`runtime.Faults`) and ignores it, and never raises. A robot whose agent
token disappears has its wheels set to zero at once and the commands still in flight for it are
discarded.
"""

from __future__ import annotations

import asyncio
from collections import deque
from dataclasses import dataclass
from typing import Final

import numpy as np
import numpy.typing as npt

import runtime as rt
from bus_schemas import (
    DecodeError,
    Disturbance,
    Leader,
    Wheels,
    WheelsBatch,
    decode,
    keys,
)
from sim_plant.accounting import SeparationMonitor
from sim_plant.plant import Plant
from sim_plant.sensors import Camera, CommandLink

__all__ = ["ARENA_LIMIT_M", "MAX_DRAG_S", "LinkCmd", "PlantInputs"]

ARENA_LIMIT_M: Final = 1000.0
"""A disturbance moving a robot (or by) more than this (m) is rejected as absurd."""
MAX_DRAG_S: Final = 3600.0
_DRAG: Final = "drag"

# Per-robot command in the link: (generation, omega_r, omega_l). The generation of a robot is
# bumped when its agent dies, so commands sent before that are discarded on delivery.
LinkCmd = tuple[int, float, float]


@dataclass
class _Sim:
    """The numpy cores of one run (built when the run starts: realtime needs its t0)."""

    plant: Plant
    camera: Camera
    link: CommandLink[LinkCmd]
    monitor: SeparationMonitor
    t0_s: float


class PlantInputs:
    """Input handlers of the plant node (state lives in :class:`sim_plant.node.PlantNode`)."""

    lockstep: bool
    log: rt.NodeLog
    index: dict[str, int]
    sim: _Sim | None
    alive: set[str]
    lost: set[str]
    coordinators: set[str]
    last_cmd: npt.NDArray[np.float64]
    applied: npt.NDArray[np.float64]
    generation: list[int]
    answer_tick: list[int | None]
    answer_tracking: list[bool]
    leader_tick: int | None
    bus_disturbances: deque[Disturbance]
    changed: asyncio.Event
    faults: rt.Faults
    ignored: int
    rx: dict[str, int]
    tick: int
    latencies_s: deque[float]
    latency_pub_s: deque[float]
    _frame_pub: dict[float, float]
    _answered: list[float | None]

    def _reject(self, what: str, why: DecodeError | str) -> None:
        """Count a dropped ``what`` message (``rejected``, and by ``<what>-<reason>`` in
        ``rejects``: a DecodeError's reason, else ``invalid``) and log it (rate limited)."""
        self.faults.reject(what, why)

    def _internal(self, where: str, exc: BaseException) -> None:
        self.faults.internal(where, exc)

    # -- inputs --------------------------------------------------------------------------------

    def on_alive_robot(self, key: str, alive: bool) -> None:
        """An agent token appeared or vanished; a vanished agent's wheels stop at once."""
        try:
            self.rx["alive"] += 1
            parsed = keys.parse_alive_key(key)
            if parsed is None or parsed[2] is None or parsed[2] not in self.index:
                return
            rid = parsed[2]
            if alive:
                self.alive.add(rid)
                self.lost.discard(rid)
            elif rid in self.alive and self.lockstep:
                # A fault event only (issue 13 item 7): a lease is wall-clock time, and an agent
                # paused past it under load still answers this tick when it resumes, so the
                # plant keeps waiting for it; only a lost agent that misses the lockstep timeout
                # is dropped (drop_lost), so the result is that of the unpaused run.
                if rid not in self.lost:
                    self.lost.add(rid)
                    self.log.info(f"robot {rid}'s token is gone (lockstep: still waited for)")
            elif rid in self.alive:
                self.drop_agent(rid)
            self.changed.set()
        except Exception as exc:
            self._internal("on_alive_robot", exc)

    def drop_agent(self, rid: str) -> None:
        """Robot ``rid``'s agent is gone: its wheels stop and nobody waits for it."""
        i = self.index[rid]
        self.alive.discard(rid)
        self.lost.discard(rid)
        self.generation[i] += 1  # commands in flight for it are discarded
        self.last_cmd[i] = 0.0
        self.applied[i] = 0.0
        self.answer_tick[i] = None
        self.log.info(f"robot {rid}'s agent is gone: its wheels stop")

    def drop_lost(self, missing: list[str]) -> None:
        """Lockstep timeout: the robots of ``missing`` whose token is gone are dropped."""
        for rid in missing:
            if rid in self.lost:
                self.drop_agent(rid)

    def on_alive_coordinator(self, key: str, alive: bool) -> None:
        """A coordinator token appeared or vanished."""
        try:
            self.rx["alive"] += 1
            parsed = keys.parse_alive_key(key)
            if parsed is None or parsed[1] != "coordinator" or parsed[2] is None:
                return
            if alive:
                self.coordinators.add(parsed[2])
            else:
                self.coordinators.discard(parsed[2])
            self.changed.set()
        except Exception as exc:
            self._internal("on_alive_coordinator", exc)

    def on_wheels(self, rx: rt.Received) -> None:
        """A wheel command: into the link now (realtime) or at the tick's end (lockstep)."""
        try:
            self.rx["wheels"] += 1
            parsed = keys.parse_robot_key(rx.key)
            if parsed is None or parsed[2] != keys.WHEELS:
                self._reject("wheels", f"not a wheels key: {rx.key[:100]!r}")
                return
            msg = decode(rx.payload, Wheels)
            if isinstance(msg, DecodeError):
                self._reject("wheels", msg)
                return
            i = self.index.get(parsed[1])
            if i is None:
                self.ignored += 1
                return
            tracking = msg.mode == "tracking"
            self._command(i, msg.omega_r, msg.omega_l, msg.tick, msg.pose_t, rx.rx_s, tracking)
        except Exception as exc:
            self._internal("on_wheels", exc)

    def on_host_wheels(self, rx: rt.Received) -> None:
        """An agent host's batch of wheel commands: each entry as a ``robot/<id>/wheels``."""
        try:
            self.rx["host_wheels"] += 1
            msg = decode(rx.payload, WheelsBatch)
            if isinstance(msg, DecodeError):
                self._reject("host wheels", msg)
                return
            index = self.index
            rows = zip(msg.robots, msg.omega_r, msg.omega_l, msg.pose_t, strict=True)
            modes = msg.mode
            for j, (rid, wr, wl, pose_t) in enumerate(rows):
                i = index.get(rid)
                if i is None:
                    self.ignored += 1
                    continue
                tracking = modes is not None and modes[j] == "tracking"
                p_t = pose_t if pose_t >= 0.0 else None
                self._command(i, wr, wl, msg.tick, p_t, rx.rx_s, tracking)
        except Exception as exc:
            self._internal("on_host_wheels", exc)

    def _command(
        self,
        i: int,
        wr: float,
        wl: float,
        tick: int | None,
        pose_t: float | None,
        rx_s: float,
        tracking: bool = False,
    ) -> None:
        """Robot ``i``'s command: into the link now (realtime) or at the tick's end (lockstep);
        ``tracking``: the command said mode TRACKING (relayed in the next clock)."""
        self.last_cmd[i] = (wr, wl)
        if self.lockstep:
            if tick is not None:
                self.answer_tick[i] = tick
                self.answer_tracking[i] = tracking
                if tick == self.tick:
                    self.changed.set()
        elif self.sim is not None:
            self.sim.link.send(rx_s, i, (self.generation[i], wr, wl))
            if pose_t is not None and pose_t != self._answered[i]:
                published = self._frame_pub.get(pose_t)
                if published is not None:  # the first command computed from this frame
                    self._answered[i] = pose_t
                    self.latencies_s.append(rx_s - published)
                    self.latency_pub_s.append(published)

    def on_leader(self, rx: rt.Received) -> None:
        """Lockstep: the coordinator's leader message closes its answer to a tick."""
        try:
            self.rx["leader"] += 1
            msg = decode(rx.payload, Leader)
            if isinstance(msg, DecodeError):
                self._reject("leader", msg)
                return
            tick = msg.tick
            if tick is None:
                self._reject("leader", "lockstep leader without a valid tick")
                return
            self.leader_tick = tick
            if tick == self.tick:
                self.changed.set()
        except Exception as exc:
            self._internal("on_leader", exc)

    def on_disturbance(self, rx: rt.Received) -> None:
        """Drag or teleport a robot at the next physics step."""
        try:
            self.rx["disturbance"] += 1
            msg = decode(rx.payload, Disturbance)
            if isinstance(msg, DecodeError):
                self._reject("disturbance", msg)
                return
            if msg.robot not in self.index:
                self.ignored += 1
                return
            lim = ARENA_LIMIT_M
            values = (msg.dx, msg.dy, msg.x or 0.0, msg.y or 0.0)
            if any(abs(v) > lim for v in values) or msg.duration_s > MAX_DRAG_S:
                self._reject("disturbance", f"beyond {lim} m or {MAX_DRAG_S} s")
                return
            self.bus_disturbances.append(msg)
        except Exception as exc:
            self._internal("on_disturbance", exc)

    # -- the simulation ------------------------------------------------------------------------
