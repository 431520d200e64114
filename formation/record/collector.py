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
status: ``RunLog.filter_counts``, ``filter_source`` ``"status"``), ``clock`` and each
coordinator's status (its run-time plans: ``RunLog.replans`` and ``meta["planner"]``,
:mod:`formation.record.collector_plans`) and the plant's status (its lockstep timeouts:
``meta["plant"]``, :mod:`formation.record.collector_plant`). Every payload is decoded with
the strict ``bus_schemas`` decoder; a bad one is counted (``rejected``) and otherwise ignored.

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

Parts
-----
:class:`RunCollector` composes the parts that own each piece of the record:
:class:`~formation.record.collector_decode.SampleGate` and
:func:`~formation.record.collector_decode.decode_sample` (which samples are read, the counters,
each stream's decoding, batched and per-robot alike),
:class:`~formation.record.collector_history.RunHistory` (the rows' sources and the memory bound),
:class:`~formation.record.collector_robots.RobotStates` (each robot's latest state, liveliness),
:class:`~formation.record.collector_faults.FaultNotices` (the scripted faults),
:class:`~formation.record.collector_plans.PlanNotices` (the coordinator's run-time plans),
:class:`~formation.record.collector_plant.PlantReports` (the plant's status); the log is
written by :mod:`formation.record.collector_build`, the live view by
:mod:`formation.record.collector_live`.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from typing import Any

from bus_schemas import Assignment, Clock, CoordinatorStatus, Fault, Leader, PlantStatus, keys
from formation.outputs.live_table import LiveView
from formation.outputs.runlog import MODE_CODES, RunLog
from formation.record.collector_build import fill_rows, reshape_intervals, row_keys
from formation.record.collector_decode import (
    Rejected,
    RobotStatuses,
    SampleGate,
    SlotPositions,
    TruthFrame,
    WheelPowers,
    decode_sample,
)
from formation.record.collector_faults import FaultNotices
from formation.record.collector_history import RunHistory
from formation.record.collector_live import live_view
from formation.record.collector_plans import PlanNotices
from formation.record.collector_plant import PlantReports
from formation.record.collector_robots import RobotStates
from scenario import Scenario

__all__ = ["RunCollector", "key_patterns", "slot_ids_of"]


def key_patterns(fleet: str, *, lockstep: bool = False) -> list[str]:
    """The key expressions a collector of ``fleet`` must subscribe to. A lockstep run's truth
    is the ``truths`` batch only: its plant puts each robot's ``truth`` only while someone
    subscribes to it (sim_plant.node.outputs), so a lockstep collector leaves those keys out."""
    return [
        *(() if lockstep else (keys.all_truth_pattern(fleet),)),
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
        keys.all_coordinator_status_pattern(fleet),
        keys.plant_status_key(fleet),
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
        self._index = {rid: i for i, rid in enumerate(self.robot_ids)}
        self.gate = SampleGate(self.fleet, self._index)
        self.history = RunHistory(len(self.robot_ids), dt_s, max_entries)
        self.robots = RobotStates(self.robot_ids, self.fleet)
        self.faults = FaultNotices()
        self.plans = PlanNotices()
        self.plant = PlantReports()
        self._apply: dict[type[Any], Callable[[Any], bool]] = {
            TruthFrame: self._on_truth,
            WheelPowers: self._on_wheels,
            RobotStatuses: self._on_statuses,
            SlotPositions: self._on_slots,
            Leader: self._on_leader,
            Assignment: self._on_assignment,
            Clock: self._on_clock,
            Fault: self._on_fault,
            CoordinatorStatus: self._on_coordinator_status,
            PlantStatus: self.plant.add,
        }

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

    # the counters (SampleGate) and the memory bound (RunHistory), read by tools and tests
    @property
    def received(self) -> dict[str, int]:
        return self.gate.received

    @property
    def rejected(self) -> int:
        return self.gate.rejected

    @property
    def ignored(self) -> int:
        return self.gate.ignored

    @property
    def reject_reasons(self) -> dict[str, int]:
        return self.gate.reject_reasons

    @property
    def max_entries(self) -> int | None:
        return self.history.max_entries

    @property
    def stride(self) -> int:
        return self.history.stride

    # ------------------------------------------------------------------------------------------
    # Input
    # ------------------------------------------------------------------------------------------

    def feed(self, key: str, payload: bytes | bytearray | memoryview) -> bool:
        """Take one sample of the bus. Returns True if it was used, False if it was ignored
        (another fleet, an unknown robot, a key the collector does not need) or rejected (bad
        payload: counted in ``rejected``)."""
        sample = self.gate.admit(key)
        if sample is None:
            return False
        seen = decode_sample(sample, payload, self._index)
        if isinstance(seen, Rejected):
            return self.gate.reject(seen.reason)
        return self._apply[type(seen)](seen)

    def _on_truth(self, frame: TruthFrame) -> bool:
        for i, pose in frame.poses:
            self.robots.pose(i, pose)
        self.history.add_truth(frame)
        return True

    def _on_wheels(self, powers: WheelPowers) -> bool:
        self.history.add_wheels(powers)
        return True

    def _on_statuses(self, seen: RobotStatuses) -> bool:
        for i, status in seen.statuses:
            self.robots.status[i] = status
            self.history.add_mode(i, seen.t, MODE_CODES.get(status.mode, 0))
        for i, counts in seen.filters:
            self.robots.filter_counters(i, seen.t, counts)
        return True

    def _on_slots(self, positions: SlotPositions) -> bool:
        self.history.add_slots(positions)
        return True

    def _on_leader(self, leader: Leader) -> bool:
        self.history.add_leader(leader)
        return True

    def _on_assignment(self, assignment: Assignment) -> bool:
        self.history.add_assignment(assignment)
        return True

    def _on_clock(self, clock: Clock) -> bool:
        self.robots.last_clock = clock
        return True

    def _on_fault(self, fault: Fault) -> bool:
        """A scripted fault's notice, kept once (a replayed tick repeats it)."""
        return self.faults.add(fault, self.history.row_key(fault.t, fault.tick))

    def _on_coordinator_status(self, status: CoordinatorStatus) -> bool:
        """A coordinator's status: its run-time plans (collector_plans)."""
        return self.plans.add(status, self.history.row_key(status.t))

    def feed_alive(self, key: str, alive: bool) -> None:
        """A liveliness token of this fleet appeared (``alive``) or vanished."""
        self.robots.feed_alive(key, alive)

    def feed_all(self, samples: Iterable[tuple[str, bytes]]) -> int:
        """Feed ``(key, payload)`` pairs in order; return how many were used."""
        return sum(self.feed(k, p) for k, p in samples)

    # ------------------------------------------------------------------------------------------
    # Live view
    # ------------------------------------------------------------------------------------------

    @property
    def frames(self) -> int:
        """Truth rows (ticks or frames) seen so far."""
        return len(self.history.truth)

    @property
    def first_tick(self) -> int | None:
        """Lockstep: the first tick whose truth arrived (0 unless the collector joined late)."""
        if not self.history.truth or self.dt_s is None:
            return None
        return int(self.history.first_key())

    @property
    def last_truth_tick(self) -> int | None:
        """Lockstep: the latest tick whose truth arrived (None in realtime or before any)."""
        last = self.history.last_truth_key
        if last is None or self.dt_s is None:
            return None
        return round(last)

    def tick_complete(self, k: int) -> bool:
        """Lockstep: whether the collector holds everything of tick ``k`` that a row needs: the
        truth of every robot, the coordinator's leader of tick ``k`` and the wheel commands
        answering it of every robot whose agent is not known to be gone (the answers the plant
        waited for before it went on). What the launcher waits for at the end of a run, instead
        of a time: on a starved machine the answers can arrive long after the truth."""
        if self.dt_s is None:
            return False
        key = float(k)
        off = self.offline_at(key)
        gone = [self.robots.alive("robot", rid) is False or rid in off for rid in self.robot_ids]
        return self.history.tick_answered(key, len(self.robot_ids), gone)

    def offline_at(self, key: float) -> set[str]:
        """The robots a scripted fault keeps from answering at row ``key`` (killed, paused or
        cut off, per the notices received: the plant does not wait for them either)."""
        return self.faults.offline_at(key)

    def fault_events(self, origin: float | None = None) -> list[dict[str, Any]]:
        """The faults sent, in the log's time base (``t_s``: lockstep ``tick * dt``; realtime
        bus time minus ``origin``, the log's first row)."""
        return self.faults.events(self._origin_time(origin))

    @property
    def last_clock_tick(self) -> int | None:
        clock = self.robots.last_clock
        return None if clock is None else clock.tick

    def alive(self, kind: str, ident: str | None = None) -> bool | None:
        """Whether the token ``alive/<kind>[/<ident>]`` is present (None: never seen)."""
        return self.robots.alive(kind, ident)

    def _key_time(self, key: float) -> float:
        if self.dt_s is not None:
            return key * self.dt_s
        t0 = self.t0_s if self.t0_s is not None else min(self.history.truth, default=key)
        return key - t0

    # ------------------------------------------------------------------------------------------
    # Output
    # ------------------------------------------------------------------------------------------

    def live(self) -> LiveView:
        """What the run looks like now, from the latest samples (cheap; call it at a few Hz;
        :func:`formation.record.collector_live.live_view`)."""
        last = self.history.last_truth_key
        return live_view(
            self.robot_ids,
            self.robots.latest_truth,
            self.robots.status,
            self.robots.tokens,
            self.history.assignment,
            self.history.slots,
            self.history.wheels,
            ref_offset_m=self.ref_offset_m,
            t_s=None if last is None else self._key_time(last),
            tick=self.last_clock_tick,
            rejected=self.rejected,
        )

    def build(self, meta: Mapping[str, Any] | None = None) -> RunLog:
        """The run so far as a :class:`RunLog` (can be called again later; it is rebuilt)."""
        history = self.history
        rows, info = row_keys(
            history.truth, len(self.robot_ids), history.leader if self.lockstep else None
        )
        # the scenario's slots, then any a runtime reshape added (seen on the bus, issue 28)
        known = self.slot_ids if self.slot_ids is not None else []
        slot_ids = [*known, *(s for s in sorted(history.slots) if s not in known)]
        log = RunLog.allocate(self.robot_ids, slot_ids, rows.size)
        origin: float | None = None  # realtime: the bus time of the log's 0 s
        if rows.size:
            if self.dt_s is not None:
                t_s = rows * self.dt_s
            else:
                origin = self.t0_s if self.t0_s is not None else float(rows[0])
                t_s = rows - origin
            info["truth_gaps"] = fill_rows(
                log,
                rows,
                t_s,
                history.sources(),
                ref_offset_m=self.ref_offset_m,
                body_radius_m=self.body_radius_m,
            )
            log.reshapes = reshape_intervals(history.reshape_marks, origin or 0.0)
        key_time = self._origin_time(origin)
        log.replans = self.plans.events(key_time)
        log.filter_counts = self.robots.filter_counts()
        log.filter_source = "status" if log.filter_counts else None
        log.meta = {
            **dict(meta or {}),
            "faults": self.fault_events(origin),
            "collector": self.stats(info),
        }
        planner = self.plans.counts()
        if planner is not None:
            log.meta["planner"] = planner
        plant = self.plant.summary()
        if plant is not None:
            log.meta["plant"] = plant
        return log

    def _origin_time(self, origin: float | None) -> Callable[[float], float]:
        """Row key -> the log's time (lockstep ``key * dt``; realtime bus time - ``origin``)."""
        dt_s, truth = self.dt_s, self.history.truth

        def key_time(key: float) -> float:
            if dt_s is not None:
                return key * dt_s
            return key - (origin if origin is not None else min(truth, default=key))

        return key_time

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
            **self.history.stats(),
        }
        if rows_info is not None:
            out.update(rows_info)
        return out
