"""Shared pytest fixtures for tests that run real processes and real Zenoh sessions on loopback.

Fixtures (function scope unless noted):

* ``spawn``: factory of subprocesses. ``spawn("router", "--listen", ep, ready="router listening")``
  runs ``python -m formation router ...``; ``spawn.command(argv)`` runs any argv and
  ``spawn.python(code, *args)`` runs ``python -c code``. Every child gets its own process group,
  the repository on ``PYTHONPATH``, and stdout/stderr in files under ``tmp_path`` (no pipe can
  fill up and block it). On teardown each child still running gets SIGTERM; one that ignores it
  for more than 2 s is SIGKILLed and the test fails. Leftover members of a child's process group
  (grandchildren) are killed and fail the test too.
* ``router``: a ``formation router`` subprocess on a free loopback port, ready when yielded
  (``.endpoint``, ``.port``, ``.proc``, ``.child``). Teardown SIGTERMs it and asserts it exited
  with status 0 within 2 s.
* ``start_router``: factory for more routers (``start_router()`` -> the same handle type).
* ``session``: factory of client sessions to ``router`` (``session(**ZenohSettings fields)``),
  all closed on teardown.
* ``free_port()``: a plain helper, a TCP port on 127.0.0.1 that was free a moment ago.
* Hypothesis profile ``formation``: no deadline, no ``too_slow`` health check (wall-clock limits
  fail on a loaded machine; a property is not a speed test).
* Nothing a test starts may outlive it (autouse, every test; the /proc bookkeeping is in
  ``tests/support/procguard.py``): every process this pytest run
  starts, at any depth, carries ``FORMATION_TEST_RUN=<pytest pid>.<nonce>`` in its environment
  (set once in ``os.environ``, inherited by every ``Popen``). After each test's teardown, one
  still running that was not running before the test is killed and fails that test; at the end
  of the run none may be left (session fixtures included). ``python -m formation`` children also
  get ``FORMATION_PARENT_PID`` (runtime.lifecycle.bind_to_parent: the kernel SIGKILLs them
  when pytest dies, even by SIGKILL; a ``formation up`` launcher's own children die with it).
  SIGTERM/SIGHUP to pytest stop every process of the run (SIGTERM, then SIGKILL) before pytest
  dies; SIGINT does through the normal teardown plus an ``atexit`` sweep. Processes of an earlier
  run whose pytest is gone (it was SIGKILLed) are killed when a run starts.

Tests using ``router``, ``start_router`` or ``session`` are marked ``zenoh`` automatically.
"""

from __future__ import annotations

import contextlib
import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import pytest
from hypothesis import HealthCheck, settings
from support.procguard import (
    SIGTERM_PATIENCE_S,
    _cmdline,
    _describe,
    _has_run_mark,
    _kill_all,
    _live_processes,
    _marked_processes,
    _now_ticks,
    _orphans_of_dead_runs,
    _proc_stat,
    _run_processes,
    _stop_run_processes,
    _terminate,
    _wait_until_gone,
)

# The test folders mirror the code (unit/<package>, bus, fleet, repo); a test may reuse another
# test module's helpers by its plain name, whichever folder it is in, so every folder is on the
# path before any test module is imported (pytest's default import mode adds only a module's own).
for _folder in sorted(Path(__file__).resolve().parent.glob("**/")):
    if _folder.name not in {"__pycache__", "support"} and str(_folder) not in sys.path:
        sys.path.append(str(_folder))

if TYPE_CHECKING:
    import zenoh

REPO_ROOT = Path(__file__).resolve().parents[1]

# Hypothesis: no wall-clock limits (a property is not a speed test: next to a CPU hog one example
# or the data generation can take longer than the 200 ms default deadline), loaded before any
# test module builds its own settings on top of the default.
settings.register_profile("formation", deadline=None, suppress_health_check=[HealthCheck.too_slow])
settings.load_profile("formation")
READY_TIMEOUT_S = 15.0  # python start + zenoh import on a loaded 2-core CI box
ROUTER_READY = "router listening on "
_ZENOH_FIXTURES = frozenset({"router", "start_router", "session"})

# Process groups created by `spawn`, checked again at the end of the whole run.
_SPAWNED_GROUPS: set[int] = set()

