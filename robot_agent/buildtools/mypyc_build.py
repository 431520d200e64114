"""One builder for every compiled (mypyc) build: compile, check against pure Python, install.

A :class:`Plan` names what to build (a :class:`~robot_agent.core._accel.CompiledBuild`: its
modules, mypyc group and install folder), how to lay out a temporary copy of the sources (mypy
follows the compiled modules' imports there), and the check: a command, ``python -m <check>``,
whose standard output is the build's outputs. :func:`build`

1. copies the sources into a temporary directory (never the working tree: nothing half-built is
   ever importable from it);
2. compiles the listed modules there as one mypyc group with ``CFLAGS=-ffp-contract=off`` (no
   fused multiply-add: an ARM board and this machine compute the same bits as the interpreter);
3. stages the group's shared library and the modules' extension shims into the temporary tree's
   own build folder, with a manifest (interpreter, SHA-256 of every source, modules, flags);
4. runs the check there with the build and with ``FORMATION_ACCEL=0``: the build must load (the
   check prints the build's status line to standard error) and both must print the same;
5. only then replaces the installed build in one rename.

A build that fails or differs leaves the installed one (or pure Python) in use and says why in one
line. ``build`` needs mypy (which ships mypyc), setuptools and a C compiler with the Python
headers; running the result needs none of them. Standard library only: the robot's firmware
build (``robot_agent.buildtools.accel``) runs on a robot's install, without numpy; the simulator
and coordinator builds (``formation.sim.accel_build``) are thin callers with their own plans.
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
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

from robot_agent.core._accel import ENV, MANIFEST, CompiledBuild, interpreter_tag

_SETUP = """\
from setuptools import setup
from mypyc.build import mypycify

setup(
    name={group!r},
    packages=[],
    ext_modules=mypycify({paths!r}, opt_level="3", group_name={group!r}),
)
"""


@dataclass(frozen=True)
class Plan:
    """What one build compiles and how it is checked."""

    #: The modules, group and install folder (the loader's own description of the build).
    target: CompiledBuild
    #: What the build is, for messages ("firmware core", "simulator", ...).
    label: str
    #: Fills the temporary directory (the argument) with the sources, laid out as under
    #: ``target.root``.
    copy_sources: Callable[[Path], None]
    #: ``python -m`` arguments of the check, run in the temporary directory.
    check: tuple[str, ...]
    #: What one line of the check's output is ("lines", "runs"), for the result line.
    unit: str
    #: The compile's expected duration, for the progress line.
    expect: str = "about 30-90 s"
    check_timeout_s: float = 600.0


def unactivated(target: CompiledBuild, root: Path | None = None) -> list[str]:
    """Compiled modules whose package's ``__init__`` does not activate the build (its native
    callers would meet a pure module)."""
    out = []
    for name in target.modules:
        init = target.source_path(name, root).parent / "__init__.py"
        try:
            text = init.read_text(encoding="utf-8")
        except OSError:
            text = ""
        if "_accel.activate(" not in text or "__path__)" not in text:
            out.append(name)
    return out


def _check(plan: Plan, work: Path, accel: bool) -> subprocess.CompletedProcess[str]:
    """The plan's check over the sources under ``work``; ``accel``: compiled, else pure."""
    env = dict(os.environ)
    env[ENV] = "1" if accel else "0"
    env["PYTHONPATH"] = str(work)
    return subprocess.run(
        [sys.executable, "-m", *plan.check],
        cwd=work,
        env=env,
        capture_output=True,
        text=True,
        timeout=plan.check_timeout_s,
        check=False,
    )


def _compile(plan: Plan, work: Path, stage: Path, log: Callable[[str], None]) -> str | None:
    """mypyc over the plan's modules in ``work``; the build staged in ``stage`` with its
    manifest. Returns why it failed, or None."""
    target = plan.target
    paths = [target.source_path(m, Path()).as_posix() for m in target.modules]
    (work / "setup.py").write_text(_SETUP.format(paths=paths, group=target.group))
    env = dict(os.environ)
    env["CFLAGS"] = (env.get("CFLAGS", "") + " -ffp-contract=off").strip()
    env.pop("PYTHONPATH", None)
    log(f"compiling {len(paths)} modules with mypyc ({plan.expect})")
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
    group_libs = sorted(work.glob(f"{target.group}__mypyc*"))
    shims = {
        m: sorted(target.source_path(m, work).parent.glob(f"{m.rsplit('.', 1)[1]}.*.so"))
        for m in target.modules
    }
    if not group_libs or any(len(found) != 1 for found in shims.values()):
        return "mypyc build produced no extension modules"
    stage.mkdir(parents=True)
    for lib in group_libs:
        shutil.move(str(lib), stage / lib.name)
    for module, found in shims.items():
        dest = stage.joinpath(*module.split(".")[:-1])
        dest.mkdir(parents=True, exist_ok=True)
        shutil.move(str(found[0]), dest / found[0].name)  # the sources must not be shadowed
    manifest = {
        "interpreter": interpreter_tag(),
        "sources": target.source_hashes(work),
        "modules": list(target.modules),
        "cflags": env["CFLAGS"],
        "built_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
    }
    (stage / MANIFEST).write_text(json.dumps(manifest, indent=1) + "\n")
    return None


