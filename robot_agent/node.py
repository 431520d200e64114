"""``formation agent``: the firmware of one robot as a process (a thin asyncio shell over Firmware).

Usage::

    formation agent --id r1 [--scenario NAME|FILE | --config ROBOT.toml] [--fleet demo]
                    [--lockstep] [--loop on-pose|fixed] [--rate-hz 50] [zenoh options]
    formation agent --check-config ROBOT.toml      # prints OK or the problems; exit 0 / 1

It prints exactly one line ``agent <id> ready`` on stdout once its Zenoh session is open, its
subscriptions are declared and its liveliness token ``formation/<fleet>/alive/robot/<id>`` is
declared; it exits 0 within a second of SIGINT/SIGTERM (``bus_schemas.transport.run_node``).

Theory of operation
-------------------
Inputs (``formation/<fleet>/...``), each decoded strictly *on the event loop* (the Zenoh
callback only hands the bytes over); every rejected message goes to ``Firmware.reject`` and shows
in ``status.rejected``, and is otherwise ignored:

* ``robot/<id>/pose``: own pose (axle centre); the newest arrival is used (its ``t`` is not
  compared with the previous one: a single bogus future stamp must not lock real poses out).
  A pose whose ``robot`` field names another robot is rejected.
* ``robot/<id>/setpoint``: own setpoint (where the reference point should be, eqs 10-11).
* ``poses``: batched poses of the fleet; the other robots' positions feed the repulsion (own
  entry ignored; entries older than :data:`NEIGHBOUR_STALE_S` dropped).
* ``estop``: ``robot`` nil (whole fleet) or this id: engage latches ``Firmware.engage_estop``
  (zero wheels at once in realtime), release calls ``release_estop``.
* ``clock`` (lockstep only).

Realtime (default): ``t`` on the bus and every receive time is this host's ``time.monotonic()``.
``--loop on-pose`` steps the firmware on every arrival of the own pose (lowest pose-to-wheels
latency) and, as a watchdog, on a ``--rate-hz`` timer whenever no step happened for one period,
so stale data drives HOLD (zero wheels) even when messages stop. ``--loop fixed`` steps on the
timer only. Every step publishes ``robot/<id>/wheels`` with ``pose_t`` = ``t`` of the pose the
firmware used (its last valid pose, also in HOLD/ESTOP); while it has used none (no setpoint
yet, so IDLE, or no pose yet) ``pose_t`` is nil, the contract's "no pose was used", and the
wheels are zero.

Lockstep (``--lockstep``, docs/runtime.md): the agent steps only on ``clock`` k, at
``now_s = clock.t``, with the latest pose (a pose received since the previous clock counts as
received at this clock's t, and so do the neighbours' batched poses) and the setpoint the
coordinator computed on tick k-1, exactly as ``formation/simulate.py`` does; it answers with
``wheels`` carrying ``tick: k``. The last two setpoints are kept because setpoint(k) may already
have arrived when clock k is handled. A setpoint carries its tick as the extra field ``tick``
(:func:`encode_ticked`; the bus contract allows added fields, and strict decoders ignore them).
If the coordinator did not send one for this robot on k-1 (robot unassigned, or the plant timed
out waiting for the coordinator) the firmware gets no setpoint and holds, which is what the
in-process simulator does for an unassigned robot. A repeated clock k (the plant re-announces it
while waiting) is answered with the same wheels message again, without stepping twice.

Outputs: ``wheels`` on every step; ``status`` at 5 Hz (mode, slot, pid, host, rejected, ex, ey,
role, robot and per-input receive counts ``rx``); the motor backend (``--config`` with
``[motor] backend = "roboclaw"``) gets every command through :class:`MotorOutput`, whose worker
thread keeps serial I/O off the event loop. ``sd_notify``: READY once connected, WATCHDOG from
the control loop (no-ops without ``$NOTIFY_SOCKET``).
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import math
import os
import socket
import sys
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final, Literal, Protocol

import msgpack
import zenoh

from bus_schemas import (
    Clock,
    DecodeError,
    Estop,
    Message,
    Pose,
    PoseBatch,
    Setpoint,
    Status,
    Wheels,
    decode,
    encode,
    keys,
    to_map,
)
from bus_schemas import transport as tp
from robot_agent.firmware import Firmware, WheelCommand
from robot_agent.firmware import Pose as FwPose
from robot_agent.firmware import Setpoint as FwSetpoint
from robot_agent.motors import MotorBackend, MotorStatus, create_backend
from robot_agent.params import AgentConfig
from robot_agent.sdnotify import Notifier

__all__ = [
    "NEIGHBOUR_STALE_S",
    "STATUS_PERIOD_S",
    "AgentNode",
    "MotorOutput",
    "NodeLog",
    "build_parser",
    "encode_ticked",
    "main",
    "payload_tick",
    "positive_rate",
    "run_timers",
    "subscribe_ordered",
]

STATUS_PERIOD_S: Final = 0.2
"""Status publication period (s): 5 Hz, the contract's minimum rate."""
NEIGHBOUR_STALE_S: Final = 1.0
"""A neighbour's batched pose older than this (s, receive time) no longer repels."""
MAX_NEIGHBOURS: Final = 1024
"""Distinct neighbour ids kept (a flood of made-up ids cannot grow memory without bound)."""
HANG_GAP_S: Final = 0.5
"""Realtime: the event loop idle for longer than this (s) means the process was stopped
(SIGSTOP, a swapped-out VM). Its loop turns at least every 1/rate_hz (20 ms at 50 Hz). With
``--lease-ms`` the limit is 0.9 lease: a shorter stop cannot have cost the robot its slot."""
RESUME_QUARANTINE_S: Final = 0.25
"""After such a stop, setpoints and poses received during this long (s) are dropped: they are the
backlog queued while the process was stopped, stamped with fresh receive times on delivery, and
the setpoint may be for a slot another robot took meanwhile (issue 4: a resumed robot must not
fight the one that took its slot). The firmware holds until fresh data arrives."""
TICK_FIELD: Final = "tick"
"""Extra wire field carrying the lockstep tick on setpoint, slot and leader messages."""
_TICK_MAX: Final = 2**64 - 1

