"""The in-process simulator: `formation sim` and `formation demo` (no Zenoh, deterministic).

``simulate`` may run compiled (mypyc) with the simulator-side build: ``sim_plant.core._accel``.
"""

from sim_plant.core import _accel

_accel.activate(__name__, __path__)
