"""The compiled firmware core (robot_agent/core/_accel.py, accel_build.py): used only when it is
right.

* the rules: FORMATION_ACCEL=0, no build, a build for another interpreter, a build of other
  sources, a build that does not load: each means the pure-Python core, and says why;
* a build of exactly these sources is used, and its outputs equal pure Python's bit for bit over
  the whole of ``robot_agent.buildtools.core_outputs`` (filter, estimator, firmware, odd inputs);
* an edit after the build is never shadowed by the stale binary.

The equality and the stale-build tests need the build ``make venv`` made (skipped, with the
reason, on a machine without a C compiler or after an edit without ``make accel``).
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from robot_agent.core import _accel

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


def _needs_build() -> None:
    use, why = _accel.decide(environ={})
    if not use:
        pytest.skip(f"no usable compiled build here: {why}")


def _run(code: str, root: Path, **env: str) -> subprocess.CompletedProcess[str]:
    full = dict(os.environ, PYTHONPATH=str(root))
    full.pop(_accel.ENV, None)
    full.update(env)
    return subprocess.run(
        [sys.executable, "-c", code],
        cwd=root,
        env=full,
        capture_output=True,
        text=True,
        timeout=120,
    )


def test_forced_pure_no_build_other_interpreter_and_unreadable_manifest(tmp_path: Path) -> None:
    build = tmp_path / "_compiled"
    use, why = _accel.decide(environ={_accel.ENV: "0"}, build_dir=build)
    assert (use, why) == (False, f"pure Python ({_accel.ENV}=0)")
    use, why = _accel.decide(environ={}, build_dir=build)
    assert not use and "no compiled build" in why
    _manifest(build, interpreter="cpython-399 3.99.0 plan9")
    use, why = _accel.decide(environ={}, build_dir=build)
    assert not use and "is for cpython-399 3.99.0 plan9" in why
    (build / _accel.MANIFEST).write_text("{not json")
    use, why = _accel.decide(environ={}, build_dir=build)
    assert not use and "unreadable manifest" in why
    _manifest(build, sources="nope")
    assert not _accel.decide(environ={}, build_dir=build)[0]


def test_a_build_of_other_sources_is_not_used_and_names_the_changed_modules(
    tmp_path: Path,
) -> None:
    build = tmp_path / "_compiled"
    hashes = _accel.source_hashes()
    fw, qp = "robot_agent.core.firmware", "robot_agent.core.qp"
    _manifest(build, sources=dict(hashes, **{fw: "0" * 64, qp: "1" * 64}))
    use, why = _accel.decide(environ={}, build_dir=build)
    assert not use
    assert f"sources changed since the compiled build: {fw}, {qp}" in why
    _manifest(build)  # the very sources on disk: this build would be used
    use, why = _accel.decide(environ={}, build_dir=build)
    assert use and f"compiled (mypyc, {len(_accel.COMPILED_MODULES)} modules" in why
    missing = dict(hashes)
    del missing["robot_agent.core.estimator"]
    _manifest(build, sources=missing)
    assert "estimator" in _accel.decide(environ={}, build_dir=build)[1]


def _copy_package(dst: Path) -> Path:
    shutil.copytree(
        ROOT / "robot_agent",
        dst / "robot_agent",
        ignore=shutil.ignore_patterns("__pycache__"),
    )
    return dst / "robot_agent"


_WHICH = (
    "import robot_agent, robot_agent.core.firmware as f, robot_agent.core._accel as a;"
    "print(a.ACTIVE, f.__file__, a.STATUS, sep='\\n')"
)


def test_a_manifest_without_binaries_falls_back_to_the_sources(tmp_path: Path) -> None:
    pkg = _copy_package(tmp_path)
    shutil.rmtree(pkg / "_compiled", ignore_errors=True)
    _manifest(pkg / "_compiled")  # right hashes, right interpreter, but no shared library
    out = _run(_WHICH, tmp_path)
    assert out.returncode == 0, out.stderr
    active, where, status = out.stdout.splitlines()
    assert active == "False" and where.endswith("robot_agent/core/firmware.py")
    assert "does not load" in status


def test_the_build_is_used_and_forced_pure_is_pure() -> None:
    _needs_build()
    out = _run(_WHICH, ROOT)
    active, where, status = out.stdout.splitlines()
    assert active == "True" and "/_compiled/robot_agent/core/firmware." in where
    assert where.endswith(".so") and status.startswith("compiled")
    out = _run(_WHICH, ROOT, **{_accel.ENV: "0"})
    active, where, status = out.stdout.splitlines()
    assert active == "False" and where.endswith("robot_agent/core/firmware.py")
    assert status == f"pure Python ({_accel.ENV}=0)"


def test_compiled_core_outputs_equal_pure_python_bit_for_bit() -> None:
    _needs_build()
    cmd = [sys.executable, "-m", "robot_agent.buildtools.core_outputs"]
    runs = {}
    for flag in ("1", "0"):
        env = dict(os.environ, PYTHONPATH=str(ROOT), **{_accel.ENV: flag})
        runs[flag] = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True)
        assert runs[flag].returncode == 0, runs[flag].stderr
    assert "compiled (mypyc" in runs["1"].stderr
    assert "pure Python" in runs["0"].stderr
    lines = runs["0"].stdout.splitlines()
    assert len(lines) > 100_000  # the whole dump, not a truncated one
    if runs["1"].stdout != runs["0"].stdout:
        compiled = runs["1"].stdout.splitlines()
        first = next(i for i, (a, b) in enumerate(zip(compiled, lines, strict=False)) if a != b)
        pytest.fail(f"line {first}: compiled {compiled[first]!r} != pure {lines[first]!r}")


# The ticks core_outputs does not reach (its pinned dump always has a setpoint): no setpoint yet,
# a setpoint, a stale pose, an estop, its release; commands and the final status of each core
_NO_SETPOINT_TICKS = """
from robot_agent.core import Firmware, Pose, Setpoint
for est in (True, False):
    from robot_agent.core import AgentConfig, EstimatorParams
    fw = Firmware(AgentConfig(estimator=EstimatorParams(enabled=est)))
    for k in range(40):
        now = k * 0.02
        sp = None if k < 10 else Setpoint(0.3, 0.1, 0.05, 0.0, 0.0, 0, now)
        if k < 25:  # then the same pose, ever older: stale (HOLD)
            pose, prx = Pose(0.0, 0.0, 0.0, now), now
        if k == 30:
            fw.engage_estop()
        if k == 35:
            fw.release_estop()
        cmd = fw.step(now, pose=pose, pose_rx_s=prx, setpoint=sp,
                      setpoint_rx_s=now, neighbours=[(0.2, 0.0)])
        print(repr(tuple(cmd)))
    print(repr(fw.status()))
