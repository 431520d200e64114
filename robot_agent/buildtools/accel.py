"""Build, check, remove or show the compiled firmware core (mypyc).

Usage::

    python -m robot_agent.buildtools.accel build     # compile, check against pure Python, install
    python -m robot_agent.buildtools.accel status   # which core runs and why (0 compiled, 1 pure)
    python -m robot_agent.buildtools.accel clean     # remove the build: pure Python from now on

``build`` needs mypy (which ships mypyc), setuptools and a C compiler with the Python headers;
none of them is needed to *run* the result, and none is a dependency of the robot install. It
copies the package's sources into a temporary directory (with the contract's modules the core
imports, ``bus_schemas.modes``: stdlib-only, under an empty ``bus_schemas`` package, so the
build and its check see nothing else of the contract), compiles the modules of
``_accel.COMPILED_MODULES`` there as one mypyc group (``CFLAGS=-ffp-contract=off``: no fused
multiply-add, so an ARM board computes the same bits as the interpreter), then runs
``python -m robot_agent.buildtools.core_outputs --quick`` with the new build and with
``FORMATION_ACCEL=0``
and installs the build into ``robot_agent/_compiled/`` only if both print the same. A build that
fails or differs leaves the pure core in use and exits 1 with one line saying why.

``make venv`` runs ``build`` once (a machine without a compiler goes on with pure Python);
``make accel`` rebuilds after an edit (an edited source makes the old build stale, and a stale
build is never used: ``_accel.py``).
"""

from __future__ import annotations

import argparse
import ast
import importlib.util
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from robot_agent.core import _accel

_SETUP = """\
from setuptools import setup
from mypyc.build import mypycify

setup(
    name="robot_agent_accel",
    packages=[],
    ext_modules=mypycify({paths!r}, opt_level="3", group_name={group!r}),
)
"""


def _log(quiet: bool, msg: str) -> None:
    if not quiet:
        print(f"accel_build: {msg}", file=sys.stderr)


def _core_outputs(root: Path, accel: bool) -> subprocess.CompletedProcess[str]:
    """``robot_agent.buildtools.core_outputs --quick`` of the package under ``root``.

    ``accel``: compiled, else pure."""
    env = dict(os.environ)
    env[_accel.ENV] = "1" if accel else "0"
    env["PYTHONPATH"] = str(root)
    return subprocess.run(
        [sys.executable, "-m", "robot_agent.buildtools.core_outputs", "--quick"],
        cwd=root,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )


def _copy_contract(core_dir: Path, dest: Path) -> None:
    """The contract's modules the firmware core imports (``from bus_schemas.modes import
    Mode``), copied to ``dest`` under an ``__init__`` without imports: mypy follows them for the
    types (the editable install's import hook is invisible to it) and the check runs on them."""
    contract = _accel.PACKAGE_DIR.parent.parent / "bus_schemas"
    dest.mkdir()
    (dest / "__init__.py").write_text('"""The contract modules the firmware core imports."""\n')
    names: set[str] = set()
    for path in core_dir.glob("*.py"):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("bus_schemas."):
                names.add(str(node.module).split(".")[1])
    for name in sorted(names):
        shutil.copy2(contract / f"{name}.py", dest / f"{name}.py")