LoopMode = Literal["on-pose", "fixed"]


# ---------------------------------------------------------------------------------------------
# Helpers shared by the three node shells (agent, coordinator, plant)
# ---------------------------------------------------------------------------------------------


def encode_ticked(msg: Message, tick: int | None) -> bytes:
    """Encode ``msg`` (validated like ``bus_schemas.encode``) plus, if ``tick`` is not None, the
    extra field ``tick`` (the lockstep clock tick the message answers).

    Only for message types without a ``tick`` field of their own (setpoint, slot, leader); the
    contract allows added fields and every strict decoder ignores unknown ones.
    """
    if tick is None:
        return encode(msg)
    if type(tick) is not int or not 0 <= tick <= _TICK_MAX:
        raise ValueError(f"tick must be an int in [0, 2^64-1], got {tick!r}")
    obj = to_map(msg)
    if TICK_FIELD in obj:
        raise ValueError(f"{type(msg).__name__} has its own {TICK_FIELD!r} field")
    obj[TICK_FIELD] = tick
    data: bytes = msgpack.packb(obj, use_bin_type=True)
    return data


def payload_tick(payload: bytes) -> int | None:
    """The ``tick`` extra field of a payload that already decoded cleanly, or None.

    None when absent or not an int in [0, 2^64-1] (bool is not an int). Never raises.
    """
    try:
        obj = msgpack.unpackb(payload, use_list=False, strict_map_key=False)
    except Exception:
        return None
    if type(obj) is not dict:
        return None
    tick = obj.get(TICK_FIELD)
    if type(tick) is not int or not 0 <= tick <= _TICK_MAX:
        return None
    return tick


class NodeLog:
    """Lines to stderr prefixed with the node's name; at most one line per second per ``topic``
    for :meth:`limited` (a flood of bad input must not turn into a flood of log lines)."""

    def __init__(self, prefix: str, min_interval_s: float = 1.0) -> None:
        self.prefix = prefix
        self._min_interval_s = min_interval_s
        self._last: dict[str, float] = {}
        self._suppressed: dict[str, int] = {}

    def info(self, text: str) -> None:
        """Write one line now."""
        with contextlib.suppress(OSError, ValueError):  # stderr closed: nothing to do
            print(f"{self.prefix}: {text}", file=sys.stderr, flush=True)

    def limited(self, topic: str, text: str) -> None:
        """Write one line unless ``topic`` was logged less than ``min_interval_s`` ago."""
        now = time.monotonic()
        last = self._last.get(topic)
        if last is not None and now - last < self._min_interval_s:
            self._suppressed[topic] = self._suppressed.get(topic, 0) + 1
            return
        self._last[topic] = now
        more = self._suppressed.pop(topic, 0)
        self.info(text + (f" (+{more} similar)" if more else ""))


