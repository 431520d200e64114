"""The history a :class:`formation.record.collector.RunCollector` keeps of a run, by row key (the
tick in lockstep, bus time in realtime), and its memory bound.

:class:`RunHistory` owns the truth rows, the leader (and its reshape marks), the slots, the
assignment, each robot's wheel commands and firmware modes, and the bound: over ``max_entries``
stored values (realtime only) every other truth row and value is dropped and from then on one
in two is kept, then one in four, ... (``stride``), so a long run of a large fleet is measured at
a lower time resolution instead of growing without bound (issue 13)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Final

from bus_schemas import Assignment, Leader
from formation.record.collector_build import RowSources
from formation.record.collector_decode import SlotPositions, TruthFrame, WheelPowers
from formation.record.collector_series import Series

__all__ = ["MAX_RESHAPE_MARKS", "RunHistory"]

MAX_RESHAPE_MARKS: Final = 100_000
"""Leader messages kept for the reshape metrics (a reshape of 10 s at 50 Hz is 500)."""
_MAX_STRIDE: Final = 1 << 20


class RunHistory:
    """What a run's rows are built from (module docstring): ``n_robots`` robots, ``dt_s`` the
    lockstep tick (None in realtime), ``max_entries`` the realtime memory bound (None: none;
    lockstep is never thinned: its rows must equal the simulator's)."""

    def __init__(self, n_robots: int, dt_s: float | None, max_entries: int | None) -> None:
        if max_entries is not None and max_entries < 1000:
            raise ValueError(f"max_entries must be >= 1000, got {max_entries}")
        self.dt_s = dt_s
        self.max_entries = max_entries if dt_s is None else None
        self.stride = 1
        self.entries = 0  # values stored (the memory bound counts these)
        self._row_decision: tuple[float, bool] | None = None  # (row key, kept) of the last row
        self._new_rows = 0
        # truth rows: row key -> {robot index: (x, y, theta)}
        self.truth: dict[float, dict[int, tuple[float, float, float]]] = {}
        self.last_truth_key: float | None = None
        self.leader = Series()
        # (t, shape, fraction, slots)
        self.reshape_marks: list[tuple[float, str | None, float, int | None]] = []
        self.slots: dict[int, Series] = {}
        self.assignment = Series()
        self.wheels = [Series() for _ in range(n_robots)]
        self.modes = [Series() for _ in range(n_robots)]

    def row_key(self, t: float, tick: int | None = None) -> float:
        """The row of a value stamped ``t`` (bus time; ``tick``: its lockstep tick, if given)."""
        if self.dt_s is None:
            return t
        return float(tick if tick is not None else round(t / self.dt_s))

    # -- adding -----------------------------------------------------------------------------------

    def add_truth(self, frame: TruthFrame) -> None:
        row = self.row_key(frame.t)
        if self._keep_row(row):
            poses = self.truth.setdefault(row, {})
            before = len(poses)
            poses.update(frame.poses)
            self._stored(len(poses) - before)
        if self.last_truth_key is None or row > self.last_truth_key:
            self.last_truth_key = row

    def add_leader(self, leader: Leader) -> None:
        pose = (leader.x, leader.y, leader.theta)
        self._stored(self.leader.add(self.row_key(leader.t), pose))
        if leader.reshape is not None and len(self.reshape_marks) < MAX_RESHAPE_MARKS:
            self.reshape_marks.append((leader.t, leader.shape, leader.reshape, leader.slots))

    def add_slots(self, positions: SlotPositions) -> None:
        row = self.row_key(positions.t, positions.tick)
        stored = 0
        for slot, xy in positions.positions:
            stored += self.slots.setdefault(slot, Series(stride=self.stride)).add(row, xy)
        self._stored(stored)

    def add_assignment(self, assignment: Assignment) -> None:
        self.assignment.add(self.row_key(assignment.t), dict(assignment.robots))

    def add_wheels(self, powers: WheelPowers) -> None:
        row = self.row_key(powers.t, powers.tick)
        self._stored(sum(self.wheels[i].add(row, power) for i, power in powers.powers))

    def add_mode(self, i: int, t: float, code: int) -> None:
        """Robot ``i``'s firmware mode (a ``formation.outputs.runlog.MODE_CODES`` value)."""
        self.modes[i].add(self.row_key(t), code)

    # -- the memory bound -------------------------------------------------------------------------

    def _keep_row(self, row: float) -> bool:
        """Whether truth row ``row`` is stored (always, unless decimated)."""
        if row in self.truth or self.stride == 1:
            return True
        last = self._row_decision
        if last is not None and last[0] == row:
            return last[1]
        self._new_rows += 1
        keep = self._new_rows % self.stride == 0
        self._row_decision = (row, keep)
        return keep

    def thinned_series(self) -> list[Series]:
        """The series the memory bound thins (with the truth rows)."""
        return [self.leader, *self.wheels, *self.slots.values()]

    def _stored(self, n: int) -> None:
        """``n`` more values stored: thin the history when over the memory bound."""
        self.entries += n
        if self.max_entries is None or self.entries <= self.max_entries:
            return
        while self.entries > self.max_entries // 2:
            kept = set(sorted(self.truth)[::2])  # the first row (time 0 of the log) stays
            self.truth = {k: v for k, v in self.truth.items() if k in kept}
            for series in self.thinned_series():
                series.halve()
            self.stride *= 2
            self.entries = sum(len(r) for r in self.truth.values()) + sum(
                len(ser.keys) for ser in self.thinned_series()
            )
            if self.stride >= _MAX_STRIDE:
                break

    # -- reading ----------------------------------------------------------------------------------

    def tick_answered(self, key: float, n_robots: int, gone: Sequence[bool]) -> bool:
        """Lockstep: row ``key`` holds the truth of all ``n_robots``, the leader of the tick and
        the wheel commands answering it of every robot ``i`` not ``gone[i]``."""
        if len(self.truth.get(key, ())) < n_robots or self.leader.max_key < key:
            return False
        return all(
            series.max_key >= key or out for series, out in zip(self.wheels, gone, strict=True)
        )

    def first_key(self) -> float:
        """The first truth row's key (call with rows only)."""
        return min(self.truth)

    def sources(self) -> RowSources:
        return RowSources(
            truth=self.truth,
            leader=self.leader,
            slots=self.slots,
            assignment=self.assignment,
            wheels=self.wheels,
            modes=self.modes,
        )

    def stats(self) -> dict[str, Any]:
        return {"decimation": self.stride, "max_entries": self.max_entries}
