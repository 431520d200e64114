"""A run's record as arrays: what metrics and figures are computed from.

The in-process simulator fills it tick by tick; a recording of a distributed run is turned into
the same structure, so both are measured by one piece of code (``formation.outputs.metrics``).
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from dataclasses import dataclass, field
from itertools import chain
from operator import itemgetter
from typing import Any

import numpy as np
import numpy.typing as npt

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]

MODE_CODES = {"idle": 0, "tracking": 1, "hold": 2, "estop": 3}


def reference_points(truth: F64, ref_offset_m: float) -> F64:
    """Reference points ``(x_r, y_r)`` (m) of axle-centre poses ``truth[..., (x, y, theta)]``
    (eqs 10-11): shape ``truth.shape[:-1] + (2,)``, NaN where the pose is.

    The one vectorised form of :func:`robot_agent.core.kinematics.reference_point` (the same
    operations), kept apart because a log holds T x n poses: one numpy pass over the whole
    array instead of a Python call per pose, and robot_agent stays stdlib-only (no numpy on a
    robot). It calls nothing else. numpy's cos / sin may round an ulp apart from libm's, so it
    equals the scalar form to rounding (tests/unit/robot_agent/test_agent_kinematics.py).
    """
    th = truth[..., 2]
    out = np.empty((*truth.shape[:-1], 2))
    out[..., 0] = truth[..., 0] + ref_offset_m * np.cos(th)  # eq 10
    out[..., 1] = truth[..., 1] + ref_offset_m * np.sin(th)  # eq 11
    return out


SLOT_ROW_WIDTH = 4
"""Entries of a coordinator slot row, ``(x_m, y_m, vx_mps, vy_mps)``; the log keeps ``x, y``."""


def floats_of(values: list[float]) -> F64:
    """``values`` as a float64 array: each number's double packed straight into the array's
    buffer (``struct.pack_into``: about 7-10 ns a value here, ``np.fromiter`` over the list
    12-21, ``np.array``'s sequence discovery about 24-30); the same bits (NaNs and signed zeros
    included)."""
    n = len(values)
    out = np.empty(n, np.float64)
    struct.pack_into(f"{n}d", out.data, 0, *values)
    return out


def ints_of(values: list[int]) -> I64:
    """``values`` (each within int64) as an int64 array, packed as :func:`floats_of` packs."""
    n = len(values)
    out = np.empty(n, np.int64)
    struct.pack_into(f"{n}q", out.data, 0, *values)
    return out


def mode_code(mode: object) -> int:
    """The :data:`MODE_CODES` value of one firmware mode (a ``Mode`` member or its name;
    anything else 0)."""
    return MODE_CODES.get(str(mode), 0)


def mode_codes(modes: Sequence[Any]) -> I64:
    """:data:`MODE_CODES` of firmware modes (:func:`mode_code` of each), ``(len(modes),)``.
    Keyed by identity: C-level hashing of ints, few distinct modes."""
    mode_ids = list(map(id, modes))
    distinct = dict(zip(mode_ids, modes, strict=True))
    code_of = {i: mode_code(md) for i, md in distinct.items()}
    return np.fromiter(map(code_of.__getitem__, mode_ids), np.int64, len(mode_ids))


@dataclass
class RunLog:
    """Time series of one run. Shapes: T ticks, n robots, m slots.

    t_s (T,), truth (T, n, 3) axle centre x, y, theta, ref (T, n, 2) reference point from truth,
    target (T, n, 2) the assigned slot's position (NaN when unassigned), slot_of (T, n) slot
    number (-1 when unassigned), slot_xy (T, m, 2) every slot, leader (T, 3) virtual leader
    x, y, theta, power (T, n, 2) commanded motor power right/left (fraction of max), mode (T, n).
    """

    robot_ids: list[str]
    slot_ids: list[int]
    t_s: F64
    truth: F64
    ref: F64
    target: F64
    slot_of: I64
    slot_xy: F64
    leader: F64
    power: F64
    mode: I64
    min_separation_m: float = float("inf")
    collisions: list[dict[str, Any]] = field(default_factory=list)
    meta: dict[str, Any] = field(default_factory=dict)
    # Safety accounting (issue 14; formation.outputs.metrics.safety_metrics). body_radius_m and
    # safety_distance_m (Ds) NaN when unknown; world the scenario's WorldMap (obstacles, arena)
    # or None; filter_counts robot id -> the firmware's safety filter counters
    # (SafetyFilterStatus.as_dict()), empty when unknown (a recording without them);
    # filter_source where they come from: "firmware" (the in-process simulator's objects),
    # "status" (the agents' last Status on the bus: formation.record.collector), None (unknown).
    body_radius_m: float = float("nan")
    safety_distance_m: float = float("nan")
    world: Any = None
    filter_counts: dict[str, dict[str, Any]] = field(default_factory=dict)
    filter_source: str | None = "firmware"
    # runtime reshapes (issue 28): one {"kind", "start_s", "end_s"} per reshape the leader
    # messages reported (times on t_s's axis); formation.outputs.metrics adds what they cost
    reshapes: list[dict[str, Any]] = field(default_factory=list)
    # run-time plans (issue 27): one {"t_s", "reason", "plan_time_s", "length_m"} (optionally
    # "path": [[x, y], ...]) per plan the coordinator switched in at run time (an operator's
    # goal, every replan) or found to have no way, times on t_s's axis;
    # formation.outputs.plan_view measures and draws them. Empty: none (planned once at start)
    replans: list[dict[str, Any]] = field(default_factory=list)

    @classmethod
    def allocate(cls, robot_ids: list[str], slot_ids: list[int], ticks: int) -> RunLog:
        n, m = len(robot_ids), len(slot_ids)
        nan = np.nan
        return cls(
            robot_ids=list(robot_ids),
            slot_ids=list(slot_ids),
            t_s=np.full(ticks, nan),
            truth=np.full((ticks, n, 3), nan),
            ref=np.full((ticks, n, 2), nan),
            target=np.full((ticks, n, 2), nan),
            slot_of=np.full((ticks, n), -1, dtype=np.int64),
            slot_xy=np.full((ticks, m, 2), nan),
            leader=np.full((ticks, 3), nan),
            power=np.zeros((ticks, n, 2)),
            mode=np.zeros((ticks, n), dtype=np.int64),
        )

    @classmethod
    def from_ticks(
        cls,
        robot_ids: list[str],
        slot_ids: list[int],
        dt_s: float,
        truth: Sequence[Sequence[Sequence[float]]],
        leader: Sequence[tuple[float, float, float]],
        slot_rows: Sequence[Sequence[Sequence[float]]],
        slot_of_changes: Sequence[tuple[int, Sequence[int]]],
        power_mode: Sequence[Sequence[Sequence[Any]]],
        ref_offset_m: float,
    ) -> RunLog:
        """Build the arrays at the end of a run from what a loop kept per tick (plain lists are
        much cheaper to append to than numpy element writes are to make, tick by tick).

        Tick ``k`` is at ``t = k * dt_s``. Per tick: ``truth[k]`` the ``n`` rows ``(x, y,
        theta)``; ``leader[k]`` ``(x, y, theta)``; ``slot_rows[k]`` the ``m`` slots' rows whose
        first two entries are ``(x, y)``, in ``slot_ids`` order; ``power_mode[k]`` per robot a
        sequence whose entries 2, 3 and 4 are power right, power left and the mode (a
        ``WheelCommand``). ``slot_of_changes``: ``(k, row)`` whenever the robots' slots (``-1``
        unassigned, robots in ``robot_ids`` order) changed, from ``k`` on, in tick order; before
        the first entry no robot has a slot. The reference point (eqs 10-11, ``ref_offset_m``)
        and the assigned slot's position (``target``) are derived here in one vectorised pass.
        """
        n, m, ticks = len(robot_ids), len(slot_ids), len(truth)
        flat = chain.from_iterable
        f64 = np.float64
        # np.fromiter over flattened tuples: C-level iteration, several times faster than
        # np.array's nested-sequence discovery.
        tr = np.fromiter(flat(flat(truth)), f64, ticks * n * 3).reshape(ticks, n, 3)
        width = len(slot_rows[0][0]) if ticks and m else 2
        slot_xy = np.ascontiguousarray(
            np.fromiter(flat(flat(slot_rows)), f64, ticks * m * width).reshape(ticks, m, width)[
                :, :, :2
            ]
        )
        cmds = list(flat(power_mode))
        power = np.empty((ticks, n, 2))  # one field at a time: no pair tuple per command
        power[:, :, 0] = np.fromiter(map(itemgetter(2), cmds), f64, len(cmds)).reshape(ticks, n)
        power[:, :, 1] = np.fromiter(map(itemgetter(3), cmds), f64, len(cmds)).reshape(ticks, n)
        mode = mode_codes(list(map(itemgetter(4), cmds))).reshape(ticks, n)
        leader_arr = np.fromiter(flat(leader), f64, ticks * 3).reshape(ticks, 3)
        return cls.from_arrays(
            robot_ids, slot_ids, dt_s, tr, leader_arr, slot_xy, slot_of_changes, power, mode,
            ref_offset_m,
        )  # fmt: skip

    @classmethod
    def from_flat(
        cls,
        robot_ids: list[str],
        slot_ids: list[int],
        dt_s: float,
        ticks: int,
        truth: F64,
        leader: F64,
        slot_rows: F64,
        tick_slot_ids: Sequence[tuple[int, ...]] | None,
        slot_of_changes: Sequence[tuple[int, Sequence[int]]],
        power: F64,
        mode: I64,
        ref_offset_m: float,
    ) -> RunLog:
        """Build the arrays at the end of a run from per-tick numbers kept flat
        (``formation.sim.ticklog.TickLog``: 1-d arrays, tick after tick): ``truth`` ``n`` x
        ``(x, y, theta)``, ``leader`` ``(x, y, theta)``, ``slot_rows`` the tick's slot rows of
        :data:`SLOT_ROW_WIDTH` entries (``(x, y, ...)``), ``power`` ``n`` x ``(power_r,
        power_l)``, ``mode`` ``n`` :data:`MODE_CODES`; ``slot_of_changes`` as in
        :meth:`from_ticks`.

        ``tick_slot_ids``: None when every tick has the rows of ``slot_ids``; else each tick's
        slot ids (an operator reshape may add, drop and reorder slots), and the log's slots are
        every slot the run had, first seen first (``slot_ids`` first), NaN where a tick had no
        such slot.
        """
        n = len(robot_ids)
        tr = truth.reshape(ticks, n, 3)
        leader_arr = leader.reshape(ticks, 3)
        power_arr = power.reshape(ticks, n, 2)
        mode_arr = mode.reshape(ticks, n)
        rows = slot_rows.reshape(-1, SLOT_ROW_WIDTH)[:, :2]
        order = list(slot_ids)
        distinct = list(dict.fromkeys(tick_slot_ids)) if tick_slot_ids is not None else []
        for ids in distinct:
            order += [s for s in ids if s not in order]
        m = len(order)
        if all(ids == tuple(order) for ids in distinct):
            slot_xy = np.ascontiguousarray(rows.reshape(ticks, m, 2))
        else:  # a reshape added, dropped or reordered slots: each row to its slot id's column
            assert tick_slot_ids is not None
            col = {s: c for c, s in enumerate(order)}
            kk = [k for k, ids in enumerate(tick_slot_ids) for _ in ids]
            cc = [col[s] for ids in tick_slot_ids for s in ids]
            slot_xy = np.full((ticks, m, 2), np.nan)
            slot_xy[kk, cc] = rows
        return cls.from_arrays(
            robot_ids, order, dt_s, tr, leader_arr, slot_xy, slot_of_changes, power_arr, mode_arr,
            ref_offset_m,
        )  # fmt: skip

    @classmethod
    def from_arrays(
        cls,
        robot_ids: list[str],
        slot_ids: list[int],
        dt_s: float,
        truth: F64,
        leader: F64,
        slot_xy: F64,
        slot_of_changes: Sequence[tuple[int, Sequence[int]]],
        power: F64,
        mode: I64,
        ref_offset_m: float,
    ) -> RunLog:
        """The log from its recorded arrays (shapes as the class says; ``slot_xy``'s slots in
        ``slot_ids`` order) and the slot changes (as :meth:`from_ticks`): ``t_s``, ``ref``
        (eqs 10-11), ``slot_of`` and ``target`` are derived here in one vectorised pass."""
        ticks, n = truth.shape[0], len(robot_ids)
        m = len(slot_ids)
        t_s = np.arange(ticks, dtype=np.float64) * dt_s  # == k * dt_s, tick by tick
        ref = reference_points(truth, ref_offset_m)  # eqs 10-11 over the whole log at once
        slot_of = np.full((ticks, n), -1, dtype=np.int64)
        for j, (k, row) in enumerate(slot_of_changes):
            end = slot_of_changes[j + 1][0] if j + 1 < len(slot_of_changes) else ticks
            slot_of[k:end] = row
        target = np.full((ticks, n, 2), np.nan)
        if m:
            row_of = np.full(max(slot_ids) + 2, -1, dtype=np.int64)  # slot id -> row; -1 -> -1
            row_of[np.asarray(slot_ids, dtype=np.int64)] = np.arange(m)
            rows_idx = row_of[slot_of]  # slot_of == -1 reads the last entry, which is -1
            kk, ii = np.nonzero(rows_idx >= 0)
            target[kk, ii] = slot_xy[kk, rows_idx[kk, ii]]
        return cls(
            robot_ids=list(robot_ids),
            slot_ids=list(slot_ids),
            t_s=t_s,
            truth=truth,
            ref=ref,
            target=target,
            slot_of=slot_of,
            slot_xy=slot_xy,
            leader=leader,
            power=power,
            mode=mode,
        )

    def truncate(self, ticks: int) -> None:
        for name in ("t_s", "truth", "ref", "target", "slot_of", "slot_xy", "leader", "power",
                     "mode"):  # fmt: skip
            setattr(self, name, getattr(self, name)[:ticks])

    def save_npz(self, path: str) -> None:
        np.savez_compressed(
            path,
            robot_ids=np.array(self.robot_ids),
            slot_ids=np.array(self.slot_ids),
            t_s=self.t_s,
            truth=self.truth,
            ref=self.ref,
            target=self.target,
            slot_of=self.slot_of,
            slot_xy=self.slot_xy,
            leader=self.leader,
            power=self.power,
            mode=self.mode,
        )
