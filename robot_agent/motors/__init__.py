"""Motor backends: how a robot agent's wheel command reaches the wheels.

- ``bus``: simulation; the wheel command published on the bus is all there is
  (:class:`BusMotorBackend`).
- ``roboclaw``: a Basicmicro RoboClaw over packet serial (:class:`RoboClawBackend`).
- ``ros2``: a ROS 2 base (TurtleBot3, ...) over rmw_zenoh: cmd_vel out, odom in
  (:class:`Ros2Backend`; Zenoh is imported when it opens).

Every backend follows the :class:`MotorBackend` contract (base.py): nothing raises into the
control loop, faults are counted and reported by ``status()``. Importing this package needs
only the standard library; pyserial is loaded when a RoboClaw port is opened.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from .base import BusMotorBackend, MotorBackend, MotorStatus
from .roboclaw import RoboClawBackend, RoboClawConfig
from .ros2 import Ros2Backend, Ros2MotorConfig

if TYPE_CHECKING:
    from robot_agent.params import RobotGeometry
    from robot_agent.robot_config import MotorConfig

__all__ = [
    "BusMotorBackend",
    "MotorBackend",
    "MotorStatus",
    "RoboClawBackend",
    "RoboClawConfig",
    "Ros2Backend",
    "Ros2MotorConfig",
    "create_backend",
]


def create_backend(
    config: MotorConfig,
    max_wheel_radps: float,
    geometry: RobotGeometry | None = None,
    subscribe: Callable[[Any, str, Callable[[Any], None]], Any] | None = None,
) -> MotorBackend:
    """The backend a robot's ``[motor]`` config section asks for (not yet opened).

    ``max_wheel_radps`` is the robot's wheel speed limit (``RobotGeometry.max_wheel_radps``);
    the ``ros2`` backend needs the whole ``geometry`` (wheel radius and track for eq 8) and
    the shell's ``subscribe`` (``runtime.bridge.subscribe_on_thread``) for its odometry.
    Raises ``ValueError`` for an unknown backend or a roboclaw backend without its settings
    (``load_robot_config`` has already rejected both).
    """
    if config.backend == "bus":
        return BusMotorBackend()
    if config.backend == "roboclaw":
        if config.roboclaw is None:
            raise ValueError("motor backend 'roboclaw' needs its port settings")
        return RoboClawBackend(config.roboclaw, max_wheel_radps)
    if config.backend == "ros2":
        if config.ros2 is None or geometry is None:
            raise ValueError("motor backend 'ros2' needs its settings and the robot geometry")
        return Ros2Backend(config.ros2, geometry, subscribe=subscribe)
    raise ValueError(
        f"unknown motor backend {config.backend!r} (expected 'bus', 'roboclaw' or 'ros2')"
    )
