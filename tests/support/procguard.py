"""Process bookkeeping of the test suite (tests/conftest.py's guard): /proc helpers and the
run's mark.

Importing this module (conftest does, once per pytest process) puts
``FORMATION_TEST_RUN=<pid>.<nonce>`` (a comma-separated chain under a nested pytest) and
``FORMATION_TEST_ROOT=<checkout>`` into ``os.environ``: every process the run starts, at any
depth, inherits them, so the guard finds them in ``/proc/<pid>/environ`` even once orphaned.
psutil is not a dependency: everything is read from /proc (Linux).
"""

from __future__ import annotations

import atexit
import contextlib
import os
import secrets
import signal
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

REPO_ROOT = Path(__file__).resolve().parents[2]
SIGTERM_PATIENCE_S = 2.0
RUN_MARK_ENV = "FORMATION_TEST_RUN"
"""In the environment of every process this pytest run starts (at any depth): ``<pid>.<nonce>``."""


# ---------------------------------------------------------------------------------------------
# /proc helpers (psutil is not a dependency)
# ---------------------------------------------------------------------------------------------


def _proc_stat(pid: int) -> tuple[str, int, int] | None:
    """(state, ppid, pgrp) of ``pid`` from /proc, or None if it is gone."""
    try:
        with open(f"/proc/{pid}/stat", encoding="ascii", errors="replace") as f:
            raw = f.read()
    except OSError:
        return None
    fields = raw[raw.rfind(")") + 2 :].split()  # the command name may contain spaces and ')'
    return fields[0], int(fields[1]), int(fields[2])


def _cmdline(pid: int) -> str:
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as f:
            return f.read().replace(b"\0", b" ").decode(errors="replace").strip()
    except OSError:
        return "?"


def _live_processes(
    *, ppid: int | None = None, pgrps: set[int] | frozenset[int] = frozenset()
) -> set[int]:
    """Non-zombie processes whose parent is ``ppid`` or whose process group is in ``pgrps``."""
    found: set[int] = set()
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        stat = _proc_stat(int(entry))
        if stat is None or stat[0] in ("Z", "X"):
            continue
        if (ppid is not None and stat[1] == ppid) or stat[2] in pgrps:
            found.add(int(entry))
    return found


def _kill_all(pids: set[int]) -> None:
    for pid in pids:
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signal.SIGKILL)


# ---------------------------------------------------------------------------------------------
# The run's mark
# ---------------------------------------------------------------------------------------------

_RUN_MARK = f"{os.getpid()}.{secrets.token_hex(6)}"
# inherited by every process this run starts; a chain, so a pytest run by a test (whose own
# processes carry its mark after this one's) keeps them visible to this run's guard
os.environ[RUN_MARK_ENV] = ",".join(m for m in (os.environ.get(RUN_MARK_ENV, ""), _RUN_MARK) if m)
os.environ["FORMATION_TEST_ROOT"] = str(REPO_ROOT)  # which checkout a leftover belongs to


def _start_ticks(pid: int | str) -> int | None:
    """The start time of ``pid`` (clock ticks since boot), or None if it is gone or a zombie."""
    try:
        with open(f"/proc/{pid}/stat", encoding="ascii", errors="replace") as f:
            raw = f.read()
    except OSError:
        return None
    fields = raw[raw.rfind(")") + 2 :].split()
    return None if fields[0] in ("Z", "X") else int(fields[19])


def _environ(pid: int | str) -> dict[bytes, bytes]:
    try:
        with open(f"/proc/{pid}/environ", "rb") as f:
            raw = f.read()
    except OSError:
        return {}
    out = {}
    for item in raw.split(b"\0"):
        key, sep, value = item.partition(b"=")
        if sep:
            out[key] = value
    return out


_MY_START = _start_ticks(os.getpid()) or 0


def _marked_processes(
    match: Callable[[dict[bytes, bytes]], bool] | None = None, since: int = _MY_START
) -> set[int]:
    """Live processes started since ``since`` whose environment carries a run mark accepted by
    ``match`` (default: this run's), pytest itself excluded."""
    me = os.getpid()
    mark = _RUN_MARK.encode()
    found: set[int] = set()
    for entry in os.listdir("/proc"):
        if not entry.isdigit() or int(entry) == me:
            continue
        ticks = _start_ticks(entry)
        if ticks is None or ticks < since:
            continue
        env = _environ(entry)
        if RUN_MARK_ENV.encode() not in env:
            continue
        marks = env[RUN_MARK_ENV.encode()].split(b",")
        if (match(env) if match is not None else mark in marks) and (
            _start_ticks(entry) is not None  # not a zombie by now
        ):
            found.add(int(entry))
    return found


def _has_run_mark(pid: int) -> bool:
    """Whether ``pid`` carries this run's mark (it, or an ancestor, was started by this run)."""
    return _RUN_MARK.encode() in _environ(pid).get(RUN_MARK_ENV.encode(), b"")


def _run_processes() -> set[int]:
    """Every live process this pytest run started, at any depth."""
    return _marked_processes()


def _describe(pids: set[int]) -> str:
    return "; ".join(f"{p}: {_cmdline(p)}" for p in sorted(pids))


def _wait_until_gone(find: Callable[[], set[int]], timeout_s: float) -> set[int]:
    deadline = time.monotonic() + timeout_s
    while True:
        left = find()
        if not left or time.monotonic() > deadline:
            return left
        time.sleep(0.05)


def _terminate(pids: set[int], patience_s: float = SIGTERM_PATIENCE_S) -> None:
    """SIGTERM ``pids`` (a launcher stops its own children and cleans up), SIGKILL what is left
    after ``patience_s``."""
    for pid in pids:
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.kill(pid, signal.SIGTERM)
    left = _wait_until_gone(lambda: {p for p in pids if _start_ticks(p) is not None}, patience_s)
    _kill_all(left)


def _stop_run_processes(signum: int, _frame: Any) -> None:
    """SIGTERM/SIGHUP to pytest: stop everything the run started, then die of the signal."""
    _terminate(_run_processes())
    signal.signal(signum, signal.SIG_DFL)
    os.kill(os.getpid(), signum)


def _sweep_at_exit() -> None:
    if os.getpid() != int(_RUN_MARK.split(".")[0]):
        return  # a forked child of pytest exiting: not the run's end
    left = _run_processes()
    if left:
        print(f"\nconftest: stopping processes of the test run at exit: {_describe(left)}")
        _terminate(left)


atexit.register(_sweep_at_exit)


def _orphans_of_dead_runs() -> set[int]:
    """Processes left by an earlier run of this checkout's tests whose pytest is gone."""
    root = str(REPO_ROOT).encode()

    def dead_run(env: dict[bytes, bytes]) -> bool:
        if env.get(b"FORMATION_TEST_ROOT") != root:
            return False
        owner = env[RUN_MARK_ENV.encode()].split(b",")[-1].split(b".")[0]  # the innermost run
        if not owner.isdigit() or int(owner) == os.getpid():
            return False
        if "pytest" in _cmdline(int(owner)):
            return False  # that run is going on
        # an xdist worker's command line does not name pytest; its parent (the controller) does
        stat = _proc_stat(int(owner))
        return stat is None or "pytest" not in _cmdline(stat[1])  # gone, or something else now

    return _marked_processes(dead_run, since=0)


def _now_ticks() -> int:
    """Now on the clock of /proc's process start times (clock ticks since boot)."""
    return int(time.clock_gettime(time.CLOCK_BOOTTIME) * os.sysconf("SC_CLK_TCK"))