def subscribe_ordered(
    session: zenoh.Session,
    key_expr: str,
    loop: asyncio.AbstractEventLoop,
    handler: Callable[[tp.Received], object],
) -> zenoh.Subscriber[None]:
    """Subscribe like ``transport.subscribe(..., handler)``, keeping the order across keys.

    zenoh-python runs a plain Python callback in a separate thread *per subscriber*
    (``handlers.Callback(indirect=True)``, the default), so samples of two subscriptions of one
    session can reach the event loop in another order than they arrived on the link (seen here:
    a plant's pose overtaken by its next clock). Lockstep relies on that order (docs/runtime.md),
    so this callback runs on Zenoh's network thread (``indirect=False``): it only copies the
    sample and posts it with ``loop.call_soon_threadsafe``, never blocks and never calls Zenoh.
    """

    def on_sample(sample: zenoh.Sample) -> None:  # Zenoh network thread
        try:
            rx = tp.Received(
                key=str(sample.key_expr),
                payload=sample.payload.to_bytes(),
                rx_s=time.monotonic(),
                deleted=sample.kind == zenoh.SampleKind.DELETE,
            )
            loop.call_soon_threadsafe(handler, rx)
        except Exception:  # loop closed at shutdown; nothing may escape into Zenoh's thread
            pass

    return session.declare_subscriber(key_expr, zenoh.handlers.Callback(on_sample, indirect=False))


def finite_or_none(value: float | None) -> float | None:
    """``value`` if it is a finite float, else None (for optional message fields)."""
    if value is None or not math.isfinite(value):
        return None
    return float(value)


# ---------------------------------------------------------------------------------------------
# Motor seam
# ---------------------------------------------------------------------------------------------


class MotorOutput:
    """Where the wheel command goes besides the bus: the seam for ``robot_agent.motors``.

    With the ``bus`` backend (simulation) the published ``wheels`` message *is* the output and
    the backend is called inline (it only records). Any other backend (``roboclaw``) may block
    for a serial round trip, so a worker thread owns it: :meth:`command` stores the newest
    command and returns at once; the worker applies the newest one (older unapplied commands
    are superseded, counted in :attr:`superseded`). A zero command (every mode but TRACKING) is
    sent as ``stop()``. Never raises into the control loop.
    """

    def __init__(self, backend: MotorBackend) -> None:
        self.backend = backend
        self.threaded = backend.name != "bus"
        self.superseded = 0
        self.faults = 0
        self._cond = threading.Condition()
        self._pending: tuple[float, float, float, bool] | None = None
        self._closing = False
        self._thread: threading.Thread | None = None

    def start(self) -> None:
        """Open the backend (in the worker thread when threaded)."""
        if not self.threaded:
            self._guard(self.backend.open)
            return
        self._thread = threading.Thread(target=self._run, name="motor-output", daemon=True)
        self._thread.start()

    def command(self, omega_r: float, omega_l: float, now_s: float, zero: bool) -> None:
        """Hand one command over (rad/s); ``zero``: stop the wheels."""
        if not self.threaded:
            if zero:
                self._guard(self.backend.stop)
            else:
                self._guard(self.backend.apply, omega_r, omega_l, now_s)
            return
        with self._cond:
            if self._pending is not None:
                self.superseded += 1
            self._pending = (omega_r, omega_l, now_s, zero)
            self._cond.notify()

    def status(self) -> MotorStatus | None:
        """The backend's status snapshot, or None if it failed."""
        try:
            return self.backend.status()
        except Exception:
            return None

    def close(self, timeout_s: float = 0.2) -> None:
        """Stop the wheels and release the backend (bounded by ``timeout_s`` when threaded)."""
        if not self.threaded:
            self._guard(self.backend.close)
            return
        with self._cond:
            self._closing = True
            self._cond.notify()
        if self._thread is not None:
            self._thread.join(timeout_s)

    def _guard(self, fn: Callable[..., object], *args: float) -> None:
        try:
            fn(*args)
        except Exception:  # the contract says backends never raise; count it if one does
            self.faults += 1

    def _run(self) -> None:  # worker thread
        self._guard(self.backend.open)
        while True:
            with self._cond:
                while self._pending is None and not self._closing:
                    self._cond.wait()
                item, self._pending = self._pending, None
                closing = self._closing
            if closing:
                break
            if item is None:
                continue
            omega_r, omega_l, now_s, zero = item
            if zero:
                self._guard(self.backend.stop)
            else:
                self._guard(self.backend.apply, omega_r, omega_l, now_s)
        self._guard(self.backend.close)


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


