"""Motor backends: how a robot agent's wheel command reaches the wheels.

Every backend is one row of :data:`BACKENDS` (like the trajectory kinds of
``coordinator.core.trajectory``): its name in a robot config's ``[motor] backend = ...``, the
dataclass of its other ``[motor]`` keys (checked by ``robot_agent.core.config_tables``, one
validator), and how to make it. Adding a backend is one module here and one row below.

Every backend follows the :class:`MotorBackend` contract (base.py): nothing raises into the
control loop, faults are counted and reported by ``status()``. Importing this package needs
only the standard library; pyserial is loaded when a RoboClaw port is opened.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from robot_agent.motors.base import BusMotorBackend, MotorBackend, MotorStatus
from robot_agent.motors.roboclaw import RoboClawBackend
from robot_agent.motors.roboclaw_config import RoboClawConfig
from robot_agent.motors.ros2_config import Ros2MotorConfig

__all__ = [
    "BACKENDS",
    "BackendContext",
    "BackendKind",
    "BusMotorBackend",
    "MotorBackend",
    "MotorStatus",
    "create_backend",
]


@dataclass(frozen=True, slots=True)
class BackendContext:
    """What the agent's shell hands every backend it makes.

    Attributes:
        geometry: the robot's ``RobotGeometry`` (wheel radius, half track, wheel speed limit).
        subscribe: the shell's ``runtime.bridge.subscribe_on_thread`` (a backend that reads a
            bus, such as ``ros2``'s odometry; a driver may not import the runtime itself).
    """

    geometry: Any
    subscribe: Callable[..., Any] | None = None


@dataclass(frozen=True, slots=True)
class BackendKind:
    """One motor backend: ``settings`` is the dataclass of its ``[motor]`` keys (None: it takes
    none); ``make(settings, context)`` builds it, not yet opened."""

    summary: str
    settings: type[Any] | None
    make: Callable[[Any, BackendContext], MotorBackend]


def _ros2_backend(settings: Ros2MotorConfig, context: BackendContext) -> MotorBackend:
    """The ``ros2`` driver, imported here: only a robot that drives a ROS 2 base loads it and
    the ROS 2 message definitions."""
    from robot_agent.motors.ros2 import Ros2Backend

    return Ros2Backend(settings, context.geometry, subscribe=context.subscribe)


BACKENDS: dict[str, BackendKind] = {
    "bus": BackendKind(
        "simulation: the wheel command published on the bus is all there is",
        None,
        lambda _settings, _context: BusMotorBackend(),
    ),
    "roboclaw": BackendKind(
        "a Basicmicro RoboClaw over packet serial",
        RoboClawConfig,
        lambda settings, context: RoboClawBackend(settings, context.geometry.max_wheel_radps),
    ),
    "ros2": BackendKind(
        "a ROS 2 base (TurtleBot3, Create 3, ...) over rmw_zenoh: cmd_vel out, odom in",
        Ros2MotorConfig,
        _ros2_backend,
    ),
}


def create_backend(backend: str, settings: Any, context: BackendContext) -> MotorBackend:
    """The backend a robot's ``[motor]`` config section asks for (not yet opened).

    Raises ``ValueError`` for an unknown backend or settings of the wrong kind
    (``load_robot_config`` has already rejected both).
    """
    kind = BACKENDS.get(backend)
    if kind is None:
        raise ValueError(f"unknown motor backend {backend!r} (one of {', '.join(BACKENDS)})")
    if (kind.settings is None) != (settings is None) or (
        kind.settings is not None and not isinstance(settings, kind.settings)
    ):
        raise ValueError(f"motor backend {backend!r} needs settings of type {kind.settings}")
    return kind.make(settings, context)
