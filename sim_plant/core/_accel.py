"""Which simulator-side code runs: the pure-Python sources or their compiled build (mypyc).

The in-process simulator's per-tick modules outside the firmware (:data:`COMPILED_MODULES`: the
plant, camera and command link of ``sim_plant.core`` and the loop of ``formation.sim.simulate``)
are plain, fully annotated Python. ``python -m formation.sim.accel_build build`` compiles *the
same files* with mypyc into ``sim_plant/_compiled/`` (one group, ``sim_accel``), checks that the
simulator's outputs are equal bit for bit to the pure sources' before installing, and
``tests/unit/sim_plant/test_sim_accel.py`` checks it again. One source of truth; a machine
without a C compiler runs the pure code. (The firmware's own build is
``robot_agent/core/_accel.py``; the two are independent.)

This module decides, once per process, which of the two is used, by the rules of the firmware's
build:

* ``FORMATION_ACCEL=0`` in the environment: pure Python, always (the same switch for both builds).
* no build, or a build for another interpreter: pure Python.
* a build whose manifest's SHA-256 of a source differs from the ``.py`` file now on disk (the code
  was edited after the build): pure Python, so an edit is never shadowed by a stale binary.
* else the compiled modules: each package holding one (``sim_plant.core``, ``formation.sim``)
  calls :func:`activate` from its ``__init__`` before importing anything, which puts the build's
  folder of that package first on the package's ``__path__``.

The modules of one mypyc group call each other natively, so they are used all together or not at
all: the decision is made once and every package gets the same answer.

To compile another pure module on the simulator's path (e.g. a ``coordinator.core`` module), add
its dotted name to :data:`COMPILED_MODULES` (dependencies first), call :func:`activate` from its
package's ``__init__`` and rebuild (``make accel``); the build refuses a module whose package does
not activate. Standard library only.
"""

from __future__ import annotations

import hashlib
import json
import os
import sys
from pathlib import Path

#: The compiled modules, by dotted name, in dependency order. The one list of what the
#: simulator-side build holds.
COMPILED_MODULES: tuple[str, ...] = (
    "sim_plant.core.commands",
    "sim_plant.core.encoders",
    "sim_plant.core.carry",
    "sim_plant.core.plant",
    "sim_plant.core.sensors",
    "formation.sim.simulate",
)
#: mypyc's group name: the shared library of the build is ``<GROUP>__mypyc``.
GROUP = "sim_accel"
#: Environment variable: ``0`` forces pure Python (shared with the firmware's build).
ENV = "FORMATION_ACCEL"
#: The project's root: the folder holding the ``sim_plant`` and ``formation`` packages.
ROOT = Path(__file__).resolve().parents[2]
#: Where the build is installed (``sim_plant/_compiled``, never packaged).
BUILD_DIR = ROOT / "sim_plant" / "_compiled"
MANIFEST = "manifest.json"

_decision: tuple[bool, str] | None = None  # (use, why), decided at the first activate()
_loaded = False  # the group's shared library was imported


def source_path(module: str, root: Path = ROOT) -> Path:
    """The ``.py`` file of dotted ``module`` under ``root``."""
    return root.joinpath(*module.split(".")).with_suffix(".py")


def source_hashes(root: Path = ROOT) -> dict[str, str]:
    """SHA-256 of each compiled module's source file (missing file: empty string)."""
    out: dict[str, str] = {}
    for name in COMPILED_MODULES:
        try:
            out[name] = hashlib.sha256(source_path(name, root).read_bytes()).hexdigest()
        except OSError:
            out[name] = ""
    return out


def interpreter_tag() -> str:
    """The interpreter a build is for (its extension suffix names the ABI; this adds the build)."""
    return f"{sys.implementation.cache_tag} {sys.version.split()[0]} {sys.platform}"


def decide(
    environ: dict[str, str] | os._Environ[str] | None = None,
    build_dir: Path = BUILD_DIR,
    root: Path = ROOT,
) -> tuple[bool, str]:
    """``(use_compiled, reason)``: the rules of the module docstring."""
    env = os.environ if environ is None else environ
    if env.get(ENV, "").strip() == "0":
        return False, f"pure Python ({ENV}=0)"
    manifest_path = build_dir / MANIFEST
    if not manifest_path.is_file():
        return False, "pure Python (no compiled build: make accel)"
    try:
        manifest = json.loads(manifest_path.read_text(encoding="utf-8"))
        built_for = str(manifest["interpreter"])
        hashes = dict(manifest["sources"])
    except (OSError, ValueError, KeyError, TypeError):
        return False, "pure Python (compiled build has an unreadable manifest: make accel)"
    if built_for != interpreter_tag():
        return False, f"pure Python (compiled build is for {built_for}: make accel)"
    now = source_hashes(root)
    changed = sorted(name for name in COMPILED_MODULES if hashes.get(name) != now[name])
    if changed:
        return False, (
            f"pure Python (sources changed since the compiled build: {', '.join(changed)}; "
            "make accel)"
        )
    return True, f"compiled (mypyc, {len(COMPILED_MODULES)} modules, {build_dir})"


def status() -> tuple[bool, str]:
    """The decision of this process (made now if no package has activated yet)."""
    global _decision
    if _decision is None:
        _decision = decide()
    return _decision


def activate(package: str, package_path: list[str]) -> bool:
    """Put the build's folder of ``package`` (dotted) first on ``package_path`` (its
    ``__path__``) if the compiled build is used. Never raises: a build that does not load means
    pure Python for every package."""
    global _decision, _loaded
    if not status()[0]:
        return False
    if not _loaded:
        root = str(BUILD_DIR)
        added = root not in sys.path
        if added:
            sys.path.append(root)  # the group's shared library is a top-level module
        try:
            __import__(f"{GROUP}__mypyc")
        except ImportError as exc:
            if added:
                sys.path.remove(root)
            _decision = (False, f"pure Python (compiled build does not load: {exc}; make accel)")
            return False
        _loaded = True
    folder = str(BUILD_DIR.joinpath(*package.split(".")))
    if folder not in package_path:
        package_path.insert(0, folder)
    return True