PARENT_ENV = "FORMATION_PARENT_PID"  # = runtime.lifecycle.PARENT_ENV (tests import no runtime here)
OUTLIVE_GRACE_S = 5.0
"""How long a process started by a test may take to finish exiting after the test's teardown
(it was signalled and is on its way out, on a loaded machine) before it counts as left behind."""


def free_port() -> int:
    """A TCP port on 127.0.0.1 that the kernel considered free a moment ago."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.bind(("127.0.0.1", 0))
        port: int = sock.getsockname()[1]
        return port


def child_env(extra: dict[str, str] | None = None) -> dict[str, str]:
    """Environment for a child: the repository importable, unbuffered output, no ZENOH_CONFIG,
    tied to this pytest (``FORMATION_PARENT_PID``: a ``python -m formation`` child dies with
    it; the run's mark, inherited from ``os.environ``, lets the guard find it at any depth)."""
    env = dict(os.environ)
    env.pop("ZENOH_CONFIG", None)
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(REPO_ROOT), env.get("PYTHONPATH", "")) if p)
    env["PYTHONUNBUFFERED"] = "1"
    env[PARENT_ENV] = str(os.getpid())
    if extra:
        env.update(extra)
    return env


# ---------------------------------------------------------------------------------------------
# Subprocesses
# ---------------------------------------------------------------------------------------------


class Child:
    """One spawned process; its stdout/stderr go to files (read with :meth:`stdout`)."""

    def __init__(
        self,
        argv: Sequence[str],
        proc: subprocess.Popen[bytes],
        stdout_path: Path,
        stderr_path: Path,
    ) -> None:
        self.argv = list(argv)
        self.proc = proc
        self.stdout_path = stdout_path
        self.stderr_path = stderr_path

    @property
    def pid(self) -> int:
        return self.proc.pid

    def stdout(self) -> str:
        return self.stdout_path.read_text(errors="replace")

    def stderr(self) -> str:
        return self.stderr_path.read_text(errors="replace")

    def describe(self) -> str:
        return (
            f"{' '.join(self.argv)} (pid {self.pid}, status {self.proc.returncode})\n"
            f"--- stdout ---\n{self.stdout()}--- stderr ---\n{self.stderr()}"
        )

    def wait_for_line(self, prefix: str, timeout_s: float = READY_TIMEOUT_S) -> str:
        """Wait until a stdout line starts with ``prefix`` and return it.

        Raises ``AssertionError`` (with the child's output) if the child exits first or the line
        does not come within ``timeout_s``.
        """
        deadline = time.monotonic() + timeout_s
        while True:
            for line in self.stdout().splitlines():
                if line.startswith(prefix):
                    return line
            if self.proc.poll() is not None:
                raise AssertionError(f"exited before printing {prefix!r}: {self.describe()}")
            if time.monotonic() > deadline:
                raise AssertionError(f"no {prefix!r} within {timeout_s} s: {self.describe()}")
            time.sleep(0.005)

    def send_signal(self, sig: int) -> None:
        with contextlib.suppress(ProcessLookupError):
            self.proc.send_signal(sig)

    def stop(self, sig: int = signal.SIGTERM, timeout_s: float = SIGTERM_PATIENCE_S) -> float:
        """Send ``sig`` and wait for the exit; return seconds from signal to exit.

        Raises ``subprocess.TimeoutExpired`` if the child is still running after ``timeout_s``.
        """
        start = time.monotonic()
        self.send_signal(sig)
        self.proc.wait(timeout=timeout_s)
        return time.monotonic() - start


