"""A run's record as arrays: what metrics and figures are computed from.

The in-process simulator fills it tick by tick; a recording of a distributed run is turned into
the same structure, so both are measured by one piece of code (``formation.metrics``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]

MODE_CODES = {"idle": 0, "tracking": 1, "hold": 2, "estop": 3}


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
