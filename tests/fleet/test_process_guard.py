"""The test suite's own guard (tests/conftest.py): nothing a test starts outlives it.

Each test runs an inner pytest on a probe file that uses this suite's conftest, and checks from
outside: a leaked process (a child, or an orphaned grandchild in its own session) fails the test
that leaked it and is stopped; SIGTERM to pytest stops every process of the run (a router, a
plain child, a grandchild) before pytest dies; after SIGKILL to pytest a ``formation`` child
dies with it (parent-death signal) and the next run of the suite stops what is left.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from support.spawn import REPO_ROOT, child_env

pytestmark = [pytest.mark.slow, pytest.mark.shares_cpu]

SUITE_CONFTEST = str(REPO_ROOT / "tests" / "conftest.py")
CONFTEST = f"""
import importlib.util, sys
sys.path.insert(0, {str(REPO_ROOT / "tests")!r})
spec = importlib.util.spec_from_file_location("suite_conftest", {SUITE_CONFTEST!r})
mod = importlib.util.module_from_spec(spec)
sys.modules["suite_conftest"] = mod
spec.loader.exec_module(mod)
globals().update({{k: v for k, v in vars(mod).items() if not k.startswith("__")}})
"""

PROBE = """
import os, subprocess, sys, time
from pathlib import Path
from support.spawn import child_env

PIDS = Path(os.environ["PROBE_PIDS"])
SLEEP = [sys.executable, "-c", "import time; time.sleep(600)"]


def note(pid):
    with open(PIDS, "a") as f:
        f.write(f"{pid}\\n")


def test_leaks_a_child():
    note(subprocess.Popen(SLEEP, env=child_env()).pid)


def test_leaks_an_orphan():
    code = (
        "import subprocess, sys; "
        f"p = subprocess.Popen({SLEEP!r}, start_new_session=True, stdout=subprocess.DEVNULL, "
        "stderr=subprocess.DEVNULL); print(p.pid)"
    )
    out = subprocess.run([sys.executable, "-c", code], env=child_env(), capture_output=True)
    note(int(out.stdout))


def test_clean(spawn):
    note(spawn.python("import time; time.sleep(600)").pid)


def test_hangs(spawn):
    note(spawn("router", "--listen", "tcp/127.0.0.1:0").pid)
    note(spawn.python("import time; time.sleep(600)").pid)
    code = (
        "import subprocess, sys, time; "
        f"p = subprocess.Popen({SLEEP!r}, start_new_session=True); "
        f"open({str(PIDS)!r}, 'a').write(f'{{p.pid}} '); time.sleep(600)"
    )
    note(subprocess.Popen([sys.executable, "-c", code], env=child_env()).pid)
    print("PROBE READY", flush=True)
    time.sleep(600)
"""


def _alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as f:
            raw = f.read()
    except OSError:
        return False
    return raw[raw.rfind(")") + 2 :].split()[0] not in ("Z", "X")


def _probe_dir(tmp_path: Path) -> Path:
    d = tmp_path / "probe"
    d.mkdir()
    (d / "conftest.py").write_text(CONFTEST)
    (d / "test_probe.py").write_text(PROBE)
    return d


def _pytest(d: Path, *args: str) -> subprocess.Popen[str]:
    env = child_env({"PROBE_PIDS": str(d / "pids")})
    return subprocess.Popen(
        [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-s", "-o",
         "asyncio_default_fixture_loop_scope=function", "--rootdir",
         str(d), str(d / "test_probe.py"), *args],
        cwd=d, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )  # fmt: skip


def _pids(d: Path) -> list[int]:
    path = d / "pids"
    return [int(x) for x in path.read_text().split()] if path.exists() else []


def _wait_for_pids(d: Path, n: int, timeout_s: float = 60.0) -> list[int]:
    """Until the probe noted ``n`` processes (and a grandchild had time to start)."""
    deadline = time.monotonic() + timeout_s
    while len(_pids(d)) < n:
        assert time.monotonic() < deadline, _pids(d)
        time.sleep(0.05)
    return _pids(d)


def _descendants_of(pids: list[int]) -> set[int]:
    """Every live process whose parent chain reaches one of ``pids``."""
    parent: dict[int, int] = {}
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                with open(f"/proc/{entry}/stat") as f:
                    raw = f.read()
            except OSError:
                continue
            parent[int(entry)] = int(raw[raw.rfind(")") + 2 :].split()[1])
    found = set(pids)
    grew = True
    while grew:
        new = {p for p, pp in parent.items() if pp in found and p not in found}
        found |= new
        grew = bool(new)
    return {p for p in found if _alive(p)}


def _all_gone(pids: set[int], timeout_s: float) -> set[int]:
    deadline = time.monotonic() + timeout_s
    while (left := {p for p in pids if _alive(p)}) and time.monotonic() < deadline:
        time.sleep(0.05)
    return left


def test_a_leaked_process_fails_the_test_that_leaked_it(tmp_path: Path) -> None:
    d = _probe_dir(tmp_path)
    run = _pytest(d, "-k", "leaks or clean")
    out, _ = run.communicate(timeout=180)
    assert run.returncode == 1, out
    assert "ERROR at teardown of test_leaks_a_child" in out, out
    assert "ERROR at teardown of test_leaks_an_orphan" in out, out
    assert "test_clean" not in out.split("short test summary")[-1], out  # spawn stopped it
    assert "3 passed, 1 deselected, 2 errors" in out, out
    pids = _pids(d)
    assert len(pids) == 3, pids
    assert not [p for p in pids if _alive(p)], out


def test_sigterm_to_pytest_stops_every_process_of_the_run(tmp_path: Path) -> None:
    d = _probe_dir(tmp_path)
    run = _pytest(d, "-k", "hangs")
    try:
        _wait_for_pids(d, 4)  # router, sleeper, shell, the shell's child in its own session
        assert run.stdout is not None
        while "PROBE READY" not in run.stdout.readline():
            pass
        tree = _descendants_of(_pids(d))
        assert len(tree) == 4, tree
        run.send_signal(signal.SIGTERM)
        run.wait(30)
        assert run.returncode == -signal.SIGTERM
        assert not _all_gone(tree, 5.0), [(p, _alive(p)) for p in tree]
    finally:
        if run.poll() is None:
            run.kill()
            run.wait()


def test_after_sigkill_formation_children_die_and_the_next_run_sweeps(tmp_path: Path) -> None:
    d = _probe_dir(tmp_path)
    run = _pytest(d, "-k", "hangs")
    try:
        router, *_ = _wait_for_pids(d, 4)
        assert run.stdout is not None
        while "PROBE READY" not in run.stdout.readline():
            pass
        tree = _descendants_of(_pids(d))
        run.send_signal(signal.SIGKILL)
        run.wait(30)
    finally:
        if run.poll() is None:
            run.kill()
            run.wait()
    assert not _all_gone({router}, 5.0), "the router outlived pytest's SIGKILL"
    assert {p for p in tree if _alive(p)}, "expected plain children left for the next run"
    again = _pytest(d, "-k", "clean")
    out, _ = again.communicate(timeout=180)
    assert again.returncode == 0, out
    assert "stopping processes left by a killed test run" in out, out
    assert not _all_gone(tree, 5.0), out
