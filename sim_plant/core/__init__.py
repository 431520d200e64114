"""Simulated plant (numpy, vectorised over robots): ground truth, sensors, safety accounting.

Pure cores only: time is passed in, randomness comes from a ``numpy.random.Generator`` passed in.

The per-tick modules may run compiled (mypyc) when a build of exactly these sources exists:
``_accel.activate`` decides before anything of the core is imported (see ``_accel.py``). The
names below are imported from their modules on first use.
"""

from typing import TYPE_CHECKING

from . import _accel

_accel.activate(__name__, __path__)

if TYPE_CHECKING:
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

# name -> the module defining it, imported on first use (PEP 562): a package of the simulator
# (formation.sim) activates its build through ``_accel`` without scipy's ~0.4 s import, so a
# command-line mistake of ``formation sim`` is reported at once.
_WHERE: dict[str, str] = {
    "BoundsMonitor": "accounting",
    "CollisionEvent": "accounting",
    "ExitEvent": "accounting",
    "SeparationMonitor": "accounting",
    "contacts_and_min_distance": "accounting",
    "GeometryLike": "kinematics",
    "unicycle_integrate": "kinematics",
    "wrap_angles": "kinematics",
    "Plant": "plant",
    "Camera": "sensors",
    "CameraFrame": "sensors",
    "CommandLink": "sensors",
}

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


def __getattr__(name: str) -> object:
    import importlib

    module = _WHERE.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f"{__name__}.{module}"), name)
    globals()[name] = value
    return value
