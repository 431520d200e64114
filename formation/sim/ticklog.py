"""What the in-process loop records per tick, kept as flat lists of numbers (:class:`TickLog`).

The loop's log holds, per tick, the true poses, the virtual leader, every slot's row and each
robot's commanded power and mode. Kept as the per-tick objects themselves (the plant's pose
tuples, the coordinator's row tuples, the firmware's commands), about a hundred container
objects a tick stay alive at 30 robots: the garbage collector's youngest generation walks each
of them once (``formation.sim.collector``, about 15 us a tick at 30 robots) and building the
arrays at the end has to walk the nested tuples again (``np.fromiter`` over chained iterators,
about 15 us a tick). Here each tick's numbers are appended to flat lists instead (a float is not
tracked by the collector; ``list.extend`` of a tuple copies its references in C), the objects
are freed by reference counting the moment the loop drops them, and every :data:`CHUNK_TICKS`
ticks the lists are converted to arrays (``floats_of``: packed, while their numbers are still in
the caches) and emptied; :meth:`TickLog.runlog` joins the chunks
(:meth:`formation.outputs.runlog.RunLog.from_flat`). The same floats, so the same bits as
:meth:`~formation.outputs.runlog.RunLog.from_ticks`. A mode is kept as its code
(:func:`~formation.outputs.runlog.mode_code`), worked out again only when the mode object
differs from the last one coded (a few shared ``Mode`` members: coding each of a chunk's modes
at the end cost about 3.6 us a tick at 30 robots).

It runs compiled with the loop (``sim_plant.core._accel``).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Final

import numpy as np
import numpy.typing as npt

from formation.outputs.runlog import RunLog, floats_of, ints_of, mode_code

__all__ = ["CHUNK_TICKS", "TickLog"]

_NO_MODE: Final = object()  # (no mode coded yet)

CHUNK_TICKS: Final = 250
"""Ticks kept as Python numbers before they are converted to arrays: ~70 000 numbers at 30
robots, read back while they are still in the processor's caches (converted at the end of a
60 s run, the scattered float objects cost ~40 ns each to read, not ~12), then freed."""

_Chunk = tuple[
    npt.NDArray[np.float64],
    npt.NDArray[np.float64],
    npt.NDArray[np.float64],
    npt.NDArray[np.float64],
    npt.NDArray[np.int64],
]


class TickLog:
    """One run's per-tick record as flat lists; :meth:`runlog` turns it into a :class:`RunLog`.

    ``keyed``: the slots may change during the run (an operator reshape): each tick's slot ids
    are kept too and the rows are put on one axis of slot ids at the end (:meth:`runlog`).
    """

    def __init__(self, keyed: bool, chunk_ticks: int = CHUNK_TICKS) -> None:
        if chunk_ticks < 1:
            raise ValueError(f"chunk_ticks must be >= 1, got {chunk_ticks}")
        self.ticks = 0
        self._keyed = keyed
        self._chunk_ticks = chunk_ticks
        self._chunks: list[_Chunk] = []  # the ticks converted so far, CHUNK_TICKS at a time
        self._truth: list[float] = []  # per tick n x (x_m, y_m, theta_rad)
        self._leader: list[float] = []  # per tick (x_m, y_m, theta_rad)
        self._slots: list[float] = []  # per tick m x (x_m, y_m, vx_mps, vy_mps)
        self._slot_ids: list[tuple[int, ...]] = []  # per tick, when keyed
        self._power: list[float] = []  # per tick n x (power_r, power_l)
        self._modes: list[int] = []  # per tick n modes' codes (runlog.MODE_CODES)
        self._last_mode: object = _NO_MODE  # the last mode coded, and its code
        self._last_code = 0

    def record(
        self,
        truth: Sequence[Sequence[float]],
        leader_x_m: float,
        leader_y_m: float,
        leader_theta_rad: float,
        rows: Sequence[Sequence[float]],
        slot_ids: tuple[int, ...],
        cmds: Sequence[Any],
    ) -> None:
        """Keep one tick: ``truth`` the ``n`` rows ``(x, y, theta)``; the leader; ``rows`` the
        ``m`` slot rows (``(x, y, vx, vy)``) of the slots ``slot_ids``; ``cmds`` per
        robot a sequence whose entries 2, 3 and 4 are power right, power left and the mode (a
        ``WheelCommand``)."""
        tr = self._truth
        # the plant's PoseRows is a tuple: typed so, it is iterated natively when compiled
        poses: tuple[Any, ...] = truth if isinstance(truth, tuple) else tuple(truth)
        for pose in poses:
            tr.extend(pose)
        ld = self._leader
        ld.append(leader_x_m)
        ld.append(leader_y_m)
        ld.append(leader_theta_rad)
        sl = self._slots
        for row in rows:
            sl.extend(row)
        if self._keyed:
            self._slot_ids.append(slot_ids)
        pw = self._power
        md = self._modes
        last = self._last_mode
        code = self._last_code
        for c in cmds:
            # a WheelCommand is a tuple: typed so, its items are read natively when compiled
            w: tuple[Any, ...] = c if isinstance(c, tuple) else tuple(c)
            pw.append(w[2])
            pw.append(w[3])
            mode = w[4]
            if mode is not last:  # (the modes are a few shared objects: coded once a change)
                last = mode
                code = mode_code(mode)
            md.append(code)
        self._last_mode = last
        self._last_code = code
        self.ticks += 1
        if self.ticks % self._chunk_ticks == 0:
            self._convert()

    def _convert(self) -> None:
        """The ticks kept as numbers since the last call, as arrays (the same bits)."""
        self._chunks.append(
            (
                floats_of(self._truth),
                floats_of(self._leader),
                floats_of(self._slots),
                floats_of(self._power),
                ints_of(self._modes),
            )
        )
        self._truth = []
        self._leader = []
        self._slots = []
        self._power = []
        self._modes = []

    def runlog(
        self,
        robot_ids: list[str],
        slot_ids: list[int],
        dt_s: float,
        slot_of_changes: Sequence[tuple[int, Sequence[int]]],
        ref_offset_m: float,
    ) -> RunLog:
        """The record as a :class:`RunLog` (:meth:`RunLog.from_flat`; ``slot_ids``: the slots of
        the first tick)."""
        if self.ticks % self._chunk_ticks or not self._chunks:  # the ticks not converted yet
            self._convert()
        chunks = self._chunks
        return RunLog.from_flat(
            robot_ids, slot_ids, dt_s, self.ticks,
            np.concatenate([c[0] for c in chunks]), np.concatenate([c[1] for c in chunks]),
            np.concatenate([c[2] for c in chunks]), self._slot_ids if self._keyed else None,
            slot_of_changes, np.concatenate([c[3] for c in chunks]),
            np.concatenate([c[4] for c in chunks]), ref_offset_m,
        )  # fmt: skip
