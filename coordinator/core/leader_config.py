"""The virtual leader's limits and its wait-for-team setting (scenario ``[leader]``): the
configuration :class:`~coordinator.core.leader.LeaderCore` runs with.

A module of its own, not compiled: :class:`LeaderConfig` validates by coercing in
``__post_init__`` whatever its fields were given, so a bad ``[leader]`` value raises the
``ValueError`` a scenario reports (a dataclass compiled by mypyc would check the declared field
types first and raise ``TypeError``), and it pickles with the scenario. ``coordinator.core.leader``
(compiled, ``coordinator/core/_accel.py``) imports and re-exports it. Pure, stdlib only.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, fields
from enum import StrEnum
from typing import Any, Final

from bus_schemas.messages_fields import LeaderMode  # the modes as the leader message names them

__all__ = ["DEADMAN_S", "LeaderConfig", "WaitSetting"]

DEADMAN_S: Final = 0.4
"""Default deadman (s): a teleop twist older than this is no longer obeyed. The operator's tool
sends 20 per second, so 0.4 s is 8 lost messages (a loaded host or Wi-Fi hiccup does not trip
it) and short enough that a leader at 0.1 m/s has gone 4 cm before it starts braking."""


class WaitSetting(StrEnum):
    """``[leader] wait`` of a scenario: whether the leader waits for its team."""

    AUTO = "auto"  # on for teleop, goals, paths and `kind = "plan"` trajectories
    ON = "on"
    OFF = "off"


@dataclass(frozen=True)
class LeaderConfig:
    """The leader's limits and the wait-for-team setting (scenario ``[leader]``)."""

    max_speed_mps: float = 0.1
    """Teleop, goal and path speed limit (m/s): the paper's leaders run at 0.02-0.1 m/s."""
    max_turn_radps: float = 0.3
    """Turn-rate limit (rad/s): a slot 0.5 m off the leader's axis then moves at most 0.15 m/s
    faster than the leader, under the firmware's 0.25 m/s reference clamp."""
    max_accel_mps2: float = 0.1
    max_turn_accel_radps2: float = 0.6
    deadman_s: float = DEADMAN_S
    goal_tol_m: float = 0.02
    """A goal or the last point of a path is reached within this distance (m)."""
    heading_tol_rad: float = 0.02
    lookahead_m: float = 0.25
    """An interior waypoint of a path counts as passed within this distance (m)."""
    wait: WaitSetting = WaitSetting.AUTO
    wait_err_full_m: float = 0.10
    wait_err_stop_m: float = 0.30
    wait_rate_slew_per_s: float = 0.5
    wait_drop_s: float = 20.0

    def __post_init__(self) -> None:
        for f in fields(self):
            if f.name == "wait":
                continue
            value = getattr(self, f.name)
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise ValueError(f"leader.{f.name}: must be a number, got {value!r}")
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f"leader.{f.name}: must be finite and > 0, got {value!r}")
            object.__setattr__(self, f.name, float(value))
        try:
            object.__setattr__(self, "wait", WaitSetting(self.wait))
        except ValueError:
            raise ValueError(
                f"leader.wait: must be one of {', '.join(w.value for w in WaitSetting)}, "
                f"got {self.wait!r}"
            ) from None
        if self.wait_err_stop_m <= self.wait_err_full_m:
            raise ValueError(
                f"leader.wait_err_stop_m ({self.wait_err_stop_m}) must exceed "
                f"leader.wait_err_full_m ({self.wait_err_full_m})"
            )

    @classmethod
    def from_dict(cls, table: Mapping[str, Any]) -> LeaderConfig:
        """From a scenario's ``[leader]`` table; unknown keys raise ValueError."""
        allowed = {f.name for f in fields(cls)}
        unknown = sorted(str(k) for k in table if k not in allowed)
        if unknown:
            raise ValueError(
                f"leader: unknown key(s) {', '.join(unknown)}; "
                f"allowed: {', '.join(sorted(allowed))}"
            )
        return cls(**dict(table))

    def waits(self, mode: LeaderMode, trajectory_kind: str) -> bool:
        """Does the leader wait for its team in ``mode`` (``auto``: for an operator's leader and
        for planned trajectories)?"""
        if self.wait is WaitSetting.ON:
            return True
        if self.wait is WaitSetting.OFF:
            return False
        return mode is not LeaderMode.SCRIPT or trajectory_kind == "plan"