def build(quiet: bool = False) -> tuple[bool, str]:
    """Compile, check and install; ``(ok, one-line reason)``."""
    missing = [m for m in ("mypyc", "setuptools") if importlib.util.find_spec(m) is None]
    if missing:
        return False, f"needs {' and '.join(missing)} to build (pip install mypy setuptools)"
    t0 = time.monotonic()
    with tempfile.TemporaryDirectory(prefix="robot_agent_accel_") as tmp:
        work = Path(tmp)
        pkg = work / "robot_agent"
        shutil.copytree(
            _accel.PACKAGE_DIR.parent,
            pkg,
            ignore=shutil.ignore_patterns("_compiled", "__pycache__", "*.so", "*.pyd"),
        )
        try:
            _copy_contract(pkg / "core", work / "bus_schemas")
        except OSError as exc:
            return False, f"cannot copy the contract modules the core imports ({exc})"
        hashes = _accel.source_hashes(pkg / "core")
        paths = [f"robot_agent/core/{name}.py" for name in _accel.COMPILED_MODULES]
        (work / "setup.py").write_text(_SETUP.format(paths=paths, group=_accel.GROUP))
        env = dict(os.environ)
        env["CFLAGS"] = (env.get("CFLAGS", "") + " -ffp-contract=off").strip()
        env.pop("PYTHONPATH", None)
        _log(quiet, f"compiling {len(paths)} modules with mypyc (about 20-60 s)")
        proc = subprocess.run(
            [sys.executable, "setup.py", "build_ext", "--inplace"],
            cwd=work,
            env=env,
            capture_output=True,
            text=True,
            timeout=1800,
            check=False,
        )
        if proc.returncode != 0:
            tail = (proc.stderr or proc.stdout).strip().splitlines()[-1:] or ["?"]
            return False, f"mypyc build failed ({tail[0][:200]})"
        group_libs = sorted(work.glob(f"{_accel.GROUP}__mypyc*"))
        modules = {
            name: sorted((pkg / "core").glob(f"{name}.*.so")) for name in _accel.COMPILED_MODULES
        }
        if not group_libs or any(len(found) != 1 for found in modules.values()):
            return False, "mypyc build produced no extension modules"
        # the build in its own tree: check it against the pure sources beside it
        stage = work / "_compiled"
        (stage / "robot_agent" / "core").mkdir(parents=True)
        for lib in group_libs:
            shutil.copy2(lib, stage / lib.name)
        for found in modules.values():
            shutil.copy2(found[0], stage / "robot_agent" / "core" / found[0].name)
            found[0].unlink()  # the checking tree's sources must not be shadowed
        manifest = {
            "interpreter": _accel.interpreter_tag(),
            "sources": hashes,
            "modules": list(_accel.COMPILED_MODULES),
            "cflags": env["CFLAGS"],
            "built_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        }
        (stage / _accel.MANIFEST).write_text(json.dumps(manifest, indent=1) + "\n")
        for lib in group_libs:
            lib.unlink()
        shutil.move(str(stage), str(pkg / "_compiled"))
        compiled = _core_outputs(work, accel=True)
        pure = _core_outputs(work, accel=False)
        if "compiled (mypyc" not in compiled.stderr:
            return False, f"the new build does not load ({compiled.stderr.strip()[-200:]})"
        if compiled.returncode or pure.returncode or compiled.stdout != pure.stdout:
            return False, "compiled core's outputs differ from pure Python's: not installed"
        lines = pure.stdout.count("\n")
        # install: replace the old build in one rename
        target = _accel.BUILD_DIR
        old = target.with_name("_compiled.old")
        shutil.rmtree(old, ignore_errors=True)
        if target.exists():
            target.rename(old)
        shutil.copytree(pkg / "_compiled", target)
        shutil.rmtree(old, ignore_errors=True)
    return True, (
        f"built {len(_accel.COMPILED_MODULES)} modules into {_accel.BUILD_DIR} in "
        f"{time.monotonic() - t0:.0f} s; outputs equal to pure Python over {lines} lines"
    )


def clean() -> str:
    if _accel.BUILD_DIR.exists():
        shutil.rmtree(_accel.BUILD_DIR)
        return f"removed {_accel.BUILD_DIR}"
    return "no compiled build"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="python -m robot_agent.buildtools.accel",
        description="Build, check, remove or show the compiled (mypyc) firmware core.",
        epilog="example: python -m robot_agent.buildtools.accel build && "
        "python -m robot_agent.buildtools.accel status",
    )
    ap.add_argument("action", choices=("build", "status", "clean"))
    ap.add_argument("--quiet", action="store_true", help="print only the result line")
    args = ap.parse_args(argv)
    if args.action == "status":
        use, why = _accel.decide()
        print(f"firmware core: {why}")
        return 0 if use else 1
    if args.action == "clean":
        print(f"accel_build: {clean()}")
        return 0
    ok, why = build(quiet=args.quiet)
    print(f"accel_build: {why}" if ok else f"accel_build: not built: {why}; pure Python in use")
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