Publish = Callable[[str, bytes, tp.QoS], None]


class AgentNode:
    """State and handlers of one agent; Zenoh-free apart from the ``publish`` callable.

    Every handler takes one :class:`bus_schemas.transport.Received` and runs on the event loop;
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
        log: NodeLog | None = None,
    ) -> None:
        self.robot_id = keys.check_robot_id(robot_id)
        self.fleet = keys.check_fleet(fleet)
        self.firmware = Firmware(config)
        self.lockstep = lockstep
        self.loop_mode: LoopMode = loop_mode
        self.period_s = 1.0 / rate_hz
        self.motor = motor
        self.log = log if log is not None else NodeLog(f"agent {robot_id}")
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
        self.wheels_qos = tp.QOS_CRITICAL if lockstep else tp.QOS_CONTROL

        self.pose: FwPose | None = None
        self.pose_rx_s = -math.inf
        self._pose_pending = False  # lockstep: received since the last clock
        self.setpoint: _SetpointIn | None = None  # realtime: the newest
        self._setpoints: deque[_SetpointIn] = deque(maxlen=2)  # lockstep: the last two
        self.role: str | None = None
        # neighbour id -> [x_m, y_m, rx_s]; rx_s is None while pending (lockstep)
        self._neighbours: dict[str, list[Any]] = {}
        self._pending_neighbours: list[str] = []

        self.rx: dict[str, int] = {"pose": 0, "setpoint": 0, "poses": 0, "estop": 0, "clock": 0}
        self.internal_errors = 0
        self.steps = 0
        self.last_step_s = -math.inf
        self.sim_t = 0.0  # lockstep: t of the last clock
        self._last_tick: int | None = None
        self._last_wheels: bytes | None = None
        self._seq_wheels = 0
        self._seq_status = 0
        self._last_loop_s: float | None = None  # realtime: last turn of run()'s loop
        self.quarantine_until_s = -math.inf
        self.hang_gap_s = HANG_GAP_S
        self.resumes = 0
        # Agent host (robot_agent.host): the host publishes the wheels of all its robots in one
        # batch and answers neighbour queries from its shared spatial index.
        self.publish_wheels = True
        self.neighbour_fn: Callable[[AgentNode, float], list[tuple[float, float]]] | None = None

    # -- bookkeeping ---------------------------------------------------------------------------

    def _reject(self, what: str, why: DecodeError | str) -> None:
        self.firmware.reject(f"{what}: {why}")
        self.log.limited(f"reject-{what}", f"rejected a {what} message: {why}")

    def _internal(self, where: str, exc: BaseException) -> None:
        self.internal_errors += 1
        self.log.limited(f"internal-{where}", f"internal error in {where}: {exc!r}")

    @property
    def rejected(self) -> int:
        """Messages rejected so far (decode errors and misaddressed messages)."""
        return self.firmware.status().rejected_count

    def _resumed(self, now_s: float) -> bool:
        """Realtime: detect a resume after a stop (see :data:`RESUME_QUARANTINE_S`) and return
        True while the quarantine lasts."""
        if self.lockstep:
            return False
        last = self._last_loop_s
        if last is not None and now_s - last > self.hang_gap_s:
            self._last_loop_s = now_s
            self.quarantine_until_s = now_s + RESUME_QUARANTINE_S
            self.resumes += 1
            self.setpoint = None
            self.pose = None
            self.log.info(f"resumed after {now_s - last:.2f} s stopped: holding until fresh data")
        return now_s < self.quarantine_until_s

    # -- input handlers (event loop) -----------------------------------------------------------

    def on_pose(self, rx: tp.Received) -> None:
        """Own pose: keep it; realtime on-pose: step now."""
        try:
            self.rx["pose"] += 1
            if self._resumed(rx.rx_s):
                return
            msg = decode(rx.payload, Pose)
            if isinstance(msg, DecodeError):
                self._reject("pose", msg)
                return
            if msg.robot is not None and msg.robot != self.robot_id:
                self._reject("pose", f"robot {msg.robot!r} on {self.robot_id}'s key")
                return
            self.pose = FwPose(msg.x, msg.y, msg.theta, msg.t)
            if self.lockstep:
                self._pose_pending = True
                return
            self.pose_rx_s = rx.rx_s
            if self.loop_mode == "on-pose":
                self.step(time.monotonic())
        except Exception as exc:
            self._internal("on_pose", exc)

    def on_setpoint(self, rx: tp.Received) -> None:
        """Own setpoint: keep the newest (realtime) or the last two with their ticks (lockstep)."""
        try:
            self.rx["setpoint"] += 1
            if self._resumed(rx.rx_s):
                return
            msg = decode(rx.payload, Setpoint)
            if isinstance(msg, DecodeError):
                self._reject("setpoint", msg)
                return
            if msg.robot != self.robot_id:
                self._reject("setpoint", f"robot {msg.robot!r} on {self.robot_id}'s key")
                return
            sp = FwSetpoint(msg.x, msg.y, msg.vx, msg.vy, msg.theta, msg.slot, msg.t)
            tick = payload_tick(rx.payload) if self.lockstep else None
            self.accept_setpoint(sp, msg.role, rx.rx_s, tick)
        except Exception as exc:
            self._internal("on_setpoint", exc)

    def accept_setpoint(self, sp: FwSetpoint, role: str, rx_s: float, tick: int | None) -> None:
        """Keep a valid setpoint: the newest (realtime) or the last two with ticks (lockstep)."""
        if self.lockstep:
            if tick is None:
                self._reject("setpoint", "lockstep setpoint without a valid tick")
                return
            # In lockstep the setpoint's t is the sim time of its tick, which is when
            # simulate.py considers it received.
            self._setpoints.append(_SetpointIn(sp, role, sp.t, tick))
        else:
            self.setpoint = _SetpointIn(sp, role, rx_s, None)

    def on_poses(self, rx: tp.Received) -> None:
        """Batched poses: the other robots' positions, for repulsion."""
        try:
            self.rx["poses"] += 1
            msg = decode(rx.payload, PoseBatch)
            if isinstance(msg, DecodeError):
                self._reject("poses", msg)
                return
            me = self.robot_id
            nb = self._neighbours
            rx_s: float | None = None if self.lockstep else rx.rx_s
            for rid, x, y in zip(msg.robots, msg.x, msg.y, strict=True):
                if rid == me:
                    continue
                entry = nb.get(rid)
                if entry is None:
                    if len(nb) >= MAX_NEIGHBOURS:
                        self._prune_neighbours()
                        if len(nb) >= MAX_NEIGHBOURS:
                            continue
                    nb[rid] = [x, y, rx_s]
                else:
                    entry[0] = x
                    entry[1] = y
                    entry[2] = rx_s
                if rx_s is None:
                    self._pending_neighbours.append(rid)
            if len(self._pending_neighbours) > 4 * MAX_NEIGHBOURS:  # no clock for ages
                self._pending_neighbours = list(dict.fromkeys(self._pending_neighbours))
        except Exception as exc:
            self._internal("on_poses", exc)

    def on_estop(self, rx: tp.Received) -> None:
        """Fleet or own estop: engage (zero wheels at once in realtime) or release."""
        try:
            self.rx["estop"] += 1
            msg = decode(rx.payload, Estop)
            if isinstance(msg, DecodeError):
                self._reject("estop", msg)
                return
            if msg.robot is not None and msg.robot != self.robot_id:
                return  # another robot's estop
            if msg.engage:
                self.firmware.engage_estop()
                self.log.info("estop engaged")
                if not self.lockstep:
                    self.step(time.monotonic())  # zero wheels now, not at the next tick
            else:
                self.firmware.release_estop()
                self.log.info("estop released")
        except Exception as exc:
            self._internal("on_estop", exc)

    def on_clock(self, rx: tp.Received) -> None:
        """Lockstep clock k: step at t_k and answer with wheels(tick=k)."""
        try:
            self.rx["clock"] += 1
            msg = decode(rx.payload, Clock)
            if isinstance(msg, DecodeError):
                self._reject("clock", msg)
                return
            k = msg.tick
            if k == self._last_tick and self._last_wheels is not None:
                self._publish(self.wheels_key, self._last_wheels, self.wheels_qos)  # re-announce
                return
            self.clock_step(k, msg.t)
        except Exception as exc:
            self._internal("on_clock", exc)

    def clock_step(self, k: int, t_k: float) -> WheelCommand | None:
        """Lockstep tick k at sim time ``t_k``: poses and neighbours received since the last
        clock count as received at ``t_k``, the setpoint of tick k-1 is chosen, one step."""
        try:
            self.sim_t = t_k
            if self._pose_pending:
                self.pose_rx_s = t_k
                self._pose_pending = False
            if self._pending_neighbours:
                nb = self._neighbours
                for rid in self._pending_neighbours:
                    entry = nb.get(rid)
                    if entry is not None and entry[2] is None:
                        entry[2] = t_k
                self._pending_neighbours = []
            chosen: _SetpointIn | None = None
            for s in self._setpoints:
                if s.tick == k - 1:
                    chosen = s
            self.setpoint = chosen
            self._last_tick = k
            return self.step(t_k, tick=k)
        except Exception as exc:
            self._internal("clock_step", exc)
            return None

    # -- control -------------------------------------------------------------------------------

    def _prune_neighbours(self) -> None:
        now = self.sim_t if self.lockstep else time.monotonic()
        stale = [
            rid
            for rid, (_, _, rx_s) in self._neighbours.items()
            if rx_s is not None and now - rx_s > NEIGHBOUR_STALE_S
        ]
        for rid in stale:
            del self._neighbours[rid]

    def neighbours(self, now_s: float) -> list[tuple[float, float]]:
        """Positions (m) of the other robots seen within :data:`NEIGHBOUR_STALE_S` of ``now_s``."""
        return [
            (x, y)
            for x, y, rx_s in self._neighbours.values()
            if rx_s is not None and -NEIGHBOUR_STALE_S <= now_s - rx_s <= NEIGHBOUR_STALE_S
        ]

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
                    self.neighbours(now_s)
                    if self.neighbour_fn is None
                    else self.neighbour_fn(self, now_s)
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
                )
            )
            self._last_wheels = payload
            self._publish(self.wheels_key, payload, self.wheels_qos)
            return cmd
        except Exception as exc:  # SchemaError (a bug) or a closed session at shutdown
            self._internal("step", exc)
            return None

    def status_message(self, now_s: float) -> Status:
        """The status message for ``now_s`` (s, this node's bus clock)."""
        st = self.firmware.status()
        self._seq_status += 1
        return Status(
            t=max(now_s, 0.0),
            seq=self._seq_status,
            mode=str(st.mode),
            slot=st.slot,
            pid=self.pid,
            host=self.host,
            rejected=st.rejected_count,
            ex=finite_or_none(st.ex),
            ey=finite_or_none(st.ey),
            role=self.role,
            rx=dict(self.rx),
            robot=self.robot_id,
        )

    def publish_status(self) -> None:
        """Publish one status message (never raises)."""
        try:
            now = self.sim_t if self.lockstep else time.monotonic()
            self._publish(self.status_key, encode(self.status_message(now)), tp.QOS_TELEMETRY)
        except Exception as exc:
            self._internal("status", exc)

    def control_timer(self, now: float) -> None:
        """Realtime timer tick: step unless an own pose stepped within the period (on-pose)."""
        if self.loop_mode == "fixed" or now - self.last_step_s >= self.period_s * 0.999:
            self.step(now)

    async def run(self, stop: asyncio.Event, notifier: Notifier | None = None) -> None:
        """Timers until ``stop``: the realtime control/watchdog timer and the 5 Hz status."""
        await run_timers(self, stop, notifier)