def _install(stage: Path, target_dir: Path) -> None:
    """Replace the installed build by ``stage`` (the old one is renamed away first)."""
    old = target_dir.with_name("_compiled.old")
    shutil.rmtree(old, ignore_errors=True)
    if target_dir.exists():
        target_dir.rename(old)
    shutil.copytree(stage, target_dir)
    shutil.rmtree(old, ignore_errors=True)


def build(plan: Plan, log: Callable[[str], None] = lambda _msg: None) -> tuple[bool, str]:
    """Compile, check and install; ``(ok, one-line reason)``."""
    missing = [m for m in ("mypyc", "setuptools") if importlib.util.find_spec(m) is None]
    if missing:
        return False, f"needs {' and '.join(missing)} to build (pip install mypy setuptools)"
    target = plan.target
    bare = unactivated(target)
    if bare:
        return False, f"the packages of {', '.join(bare)} do not call _accel.activate"
    t0 = time.monotonic()
    with tempfile.TemporaryDirectory(prefix=f"{target.group}_") as tmp:
        work = Path(tmp).resolve()
        try:
            plan.copy_sources(work)
        except OSError as exc:
            return False, f"cannot copy the sources to build ({exc})"
        # the build in its own tree, where the copied loader looks for it
        stage = work / target.build_dir.relative_to(target.root)
        failed = _compile(plan, work, stage, log)
        if failed:
            return False, failed
        log(f"checking the {plan.label}'s outputs against pure Python's")
        compiled = _check(plan, work, accel=True)
        pure = _check(plan, work, accel=False)
        loaded = f"compiled (mypyc, {len(target.modules)} modules, {stage})"
        if loaded not in compiled.stderr:
            return False, f"the new build does not load ({compiled.stderr.strip()[-200:]})"
        if compiled.returncode or pure.returncode or compiled.stdout != pure.stdout:
            return False, f"the compiled {plan.label}'s outputs differ from pure Python's"
        _install(stage, target.build_dir)
    return True, (
        f"built {len(target.modules)} modules into {target.build_dir} in "
        f"{time.monotonic() - t0:.0f} s; outputs equal to pure Python over "
        f"{compiled.stdout.count(chr(10))} {plan.unit}"
    )


def clean(target: CompiledBuild) -> str:
    """Remove the installed build: pure Python from now on."""
    if target.build_dir.exists():
        shutil.rmtree(target.build_dir)
        return f"removed {target.build_dir}"
    return "no compiled build"


def main(plans: Sequence[Plan], prog: str, argv: list[str] | None = None) -> int:
    """The ``build | status | clean`` command over ``plans`` (each by its label, in order).
    ``status`` exits 0 only when every build is used; ``build`` only when every one is built."""
    ap = argparse.ArgumentParser(
        prog=f"python -m {prog}",
        description="Build, check, remove or show the compiled (mypyc) build of the "
        + ", ".join(p.label for p in plans)
        + ".",
        epilog=f"example: python -m {prog} build && python -m {prog} status",
    )
    ap.add_argument("action", choices=("build", "status", "clean"))
    ap.add_argument("--quiet", action="store_true", help="print only the result line")
    if len(plans) > 1:
        ap.add_argument(
            "--only", choices=[p.label for p in plans], help="one build instead of all of them"
        )
    args = ap.parse_args(argv)
    only = getattr(args, "only", None)
    rc = 0
    for plan in plans:
        if only is not None and plan.label != only:
            continue
        if args.action == "status":
            use, why = plan.target.decide()
            print(f"{plan.label}: {why}")
            rc |= 0 if use else 1
        elif args.action == "clean":
            print(f"{plan.label}: {clean(plan.target)}")
        else:

            def log(msg: str, label: str = plan.label) -> None:
                if not args.quiet:
                    print(f"{label}: {msg}", file=sys.stderr)

            ok, why = build(plan, log)
            print(f"{plan.label}: {why}" if ok else f"{plan.label}: not built: {why}; pure Python")
            rc |= 0 if ok else 1
    return rc
