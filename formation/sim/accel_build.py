"""Build, check, remove or show the simulator-side compiled build (mypyc).

Usage::

    python -m formation.sim.accel_build build     # compile, check against pure Python, install
    python -m formation.sim.accel_build status    # which code runs and why (0 compiled, 1 pure)
    python -m formation.sim.accel_build clean     # remove the build: pure Python from now on

The modules of ``sim_plant.core._accel.COMPILED_MODULES`` (the plant, camera and link, the
in-process loop) are compiled as one mypyc group, the same way as the firmware's build
(``robot_agent.buildtools.accel``): in a temporary copy of the project's packages, with
``CFLAGS=-ffp-contract=off`` (no fused multiply-add: the same bits as the interpreter). Then
``python -m formation.sim.accel_outputs`` runs there with the build and with ``FORMATION_ACCEL=0``,
and the build is installed into ``sim_plant/_compiled/`` only if both print the same. A build that
fails or differs leaves pure Python in use and exits 1 with one line saying why. ``build`` needs
mypy (which ships mypyc), setuptools and a C compiler; running the result needs none of them.

``make venv`` runs ``build`` once; ``make accel`` rebuilds after an edit (an edited source makes
the old build stale, and a stale build is never used: ``sim_plant/core/_accel.py``).
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from sim_plant.core import _accel

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

_SETUP = """\
from setuptools import setup
from mypyc.build import mypycify

setup(
    name={group!r},
    packages=[],
    ext_modules=mypycify({paths!r}, opt_level="3", group_name={group!r}),
)
"""


def _log(quiet: bool, msg: str) -> None:
    if not quiet:
        print(f"sim_accel_build: {msg}", file=sys.stderr)


def _outputs(root: Path, accel: bool) -> subprocess.CompletedProcess[str]:
    """``formation.sim.accel_outputs`` of the packages under ``root``; ``accel``: compiled."""
    env = dict(os.environ)
    env[_accel.ENV] = "1" if accel else "0"
    env["PYTHONPATH"] = str(root)
    return subprocess.run(
        [sys.executable, "-m", "formation.sim.accel_outputs"],
        cwd=root,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
        check=False,
    )


def unactivated(root: Path = _accel.ROOT) -> list[str]:
    """Compiled modules whose package's ``__init__`` does not call ``_accel.activate``."""
    out = []
    for name in _accel.COMPILED_MODULES:
        init = _accel.source_path(name, root).parent / "__init__.py"
        try:
            text = init.read_text(encoding="utf-8")
        except OSError:
            text = ""
        if "_accel.activate(__name__, __path__)" not in text:
            out.append(name)
    return out


def _copy_tree(work: Path) -> None:
    ignore = shutil.ignore_patterns("_compiled", "_compiled.old", "__pycache__", "*.so", "*.pyd")
    for pkg in PACKAGES:
        shutil.copytree(_accel.ROOT / pkg, work / pkg, ignore=ignore)
    shutil.copy2(_accel.ROOT / "pyproject.toml", work / "pyproject.toml")  # mypy's settings


