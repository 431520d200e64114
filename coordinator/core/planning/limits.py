"""What a slot may ask of the robot that tracks it: speed, turn rate, acceleration (pure).

Derived from the robot's parameters (``robot_agent.core.params``), not hand-set:

* speed: the firmware tracks a slot with its REFERENCE POINT (eqs 10-11), whose velocity maps to
  the wheels as ``v = vx cos(theta) + vy sin(theta)``, ``omega = (-vx sin(theta) + vy
  cos(theta)) / l``; with ``l = ref_offset_m`` and ``L = half_track_m`` equal (the default 5 cm)
  a reference-point speed ``u`` in the worst direction needs ``|v| + L |omega| = sqrt(2) u``
  of the top speed ``R * max_wheel_radps`` (0.3 m/s). The command is also capped at
  ``TrackingGains.max_ref_speed_mps`` (0.25 m/s). A slot may use :data:`HEADROOM` of the smaller
  of the two, so the PID's correction still fits under the wheel limit: 0.6 x min(0.25,
  0.3 / sqrt(2)) = 0.127 m/s with the defaults.
* turn rate: a differential robot moving at the slot speed ``u`` turns at most
  ``(top speed - u) / half_track_m``; the slot may use :data:`HEADROOM` of it (2.1 rad/s with
  the defaults). It bounds the formation's heading rate (every slot's heading is the leader's)
  and the rate at which a moving slot's velocity changes direction.
* acceleration: the firmware has no acceleration limit of its own; :data:`ACCEL_MPS2` (0.1
  m/s^2: 0.1 m/s in 1 s, 20 motor time constants of 50 ms) keeps the feed-forward smooth.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Final

from robot_agent.core.params import AgentConfig

__all__ = ["ACCEL_MPS2", "HEADROOM", "SlotLimits"]

HEADROOM: Final = 0.6
"""Share of the robot's capability a slot's feed-forward may use (the rest is for feedback)."""
ACCEL_MPS2: Final = 0.1
"""A slot's acceleration limit (m/s^2)."""


@dataclass(frozen=True, slots=True)
class SlotLimits:
    """Limits of one slot's motion: ``speed_mps``, ``turn_radps``, ``accel_mps2`` (all > 0)."""

    speed_mps: float
    turn_radps: float
    accel_mps2: float

    def __post_init__(self) -> None:
        for name in ("speed_mps", "turn_radps", "accel_mps2"):
            v = getattr(self, name)
            if (
                isinstance(v, bool)
                or not isinstance(v, int | float)
                or not (math.isfinite(v) and v > 0.0)
            ):
                raise ValueError(f"SlotLimits: {name} must be a finite number > 0, got {v!r}")

    @classmethod
    def from_robot(
        cls,
        *,
        wheel_radius_m: float,
        half_track_m: float,
        max_wheel_radps: float,
        max_ref_speed_mps: float,
        accel_mps2: float = ACCEL_MPS2,
    ) -> SlotLimits:
        """The limits of a robot of this geometry (module docstring)."""
        top = wheel_radius_m * max_wheel_radps
        speed = HEADROOM * min(max_ref_speed_mps, top / math.sqrt(2.0))
        turn = HEADROOM * (top - speed) / half_track_m
        return cls(speed, turn, accel_mps2)

    @classmethod
    def from_agent(cls, agent: AgentConfig) -> SlotLimits:
        """The limits of ``agent``'s robot."""
        g = agent.geometry
        return cls.from_robot(
            wheel_radius_m=g.wheel_radius_m,
            half_track_m=g.half_track_m,
            max_wheel_radps=g.max_wheel_radps,
            max_ref_speed_mps=agent.gains.max_ref_speed_mps,
        )
