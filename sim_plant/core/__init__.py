"""Simulated plant (numpy, vectorised over robots): ground truth, sensors, safety accounting.

Pure cores only: time is passed in, randomness comes from a ``numpy.random.Generator`` passed in.

The per-tick modules may run compiled (mypyc) when a build of exactly these sources exists:
``_accel.activate`` decides before anything of the core is imported (see ``_accel.py``).
"""

from . import _accel

_accel.activate(__name__, __path__)

from sim_plant.core.accounting import (
    BoundsMonitor,
    CollisionEvent,
    ExitEvent,
    SeparationMonitor,
    contacts_and_min_distance,
)
from sim_plant.core.kinematics import GeometryLike, unicycle_integrate, wrap_angles
from sim_plant.core.plant import Plant
from sim_plant.core.sensors import Camera, CameraFrame, CommandLink

__all__ = [
    "BoundsMonitor",
    "Camera",
    "CameraFrame",
    "CollisionEvent",
    "CommandLink",
    "ExitEvent",
    "GeometryLike",
    "Plant",
    "SeparationMonitor",
    "contacts_and_min_distance",
    "unicycle_integrate",
    "wrap_angles",
]
