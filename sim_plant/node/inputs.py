"""The plant process's inputs: wheel commands, disturbances, liveliness, the lockstep leader.

:class:`PlantInputs` is a part the plant (:class:`sim_plant.node.plant.PlantNode`) builds and owns:
it keeps what arrived (the latest command of each robot, the lockstep answers, who is alive, the
disturbances from the bus) and tells the node through the callables it is given. Each handler
decodes, counts a bad message and ignores it, and never raises; it holds the node's guard while
it runs (a lockstep plant takes its answers on Zenoh's thread and ticks on a thread of its own,
:class:`sim_plant.node.plant.PlantNode`). A robot whose
agent token disappears has its wheels set to zero at once and the commands still in flight for it
are discarded.
"""

from __future__ import annotations

import asyncio
import contextlib
import threading
from collections import deque
from collections.abc import Callable, Collection, Sequence
from typing import Any, Final

import numpy as np
import numpy.typing as npt

import runtime as rt
from bus_schemas import (
    MAX_LIST_LEN,
    DecodeError,
    Disturbance,
    Leader,
    Wheels,
    WheelsBatch,
    decode,
    keys,
)

__all__ = ["ARENA_LIMIT_M", "MAX_DRAG_S", "LinkCmd", "PlantInputs"]

ARENA_LIMIT_M: Final = 1000.0
"""A disturbance moving a robot (or by) more than this (m) is rejected as absurd."""
MAX_DRAG_S: Final = 3600.0
_DRAG: Final = "drag"

# Per-robot command in the link: (generation, omega_r, omega_l). The generation of a robot is
# bumped when its agent dies, so commands sent before that are discarded on delivery.
LinkCmd = tuple[int, float, float]


