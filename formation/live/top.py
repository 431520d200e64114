"""``formation top``: live status table of a fleet, from any machine that reaches its Zenoh.

Usage::

    formation top [--fleet demo] [--once] [--period S] [--endpoint tcp/HOST:7447 ...]

One row per robot (every robot seen in a key or a liveliness token): liveliness, assigned slot
and role (the coordinator's ``assignment`` and ``slot/<k>``), firmware mode and tracking error
(the agent's ``status``: hypot(ex, ey), eqs 17-18), message rates per key over the last
``--window`` seconds (pose, setpoint, wheels, status, truth), the agent's count of rejected
messages, and the age of its last message. A header says who is alive (plant, coordinators,
with the plant's state and each coordinator's role and epoch from their status), who leads, and
the latest clock tick (lockstep).

One row per camera tracker (``camera/<name>/status``, ``CameraStatus``): its state, frames
processed per second, tag detections per second (from the last two statuses, on the camera's
clock), frames dropped, detection and capture -> published latency (p50/p99, ms, over its last
1000 frames), detections rejected (with the reasons), robots missed, and the status's age.

Batched fleets (``formation up --hosts H``, docs/scale.md) have no per-robot keys: their robots
are read out of the batches, with the same columns. ``host/<name>/status`` (``StatusBatch``)
gives each robot's mode, slot, tracking error and rejected count; ``poses``, ``setpoints``,
``truths`` and ``host/<name>/wheels`` count as one message of each robot they carry (a robot's
pose rate is the rate of the frames that carry it); the ``host`` column names the agent host.
Redrawn every ``--period`` seconds (0.5) on a terminal; ``--once`` prints one table after
``--wait`` seconds (1.5) and exits 0, for scripts and tests. Only subscribes: it never
publishes, so it is safe on a live fleet.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import math
import sys
import threading
import time
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Final

import runtime as rt
from bus_schemas import (
    Assignment,
    CameraStatus,
    Clock,
    CoordinatorStatus,
    DecodeError,
    Message,
    PlantStatus,
    PoseBatch,
    SetpointBatch,
    Slot,
    Status,
    StatusBatch,
    TruthBatch,
    WheelsBatch,
    keys,
)
from formation.outputs.bus_json import alive_kind, decode_sample
from runtime.tap import BusItem, BusTap

RATE_LEAVES: Final = (keys.POSE, keys.SETPOINT, keys.WHEELS, keys.STATUS, keys.TRUTH)
"""Per-robot keys whose message rate is shown, in column order."""
_RATE_HEAD: Final = {
    keys.POSE: "pose",
    keys.SETPOINT: "setp",
    keys.WHEELS: "whl",
    keys.STATUS: "stat",
    keys.TRUTH: "truth",
}
CLEAR: Final = "\x1b[H\x1b[2J"
BATCH_LEAVES: Final = {
    keys.POSES: keys.POSE,
    keys.SETPOINTS: keys.SETPOINT,
    keys.TRUTHS: keys.TRUTH,
    keys.HOST_WHEELS: keys.WHEELS,
    keys.HOST_STATUS: keys.STATUS,
}
"""Batched leaf -> the per-robot leaf whose rate each robot of a batch counts for."""
_Batch = PoseBatch | SetpointBatch | TruthBatch | WheelsBatch | StatusBatch


def _natural(rid: str) -> tuple[str, int, str]:
    head = rid.rstrip("0123456789")
    tail = rid[len(head) :]
    return (head, int(tail) if tail else -1, rid)


@dataclass
class RobotState:
    """What the bus said last about one robot (receive times in monotonic ns)."""

    alive: bool | None = None
    status: Status | None = None
    last_rx_ns: int | None = None
    arrivals: dict[str, deque[int]] = field(default_factory=dict)
    host: str | None = None  # the agent host that runs it (batched fleets)


@dataclass(frozen=True)
class RobotRow:
    """One line of the table."""

    robot: str
    alive: bool | None
    slot: int | None
    role: str | None
    mode: str | None
    error_m: float | None
    rates_hz: dict[str, float]
    rejected: int | None
    age_s: float | None
    host: str | None = None


@dataclass(frozen=True)
class CameraRow:
    """One camera tracker's line."""

    name: str
    state: str
    fps: float
    detections_hz: float | None  # None before two statuses (or after a restart)
    dropped: int
    detect_ms: tuple[float | None, float | None]  # p50, p99
    latency_ms: tuple[float | None, float | None]  # p50, p99
    rejected: int
    rejects: dict[str, int]
    misses: int
    truth_rejected: int
    internal_errors: int
    detector: str
    source: str
    age_s: float


