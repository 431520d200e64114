"""The rows of a collected run: which rows :meth:`formation.record.collector.RunCollector.build`
keeps
(:func:`row_keys`) and what it writes into them (:func:`fill_rows`), into a
:class:`~formation.outputs.runlog.RunLog`, from the series it stored.

Row ``r`` holds the truth of every robot at the row's key (a robot's previous pose stands in for
a dropped sample), the reference points computed from it (eqs 10-11), and, sampled as "the
latest value at or before the row", the leader, the slots, the assignment, the wheel commands
and the firmware modes. Separation and collisions come from
:class:`sim_plant.core.accounting.SeparationMonitor` fed with the rows in order, as in the
simulator.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from formation.outputs.runlog import RunLog, reference_points
from formation.record.collector_series import Series, sample_at
from sim_plant.core.accounting import SeparationMonitor

__all__ = ["RowSources", "fill_rows", "row_keys"]

F64 = npt.NDArray[np.float64]


@dataclass(frozen=True, slots=True)
class RowSources:
    """What the collector stored, by row key (tick in lockstep, bus time in realtime)."""

    truth: Mapping[float, Mapping[int, tuple[float, float, float]]]  # row -> robot index -> pose
    leader: Series  # (x, y, theta)
    slots: Mapping[int, Series]  # slot -> (x, y)
    assignment: Series  # {robot id: slot}
    wheels: Sequence[Series]  # per robot index: (power_r, power_l)
    modes: Sequence[Series]  # per robot index: formation.outputs.runlog.MODE_CODES value


def row_keys(
    truth: Mapping[float, Mapping[int, object]], n_robots: int, leader: Series | None
) -> tuple[F64, dict[str, Any]]:
    """The sorted keys of the rows a log gets from ``truth`` (row key -> robot index -> pose),
    and what was dropped: leading rows before all ``n_robots`` robots appeared and, in lockstep
    (``leader``: the coordinator's leader series; None in realtime), trailing ticks the
    coordinator did not answer."""
    info: dict[str, Any] = {
        "leading_incomplete": 0,
        "trailing_unanswered": 0,
        "missing_ticks": 0,
    }
    all_keys = sorted(truth)
    n = n_robots
    seen: set[int] = set()
    start = len(all_keys)
    for j, k in enumerate(all_keys):
        seen.update(truth[k])
        if len(seen) == n:
            start = j
            break
    info["leading_incomplete"] = start
    kept = all_keys[start:]
    if leader is not None and kept:
        answered = max(leader.keys, default=-math.inf)
        while kept and kept[-1] > answered:
            kept.pop()
            info["trailing_unanswered"] += 1
        if kept:
            info["missing_ticks"] = int(kept[-1] - kept[0] + 1) - len(kept)
    return np.array(kept, dtype=float), info


def fill_rows(
    log: RunLog,
    rows: F64,
    t_s: F64,
    src: RowSources,
    *,
    ref_offset_m: float,
    body_radius_m: float,
) -> int:
    """Fill ``log`` (allocated with ``rows.size`` rows) from ``src``; return the truth gaps (robot
    poses held over a dropped sample). ``t_s`` is the time of each row in the log."""
    robot_ids = log.robot_ids
    n = len(robot_ids)
    gaps = 0
    last: list[tuple[float, float, float] | None] = [None] * n
    for r, k in enumerate(rows.tolist()):
        frame = src.truth[k]
        for i in range(n):
            pose = frame.get(i)
            if pose is None:
                gaps += last[i] is not None
                pose = last[i]
            if pose is not None:
                log.truth[r, i] = pose
                last[i] = pose
    log.t_s[:] = t_s
    log.ref[:] = reference_points(log.truth, ref_offset_m)  # eqs 10-11

    for r, v in enumerate(sample_at(src.leader, rows)):
        if v is not None:
            log.leader[r] = v
    slot_row = {s: m for m, s in enumerate(log.slot_ids)}
    for s, series in src.slots.items():
        m = slot_row.get(s)
        if m is None:
            continue
        for r, v in enumerate(sample_at(series, rows)):
            if v is not None:
                log.slot_xy[r, m] = v
    index = {rid: j for j, rid in enumerate(robot_ids)}
    for r, a in enumerate(sample_at(src.assignment, rows)):
        if a is None:
            continue
        for rid, slot in a.items():
            j = index.get(rid)
            if j is None:
                continue
            log.slot_of[r, j] = slot
            m = slot_row.get(slot)
            if m is not None:
                log.target[r, j] = log.slot_xy[r, m]
    for i in range(n):
        for r, v in enumerate(sample_at(src.wheels[i], rows)):
            if v is not None:
                log.power[r, i] = v
        for r, v in enumerate(sample_at(src.modes[i], rows)):
            if v is not None:
                log.mode[r, i] = v

    monitor = SeparationMonitor(body_radius_m)
    for r in range(rows.size):
        monitor.update(float(log.t_s[r]), log.truth[r])
    log.min_separation_m = float(monitor.min_separation_m)
    log.collisions = [
        {
            "t_s": float(e.t_s),
            "i": robot_ids[e.i],
            "j": robot_ids[e.j],
            "distance_m": float(e.distance_m),
        }
        for e in monitor.collisions
    ]
    return gaps


def reshape_intervals(marks: Sequence[tuple[Any, ...]], origin_s: float) -> list[dict[str, Any]]:
    """The runtime reshapes (issue 28) in the leader messages' ``(t, shape, reshape fraction[,
    slots])`` marks: one ``{"kind", "start_s", "end_s", "complete"}`` per reshape (times minus
    ``origin_s``, the RunLog's axis), with ``"slots"`` (the number it ends with) when the marks
    carry it. A new reshape starts where the fraction falls back or the shape changes."""
    out: list[dict[str, Any]] = []
    last: tuple[Any, ...] | None = None
    for mark in sorted(marks, key=lambda m: m[0]):
        t, shape, frac = mark[0], mark[1], mark[2]
        slots = mark[3] if len(mark) > 3 else None
        if last is None or shape != last[1] or frac < last[2]:
            out.append({"kind": shape, "start_s": t - origin_s, "end_s": t - origin_s})
        out[-1]["end_s"] = t - origin_s
        out[-1]["complete"] = frac >= 1.0
        if slots is not None:
            out[-1]["slots"] = slots
        last = mark
    return out
