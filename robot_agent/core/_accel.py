"""Which code runs: pure-Python sources or their compiled build (mypyc). One loader for every build.

Three parts of the project are plain, fully annotated Python that may also run compiled, each as
its own mypyc group built from *the same files* (one source of truth; a machine without a C
compiler runs the pure code):

* the firmware's per-tick modules (:data:`COMPILED_MODULES` below; this module decides for them
  when ``robot_agent.core`` is imported; built by ``python -m robot_agent.buildtools.accel``);
* the simulator's plant, camera, link and loop (``sim_plant/core/_accel.py``);
* the coordinator's tick (``coordinator/core/_accel.py``).

Each is a :class:`CompiledBuild`: its module list (dotted names, dependency order), its mypyc group
name and the folder its build is installed in. The rules are the same for every build:

* ``FORMATION_ACCEL=0`` in the environment: pure Python, always (one switch for all builds).
* no build, or a build for another interpreter: pure Python.
* a build whose manifest's SHA-256 of a source differs from the ``.py`` file now on disk (the code
  was edited after the build): pure Python, so an edit is never shadowed by a stale binary.
  ``make accel`` brings the compiled build back.
* else the compiled modules: each package holding one calls :meth:`CompiledBuild.activate` from
  its ``__init__`` before importing anything, which puts the build's folder of that package first
  on the package's ``__path__``; every other module of the package loads from its source.

The modules of one mypyc group call each other natively, so they are used all together or not at
all: the decision is made once per process and every package of the group gets the same answer.
A build that does not load (a manifest without its shared library) means pure Python.

The builder (``robot_agent/buildtools/mypyc_build.py``) writes the manifest these rules read and
installs a build only after checking its outputs equal pure Python's bit for bit. Standard
library only; no I/O beyond reading a manifest and hashing the listed sources.
"""

from __future__ import annotations

import hashlib
import json
import os
import sys
from pathlib import Path

#: Environment variable: ``0`` forces pure Python (every build).
ENV = "FORMATION_ACCEL"
#: The file a build's folder holds beside its binaries (interpreter, source hashes, modules).
MANIFEST = "manifest.json"
#: The project's root: the folder holding the ``robot_agent`` package (site-packages on a robot).
ROOT = Path(__file__).resolve().parents[2]


def interpreter_tag() -> str:
    """The interpreter a build is for (its extension suffix names the ABI; this adds the build)."""
    return f"{sys.implementation.cache_tag} {sys.version.split()[0]} {sys.platform}"


