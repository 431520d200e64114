"""The simulator-side compiled build (sim_plant/core/_accel.py, formation/sim/accel_build.py):
used only when it is right, and then equal to pure Python bit for bit.

* the rules: FORMATION_ACCEL=0, no build, a build for another interpreter, an unreadable
  manifest, a build of other sources: each means pure Python, and says why; a build of exactly
  these sources is used;
* every compiled module's package activates the build (else its native callers would meet a pure
  module);
* with the build ``make venv`` made, the modules load from it, and the simulator's outputs
  (``formation.sim.accel_outputs``: faults, encoders, an operator reshape, a mover, motion claims,
  a fleet above SMALL_N) are the same compiled and pure (skipped, with the reason, without a
  usable build).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from formation.sim import accel_build
from sim_plant.core import _accel

ROOT = Path(__file__).resolve().parents[3]


def _manifest(build: Path, **over: object) -> None:
    data: dict[str, object] = {
        "interpreter": _accel.interpreter_tag(),
        "sources": _accel.source_hashes(),
        "modules": list(_accel.COMPILED_MODULES),
    }
    data.update(over)
    build.mkdir(parents=True, exist_ok=True)
    (build / _accel.MANIFEST).write_text(json.dumps(data))


def _run(module: str, **env: str) -> subprocess.CompletedProcess[str]:
    full = dict(os.environ, PYTHONPATH=str(ROOT))
    full.pop(_accel.ENV, None)
    full.update(env)
    return subprocess.run(
        [sys.executable, "-m", module],
        cwd=ROOT,
        env=full,
        capture_output=True,
        text=True,
        timeout=300,
    )


def test_forced_pure_no_build_other_interpreter_and_unreadable_manifest(tmp_path: Path) -> None:
    build = tmp_path / "_compiled"
    assert _accel.decide(environ={_accel.ENV: "0"}, build_dir=build) == (
        False,
        f"pure Python ({_accel.ENV}=0)",
    )
    use, why = _accel.decide(environ={}, build_dir=build)
    assert not use and "no compiled build" in why
    _manifest(build, interpreter="cpython-399 3.99.0 plan9")
    use, why = _accel.decide(environ={}, build_dir=build)
    assert not use and "is for cpython-399 3.99.0 plan9" in why
    (build / _accel.MANIFEST).write_text("{not json")
    use, why = _accel.decide(environ={}, build_dir=build)
    assert not use and "unreadable manifest" in why


def test_a_build_of_these_sources_is_used_and_an_edit_makes_it_stale(tmp_path: Path) -> None:
    build = tmp_path / "_compiled"
    _manifest(build)
    use, why = _accel.decide(environ={}, build_dir=build)
    assert use and why.startswith("compiled (mypyc")
    edited = dict(_accel.source_hashes())
    edited["sim_plant.core.plant"] = "0" * 64
    _manifest(build, sources=edited)
    use, why = _accel.decide(environ={}, build_dir=build)
    assert not use and "sources changed since the compiled build: sim_plant.core.plant" in why


def test_every_compiled_module_exists_and_its_package_activates_the_build() -> None:
    for name in _accel.COMPILED_MODULES:
        assert _accel.source_path(name).is_file(), name
    assert accel_build.unactivated() == []


def test_the_compiled_simulator_loads_and_equals_pure_python_bit_for_bit() -> None:
    use, why = _accel.decide(environ={})
    if not use:
        pytest.skip(f"no usable simulator build here: {why}")
    compiled = _run("formation.sim.accel_outputs")
    pure = _run("formation.sim.accel_outputs", **{_accel.ENV: "0"})
    assert compiled.returncode == 0, compiled.stderr
    assert pure.returncode == 0, pure.stderr
    assert "simulator: compiled (mypyc" in compiled.stderr
    assert "simulator: pure Python" in pure.stderr
    assert len(compiled.stdout.splitlines()) == 5
    assert compiled.stdout == pure.stdout