class _TimedNode(Protocol):
    """What :func:`run_timers` drives (an :class:`AgentNode` or an agent host)."""

    period_s: float
    lockstep: bool
    _last_loop_s: float | None

    def _resumed(self, now_s: float) -> bool: ...
    def control_timer(self, now: float) -> None: ...
    def publish_status(self) -> None: ...


async def run_timers(node: _TimedNode, stop: asyncio.Event, notifier: Notifier | None) -> None:
    """The timers of an agent process until ``stop``: the realtime control/watchdog tick
    (``node.control_timer``, also where sd_notify WATCHDOG is sent: the control loop is alive)
    and the 5 Hz status. Records each loop turn in ``node._last_loop_s`` (hang detection)."""
    period = node.period_s
    wd_period = notifier.watchdog_interval_s() if notifier is not None else None
    now = time.monotonic()
    next_ctrl = now + period
    next_status = now
    next_wd = now
    while not stop.is_set():
        now = time.monotonic()
        node._resumed(now)
        if now >= next_ctrl:
            if not node.lockstep:
                node.control_timer(now)
            next_ctrl += period
            if next_ctrl <= now:  # fell behind (loop stalled): resynchronise
                next_ctrl = now + period
            if notifier is not None and wd_period is not None and now >= next_wd:
                notifier.watchdog()  # the control loop is alive
                next_wd = now + wd_period
        if now >= next_status:
            node.publish_status()
            next_status += STATUS_PERIOD_S
            if next_status <= now:
                next_status = now + STATUS_PERIOD_S
        node._last_loop_s = time.monotonic()
        await asyncio.sleep(max(0.0, min(next_ctrl, next_status) - node._last_loop_s))