def _compile(work: Path, quiet: bool) -> str | None:
    """mypyc over the modules in ``work``; the build staged in ``work/sim_plant/_compiled``.
    Returns why it failed, or None."""
    paths = [str(_accel.source_path(m, Path())) for m in _accel.COMPILED_MODULES]
    (work / "setup.py").write_text(_SETUP.format(paths=paths, group=_accel.GROUP))
    env = dict(os.environ)
    env["CFLAGS"] = (env.get("CFLAGS", "") + " -ffp-contract=off").strip()
    env.pop("PYTHONPATH", None)
    _log(quiet, f"compiling {len(paths)} modules with mypyc (about 30-90 s)")
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
        errors = [ln for ln in proc.stdout.splitlines() if ": error:" in ln]
        tail = errors or (proc.stderr or proc.stdout).strip().splitlines()[-1:] or ["?"]
        return f"mypyc build failed ({tail[0][:200]})"
    group_libs = sorted(work.glob(f"{_accel.GROUP}__mypyc*"))
    shims = {m: sorted(_accel.source_path(m, work).parent.glob(f"{m.rsplit('.', 1)[1]}.*.so"))
             for m in _accel.COMPILED_MODULES}  # fmt: skip
    if not group_libs or any(len(found) != 1 for found in shims.values()):
        return "mypyc build produced no extension modules"
    stage = work / "sim_plant" / "_compiled"
    stage.mkdir()
    for lib in group_libs:
        shutil.move(str(lib), stage / lib.name)
    for module, found in shims.items():
        dest = stage.joinpath(*module.split(".")[:-1])
        dest.mkdir(parents=True, exist_ok=True)
        shutil.move(str(found[0]), dest / found[0].name)  # the sources must not be shadowed
    manifest = {
        "interpreter": _accel.interpreter_tag(),
        "sources": _accel.source_hashes(work),
        "modules": list(_accel.COMPILED_MODULES),
        "cflags": env["CFLAGS"],
        "built_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
    }
    (stage / _accel.MANIFEST).write_text(json.dumps(manifest, indent=1) + "\n")
    return None


def build(quiet: bool = False) -> tuple[bool, str]:
    """Compile, check and install; ``(ok, one-line reason)``."""
    missing = [m for m in ("mypyc", "setuptools") if importlib.util.find_spec(m) is None]
    if missing:
        return False, f"needs {' and '.join(missing)} to build (pip install mypy setuptools)"
    bare = unactivated()
    if bare:
        return False, f"the packages of {', '.join(bare)} do not call _accel.activate"
    t0 = time.monotonic()
    with tempfile.TemporaryDirectory(prefix="sim_accel_") as tmp:
        work = Path(tmp)
        _copy_tree(work)
        failed = _compile(work, quiet)
        if failed:
            return False, failed
        _log(quiet, "checking the build's outputs against pure Python's")
        compiled = _outputs(work, accel=True)
        pure = _outputs(work, accel=False)
        if "compiled (mypyc" not in compiled.stderr:
            return False, f"the new build does not load ({compiled.stderr.strip()[-200:]})"
        if compiled.returncode or pure.returncode or compiled.stdout != pure.stdout:
            return (
                False,
                "the compiled simulator's outputs differ from pure Python's: not installed",
            )
        runs = compiled.stdout.count("\n")
        target = _accel.BUILD_DIR
        old = target.with_name("_compiled.old")
        shutil.rmtree(old, ignore_errors=True)
        if target.exists():
            target.rename(old)
        shutil.copytree(work / "sim_plant" / "_compiled", target)
        shutil.rmtree(old, ignore_errors=True)
    return True, (
        f"built {len(_accel.COMPILED_MODULES)} modules into {_accel.BUILD_DIR} in "
        f"{time.monotonic() - t0:.0f} s; outputs equal to pure Python over {runs} runs"
    )


def clean() -> str:
    if _accel.BUILD_DIR.exists():
        shutil.rmtree(_accel.BUILD_DIR)
        return f"removed {_accel.BUILD_DIR}"
    return "no compiled build"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="python -m formation.sim.accel_build",
        description="Build, check, remove or show the simulator-side compiled (mypyc) build.",
        epilog="example: python -m formation.sim.accel_build build && "
        "python -m formation.sim.accel_build status",
    )
    ap.add_argument("action", choices=("build", "status", "clean"))
    ap.add_argument("--quiet", action="store_true", help="print only the result line")
    args = ap.parse_args(argv)
    if args.action == "status":
        use, why = _accel.decide()
        print(f"simulator: {why}")
        return 0 if use else 1
    if args.action == "clean":
        print(f"sim_accel_build: {clean()}")
        return 0
    ok, why = build(quiet=args.quiet)
    print(f"sim_accel_build: {why}" if ok else f"sim_accel_build: not built: {why}; pure Python")
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