def _detections_hz(previous: CameraStatus | None, last: CameraStatus) -> float | None:
    """Tag detections per second between two statuses of one camera (its own clock), or None
    (a first status, a restart: counts or time going back)."""
    if previous is None or last.t <= previous.t:
        return None
    done = sum(last.detections.values()) - sum(previous.detections.values())
    return done / (last.t - previous.t) if done >= 0 else None


class FleetStatus:
    """The fleet as seen on the bus: fed :class:`BusItem` s, read as :class:`RobotRow` s.

    Thread-safe: :meth:`observe` runs on the tap's worker thread, :meth:`rows` / :meth:`render`
    on the display's. No clock reads: times come with the items and the callers.
    """

    def __init__(self, fleet: str = keys.DEFAULT_FLEET, window_s: float = 2.0) -> None:
        self.fleet = keys.check_fleet(fleet)
        self.window_ns = int(window_s * 1e9)
        self.robots: dict[str, RobotState] = {}
        self.assignment: Assignment | None = None
        self.slot_roles: dict[int, str] = {}
        self.tick: int | None = None
        self.others: dict[str, bool] = {}  # "plant", "coordinator/<name>" -> alive
        self.node_status: dict[str, str] = {}  # the same names -> a word from their status
        self.cameras: dict[str, tuple[CameraStatus | None, CameraStatus, int]] = {}
        """Camera name -> (previous status, last status, last receive time ns)."""
        self.samples = 0
        self.rejected = 0
        self._first_rx_ns: int | None = None  # rates over min(window, time listened)
        self._lock = threading.Lock()

    def _robot(self, rid: str) -> RobotState:
        st = self.robots.get(rid)
        if st is None:
            st = self.robots[rid] = RobotState()
        return st

    def observe(self, item: BusItem) -> None:
        """Take one bus observation."""
        with self._lock:
            if item.kind in ("alive", "dead"):
                kind, ident = alive_kind(item.key)
                alive = item.kind == "alive"
                if kind == "robot" and ident is not None:
                    self._robot(ident).alive = alive
                elif kind != "other":
                    self.others[kind if ident is None else f"{kind}/{ident}"] = alive
                return
            if item.kind != "put":
                return
            self.samples += 1
            if self._first_rx_ns is None:
                self._first_rx_ns = item.rx_ns
            parsed = keys.parse_robot_key(item.key)
            if parsed is not None:
                self._arrival(parsed[1], parsed[2], item.rx_ns)
                if parsed[2] != keys.STATUS:
                    return  # rates only: no need to decode poses, wheels, ...
            else:
                info = keys.parse_key(item.key)
                if info is not None and info.leaf in BATCH_LEAVES:
                    self._observe_batch(item, info)
                    return
            msg = self._decode(item)
            if isinstance(msg, Status) and parsed is not None:
                self._robot(parsed[1]).status = msg
            elif isinstance(msg, Assignment):
                self.assignment = msg
            elif isinstance(msg, Slot):
                self.slot_roles[msg.slot] = msg.role
            elif isinstance(msg, Clock):
                self.tick = msg.tick
            elif isinstance(msg, CoordinatorStatus):
                self.node_status[f"coordinator/{msg.name}"] = f"{msg.role}, epoch {msg.epoch}"
            elif isinstance(msg, PlantStatus):  # a lockstep plant that went on says how often
                late = msg.mode == "lockstep" and msg.timeouts > 0
                self.node_status["plant"] = (
                    f"{msg.state}, {msg.timeouts} lockstep timeouts" if late else msg.state
                )
            elif isinstance(msg, CameraStatus):
                info = keys.parse_key(item.key)
                if info is not None and info.name is not None:
                    seen = self.cameras.get(info.name)
                    self.cameras[info.name] = (seen[1] if seen else None, msg, item.rx_ns)

    def _decode(self, item: BusItem) -> Message | None:
        """The message of ``item``, strictly decoded; None for a key of no known type or a
        payload rejected (counted) (lock held)."""
        decoded = decode_sample(item.key, item.payload)
        if isinstance(decoded, DecodeError):
            self.rejected += 1
            return None
        return None if decoded is None else decoded.msg

    def _arrival(self, rid: str, leaf: str, rx_ns: int) -> None:
        st = self._robot(rid)
        st.last_rx_ns = rx_ns
        q = st.arrivals.setdefault(leaf, deque())
        q.append(rx_ns)
        while q and rx_ns - q[0] > self.window_ns:
            q.popleft()

    def _observe_batch(self, item: BusItem, info: keys.KeyInfo) -> None:
        """One batch: an arrival of its leaf for every robot it carries; a status batch also
        sets each robot's status (lock held)."""
        msg: _Batch | None = self._decode(item)  # type: ignore[assignment]
        if msg is None:
            return
        leaf = BATCH_LEAVES[info.leaf]
        for rid in msg.robots:
            self._arrival(rid, leaf, item.rx_ns)
        if isinstance(msg, StatusBatch):
            for k, rid in enumerate(msg.robots):
                st = self._robot(rid)
                st.host = info.name
                slot = msg.slot[k]
                st.status = Status(
                    t=msg.t,
                    seq=msg.seq,
                    mode=msg.mode[k],
                    slot=None if slot < 0 else slot,
                    pid=msg.pid,
                    host=msg.host,
                    rejected=msg.rejected[k],
                    ex=msg.ex[k],
                    ey=msg.ey[k],
                    robot=rid,
                )

    def rows(self, now_ns: int) -> list[RobotRow]:
        """The table's rows at ``now_ns`` (monotonic ns), robots in natural order."""
        with self._lock:
            out: list[RobotRow] = []
            robots_slots = dict(self.assignment.robots) if self.assignment is not None else {}
            listened_ns = now_ns - (self._first_rx_ns if self._first_rx_ns is not None else now_ns)
            span_s = min(self.window_ns, max(listened_ns, 1)) / 1e9
            for rid in sorted(self.robots, key=_natural):
                st = self.robots[rid]
                s = st.status
                slot = robots_slots.get(rid, s.slot if s is not None else None)
                role = self.slot_roles.get(slot) if slot is not None else None
                if role is None and s is not None:
                    role = s.role
                err = None
                if s is not None and s.ex is not None and s.ey is not None:
                    err = math.hypot(s.ex, s.ey)
                rates: dict[str, float] = {}
                for leaf in RATE_LEAVES:
                    q = st.arrivals.get(leaf)
                    recent = [t for t in q if now_ns - t <= self.window_ns] if q else []
                    rates[leaf] = len(recent) / span_s
                out.append(
                    RobotRow(
                        robot=rid,
                        alive=st.alive,
                        slot=slot,
                        role=role,
                        mode=s.mode if s is not None else None,
                        error_m=err,
                        rates_hz=rates,
                        rejected=s.rejected if s is not None else None,
                        age_s=None if st.last_rx_ns is None else (now_ns - st.last_rx_ns) / 1e9,
                        host=st.host,
                    )
                )
            return out

    def camera_rows(self, now_ns: int) -> list[CameraRow]:
        """One row per camera tracker seen, by name."""
        with self._lock:
            out: list[CameraRow] = []
            for name in sorted(self.cameras):
                previous, c, rx_ns = self.cameras[name]
                rejects = {reason: n for reason, n in sorted(c.rejects.items()) if n}
                out.append(
                    CameraRow(
                        name=name,
                        state=c.state,
                        fps=c.fps,
                        detections_hz=_detections_hz(previous, c),
                        dropped=c.dropped,
                        detect_ms=(c.detect_p50_ms, c.detect_p99_ms),
                        latency_ms=(c.latency_p50_ms, c.latency_p99_ms),
                        rejected=sum(rejects.values()),
                        rejects=rejects,
                        misses=sum(c.misses.values()),
                        truth_rejected=c.truth_rejected,
                        internal_errors=c.internal_errors,
                        detector=c.detector,
                        source=c.source,
                        age_s=(now_ns - rx_ns) / 1e9,
                    )
                )
            return out

    def header(self) -> str:
        """One line: fleet, plant/coordinators alive, leader, tick, samples."""
        with self._lock:
            parts = [f"fleet {self.fleet}"]
            for name in sorted(self.others):
                said = self.node_status.get(name)
                extra = f" ({said})" if said and self.others[name] else ""
                parts.append(f"{name} {'up' if self.others[name] else 'DOWN'}{extra}")
            leader = self.assignment.leader if self.assignment is not None else None
            parts.append(f"leader {leader or '-'}")
            if self.tick is not None:
                parts.append(f"tick {self.tick}")
            parts.append(f"{self.samples} samples")
            if self.rejected:
                parts.append(f"{self.rejected} rejected here")
            return ", ".join(parts)

    def render(self, now_ns: int) -> str:
        """The whole table as text."""
        rows = self.rows(now_ns)
        rate_cols = "".join(f"{_RATE_HEAD[leaf]:>7}" for leaf in RATE_LEAVES)
        hosted = any(r.host is not None for r in rows)
        lines = [
            self.header(),
            f"{'robot':<8}{'alive':<7}{'slot':>5} {'role':<10}{'mode':<9}{'err cm':>8}"
            f"{rate_cols}{'rej':>6}{'age s':>7}" + ("  host" if hosted else ""),
        ]
        for r in rows:
            alive = {True: "yes", False: "LOST", None: "?"}[r.alive]
            slot = "-" if r.slot is None else str(r.slot)
            err = "-" if r.error_m is None else f"{r.error_m * 100:.1f}"
            rates = "".join(f"{r.rates_hz[leaf]:>7.1f}" for leaf in RATE_LEAVES)
            rej = "-" if r.rejected is None else str(r.rejected)
            age = "-" if r.age_s is None else f"{r.age_s:.1f}"
            lines.append(
                f"{r.robot:<8}{alive:<7}{slot:>5} {r.role or '-':<10}{r.mode or '-':<9}{err:>8}"
                f"{rates}{rej:>6}{age:>7}" + (f"  {r.host or '-'}" if hosted else "")
            )
        if not rows:
            lines.append("(no robots seen yet)")
        cameras = self.camera_rows(now_ns)
        if cameras:
            lines.append(
                f"{'camera':<10}{'state':<9}{'fps':>7}{'det/s':>8}{'drop':>6}"
                f"{'detect ms':>12}{'latency ms':>13}{'rej':>6}{'miss':>6}{'age s':>7}  detail"
            )
            lines.extend(_camera_line(c) for c in cameras)
        lines.append(f"rates in Hz over the last {self.window_ns / 1e9:g} s")
        if cameras:
            lines.append("camera: ms are p50/p99 of its last 1000 frames; det/s from its clock")
        return "\n".join(lines)


