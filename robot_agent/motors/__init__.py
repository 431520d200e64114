"""Motor backends: how a robot agent's wheel command reaches the wheels.

- ``bus``: simulation; the wheel command published on the bus is all there is
  (:class:`BusMotorBackend`).
- ``roboclaw``: a Basicmicro RoboClaw over packet serial (:class:`RoboClawBackend`).

Every backend follows the :class:`MotorBackend` contract (base.py): nothing raises into the
control loop, faults are counted and reported by ``status()``. Importing this package needs
only the standard library; pyserial is loaded when a RoboClaw port is opened.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from .base import BusMotorBackend, MotorBackend, MotorStatus
from .roboclaw import RoboClawBackend, RoboClawConfig

if TYPE_CHECKING:
    from robot_agent.robot_config import MotorConfig

__all__ = [
    "BusMotorBackend",
    "MotorBackend",
    "MotorStatus",
    "RoboClawBackend",
    "RoboClawConfig",
    "create_backend",
]


def create_backend(config: MotorConfig, max_wheel_radps: float) -> MotorBackend:
    """The backend a robot's ``[motor]`` config section asks for (not yet opened).

    ``max_wheel_radps`` is the robot's wheel speed limit (``RobotGeometry.max_wheel_radps``).
    Raises ``ValueError`` for an unknown backend or a roboclaw backend without its settings
    (``load_robot_config`` has already rejected both).
    """
    if config.backend == "bus":
        return BusMotorBackend()
    if config.backend == "roboclaw":
        if config.roboclaw is None:
            raise ValueError("motor backend 'roboclaw' needs its port settings")
        return RoboClawBackend(config.roboclaw, max_wheel_radps)
    raise ValueError(f"unknown motor backend {config.backend!r} (expected 'bus' or 'roboclaw')")
