"""Build, check, remove or show the simulator's and the coordinator's compiled builds (mypyc).

Usage::

    python -m formation.sim.accel_build build     # compile, check against pure Python, install
    python -m formation.sim.accel_build status    # which code runs and why (0: both compiled)
    python -m formation.sim.accel_build clean     # remove the builds: pure Python from now on
    python -m formation.sim.accel_build build --only coordinator   # one of the two

Two plans for the one builder (``robot_agent.buildtools.mypyc_build``: a temporary copy of the
project's packages, one mypyc group each with ``CFLAGS=-ffp-contract=off``, a manifest, the check
before install), each with its own module list:

* ``simulator``: ``sim_plant.core._accel.COMPILED_MODULES`` (plant, camera, link, the in-process
  loop), installed into ``sim_plant/_compiled/``;
* ``coordinator``: ``coordinator.core._accel.COMPILED_MODULES`` (the coordinator's tick),
  installed into ``coordinator/_compiled/``. It is built here, on the top floor, because its check
  needs a closed loop: the coordinator's inputs are the robots' poses, which only the simulator
  makes. The loader stays on the coordinator's floor (``coordinator/core/_accel.py``), so the
  coordinator process over Zenoh uses the same build.

Both are checked by ``python -m formation.sim.accel_outputs`` (the in-process simulator's digests
over faults, encoders, an operator reshape, a mover, motion claims, a fleet above ``SMALL_N``),
run with the new build and with ``FORMATION_ACCEL=0``; the copy holds no other build, so the
check compares exactly the new group against pure Python. ``make venv`` runs ``build`` once;
``make accel`` rebuilds after an edit (a stale build is never used).
"""

from __future__ import annotations

import shutil
from pathlib import Path

from coordinator.core import _accel as coordinator_accel
from robot_agent.buildtools import mypyc_build
from sim_plant.core import _accel as sim_accel

#: The project's packages copied for the build (mypy follows the compiled modules' imports).
PACKAGES = (
    "bus_schemas",
    "robot_agent",
    "coordinator",
    "sim_plant",
    "localization",
    "scenario",
    "runtime",
    "formation",
)


def _copy_tree(work: Path) -> None:
    """The project's packages (without builds) and its ``pyproject.toml`` (mypy's settings)."""
    ignore = shutil.ignore_patterns("_compiled", "_compiled.old", "__pycache__", "*.so", "*.pyd")
    for pkg in PACKAGES:
        shutil.copytree(sim_accel.ROOT / pkg, work / pkg, ignore=ignore)
    shutil.copy2(sim_accel.ROOT / "pyproject.toml", work / "pyproject.toml")


SIMULATOR = mypyc_build.Plan(
    target=sim_accel.BUILD,
    label="simulator",
    copy_sources=_copy_tree,
    check=("formation.sim.accel_outputs",),
    unit="runs",
)
COORDINATOR = mypyc_build.Plan(
    target=coordinator_accel.BUILD,
    label="coordinator",
    copy_sources=_copy_tree,
    check=("formation.sim.accel_outputs",),
    unit="runs",
)


def unactivated() -> list[str]:
    """Compiled modules of either build whose package's ``__init__`` does not activate it."""
    return [m for plan in (SIMULATOR, COORDINATOR) for m in mypyc_build.unactivated(plan.target)]


def main(argv: list[str] | None = None) -> int:
    return mypyc_build.main([SIMULATOR, COORDINATOR], "formation.sim.accel_build", argv)


if __name__ == "__main__":
    raise SystemExit(main())
