"""Build, check, remove or show the compiled firmware core (mypyc).

Usage::

    python -m robot_agent.buildtools.accel build     # compile, check against pure Python, install
    python -m robot_agent.buildtools.accel status   # which core runs and why (0 compiled, 1 pure)
    python -m robot_agent.buildtools.accel clean     # remove the build: pure Python from now on

The firmware's plan for the one builder (``robot_agent.buildtools.mypyc_build``: a temporary
copy, one mypyc group with ``CFLAGS=-ffp-contract=off``, a manifest, the check before install).
The copy is the ``robot_agent`` package with the contract's modules the core imports
(``bus_schemas.modes``: stdlib-only, under an empty ``bus_schemas`` package, so the build and its
check see nothing else of the contract). The modules are ``_accel.COMPILED_MODULES``; the check
is ``python -m robot_agent.buildtools.core_outputs --quick``, with the new build and with
``FORMATION_ACCEL=0``: the build is installed into ``robot_agent/_compiled/`` only if both print
the same. ``build`` needs mypy (which ships mypyc), setuptools and a C compiler with the Python
headers; none of them is needed to *run* the result, and none is a dependency of the robot
install.

``make venv`` runs ``build`` once (a machine without a compiler goes on with pure Python);
``make accel`` rebuilds after an edit (an edited source makes the old build stale, and a stale
build is never used: ``robot_agent/core/_accel.py``).
"""

from __future__ import annotations

import ast
import shutil
from pathlib import Path

from robot_agent.buildtools import mypyc_build
from robot_agent.core import _accel


def _copy_contract(core_dir: Path, dest: Path) -> None:
    """The contract's modules the firmware core imports (``from bus_schemas.modes import
    Mode``), copied to ``dest`` under an ``__init__`` without imports: mypy follows them for the
    types (the editable install's import hook is invisible to it) and the check runs on them."""
    contract = _accel.ROOT / "bus_schemas"
    dest.mkdir()
    (dest / "__init__.py").write_text('"""The contract modules the firmware core imports."""\n')
    names: set[str] = set()
    for path in core_dir.glob("*.py"):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("bus_schemas."):
                names.add(str(node.module).split(".")[1])
    for name in sorted(names):
        shutil.copy2(contract / f"{name}.py", dest / f"{name}.py")


def _copy_sources(work: Path) -> None:
    """The ``robot_agent`` package (without builds) and the contract modules its core imports."""
    shutil.copytree(
        _accel.ROOT / "robot_agent",
        work / "robot_agent",
        ignore=shutil.ignore_patterns("_compiled", "_compiled.old", "__pycache__", "*.so", "*.pyd"),
    )
    _copy_contract(work / "robot_agent" / "core", work / "bus_schemas")


PLAN = mypyc_build.Plan(
    target=_accel.FIRMWARE,
    label="firmware core",
    copy_sources=_copy_sources,
    check=("robot_agent.buildtools.core_outputs", "--quick"),
    unit="lines",
    expect="about 20-60 s",
    check_timeout_s=300.0,
)


def main(argv: list[str] | None = None) -> int:
    return mypyc_build.main([PLAN], "robot_agent.buildtools.accel", argv)


if __name__ == "__main__":
    raise SystemExit(main())