# ---------------------------------------------------------------------------------------------
# CLI
# ---------------------------------------------------------------------------------------------


def positive_rate(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not 0.5 <= value <= 2000.0:
        raise argparse.ArgumentTypeError(f"rate must be in [0.5, 2000] Hz, got {text}")
    return value


def build_parser() -> argparse.ArgumentParser:
    """The ``formation agent`` argument parser."""
    parser = argparse.ArgumentParser(
        prog="formation agent", description="Run the firmware of one robot as a Zenoh node."
    )
    parser.add_argument("--id", dest="robot_id", metavar="ID", help="robot id ([a-z0-9_-]+)")
    source = parser.add_mutually_exclusive_group()
    source.add_argument(
        "--scenario", metavar="NAME|FILE", help="take the robot parameters from a scenario"
    )
    source.add_argument(
        "--config",
        metavar="ROBOT.toml",
        help="robot config file: id, fleet, parameters, Zenoh connection, motor backend",
    )
    source.add_argument(
        "--check-config",
        metavar="ROBOT.toml",
        help="check a robot config file, print OK or every problem, exit 0/1 (no Zenoh)",
    )
    parser.add_argument("--fleet", metavar="NAME", help="fleet name (default demo, or --config's)")
    parser.add_argument(
        "--lockstep", action="store_true", help="step on the plant's clock (docs/runtime.md)"
    )
    parser.add_argument(
        "--loop",
        choices=("on-pose", "fixed"),
        default="on-pose",
        help="realtime: step on every own pose plus a watchdog timer (default), or on the "
        "timer only",
    )
    parser.add_argument(
        "--rate-hz",
        type=positive_rate,
        default=50.0,
        metavar="HZ",
        help="realtime timer rate (default 50 Hz)",
    )
    tp.add_zenoh_arguments(parser)
    return parser


@dataclass(frozen=True)
class _Setup:
    robot_id: str
    fleet: str
    config: AgentConfig
    settings: tp.ZenohSettings
    motor: MotorBackend | None


def _setup(ns: argparse.Namespace, log_err: Callable[[str], None]) -> _Setup | None:
    """Resolve id, fleet, parameters, Zenoh settings and motor backend; None after an error."""
    from robot_agent.robot_config import ConfigError, load_robot_config

    robot_id: str | None = ns.robot_id
    fleet: str | None = ns.fleet
    config = AgentConfig()
    motor: MotorBackend | None = None
    if ns.config is not None:
        try:
            rc = load_robot_config(ns.config)
        except ConfigError as exc:
            log_err(str(exc))
            return None
        if robot_id is not None and robot_id != rc.robot_id:
            log_err(f"--id {robot_id} does not match robot_id {rc.robot_id!r} of {ns.config}")
            return None
        robot_id = rc.robot_id
        fleet = fleet or rc.fleet
        config = rc.agent
        # The file's Zenoh section fills in what the command line did not say.
        ns.zenoh_mode = ns.zenoh_mode or rc.zenoh.mode
        ns.zenoh_connect = ns.zenoh_connect or (list(rc.zenoh.endpoints) or None)
        ns.zenoh_config = ns.zenoh_config or rc.zenoh.config_file
        if rc.motor.backend != "bus":
            try:
                motor = create_backend(rc.motor, config.geometry.max_wheel_radps)
            except ValueError as exc:
                log_err(f"motor backend: {exc}")
                return None
    elif ns.scenario is not None:
        from formation.scenario import ScenarioError, load

        try:
            scenario = load(ns.scenario)
        except (ScenarioError, OSError) as exc:
            log_err(f"scenario: {exc}")
            return None
        if robot_id is not None and robot_id not in scenario.robot_ids:
            log_err(
                f"robot {robot_id!r} is not in scenario {scenario.name!r} "
                f"({', '.join(scenario.robot_ids)})"
            )
            return None
        config = scenario.agent
    if robot_id is None:
        log_err("--id is required (or --config with a robot_id)")
        return None
    fleet = fleet or keys.DEFAULT_FLEET
    if not keys.is_robot_id(robot_id):
        log_err(f"invalid robot id {robot_id!r}: must match {keys.ROBOT_ID_PATTERN}")
        return None
    if not keys.is_name(fleet):
        log_err(f"invalid fleet name {fleet!r}: must match {keys.NAME_PATTERN}")
        return None
    try:
        settings = tp.settings_from_args(ns)
    except (TypeError, ValueError) as exc:
        log_err(f"zenoh settings: {exc}")
        return None
    return _Setup(robot_id, fleet, config, settings, motor)


def check_config_command(path: str) -> int:
    """``--check-config``: print OK or every problem (one per line); 0 if valid, else 1."""
    from robot_agent.robot_config import check_config

    problems = check_config(Path(path))
    print("\n".join(problems) or "OK", flush=True)
    return 1 if problems else 0


def main(argv: list[str]) -> int:
    """Entry point of ``formation agent``; returns the exit status."""
    ns = build_parser().parse_args(argv)
    if ns.check_config is not None:
        return check_config_command(ns.check_config)
    errlog = NodeLog("formation agent")
    setup = _setup(ns, errlog.info)
    if setup is None:
        return 2
    return tp.run_node(
        lambda stop: _node(
            stop, setup, lockstep=bool(ns.lockstep), loop_mode=ns.loop, rate_hz=ns.rate_hz
        )
    )


async def _node(
    stop: asyncio.Event, setup: _Setup, *, lockstep: bool, loop_mode: LoopMode, rate_hz: float
) -> int:
    loop = asyncio.get_running_loop()
    log = NodeLog(f"agent {setup.robot_id}")
    try:
        session = await tp.open_session_async(setup.settings)
    except (tp.TransportError, ValueError) as exc:
        log.info(str(exc))
        return 1
    motor = MotorOutput(setup.motor) if setup.motor is not None else None
    notifier = Notifier()
    try:
        pubs = tp.Publishers(session)
        node = AgentNode(
            setup.robot_id,
            setup.fleet,
            setup.config,
            pubs.put,
            lockstep=lockstep,
            loop_mode=loop_mode,
            rate_hz=rate_hz,
            motor=motor,
            log=log,
        )
        if setup.settings.lease_ms is not None:
            node.hang_gap_s = max(0.3, 0.9 * setup.settings.lease_ms / 1000.0)
        if motor is not None:
            motor.start()
        # Declare the publishers first, so the first command is not delayed by a declaration.
        pubs.get(node.wheels_key, node.wheels_qos)
        pubs.get(node.status_key, tp.QOS_TELEMETRY)
        subscribe_ordered(session, node.setpoint_key, loop, node.on_setpoint)
        subscribe_ordered(session, node.poses_key, loop, node.on_poses)
        subscribe_ordered(session, node.estop_key, loop, node.on_estop)
        if lockstep:
            subscribe_ordered(session, node.clock_key, loop, node.on_clock)
        subscribe_ordered(session, node.pose_key, loop, node.on_pose)
        token = tp.declare_token(session, node.alive_key)
        print(f"agent {setup.robot_id} ready", flush=True)
        notifier.ready(f"agent {setup.robot_id} connected")
        mode = "lockstep" if lockstep else f"realtime, loop {loop_mode} at {rate_hz:g} Hz"
        backend = setup.motor.name if setup.motor is not None else "bus"
        log.info(f"fleet {setup.fleet}, {mode}, motor backend {backend}")
        await node.run(stop, notifier)
        notifier.stopping()
        del token
        return 0
    finally:
        if motor is not None:
            motor.close()
        session.close()
        notifier.close()


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main(sys.argv[1:]))