class PlantInputs:
    """What the plant received, and its input handlers.

    Args:
        ids: the simulated robots, in robot order (index ``i`` is ``ids[i]``).
        lockstep: a command is kept for the end of the tick it answers (else: sent now).
        faults: the node's counters (``runtime.faults.Faults``).
        current_tick: the tick the plant waits answers for (lockstep).
        send: realtime, a valid command of robot ``i``: ``send(i, command, pose_t, rx_s)``
            (the frame stamp it was computed from, if any, and its receive time).
        stop_wheels: robot ``i``'s agent is gone: its applied wheel speeds go to zero.
        offline: the robots a scripted fault keeps out (sim_plant.node.faults): not waited for.
        guard: held by every handler while it runs (the node's lock; none by default).
    """

    def __init__(
        self,
        ids: Sequence[str],
        *,
        lockstep: bool,
        faults: rt.Faults,
        current_tick: Callable[[], int],
        send: Callable[[int, LinkCmd, float | None, float], None],
        stop_wheels: Callable[[int], None],
        offline: Callable[[], Collection[str]] = tuple,
        guard: contextlib.AbstractContextManager[Any] | None = None,
    ) -> None:
        self.ids = list(ids)
        self._guard = guard if guard is not None else contextlib.nullcontext()
        self._offline = offline  # robots a scripted fault keeps out (no answer awaited)
        self.index = {rid: i for i, rid in enumerate(self.ids)}
        n = len(self.ids)
        self.lockstep = lockstep
        self._faults = faults
        self._log = faults.log
        self._current_tick = current_tick
        self._send = send
        self._stop_wheels = stop_wheels
        self.alive: set[str] = set()
        self.lost: set[str] = set()  # lockstep: token gone, still waited for
        self.coordinators: set[str] = set()
        self.last_cmd: npt.NDArray[np.float64] = np.zeros((n, 2))
        self.generation = [0] * n
        self.answer_tick: list[int | None] = [None] * n
        # lockstep: the answer's mode was TRACKING (Wheels.mode); relayed in the next clock
        self.answer_tracking: list[bool] = [False] * n
        # lockstep: the answer's motion claim (Wheels t, ux, uy, w, accel); relayed likewise
        self.answer_claim: list[tuple[float, float, float, float, float] | None] = [None] * n
        self.leader_tick: int | None = None
        self.bus_disturbances: deque[Disturbance] = deque(maxlen=64)
        self.changed = asyncio.Event()  # a token, anything the event loop's waits look at
        # the lockstep tick thread's wake (thread-safe): a tick's last answer, a token, a notice
        self.wake = threading.Event()
        self.ignored = 0  # valid messages for robots this plant does not simulate
        self.rx: dict[str, int] = {
            "wheels": 0, "host_wheels": 0, "disturbance": 0, "leader": 0, "alive": 0,
        }  # fmt: skip

    # -- lockstep answers ----------------------------------------------------------------------

    def answered(self, k: int) -> bool:
        """Every live agent answered tick ``k`` and, if a coordinator is alive, its leader."""
        off = self._offline()
        for rid in self.alive:
            if self.answer_tick[self.index[rid]] != k and rid not in off:
                return False
        return not self.coordinators or self.leader_tick == k

    def missing(self, k: int) -> list[str]:
        """Who has not answered tick ``k``: live robots in id order, then ``"coordinator"``."""
        off = self._offline()
        out = [
            r for r in sorted(self.alive) if self.answer_tick[self.index[r]] != k and r not in off
        ]
        if self.coordinators and self.leader_tick != k:
            out.append("coordinator")
        return out

    def tracking_answers(self, k: int) -> tuple[str, ...]:
        """The robots whose answer to tick ``k`` said TRACKING (in robot order), what clock
        ``k + 1`` relays so every agent knows which neighbours were cooperative
        (``robot_agent.core.neighbours``, rule 3); at most a list's bound."""
        tick = self.answer_tick
        tr = self.answer_tracking
        out = tuple(rid for i, rid in enumerate(self.ids) if tr[i] and tick[i] == k)
        return out[:MAX_LIST_LEN]

    def claim_answers(self, k: int) -> list[tuple[str, tuple[float, float, float, float, float]]]:
        """The motion claims of the answers to tick ``k`` (in robot order, at most a list's
        bound), what clock ``k + 1`` relays (``robot_agent.core.neighbours``, rule 4)."""
        tick = self.answer_tick
        out = [
            (rid, c)
            for i, (rid, c) in enumerate(zip(self.ids, self.answer_claim, strict=True))
            if c is not None and tick[i] == k
        ]
        return out[:MAX_LIST_LEN]

    def touch(self) -> None:
        """A token came or went: wake the event loop's wait for the fleet and the lockstep
        thread's wait for the answers. On the loop only."""
        self.changed.set()
        self.wake.set()

    # -- inputs --------------------------------------------------------------------------------

    def on_alive_robot(self, key: str, alive: bool) -> None:
        """An agent token appeared or vanished; a vanished agent's wheels stop at once."""
        with self._guard:
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
                        self._log.info(f"robot {rid}'s token is gone (lockstep: still waited for)")
                elif rid in self.alive:
                    self.drop_agent(rid)
                self.touch()
            except Exception as exc:
                self._faults.internal("on_alive_robot", exc)

    def drop_agent(self, rid: str) -> None:
        """Robot ``rid``'s agent is gone: its wheels stop and nobody waits for it."""
        i = self.index[rid]
        self.alive.discard(rid)
        self.lost.discard(rid)
        self.generation[i] += 1  # commands in flight for it are discarded
        self.last_cmd[i] = 0.0
        self._stop_wheels(i)
        self.answer_tick[i] = None
        self._log.info(f"robot {rid}'s agent is gone: its wheels stop")

    def drop_lost(self, missing: list[str]) -> None:
        """Lockstep timeout: the robots of ``missing`` whose token is gone are dropped."""
        for rid in missing:
            if rid in self.lost:
                self.drop_agent(rid)

    def on_alive_coordinator(self, key: str, alive: bool) -> None:
        """A coordinator token appeared or vanished."""
        with self._guard:
            try:
                self.rx["alive"] += 1
                parsed = keys.parse_alive_key(key)
                if parsed is None or parsed[1] != "coordinator" or parsed[2] is None:
                    return
                if alive:
                    self.coordinators.add(parsed[2])
                else:
                    self.coordinators.discard(parsed[2])
                self.touch()
            except Exception as exc:
                self._faults.internal("on_alive_coordinator", exc)

    def on_wheels(self, rx: rt.Received) -> None:
        """A wheel command: into the link now (realtime) or at the tick's end (lockstep)."""
        with self._guard:
            try:
                self.rx["wheels"] += 1
                parsed = keys.parse_robot_key(rx.key)
                if parsed is None or parsed[2] != keys.WHEELS:
                    self._faults.reject("wheels", f"not a wheels key: {rx.key[:100]!r}")
                    return
                msg = decode(rx.payload, Wheels)
                if isinstance(msg, DecodeError):
                    self._faults.reject("wheels", msg)
                    return
                i = self.index.get(parsed[1])
                if i is None:
                    self.ignored += 1
                    return
                tracking = msg.mode == "tracking"
                claim = None
                if msg.ux is not None and msg.uy is not None and msg.w is not None:
                    claim = (msg.t, msg.ux, msg.uy, msg.w, msg.accel or 0.0)
                self._command(
                    i, msg.omega_r, msg.omega_l, msg.tick, msg.pose_t, rx.rx_s, tracking, claim
                )
            except Exception as exc:
                self._faults.internal("on_wheels", exc)

    def on_host_wheels(self, rx: rt.Received) -> None:
        """An agent host's batch of wheel commands: each entry as a ``robot/<id>/wheels``."""
        with self._guard:
            try:
                self.rx["host_wheels"] += 1
                msg = decode(rx.payload, WheelsBatch)
                if isinstance(msg, DecodeError):
                    self._faults.reject("host wheels", msg)
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
                    self._command(i, wr, wl, msg.tick, p_t, rx.rx_s, tracking, notify=False)
                if self.lockstep and msg.tick == self._current_tick():
                    self._notify_if_answered(msg.tick)  # once for the batch
            except Exception as exc:
                self._faults.internal("on_host_wheels", exc)

    def _notify_if_answered(self, k: int) -> None:
        """Lockstep: wake the plant's wait for tick ``k``'s answers once they are all in, not
        at every answer (each wake was a turn of its task: a timeout armed and cancelled,
        :meth:`answered` again). What else can end the wait (a token gone, a scripted fault)
        calls :meth:`touch` itself. Called on Zenoh's thread in lockstep: it sets only the
        thread-safe :attr:`wake`."""
        if self.answered(k):
            self.wake.set()

    def _command(
        self,
        i: int,
        wr: float,
        wl: float,
        tick: int | None,
        pose_t: float | None,
        rx_s: float,
        tracking: bool = False,
        claim: tuple[float, float, float, float, float] | None = None,
        *,
        notify: bool = True,
    ) -> None:
        """Robot ``i``'s command: into the link now (realtime) or at the tick's end (lockstep);
        ``tracking``: the command said mode TRACKING (relayed in the next clock); ``notify``:
        wake the answer wait if this completes the tick (a batch does it once, at its end)."""
        self.last_cmd[i] = (wr, wl)
        if self.lockstep:
            if tick is not None:
                self.answer_tick[i] = tick
                self.answer_tracking[i] = tracking
                self.answer_claim[i] = claim
                if notify and tick == self._current_tick():
                    self._notify_if_answered(tick)
        else:
            self._send(i, (self.generation[i], wr, wl), pose_t, rx_s)

    def on_leader(self, rx: rt.Received) -> None:
        """Lockstep: the coordinator's leader message closes its answer to a tick."""
        with self._guard:
            try:
                self.rx["leader"] += 1
                msg = decode(rx.payload, Leader)
                if isinstance(msg, DecodeError):
                    self._faults.reject("leader", msg)
                    return
                tick = msg.tick
                if tick is None:
                    self._faults.reject("leader", "lockstep leader without a valid tick")
                    return
                self.leader_tick = tick
                if tick == self._current_tick():
                    self._notify_if_answered(tick)
            except Exception as exc:
                self._faults.internal("on_leader", exc)

    def on_disturbance(self, rx: rt.Received) -> None:
        """Drag or teleport a robot at the next physics step."""
        with self._guard:
            try:
                self.rx["disturbance"] += 1
                msg = decode(rx.payload, Disturbance)
                if isinstance(msg, DecodeError):
                    self._faults.reject("disturbance", msg)
                    return
                if msg.robot not in self.index:
                    self.ignored += 1
                    return
                lim = ARENA_LIMIT_M
                values = (msg.dx, msg.dy, msg.x or 0.0, msg.y or 0.0)
                if any(abs(v) > lim for v in values) or msg.duration_s > MAX_DRAG_S:
                    self._faults.reject("disturbance", f"beyond {lim} m or {MAX_DRAG_S} s")
                    return
                self.bus_disturbances.append(msg)
            except Exception as exc:
                self._faults.internal("on_disturbance", exc)