class Spawner:
    """The ``spawn`` fixture: starts subprocesses and cleans them up (see module docstring)."""

    def __init__(self, log_dir: Path) -> None:
        self.log_dir = log_dir
        self.children: list[Child] = []

    def command(
        self,
        argv: Sequence[str],
        *,
        ready: str | None = None,
        env: dict[str, str] | None = None,
        timeout_s: float = READY_TIMEOUT_S,
    ) -> Child:
        """Start ``argv`` (cwd = repository); with ``ready``, wait for a stdout line starting so."""
        self.log_dir.mkdir(parents=True, exist_ok=True)
        stem = f"child{len(self.children)}"
        out_path, err_path = self.log_dir / f"{stem}.out", self.log_dir / f"{stem}.err"
        with open(out_path, "wb") as out, open(err_path, "wb") as err:
            proc = subprocess.Popen(
                list(argv),
                cwd=REPO_ROOT,
                env=child_env(env),
                stdin=subprocess.DEVNULL,
                stdout=out,
                stderr=err,
                start_new_session=True,  # own process group: grandchildren can be found
            )
        _SPAWNED_GROUPS.add(proc.pid)
        child = Child(argv, proc, out_path, err_path)
        self.children.append(child)
        if ready is not None:
            child.wait_for_line(ready, timeout_s)
        return child

    def __call__(
        self,
        *formation_args: str,
        ready: str | None = None,
        env: dict[str, str] | None = None,
        timeout_s: float = READY_TIMEOUT_S,
    ) -> Child:
        """Start ``python -m formation <formation_args>``."""
        argv = [sys.executable, "-m", "formation", *formation_args]
        return self.command(argv, ready=ready, env=env, timeout_s=timeout_s)

    def python(
        self,
        code: str,
        *args: str,
        ready: str | None = None,
        env: dict[str, str] | None = None,
        timeout_s: float = READY_TIMEOUT_S,
    ) -> Child:
        """Start ``python -c code args...``."""
        argv = [sys.executable, "-c", code, *args]
        return self.command(argv, ready=ready, env=env, timeout_s=timeout_s)

    def cleanup(self) -> list[str]:
        """Stop every child; return the problems found (empty: all good)."""
        problems: list[str] = []
        running = [c for c in self.children if c.proc.poll() is None]
        for child in running:
            child.send_signal(signal.SIGTERM)
        deadline = time.monotonic() + SIGTERM_PATIENCE_S
        for child in running:
            try:
                child.proc.wait(timeout=max(0.0, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                child.send_signal(signal.SIGKILL)
                child.proc.wait()
                problems.append(f"ignored SIGTERM for > {SIGTERM_PATIENCE_S} s: {child.describe()}")
        groups = {c.pid for c in self.children}
        deadline = time.monotonic() + 0.5  # let grandchildren already exiting finish
        while _live_processes(pgrps=groups) and time.monotonic() < deadline:
            time.sleep(0.02)
        for child in self.children:
            leftovers = _live_processes(pgrps={child.pid})
            if leftovers:
                desc = ", ".join(f"{p}: {_cmdline(p)}" for p in sorted(leftovers))
                _kill_all(leftovers)
                problems.append(f"{' '.join(child.argv)} left processes behind: {desc}")
            _SPAWNED_GROUPS.discard(child.pid)
        return problems


@pytest.fixture
def spawn(tmp_path: Path) -> Iterator[Spawner]:
    """Factory of subprocesses, all stopped at teardown (fails on ones that ignore SIGTERM)."""
    spawner = Spawner(tmp_path / "procs")
    try:
        yield spawner
    finally:
        problems = spawner.cleanup()
    if problems:
        pytest.fail("\n\n".join(problems), pytrace=False)


# ---------------------------------------------------------------------------------------------
# Zenoh router and sessions
# ---------------------------------------------------------------------------------------------


@dataclass
class RouterHandle:
    """A running ``formation router`` subprocess."""

    endpoint: str  # e.g. "tcp/127.0.0.1:40123"
    port: int
    child: Child

    @property
    def proc(self) -> subprocess.Popen[bytes]:
        return self.child.proc


def _start_router(spawn: Spawner, *extra: str, attempts: int = 3) -> RouterHandle:
    """Start a router on a free port, retrying on the rare port race (another process took it)."""
    failure = ""
    for _ in range(attempts):
        port = free_port()
        endpoint = f"tcp/127.0.0.1:{port}"
        child = spawn("router", "--listen", endpoint, *extra)
        try:
            child.wait_for_line(ROUTER_READY)
        except AssertionError as exc:
            failure = str(exc)
            if child.proc.poll() is None:
                raise
            continue  # exited: most likely the port was taken meanwhile
        return RouterHandle(endpoint=endpoint, port=port, child=child)
    raise AssertionError(f"router did not start in {attempts} attempts: {failure}")


def _stop_router(handle: RouterHandle) -> None:
    if handle.proc.poll() is not None:
        return  # a test stopped or killed it on purpose and checked what it wanted
    try:
        handle.child.stop(signal.SIGTERM, SIGTERM_PATIENCE_S)
    except subprocess.TimeoutExpired:
        pytest.fail(f"router ignored SIGTERM: {handle.child.describe()}", pytrace=False)
    assert handle.proc.returncode == 0, handle.child.describe()


@pytest.fixture
def start_router(spawn: Spawner) -> Iterator[Callable[..., RouterHandle]]:
    """Factory: ``start_router(*extra_router_args)`` -> a ready :class:`RouterHandle`."""
    handles: list[RouterHandle] = []

    def start(*extra: str) -> RouterHandle:
        handle = _start_router(spawn, *extra)
        handles.append(handle)
        return handle

    yield start
    for handle in handles:
        _stop_router(handle)


@pytest.fixture
def router(start_router: Callable[..., RouterHandle]) -> RouterHandle:
    """A ready ``formation router`` on a free loopback port (stopped and checked at teardown)."""
    return start_router()


@pytest.fixture
def session(router: RouterHandle) -> Iterator[Callable[..., zenoh.Session]]:
    """Factory of client sessions to ``router``: ``session(**ZenohSettings overrides)``."""
    import runtime as rt

    opened: list[zenoh.Session] = []

    def open_client(**overrides: Any) -> zenoh.Session:
        fields: dict[str, Any] = {"connect": (router.endpoint,), "open_timeout_s": 5.0}
        fields.update(overrides)
        s = rt.open_session(rt.ZenohSettings(**fields))
        opened.append(s)
        return s

    try:
        yield open_client
    finally:
        for s in opened:
            s.close()


# ---------------------------------------------------------------------------------------------
# Hooks
# ---------------------------------------------------------------------------------------------


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    for item in items:
        if _ZENOH_FIXTURES.intersection(getattr(item, "fixturenames", ())):
            item.add_marker(pytest.mark.zenoh)


# ---------------------------------------------------------------------------------------------
# The guard: nothing a test starts outlives it (module docstring; mechanics in procguard.py)
# ---------------------------------------------------------------------------------------------


@pytest.fixture(scope="session", autouse=True)
def no_leftover_processes() -> Iterator[None]:
    """The run's frame: orphans of a SIGKILLed earlier run are stopped first; SIGTERM/SIGHUP
    stop the run's processes; at the end nothing the run started may still be alive."""
    orphans = _orphans_of_dead_runs()
    if orphans:
        print(f"\nconftest: stopping processes left by a killed test run: {_describe(orphans)}")
        _terminate(orphans)
    previous = {
        sig: signal.signal(sig, _stop_run_processes) for sig in (signal.SIGTERM, signal.SIGHUP)
    }
    me = os.getpid()
    before = _live_processes(ppid=me)
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    leftover = _wait_until_gone(
        lambda: (_live_processes(ppid=me, pgrps=set(_SPAWNED_GROUPS)) - before) | _run_processes(),
        SIGTERM_PATIENCE_S,
    )
    if leftover:
        desc = _describe(leftover)
        _terminate(leftover)
        pytest.fail(f"processes left behind at the end of the test run (killed): {desc}")


@pytest.fixture(autouse=True)
def nothing_outlives_the_test(request: pytest.FixtureRequest) -> Iterator[None]:
    """After the test's teardown (this fixture is set up first, so torn down last), a process
    the test started that is still running fails it (and is stopped). "Started by the test":
    carries the run's mark, started at or after this fixture's setup (so after any module or
    session fixture of the test), was not running then, and no process that was running then
    (other than pytest) is its ancestor: a process that a module fixture's launcher respawns
    during the test belongs to the fixture."""
    running = set(os.listdir("/proc"))  # cheap: names only
    since = _now_ticks()
    yield
    me = os.getpid()

    def owned_by_an_older_process(pid: int) -> bool:
        for _ in range(64):
            stat = _proc_stat(pid)
            if stat is None:
                return False
            pid = stat[1]
            if pid in (me, 0, 1):
                return False  # pytest's own child, or an orphan: the test's
            if str(pid) in running:  # an older process of this run (else a reaper: orphan)
                return _has_run_mark(pid)
        return False

    def started_here() -> set[int]:
        return {
            p
            for p in _marked_processes(since=since)
            if str(p) not in running and not owned_by_an_older_process(p)
        }

    left = _wait_until_gone(started_here, OUTLIVE_GRACE_S)
    if left:
        desc = _describe(left)
        _terminate(left)
        pytest.fail(f"{request.node.nodeid} left processes running (stopped): {desc}", False)
