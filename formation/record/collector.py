"""Bus traffic -> :class:`~formation.outputs.runlog.RunLog`: the same record the in-process
simulator keeps.

A :class:`RunCollector` is fed the samples of one fleet (``feed(key, payload)``: Zenoh key and
msgpack bytes, exactly as received) and builds, at the end, a ``RunLog`` that
``formation.outputs.metrics`` and ``formation.outputs.figures`` measure like any in-process run. It
has no Zenoh
and no clock of its own, so a live subscriber (``formation up``), a recording replay or a test can
all drive it.

What it listens to (the bus contract, docs/bus.md): ``robot/<id>/truth`` (rows), ``leader``,
``slot/<k>``, ``assignment``, ``robot/<id>/wheels`` (motor power), ``robot/<id>/status`` (mode,
live view, and the safety filter counters ``filter`` / ``min_clearance_m`` of each robot's newest
status: ``RunLog.filter_counts``, ``filter_source`` ``"status"``) and ``clock``. Every payload
is decoded with the strict ``bus_schemas`` decoder; a bad one is counted (``rejected``) and
otherwise ignored.

Rows
----
One row per plant tick of truth:

* **lockstep** (``dt_s`` given): every message is placed on its tick ``k = round(t / dt_s)``
  (``t`` is sim time; ``Wheels.tick`` is used when present). Row ``k`` holds the truth of every
  robot at ``t_k`` and the coordinator's leader, slots and assignment of tick ``k`` and the wheel
  commands answering tick ``k``: the same quantities, from the same cores, as row ``k`` of
  ``formation.sim.simulate.run``. Ticks after the last one the coordinator answered are dropped
  (the plant may publish a final truth it no longer waits on).
* **realtime** (``dt_s=None``): one row per truth frame (every truth message with the same ``t``);
  ``t`` is the publishers' ``time.monotonic()`` (one host), shifted so the first frame is at 0 s.
  The other series are sampled as "latest with ``t`` <= the frame's ``t``".

A robot missing from a row (a dropped truth sample) keeps its previous pose (counted in
``stats["truth_gaps"]``); rows before every robot has been seen once are skipped. Reference
points are computed from truth with the geometry's ``ref_offset_m`` (eqs 10-11); separation and
collisions come from :class:`sim_plant.core.accounting.SeparationMonitor` fed with the truth rows in
order, exactly as in the simulator.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from typing import Any, Final

from bus_schemas import (
    Assignment,
    Clock,
    DecodeError,
    Fault,
    Leader,
    SetpointBatch,
    Slot,
    Status,
    StatusBatch,
    Truth,
    TruthBatch,
    Wheels,
    WheelsBatch,
    decode,
    keys,
)
from formation.outputs.live_table import LiveRobot, LiveView
from formation.outputs.runlog import MODE_CODES, RunLog
from formation.record.collector_build import RowSources, fill_rows, reshape_intervals, row_keys
from formation.record.collector_live import live_view
from formation.record.collector_series import Series
from scenario import Scenario

MAX_FAULTS: Final = 10_000
"""Fault notices kept at most (a run's scripted faults are a handful)."""

__all__ = ["LiveRobot", "LiveView", "RunCollector", "key_patterns", "slot_ids_of"]

_LEAVES: Final = frozenset(
    {
        keys.TRUTH, keys.LEADER, keys.SLOT, keys.ASSIGNMENT, keys.WHEELS, keys.STATUS, keys.CLOCK,
        # the batched forms of a large fleet (plant/coordinator --batch, agent hosts)
        keys.TRUTHS, keys.HOST_WHEELS, keys.HOST_STATUS, keys.SETPOINTS,
        keys.FAULT,  # the scripted faults' notices: metrics.json "faults"
    }
)  # fmt: skip


MAX_RESHAPE_MARKS: Final = 100_000
"""Leader messages kept for the reshape metrics (a reshape of 10 s at 50 Hz is 500)."""
_BATCH_LEAVES: Final = frozenset({keys.TRUTHS, keys.HOST_WHEELS, keys.HOST_STATUS, keys.SETPOINTS})


def key_patterns(fleet: str) -> list[str]:
    """The key expressions a collector of ``fleet`` must subscribe to."""
    return [
        keys.all_truth_pattern(fleet),
        keys.leader_key(fleet),
        keys.all_slots_pattern(fleet),
        keys.assignment_key(fleet),
        keys.all_wheels_pattern(fleet),
        keys.all_status_pattern(fleet),
        keys.clock_key(fleet),
        keys.truths_key(fleet),
        keys.all_host_wheels_pattern(fleet),
        keys.all_host_status_pattern(fleet),
        keys.setpoints_key(fleet),
        keys.fault_key(fleet),
    ]


def slot_ids_of(scn: Scenario) -> list[int]:
    """Slot numbers of a scenario's formation, in definition order (as the simulator logs them)."""
    from coordinator.core.formation import FormationSpec

    return [s.slot for s in FormationSpec.from_dict(dict(scn.formation)).slots]


class RunCollector:
    """Builds a :class:`RunLog` from the bus traffic of one fleet (see the module docstring).

    Args:
        robot_ids: the robots of the run, in the order of the log's robot axis.
        slot_ids: the formation's slot numbers in the order of the log's slot axis; ``None``
            takes every slot seen on the bus, sorted.
        fleet: the fleet name; samples of other fleets are ignored.
        dt_s: the plant tick in lockstep (sim time), ``None`` in realtime.
        ref_offset_m: distance ``l`` of the reference point ahead of the axle (eqs 10-11), m.
        body_radius_m: robot body radius for the separation monitor, m.
        t0_s: realtime only: bus time that becomes 0 s in the log (default: the first frame's).
        max_entries: realtime only: memory bound, the number of stored values (truth poses,
            wheel commands, slot positions, leader poses) above which the history is thinned:
            every other row (and value) is dropped and from then on one in two is kept, then
            one in four, ... (``stats()["decimation"]``: the current stride). A long run of a
            large fleet is so measured at a lower time resolution instead of growing without
            bound (issue 13: the launcher grew ~5.9 MiB/s with 300 robots). ``None``: no bound
            (lockstep is never thinned: its rows must equal the simulator's).
    """

    def __init__(
        self,
        robot_ids: Sequence[str],
        *,
        slot_ids: Sequence[int] | None = None,
        fleet: str = keys.DEFAULT_FLEET,
        dt_s: float | None = None,
        ref_offset_m: float,
        body_radius_m: float,
        t0_s: float | None = None,
        max_entries: int | None = None,
    ) -> None:
        if not robot_ids:
            raise ValueError("a run needs at least one robot")
        for rid in robot_ids:
            keys.check_robot_id(rid)
        if len(set(robot_ids)) != len(robot_ids):
            raise ValueError("duplicate robot id")
        if dt_s is not None and not (dt_s > 0.0 and math.isfinite(dt_s)):
            raise ValueError(f"dt_s must be positive and finite, got {dt_s!r}")
        self.fleet = keys.check_fleet(fleet)
        self.robot_ids = list(robot_ids)
        self.slot_ids = None if slot_ids is None else [int(s) for s in slot_ids]
        self.dt_s = dt_s
        self.ref_offset_m = float(ref_offset_m)
        self.body_radius_m = float(body_radius_m)
        self.t0_s = t0_s
        if max_entries is not None and max_entries < 1000:
            raise ValueError(f"max_entries must be >= 1000, got {max_entries}")
        self.max_entries = max_entries if dt_s is None else None
        self.stride = 1
        self._entries = 0
        self._row_decision: tuple[float, bool] | None = None  # (row key, kept) of the last row
        self._new_rows = 0
        self._index = {rid: i for i, rid in enumerate(self.robot_ids)}
        # truth rows: row key -> {robot index: (x, y, theta)}
        self._truth: dict[float, dict[int, tuple[float, float, float]]] = {}
        self._leader = Series()
        self._reshape_marks: list[tuple[float, str | None, float, int | None]] = []  # + slots
        self._slots: dict[int, Series] = {}
        self._assignment = Series()
        self._wheels = [Series() for _ in self.robot_ids]
        self._modes = [Series() for _ in self.robot_ids]
        self._status: list[Status | None] = [None] * len(self.robot_ids)
        # the safety filter counters of each robot's newest status (by t), None before any
        self._filter: list[dict[str, Any] | None] = [None] * len(self.robot_ids)
        self._filter_t: list[float] = [-math.inf] * len(self.robot_ids)
        self._latest_truth: list[tuple[float, float, float] | None] = [None] * len(robot_ids)
        self._alive: dict[str, bool] = {}
        self._last_truth_key: float | None = None
        self._last_clock: Clock | None = None
        # scripted faults' notices (bus_schemas.messages_fault), once each: row key -> entries
        self._faults: list[tuple[float, dict[str, Any]]] = []
        self._fault_ids: set[tuple[Any, ...]] = set()
        # Counters: per message name, plus rejected (bad payload), ignored (not ours / unknown).
        self.received: dict[str, int] = {}
        self.rejected = 0
        self.ignored = 0
        self.reject_reasons: dict[str, int] = {}

    @classmethod
    def for_scenario(
        cls,
        scn: Scenario,
        *,
        fleet: str = keys.DEFAULT_FLEET,
        lockstep: bool,
        max_entries: int | None = None,
    ) -> RunCollector:
        """A collector for a run of ``scn`` (robots, slots, dt and geometry from the scenario)."""
        geom = scn.agent.geometry
        return cls(
            scn.robot_ids,
            slot_ids=slot_ids_of(scn),
            fleet=fleet,
            dt_s=scn.dt_s if lockstep else None,
            ref_offset_m=geom.ref_offset_m,
            body_radius_m=geom.body_radius_m,
            max_entries=max_entries,
        )

    @property
    def lockstep(self) -> bool:
        return self.dt_s is not None

    # ------------------------------------------------------------------------------------------
    # Input
    # ------------------------------------------------------------------------------------------

    def _row_key(self, t: float, tick: int | None = None) -> float:
        if self.dt_s is None:
            return t
        return float(tick if tick is not None else round(t / self.dt_s))

    def _keep_row(self, row: float) -> bool:
        """Whether truth row ``row`` is stored (always, unless decimated)."""
        if row in self._truth:
            return True
        if self.stride == 1:
            return True
        last = self._row_decision
        if last is not None and last[0] == row:
            return last[1]
        self._new_rows += 1
        keep = self._new_rows % self.stride == 0
        self._row_decision = (row, keep)
        return keep

    def _thinned_series(self) -> list[Series]:
        return [self._leader, *self._wheels, *self._slots.values()]

    def _stored(self, n: int) -> None:
        """``n`` more values stored: thin the history when over the memory bound."""
        self._entries += n
        if self.max_entries is None or self._entries <= self.max_entries:
            return
        while self._entries > self.max_entries // 2:
            kept = set(sorted(self._truth)[::2])  # the first row (time 0 of the log) stays
            self._truth = {k: v for k, v in self._truth.items() if k in kept}
            for series in self._thinned_series():
                series.halve()
            self.stride *= 2
            self._entries = sum(len(r) for r in self._truth.values()) + sum(
                len(ser.keys) for ser in self._thinned_series()
            )
            if self.stride >= 1 << 20:
                break

    def _series(self) -> Series:
        return Series(stride=self.stride)

    def _reject(self, reason: str) -> bool:
        self.rejected += 1
        self.reject_reasons[reason] = self.reject_reasons.get(reason, 0) + 1
        return False

    def feed(self, key: str, payload: bytes | bytearray | memoryview) -> bool:  # noqa: PLR0915 (one branch per key the collector reads)
        """Take one sample of the bus. Returns True if it was used, False if it was ignored
        (another fleet, an unknown robot, a key the collector does not need) or rejected (bad
        payload: counted in ``rejected``)."""
        info = keys.parse_key(key)
        if info is None or info.fleet != self.fleet or info.leaf not in _LEAVES:
            self.ignored += 1
            return False
        leaf = info.leaf
        i: int | None = None
        if info.robot is not None:
            i = self._index.get(info.robot)
            if i is None:
                self.ignored += 1
                return False
        self.received[leaf] = self.received.get(leaf, 0) + 1
        if leaf in _BATCH_LEAVES:
            return self._feed_batch(leaf, payload)
        if leaf == keys.TRUTH:
            assert i is not None
            truth = decode(payload, Truth)
            if isinstance(truth, DecodeError):
                return self._reject(f"truth: {truth.reason}")
            row = self._row_key(truth.t)
            pose = (truth.x, truth.y, truth.theta)
            self._latest_truth[i] = pose
            if self._keep_row(row):
                frame = self._truth.setdefault(row, {})
                fresh = i not in frame
                frame[i] = pose
                self._stored(int(fresh))
            if self._last_truth_key is None or row > self._last_truth_key:
                self._last_truth_key = row
        elif leaf == keys.LEADER:
            leader = decode(payload, Leader)
            if isinstance(leader, DecodeError):
                return self._reject(f"leader: {leader.reason}")
            self._stored(
                self._leader.add(self._row_key(leader.t), (leader.x, leader.y, leader.theta))
            )
            if leader.reshape is not None and len(self._reshape_marks) < MAX_RESHAPE_MARKS:
                self._reshape_marks.append((leader.t, leader.shape, leader.reshape, leader.slots))
        elif leaf == keys.SLOT:
            slot = decode(payload, Slot)
            if isinstance(slot, DecodeError):
                return self._reject(f"slot: {slot.reason}")
            if slot.slot != info.slot:
                return self._reject("slot: field does not match the key")
            series = self._slots.setdefault(slot.slot, self._series())
            self._stored(series.add(self._row_key(slot.t), (slot.x, slot.y)))
        elif leaf == keys.ASSIGNMENT:
            assignment = decode(payload, Assignment)
            if isinstance(assignment, DecodeError):
                return self._reject(f"assignment: {assignment.reason}")
            self._assignment.add(self._row_key(assignment.t), dict(assignment.robots))
        elif leaf == keys.WHEELS:
            assert i is not None
            wheels = decode(payload, Wheels)
            if isinstance(wheels, DecodeError):
                return self._reject(f"wheels: {wheels.reason}")
            self._stored(
                self._wheels[i].add(
                    self._row_key(wheels.t, wheels.tick), (wheels.power_r, wheels.power_l)
                )
            )
        elif leaf == keys.STATUS:
            assert i is not None
            status = decode(payload, Status)
            if isinstance(status, DecodeError):
                return self._reject(f"status: {status.reason}")
            self._status[i] = status
            self._modes[i].add(self._row_key(status.t), MODE_CODES.get(status.mode, 0))
            if status.filter is not None:
                counts = {**status.filter, "min_clearance_m": status.min_clearance_m}
                self._filter_counters(i, status.t, counts)
        elif leaf == keys.FAULT:
            return self._feed_fault(payload)
        else:  # clock
            clock = decode(payload, Clock)
            if isinstance(clock, DecodeError):
                return self._reject(f"clock: {clock.reason}")
            self._last_clock = clock
        return True

    def _feed_fault(self, payload: bytes | bytearray | memoryview) -> bool:
        """A scripted fault's notice, kept once (a replayed tick repeats it); requests are the
        coordinator's business."""
        msg = decode(payload, Fault)
        if isinstance(msg, DecodeError):
            return self._reject(f"fault: {msg.reason}")
        if msg.request:
            return False
        ident = (msg.tick, msg.fault, msg.kind, msg.robot, bool(msg.undo), msg.t)
        if ident in self._fault_ids or len(self._faults) >= MAX_FAULTS:
            return False
        self._fault_ids.add(ident)
        entry = {
            "fault": msg.fault,
            "kind": msg.kind,
            "robot": msg.robot,
            "undo": bool(msg.undo),
            "tick": msg.tick,
        }
        self._faults.append((self._row_key(msg.t, msg.tick), entry))
        return True

    def fault_events(self, origin: float | None = None) -> list[dict[str, Any]]:
        """The faults sent, in the log's time base (``t_s``: lockstep ``tick * dt``; realtime
        bus time minus ``origin``, the log's first row)."""
        out = []
        for key, entry in self._faults:
            if self.dt_s is not None:
                t_s = key * self.dt_s
            else:
                base = origin if origin is not None else min(self._truth, default=key)
                t_s = key - base
            out.append({**entry, "t_s": t_s})
        return out

    def _feed_batch(self, leaf: str, payload: bytes | bytearray | memoryview) -> bool:
        """A batched message: each entry of a known robot as its per-robot message would be."""
        index = self._index
        if leaf == keys.TRUTHS:
            tb = decode(payload, TruthBatch)
            if isinstance(tb, DecodeError):
                return self._reject(f"truths: {tb.reason}")
            row = self._row_key(tb.stamp)
            keep = self._keep_row(row)
            frame = self._truth.setdefault(row, {}) if keep else {}
            before = len(frame)
            for rid, x, y, th in zip(tb.robots, tb.x, tb.y, tb.theta, strict=True):
                i = index.get(rid)
                if i is not None:
                    frame[i] = self._latest_truth[i] = (x, y, th)
            if keep:
                self._stored(len(frame) - before)
            if self._last_truth_key is None or row > self._last_truth_key:
                self._last_truth_key = row
        elif leaf == keys.HOST_WHEELS:
            wb = decode(payload, WheelsBatch)
            if isinstance(wb, DecodeError):
                return self._reject(f"host wheels: {wb.reason}")
            row = self._row_key(wb.t, wb.tick)
            stored = 0
            for rid, pr, pl in zip(wb.robots, wb.power_r, wb.power_l, strict=True):
                i = index.get(rid)
                if i is not None:
                    stored += self._wheels[i].add(row, (pr, pl))
            self._stored(stored)
        elif leaf == keys.HOST_STATUS:
            sb = decode(payload, StatusBatch)
            if isinstance(sb, DecodeError):
                return self._reject(f"host status: {sb.reason}")
            rows = zip(sb.robots, sb.mode, sb.slot, sb.rejected, sb.ex, sb.ey, strict=True)
            for rid, mode, slot, rejected, ex, ey in rows:
                i = index.get(rid)
                if i is None:
                    continue
                self._status[i] = Status(
                    t=sb.t, seq=sb.seq, mode=mode, slot=None if slot < 0 else slot, pid=sb.pid,
                    host=sb.host, rejected=rejected, ex=ex, ey=ey, robot=rid,
                )  # fmt: skip
                self._modes[i].add(self._row_key(sb.t), MODE_CODES.get(mode, 0))
            if sb.filter_active is not None:  # no tick count in the batched form
                filters = zip(
                    sb.robots, sb.filter_active, sb.filter_violations or (),
                    sb.filter_infeasible or (), sb.filter_tiebreaks or (), strict=False,
                )  # fmt: skip
                for rid, active, violations, infeasible, tiebreaks in filters:
                    i = index.get(rid)
                    if i is not None:
                        counts = {"active": active, "violations": violations,
                                  "infeasible": infeasible, "tiebreaks": tiebreaks}  # fmt: skip
                        self._filter_counters(i, sb.t, counts)
        else:  # setpoints: the assigned slots' positions of every tick (slot keys come at 1 Hz)
            sp = decode(payload, SetpointBatch)
            if isinstance(sp, DecodeError):
                return self._reject(f"setpoints: {sp.reason}")
            row = self._row_key(sp.t, sp.tick)
            stored = 0
            for slot, x, y in zip(sp.slot, sp.x, sp.y, strict=True):
                stored += self._slots.setdefault(slot, self._series()).add(row, (x, y))
            self._stored(stored)
        return True

    def _filter_counters(self, i: int, t: float, counts: dict[str, Any]) -> None:
        """Robot ``i``'s safety filter counters as of its status at ``t`` (the newest kept: the
        counters only grow, and a status may arrive after a newer one)."""
        if t >= self._filter_t[i]:
            self._filter[i], self._filter_t[i] = counts, t

    def feed_alive(self, key: str, alive: bool) -> None:
        """A liveliness token of this fleet appeared (``alive``) or vanished."""
        parsed = keys.parse_alive_key(key)
        if parsed is None or parsed[0] != self.fleet:
            return
        _, kind, ident = parsed
        self._alive[f"{kind}/{ident}" if ident is not None else kind] = alive

    def feed_all(self, samples: Iterable[tuple[str, bytes]]) -> int:
        """Feed ``(key, payload)`` pairs in order; return how many were used."""
        return sum(self.feed(k, p) for k, p in samples)

    # ------------------------------------------------------------------------------------------
    # Live view
    # ------------------------------------------------------------------------------------------

    @property
    def frames(self) -> int:
        """Truth rows (ticks or frames) seen so far."""
        return len(self._truth)

    @property
    def first_tick(self) -> int | None:
        """Lockstep: the first tick whose truth arrived (0 unless the collector joined late)."""
        if not self._truth or self.dt_s is None:
            return None
        return int(min(self._truth))

    @property
    def last_truth_tick(self) -> int | None:
        """Lockstep: the latest tick whose truth arrived (None in realtime or before any)."""
        if self._last_truth_key is None or self.dt_s is None:
            return None
        return round(self._last_truth_key)

    def tick_complete(self, k: int) -> bool:
        """Lockstep: whether the collector holds everything of tick ``k`` that a row needs: the
        truth of every robot, the coordinator's leader of tick ``k`` and the wheel commands
        answering it of every robot whose agent is not known to be gone (the answers the plant
        waited for before it went on). What the launcher waits for at the end of a run, instead
        of a time: on a starved machine the answers can arrive long after the truth."""
        if self.dt_s is None:
            return False
        key = float(k)
        if len(self._truth.get(key, ())) < len(self.robot_ids) or self._leader.max_key < key:
            return False
        off = self.offline_at(key)
        return all(
            series.max_key >= key or self._alive.get(f"robot/{rid}") is False or rid in off
            for rid, series in zip(self.robot_ids, self._wheels, strict=True)
        )

    def offline_at(self, key: float) -> set[str]:
        """The robots a scripted fault keeps from answering at row ``key`` (killed, paused or
        cut off, per the notices received: the plant does not wait for them either)."""
        off: set[str] = set()
        for at, entry in self._faults:
            if at > key or entry["robot"] is None:
                continue
            if entry["kind"] in ("kill", "pause", "cut_link"):
                off.add(entry["robot"])
            elif entry["kind"] in ("resume", "restore_link") and entry["robot"] in off:
                off.discard(entry["robot"])
        return off

    @property
    def last_clock_tick(self) -> int | None:
        return None if self._last_clock is None else self._last_clock.tick

    def alive(self, kind: str, ident: str | None = None) -> bool | None:
        """Whether the token ``alive/<kind>[/<ident>]`` is present (None: never seen)."""
        return self._alive.get(f"{kind}/{ident}" if ident is not None else kind)

    def _key_time(self, key: float) -> float:
        if self.dt_s is not None:
            return key * self.dt_s
        t0 = self.t0_s if self.t0_s is not None else min(self._truth, default=key)
        return key - t0

    # ------------------------------------------------------------------------------------------
    # Output
    # ------------------------------------------------------------------------------------------

    def live(self) -> LiveView:
        """What the run looks like now, from the latest samples (cheap; call it at a few Hz;
        :func:`formation.record.collector_live.live_view`)."""
        last = self._last_truth_key
        return live_view(
            self.robot_ids,
            self._latest_truth,
            self._status,
            self._alive,
            self._assignment,
            self._slots,
            self._wheels,
            ref_offset_m=self.ref_offset_m,
            t_s=None if last is None else self._key_time(last),
            tick=self.last_clock_tick,
            rejected=self.rejected,
        )

    def build(self, meta: Mapping[str, Any] | None = None) -> RunLog:
        """The run so far as a :class:`RunLog` (can be called again later; it is rebuilt)."""
        rows, info = row_keys(
            self._truth, len(self.robot_ids), self._leader if self.lockstep else None
        )
        # the scenario's slots, then any a runtime reshape added (seen on the bus, issue 28)
        known = self.slot_ids if self.slot_ids is not None else []
        slot_ids = [*known, *(s for s in sorted(self._slots) if s not in known)]
        log = RunLog.allocate(self.robot_ids, slot_ids, rows.size)
        if rows.size:
            if self.dt_s is not None:
                t_s = rows * self.dt_s
            else:
                t_s = rows - (self.t0_s if self.t0_s is not None else float(rows[0]))
            info["truth_gaps"] = fill_rows(
                log,
                rows,
                t_s,
                RowSources(
                    truth=self._truth,
                    leader=self._leader,
                    slots=self._slots,
                    assignment=self._assignment,
                    wheels=self._wheels,
                    modes=self._modes,
                ),
                ref_offset_m=self.ref_offset_m,
                body_radius_m=self.body_radius_m,
            )
        if rows.size:
            origin = (
                (self.t0_s if self.t0_s is not None else float(rows[0]))
                if self.dt_s is None
                else 0.0
            )
            log.reshapes = reshape_intervals(self._reshape_marks, origin)
        log.filter_counts = {
            rid: dict(counts)
            for rid, counts in zip(self.robot_ids, self._filter, strict=True)
            if counts is not None
        }
        log.filter_source = "status" if log.filter_counts else None
        fault_origin: float | None = None
        if rows.size and self.dt_s is None:
            fault_origin = self.t0_s if self.t0_s is not None else float(rows[0])
        log.meta = {
            **dict(meta or {}),
            "faults": self.fault_events(fault_origin),
            "collector": self.stats(info),
        }
        return log

    def stats(self, rows_info: Mapping[str, Any] | None = None) -> dict[str, Any]:
        """Counters for the run's metadata: messages received per name, rejected, ignored, and
        (after :meth:`build`) rows dropped or patched."""
        out: dict[str, Any] = {
            "received": dict(sorted(self.received.items())),
            "rejected": self.rejected,
            "reject_reasons": dict(self.reject_reasons),
            "ignored": self.ignored,
            "frames": self.frames,
            "first_tick": self.first_tick,
            "decimation": self.stride,
            "max_entries": self.max_entries,
        }
        if rows_info is not None:
            out.update(rows_info)
        return out
