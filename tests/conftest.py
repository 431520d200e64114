"""Shared pytest fixtures for tests that run real processes and real Zenoh sessions on loopback.

Only fixtures and hooks live here; the helpers a test imports are in ``tests/support/`` (a
package on pytest's ``pythonpath``: ``from support.spawn import Spawner, free_port``), and no
test file imports another test file (tests/repo/test_tests_layout.py).

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
* ``support.spawn.free_port()``: a plain helper, a TCP port on 127.0.0.1 that was free a moment
  ago; ``support.spawn.child_env()`` the environment of a child a test starts itself.
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

Tier 2 (``tests/bus``, ``tests/fleet``) has two parts (docs/testing.md). A test there is marked
``alone`` automatically (``make test`` runs these one at a time, after everything else) unless it
is marked ``shares_cpu``: it asserts no wall-clock bound (a latency, a rate, an exit time, a
realtime formation's quality), so it may run on two workers beside the in-process tiers. An
explicit ``@pytest.mark.alone`` on a test overrides its module's ``shares_cpu``.
"""

from __future__ import annotations

import os
import signal
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

import pytest
from hypothesis import HealthCheck, settings
from support.procguard import (
    SIGTERM_PATIENCE_S,
    _describe,
    _has_run_mark,
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
from support.routers import RouterHandle, launch_router, stop_router
from support.spawn import SPAWNED_GROUPS, Spawner

if TYPE_CHECKING:
    import zenoh

# Hypothesis: no wall-clock limits (a property is not a speed test: next to a CPU hog one example
# or the data generation can take longer than the 200 ms default deadline), loaded before any
# test module builds its own settings on top of the default.
settings.register_profile("formation", deadline=None, suppress_health_check=[HealthCheck.too_slow])
settings.load_profile("formation")
_ZENOH_FIXTURES = frozenset({"router", "start_router", "session"})
TESTS_DIR = Path(__file__).resolve().parent

OUTLIVE_GRACE_S = 5.0
"""How long a process started by a test may take to finish exiting after the test's teardown
(it was signalled and is on its way out, on a loaded machine) before it counts as left behind."""


# ---------------------------------------------------------------------------------------------
# Subprocesses
# ---------------------------------------------------------------------------------------------


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


@pytest.fixture
def start_router(spawn: Spawner) -> Iterator[Callable[..., RouterHandle]]:
    """Factory: ``start_router(*extra_router_args)`` -> a ready :class:`RouterHandle`."""
    handles: list[RouterHandle] = []

    def start(*extra: str) -> RouterHandle:
        handle = launch_router(spawn, *extra)
        handles.append(handle)
        return handle

    yield start
    for handle in handles:
        stop_router(handle)


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


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line(
        "markers",
        "shares_cpu: a tests/bus or tests/fleet test that asserts no wall-clock bound: make test "
        "runs it on two workers beside the in-process tiers (docs/testing.md)",
    )
    config.addinivalue_line(
        "markers",
        "alone: a tests/bus or tests/fleet test that make test runs one at a time (set on every "
        "test there not marked shares_cpu; explicit on a test, it overrides its module's mark)",
    )


def _runs_alone(item: pytest.Item) -> bool:
    """Whether make test runs ``item`` in tier 2's serial part (the module docstring)."""
    if not item.path.is_relative_to(TESTS_DIR):
        return False
    if item.path.relative_to(TESTS_DIR).parts[0] not in ("bus", "fleet"):
        return False
    if any(m.name == "alone" for m in item.own_markers):
        return True  # explicit on the test: overrides its module's shares_cpu
    return item.get_closest_marker("shares_cpu") is None


@pytest.hookimpl(tryfirst=True)  # before -m selects on the marks set here
def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    for item in items:
        if _ZENOH_FIXTURES.intersection(getattr(item, "fixturenames", ())):
            item.add_marker(pytest.mark.zenoh)
        if _runs_alone(item):
            item.add_marker(pytest.mark.alone)


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
        lambda: (_live_processes(ppid=me, pgrps=set(SPAWNED_GROUPS)) - before) | _run_processes(),
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
