"""The estimator's twist for a status message (issue 29: a ROS 2 odometry's twist).

A process-shell helper of :mod:`robot_agent.node.agent` and :mod:`robot_agent.node.host_status`:
it reads the firmware's estimator and never writes it, so the firmware's outputs stay the same.
"""

from __future__ import annotations

import math

from bus_schemas.spec import SPEED_MAX_MPS, TURN_RATE_MAX_RADPS
from robot_agent.core.firmware import Firmware

__all__ = ["estimator_twist"]


def estimator_twist(firmware: Firmware, now_s: float) -> tuple[float, float] | None:
    """``(v_mps, omega_radps)`` of the robot at ``now_s`` (the firmware's clock) as its estimator
    has it (paper eq 9's twist: measured by the encoders, else the commanded one), or None when
    unknown: no estimator, no valid estimate on the last tick, or a twist outside the bus
    contract's bounds (``Status.v_mps``, ``Status.omega_radps``)."""
    est = firmware.estimator
    if est is None or not math.isfinite(firmware.pose_uncertainty_m):
        return None
    tw = est.twist(now_s)
    if tw is None:
        return None
    v, w = tw
    if not (abs(v) <= SPEED_MAX_MPS and abs(w) <= TURN_RATE_MAX_RADPS):
        return None  # (also NaN)
    return float(v), float(w)
