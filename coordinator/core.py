"""The coordinator's pure tick: virtual leader -> slots -> role assignment -> setpoints.

One call per control tick, time passed in. The in-process simulator and the Zenoh coordinator
process both run exactly this, so they make the same decisions from the same poses.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from coordinator.assignment import RoleAssigner
from coordinator.formation import FormationSpec, SlotState, slot_states
from coordinator.trajectory import LeaderState, Trajectory, make_trajectory


@dataclass(frozen=True)
class CoordinatorOutput:
    leader: LeaderState
    slots: list[SlotState]
    assignment: dict[str, int]  # robot id -> slot
    changed: bool  # assignment differs from the previous tick's

    def setpoint_for(self, robot: str) -> SlotState | None:
        slot = self.assignment.get(robot)
        if slot is None:
            return None
        return self.slots_by_id[slot]

    @property
    def slots_by_id(self) -> dict[int, SlotState]:
        return {s.slot: s for s in self.slots}

    @property
    def leader_robot(self) -> str | None:
        for rid, slot in self.assignment.items():
            if slot == 0:
                return rid
        return None


class CoordinatorCore:
    """Virtual leader (eqs 1-2), slots (eqs 3-5), greedy/optimal role assignment (eq 6)."""

    def __init__(
        self,
        trajectory: Trajectory,
        formation: FormationSpec,
        assigner: RoleAssigner,
        ref_offset_m: float,
        t0_s: float = 0.0,
    ) -> None:
        if not (ref_offset_m > 0 and math.isfinite(ref_offset_m)):
            raise ValueError(f"ref_offset_m must be positive and finite, got {ref_offset_m!r}")
        self.trajectory = trajectory
        self.formation = formation
        self.assigner = assigner
        self.ref_offset_m = ref_offset_m
        self.t0_s = t0_s
        self.assignment: dict[str, int] = {}

    @classmethod
    def from_config(
        cls,
        trajectory: Mapping[str, Any],
        formation: Mapping[str, Any],
        method: str,
        hysteresis_m: float,
        tie_tol_m: float,
        ref_offset_m: float,
        t0_s: float = 0.0,
    ) -> CoordinatorCore:
        traj_params = {k: v for k, v in trajectory.items() if k != "kind"}
        return cls(
            make_trajectory(str(trajectory["kind"]), traj_params),
            FormationSpec.from_dict(dict(formation)),
            RoleAssigner(method=method, hysteresis_m=hysteresis_m, tie_tol_m=tie_tol_m),
            ref_offset_m=ref_offset_m,
            t0_s=t0_s,
        )

    def reference_points(
        self, poses: Mapping[str, tuple[float, float, float]]
    ) -> dict[str, tuple[float, float]]:
        """Robot axle-centre poses -> reference points (eqs 10-11), skipping non-finite ones."""
        l_m = self.ref_offset_m
        out: dict[str, tuple[float, float]] = {}
        for rid, (x, y, th) in poses.items():
            xr, yr = x + l_m * math.cos(th), y + l_m * math.sin(th)
            if math.isfinite(xr) and math.isfinite(yr):
                out[rid] = (xr, yr)
        return out

    def tick(
        self, now_s: float, poses: Mapping[str, tuple[float, float, float]]
    ) -> CoordinatorOutput:
        """``poses``: the latest fresh pose of every live robot (axle centre x, y, theta)."""
        leader = self.trajectory.sample(now_s - self.t0_s)
        slots = slot_states(self.formation, leader)
        assignment, changed = self.assigner.update(self.reference_points(poses), slots)
        self.assignment = dict(assignment)
        return CoordinatorOutput(leader, slots, self.assignment, changed)
