"""Which firmware core runs: the pure-Python sources or their compiled build (mypyc).

The per-tick code of the firmware (estimator, tracking, repulsion, safety filter, mode machine)
and of the agent host's neighbour lists (:data:`COMPILED_MODULES`) is plain, fully annotated
Python. ``python -m robot_agent.buildtools.accel build`` compiles *the same files* with mypyc into
``robot_agent/_compiled/`` (about 5x faster, outputs equal bit for bit: the build checks it
before installing, and tests/unit/robot_agent/test_accel.py checks it again). Nothing else changes:
there is one
source of truth, and a robot without a C compiler runs the pure code.

This module decides, once, when ``robot_agent.core`` is imported, which of the two is used:

* ``FORMATION_ACCEL=0`` in the environment: pure Python, always.
* no build, or a build for another interpreter: pure Python.
* a build whose manifest's SHA-256 of each source differs from the ``.py`` file now on disk (the
  code was edited after the build): pure Python, so an edit is never shadowed by a stale binary.
  ``make accel`` (or the build command) brings the compiled core back.
* else the compiled modules: ``_compiled/robot_agent/core`` goes first on the package's
  ``__path__``, so ``robot_agent.core.firmware`` and the other listed modules load from there; every
  other module of the package loads from its source as before.

:data:`STATUS` says which one runs and why (``accel_build status`` prints it, the benchmarks
print it with their figures). Standard library only; no I/O beyond reading the manifest and
hashing ~150 kB of sources.
"""

from __future__ import annotations

import hashlib
import json
import os
import sys
from pathlib import Path

#: The modules compiled (the firmware's per-tick path), in dependency order.
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
    "firmware_types",
    "firmware_rejects",
    "firmware_modes",
    "firmware",
    "neighbours",  # the agent host's per-frame neighbour lists (host_grid): ~0.4 ms a frame
    "host_grid",  # for 100 robots (bench/bench_host.py)
)
#: mypyc's group name: the shared library of the build is ``<GROUP>__mypyc``.
GROUP = "robot_agent_accel"
#: Environment variable: ``0`` forces the pure-Python core.
ENV = "FORMATION_ACCEL"
#: The compiled modules' sources (``robot_agent/core``).
PACKAGE_DIR = Path(__file__).resolve().parent
#: Where the build is installed (``robot_agent/_compiled``, never packaged).
BUILD_DIR = PACKAGE_DIR.parent / "_compiled"
MANIFEST = "manifest.json"

#: Whether the compiled core is in use (set by :func:`activate`).
ACTIVE = False
#: One line: which core runs and why.
STATUS = "pure Python (not decided yet)"


def source_hashes(package_dir: Path = PACKAGE_DIR) -> dict[str, str]:
    """SHA-256 of each compiled module's source file (missing file: empty string)."""
    out: dict[str, str] = {}
    for name in COMPILED_MODULES:
        path = package_dir / f"{name}.py"
        try:
            out[name] = hashlib.sha256(path.read_bytes()).hexdigest()
        except OSError:
            out[name] = ""
    return out


def interpreter_tag() -> str:
    """The interpreter a build is for (its extension suffix names the ABI; this adds the build)."""
    return f"{sys.implementation.cache_tag} {sys.version.split()[0]} {sys.platform}"


def decide(
    environ: dict[str, str] | os._Environ[str] | None = None,
    build_dir: Path = BUILD_DIR,
    package_dir: Path = PACKAGE_DIR,
) -> tuple[bool, str]:
    """``(use_compiled, reason)`` for this process: the rules of the module docstring."""
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
    now = source_hashes(package_dir)
    changed = sorted(name for name in COMPILED_MODULES if hashes.get(name) != now[name])
    if changed:
        return False, (
            f"pure Python (sources changed since the compiled build: {', '.join(changed)}; "
            "make accel)"
        )
    return True, f"compiled (mypyc, {len(COMPILED_MODULES)} modules, {build_dir})"


def activate(package_path: list[str]) -> bool:
    """Put the compiled build first on ``package_path`` (the package's ``__path__``) if usable.

    Called by ``robot_agent/core/__init__.py`` before it imports anything of the core. Sets
    :data:`ACTIVE` and :data:`STATUS`; never raises (a build that does not load means pure).
    """
    global ACTIVE, STATUS
    use, why = decide()
    if use:
        root = str(BUILD_DIR)
        added = root not in sys.path
        if added:
            sys.path.append(root)  # the group's shared library is a top-level module
        try:
            __import__(f"{GROUP}__mypyc")
        except ImportError as exc:
            if added:
                sys.path.remove(root)
            use, why = False, f"pure Python (compiled build does not load: {exc}; make accel)"
        else:
            package_path.insert(0, str(BUILD_DIR / "robot_agent" / "core"))
    ACTIVE, STATUS = use, why
    return use
