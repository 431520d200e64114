"""The coordinator's compiled build (coordinator/core/_accel.py, formation/sim/accel_build.py):
used only when it is right (the rules are the one loader's, robot_agent/core/_accel.py, tested in
tests/unit/robot_agent/test_accel.py and tests/unit/sim_plant/test_sim_accel.py).

* every compiled module exists and its package activates the build;
* a build of exactly these sources is used, an edit makes it stale;
* with the build ``make venv`` made, the modules load from it and ``FORMATION_ACCEL=0`` loads the
  sources; a coordinator replay's outputs are the same compiled and pure (the in-process
  simulator's digests compare them too: tests/unit/sim_plant/test_sim_accel.py).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from coordinator.core import _accel
from formation.sim import accel_build
from robot_agent.core._accel import ENV, MANIFEST, interpreter_tag

ROOT = Path(__file__).resolve().parents[3]


def test_every_compiled_module_exists_and_its_package_activates_the_build() -> None:
    for name in _accel.COMPILED_MODULES:
        assert _accel.BUILD.source_path(name).is_file(), name
    assert accel_build.unactivated() == []


def test_a_build_of_these_sources_is_used_and_an_edit_makes_it_stale(tmp_path: Path) -> None:
    build = tmp_path / "_compiled"
    build.mkdir()
    hashes = _accel.BUILD.source_hashes()
    manifest = {"interpreter": interpreter_tag(), "sources": hashes}
    (build / MANIFEST).write_text(json.dumps(manifest))
    use, why = _accel.BUILD.decide(environ={}, build_dir=build)
    assert use and why == f"compiled (mypyc, {len(_accel.COMPILED_MODULES)} modules, {build})"
    assert _accel.BUILD.decide(environ={ENV: "0"}, build_dir=build) == (
        False,
        f"pure Python ({ENV}=0)",
    )
    manifest["sources"] = dict(hashes, **{"coordinator.core.movers": "0" * 64})
    (build / MANIFEST).write_text(json.dumps(manifest))
    use, why = _accel.BUILD.decide(environ={}, build_dir=build)
    assert not use and "sources changed since the compiled build: coordinator.core.movers" in why


# Which file each compiled module loaded from, then a paper-exp2 replay of 600 ticks (a drag,
# a reshape to a column half-way) through the coordinator core alone: its outputs' digest.
_PROBE = """
import hashlib, importlib
from coordinator.core import _accel
import scenario
from scenario.assemble import coordinator_core
for name in _accel.COMPILED_MODULES:
    print(importlib.import_module(name).__file__)
core = coordinator_core(scenario.load("paper-exp2"))
poses = {f"r{i}": (0.3 * i - 0.5, 0.2 * (i % 2), 0.1 * i) for i in range(1, 4)}
h = hashlib.sha256()
for k in range(600):
    t = 0.02 * k
    if k == 300:
        h.update(repr(core.reshape("column", 0.5, 0.3)).encode())
    o = core.tick(t, poses, (), {})
    h.update(repr((o.leader, o.theta, o.rows, o.slot_ids, list(o.assignment.items()), o.changed,
                   sorted(o.approach.items()), o.movers)).encode())
    poses = {r: (x + 0.004, y + 0.001 * (k % 3 - 1), th) for r, (x, y, th) in poses.items()}
print(h.hexdigest())
"""


def _probe(**env: str) -> list[str]:
    full = dict(os.environ, PYTHONPATH=str(ROOT))
    full.pop(ENV, None)
    full.update(env)
    out = subprocess.run(
        [sys.executable, "-c", _PROBE],
        cwd=ROOT,
        env=full,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert out.returncode == 0, out.stderr
    return out.stdout.splitlines()


def test_the_build_is_used_and_its_ticks_equal_pure_python_bit_for_bit() -> None:
    use, why = _accel.BUILD.decide(environ={})
    if not use:
        pytest.skip(f"no usable coordinator build here: {why}")
    n = len(_accel.COMPILED_MODULES)
    compiled, pure = _probe(), _probe(**{ENV: "0"})
    assert all("/coordinator/_compiled/coordinator/core/" in f for f in compiled[:n]), compiled
    assert all(f.endswith(".so") for f in compiled[:n])
    assert all(f.endswith(".py") and "_compiled" not in f for f in pure[:n]), pure
    assert compiled[n:] == pure[n:] and len(pure) == n + 1
