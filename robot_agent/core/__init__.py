"""Firmware of one differential-drive robot (standard library only).

The pure core: parameters, kinematics (eqs 7-16), the reference-point tracking law (eqs 21-22),
potential-field repulsion and the ``Firmware`` mode machine. No I/O, no clock reads, no numpy:
it could be ported to a microcontroller loop. The I/O shell lives in separate modules.

The same core may run compiled (mypyc) when a build of exactly these sources exists:
``_accel.activate`` decides before anything of the core is imported (see ``_accel.py``).
"""

from . import _accel

_accel.activate(__path__)

from robot_agent.core.estimator import Estimator, EstimatorStatus
from robot_agent.core.firmware import Firmware, FirmwareStatus, Mode, Pose, Setpoint, WheelCommand
from robot_agent.core.kinematics import (
    ref_point_velocity,
    reference_point,
    saturate_wheels,
    twist_from_ref_velocity,
    twist_from_wheels,
    wheels_from_twist,
    wrap_angle,
)
from robot_agent.core.params import (
    DEFAULT_K_REP,
    AgentConfig,
    EstimatorParams,
    RepulsionParams,
    RobotGeometry,
    SafetyFilterParams,
    SafetyParams,
    TrackingGains,
    WorldMap,
)
from robot_agent.core.repulsion import repulsion_velocity, repulsion_velocity_counted
from robot_agent.core.safety_filter import Neighbour, SafetyFilter, SafetyFilterStatus
from robot_agent.core.tracking import AxisPID, PIDInfo, TrackingController

__all__ = [
    "DEFAULT_K_REP",
    "AgentConfig",
    "AxisPID",
    "Estimator",
    "EstimatorParams",
    "EstimatorStatus",
    "Firmware",
    "FirmwareStatus",
    "Mode",
    "Neighbour",
    "PIDInfo",
    "Pose",
    "RepulsionParams",
    "RobotGeometry",
    "SafetyFilter",
    "SafetyFilterParams",
    "SafetyFilterStatus",
    "SafetyParams",
    "Setpoint",
    "TrackingController",
    "TrackingGains",
    "WheelCommand",
    "WorldMap",
    "ref_point_velocity",
    "reference_point",
    "repulsion_velocity",
    "repulsion_velocity_counted",
    "saturate_wheels",
    "twist_from_ref_velocity",
    "twist_from_wheels",
    "wheels_from_twist",
    "wrap_angle",
]