def _ms_pair(pair: tuple[float | None, float | None]) -> str:
    return "/".join("-" if v is None else f"{v:.1f}" for v in pair)


def _camera_line(c: CameraRow) -> str:
    """One camera's line of the table: the columns, then what is worth a word."""
    det = "-" if c.detections_hz is None else f"{c.detections_hz:.1f}"
    detail = [f"{c.detector}, {c.source}"]
    if c.rejects:
        detail.append("rejects " + ", ".join(f"{k} {n}" for k, n in c.rejects.items()))
    if c.truth_rejected:
        detail.append(f"{c.truth_rejected} truth rejected")
    if c.internal_errors:
        detail.append(f"{c.internal_errors} INTERNAL ERRORS")
    return (
        f"{c.name:<10}{c.state:<9}{c.fps:>7.1f}{det:>8}{c.dropped:>6}"
        f"{_ms_pair(c.detect_ms):>12}{_ms_pair(c.latency_ms):>13}{c.rejected:>6}{c.misses:>6}"
        f"{c.age_s:>7.1f}  " + "; ".join(detail)
    )


def build_parser() -> argparse.ArgumentParser:
    """The ``formation top`` argument parser."""
    p = argparse.ArgumentParser(
        prog="formation top",
        description="Live status table of a fleet (robots, roles, modes, tracking error, "
        "message rates, rejects, liveliness; camera trackers) from anywhere on its Zenoh "
        "network.",
    )
    p.add_argument(
        "--fleet",
        default=None,
        help="fleet name (default: $FORMATION_FLEET, else the running `formation up`'s, else demo)",
    )
    p.add_argument("--once", action="store_true", help="print one table after --wait s, exit")
    p.add_argument("--wait", type=float, default=1.5, metavar="S", help="--once: listen S s")
    p.add_argument("--period", type=float, default=0.5, metavar="S", help="redraw period (s)")
    p.add_argument("--window", type=float, default=2.0, metavar="S", help="rate window (s)")
    rt.add_zenoh_arguments(p)
    return p


