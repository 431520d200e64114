"""Which simulator-side code runs: the pure-Python sources or their compiled build (mypyc).

The in-process simulator's per-tick modules outside the firmware and the coordinator
(:data:`COMPILED_MODULES`: the plant, camera and command link of ``sim_plant.core`` and the loop
of ``formation.sim.simulate``) are plain, fully annotated Python. ``python -m
formation.sim.accel_build build`` compiles *the same files* with mypyc into ``sim_plant/_compiled/``
(one group, ``sim_accel``), checks that the simulator's outputs are equal bit for bit to the pure
sources' before installing, and ``tests/unit/sim_plant/test_sim_accel.py`` checks it again.

The decision follows the rules of every compiled build (``robot_agent/core/_accel.py``,
:class:`~robot_agent.core._accel.CompiledBuild`): ``FORMATION_ACCEL=0``, no build, another
interpreter or edited sources mean pure Python. Each package holding a compiled module
(``sim_plant.core``, ``formation.sim``) calls :func:`activate` from its ``__init__`` before
importing anything. To compile another pure module on the simulator's own path, add its dotted
name to :data:`COMPILED_MODULES` (dependencies first), call :func:`activate` from its package's
``__init__`` and rebuild (``make accel``); the build refuses a module whose package does not
activate. Standard library only.
"""

from __future__ import annotations

from pathlib import Path

from robot_agent.core._accel import ENV, MANIFEST, CompiledBuild, interpreter_tag

__all__ = ["ENV", "MANIFEST", "interpreter_tag"]

#: The compiled modules, by dotted name, in dependency order. The one list of what the
#: simulator-side build holds.
COMPILED_MODULES: tuple[str, ...] = (
    "sim_plant.core.commands",
    "sim_plant.core.encoders",
    "sim_plant.core.carry",
    "sim_plant.core.plant",
    "sim_plant.core.sensors",
    "formation.sim.ticklog",
    "formation.sim.simulate",
)
#: The project's root: the folder holding the ``sim_plant`` and ``formation`` packages.
ROOT = Path(__file__).resolve().parents[2]
#: The simulator's build: ``sim_plant/_compiled``, group ``sim_accel``.
BUILD = CompiledBuild("sim_accel", COMPILED_MODULES, ROOT, ROOT / "sim_plant" / "_compiled")
GROUP = BUILD.group
BUILD_DIR = BUILD.build_dir
source_path = BUILD.source_path
source_hashes = BUILD.source_hashes
decide = BUILD.decide
status = BUILD.status
activate = BUILD.activate
