"""Coordinator core: virtual-leader trajectories, formation geometry and role assignment.

Pure (numpy/scipy, no I/O, no clock): time is always passed in. See docs/architecture.md.

The per-tick modules may run compiled (mypyc) when a build of exactly these sources exists:
``_accel.activate`` decides before anything of the core is imported (see ``_accel.py``).

Import what you use from its module (``coordinator.core.formation``, ``.assignment``,
``.trajectory``, ...): the package itself imports nothing else, so a process that needs only the
formation's geometry (a launcher, a plant) does not pay for scipy's optimizer and the planner.
"""

from . import _accel

_accel.activate(__name__, __path__)