def main(argv: Sequence[str]) -> int:
    """``formation top``: 0 on a clean stop, 1 if the session cannot open, 2 on bad args."""
    args = build_parser().parse_args(list(argv))
    from formation.outputs.runfile import resolve_target

    resolve_target(args)  # --endpoint / --fleet not given: $FORMATION_*, the running fleet
    try:
        keys.check_fleet(args.fleet)
    except ValueError as exc:
        print(f"formation top: {exc}", file=sys.stderr)
        return 2
    for name in ("wait", "period", "window"):
        value = getattr(args, name)
        if not (value > 0 and math.isfinite(value)):
            print(f"formation top: --{name} must be > 0", file=sys.stderr)
            return 2
    from formation.outputs.runfile import tool_settings  # a --secure run: its observer credentials

    settings = tool_settings(args, "observer")
    interactive = sys.stdout.isatty() and not args.once

    async def node(stop: asyncio.Event) -> int:
        try:
            session = await rt.open_session_async(settings)
        except rt.TransportError as exc:
            print(f"formation top: {exc}", file=sys.stderr)
            return 1
        status = FleetStatus(args.fleet, args.window)
        tap: BusTap | None = None
        try:
            tap = BusTap(session, args.fleet, status.observe, name="top")
            if args.once:
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(stop.wait(), timeout=args.wait)
                print(status.render(time.monotonic_ns()), flush=True)
                return 0
            while not stop.is_set():
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(stop.wait(), timeout=args.period)
                text = status.render(time.monotonic_ns())
                sys.stdout.write((CLEAR if interactive else "\n") + text + "\n")
                sys.stdout.flush()
            return 0
        finally:
            if tap is not None:
                await asyncio.to_thread(tap.close)
            session.close()

    return rt.run_node(node)