"""


def test_idle_hold_and_estop_ticks_equal_pure_python_and_reject_nothing() -> None:
    """The paths the pinned dump misses: mypyc once read a Final tuple of NaNs (the "no
    setpoint" answer) as unset, a NameError on every tick without a setpoint, counted as a
    rejection; the build's check did not see it."""
    _needs_build()
    compiled = _run(_NO_SETPOINT_TICKS, ROOT)
    pure = _run(_NO_SETPOINT_TICKS, ROOT, **{_accel.ENV: "0"})
    assert compiled.returncode == 0 and pure.returncode == 0, compiled.stderr + pure.stderr
    assert compiled.stdout == pure.stdout
    statuses = [ln for ln in pure.stdout.splitlines() if ln.startswith("FirmwareStatus(")]
    assert len(statuses) == 2
    assert all("rejected_count=0," in st and "last_reject_reason=''" in st for st in statuses)


def test_an_edit_after_the_build_is_never_shadowed_by_the_stale_binary(tmp_path: Path) -> None:
    _needs_build()
    pkg = _copy_package(tmp_path)
    out = _run(_WHICH, tmp_path)
    assert out.stdout.splitlines()[0] == "True", out.stdout + out.stderr
    src = pkg / "core" / "firmware.py"
    src.write_text(src.read_text() + "\nEDITED_AFTER_THE_BUILD = True\n")
    out = _run(_WHICH + ";print(f.EDITED_AFTER_THE_BUILD)", tmp_path)
    assert out.returncode == 0, out.stderr
    active, where, status, edited = out.stdout.splitlines()
    assert active == "False" and where == str(src) and edited == "True"
    assert "sources changed since the compiled build: robot_agent.core.firmware" in status
    status_cmd = [sys.executable, "-m", "robot_agent.buildtools.accel", "status"]
    env = dict(os.environ, PYTHONPATH=str(tmp_path))
    env.pop(_accel.ENV, None)
    st = subprocess.run(status_cmd, cwd=tmp_path, env=env, capture_output=True, text=True)
    assert st.returncode == 1 and "sources changed" in st.stdout