class CompiledBuild:
    """One mypyc group: which modules, where its build lives, whether this process uses it."""

    def __init__(self, group: str, modules: tuple[str, ...], root: Path, build_dir: Path) -> None:
        #: mypyc's group name: the shared library of the build is ``<group>__mypyc``.
        self.group = group
        #: The compiled modules, by dotted name, in dependency order.
        self.modules = modules
        #: The folder holding the modules' top-level packages.
        self.root = root
        #: Where the build is installed (a ``_compiled`` folder, never packaged).
        self.build_dir = build_dir
        self._decision: tuple[bool, str] | None = None  # (use, why), at the first status()
        self._loaded = False  # the group's shared library was imported

    def source_path(self, module: str, root: Path | None = None) -> Path:
        """The ``.py`` file of dotted ``module`` under ``root`` (default: this build's root)."""
        return (self.root if root is None else root).joinpath(*module.split(".")).with_suffix(".py")

    def source_hashes(self, root: Path | None = None) -> dict[str, str]:
        """SHA-256 of each compiled module's source file (missing file: empty string)."""
        out: dict[str, str] = {}
        for name in self.modules:
            try:
                out[name] = hashlib.sha256(self.source_path(name, root).read_bytes()).hexdigest()
            except OSError:
                out[name] = ""
        return out

    def decide(
        self,
        environ: dict[str, str] | os._Environ[str] | None = None,
        build_dir: Path | None = None,
        root: Path | None = None,
    ) -> tuple[bool, str]:
        """``(use_compiled, reason)``: the rules of the module docstring."""
        env = os.environ if environ is None else environ
        build_dir = self.build_dir if build_dir is None else build_dir
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
        now = self.source_hashes(root)
        changed = sorted(name for name in self.modules if hashes.get(name) != now[name])
        if changed:
            return False, (
                f"pure Python (sources changed since the compiled build: {', '.join(changed)}; "
                "make accel)"
            )
        return True, f"compiled (mypyc, {len(self.modules)} modules, {build_dir})"

    def status(self) -> tuple[bool, str]:
        """The decision of this process (made now if no package has activated yet)."""
        if self._decision is None:
            self._decision = self.decide()
        return self._decision

    def activate(self, package: str, package_path: list[str]) -> bool:
        """Put the build's folder of ``package`` (dotted) first on ``package_path`` (its
        ``__path__``) if the compiled build is used. Never raises: a build that does not load
        means pure Python for every package of the group."""
        if not self.status()[0]:
            return False
        if not self._loaded:
            root = str(self.build_dir)
            added = root not in sys.path
            if added:
                sys.path.append(root)  # the group's shared library is a top-level module
            try:
                __import__(f"{self.group}__mypyc")
            except ImportError as exc:
                if added:
                    sys.path.remove(root)
                why = f"pure Python (compiled build does not load: {exc}; make accel)"
                self._decision = (False, why)
                return False
            self._loaded = True
        folder = str(self.build_dir.joinpath(*package.split(".")))
        if folder not in package_path:
            package_path.insert(0, folder)
        return True


# The firmware's build ----------------------------------------------------------------------

#: The firmware's compiled modules of ``robot_agent.core`` (its per-tick path), in dependency
#: order.
COMPILED_MODULES: tuple[str, ...] = (
    "estimator_math",
    "estimator",
    "kinematics",
    "tracking",
    "repulsion",
    "qp",
    "neighbour_motion",
    "safety_types",
    "safety_plane",
    "safety_world",
    "safety_neighbours",
    "deadlock",
    "safety_filter",
    "neighbour_select",  # a long neighbour list's far entries dropped once a tick
    "neighbour_index",  # the in-process fleet's entries in a grid once a tick: near ones read
    "firmware_types",
    "firmware_rejects",
    "firmware_modes",
    "firmware",
    "neighbours",  # the agent host's per-frame neighbour lists (host_grid): ~0.4 ms a frame
    "host_grid",  # for 100 robots (bench/bench_host.py)
    "lockstep",  # the tick time and setpoint window every simulator and lockstep tick asks
)
#: The firmware's compiled modules' sources (``robot_agent/core``).
PACKAGE_DIR = Path(__file__).resolve().parent
#: The firmware's build: ``robot_agent/_compiled``, group ``robot_agent_accel``.
FIRMWARE = CompiledBuild(
    "robot_agent_accel",
    tuple(f"robot_agent.core.{name}" for name in COMPILED_MODULES),
    ROOT,
    PACKAGE_DIR.parent / "_compiled",
)
GROUP = FIRMWARE.group
BUILD_DIR = FIRMWARE.build_dir
decide = FIRMWARE.decide
source_hashes = FIRMWARE.source_hashes

#: Whether the compiled firmware core is in use (set by :func:`activate`).
ACTIVE = False
#: One line: which firmware core runs and why.
STATUS = "pure Python (not decided yet)"


def activate(package_path: list[str]) -> bool:
    """The firmware's build for ``robot_agent.core`` (its ``__path__``): called by
    ``robot_agent/core/__init__.py`` before it imports anything of the core. Sets
    :data:`ACTIVE` and :data:`STATUS`; never raises."""
    global ACTIVE, STATUS
    FIRMWARE.activate("robot_agent.core", package_path)
    ACTIVE, STATUS = FIRMWARE.status()
    return ACTIVE
