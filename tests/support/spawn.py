"""Subprocesses of a test: :class:`Spawner` (the ``spawn`` fixture of tests/conftest.py) starts
``python -m formation ...`` or any argv in its own process group, with the repository on
``PYTHONPATH``, tied to this pytest, its stdout and stderr in files (no pipe can fill up and
block it), and stops them all at teardown; :func:`child_env` is that environment for a test
that starts a process itself; :func:`free_port` a TCP port on 127.0.0.1 free a moment ago."""

from __future__ import annotations

import contextlib
import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Sequence
from pathlib import Path

from support.procguard import SIGTERM_PATIENCE_S, _cmdline, _kill_all, _live_processes

REPO_ROOT = Path(__file__).resolve().parents[2]
READY_TIMEOUT_S = 15.0  # python start + zenoh import on a loaded 2-core CI box
PARENT_ENV = "FORMATION_PARENT_PID"  # = runtime.lifecycle.PARENT_ENV (tests import no runtime here)
SPAWNED_GROUPS: set[int] = set()
"""Process groups created by a :class:`Spawner`, checked again at the end of the whole run."""


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
        SPAWNED_GROUPS.add(proc.pid)
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
            SPAWNED_GROUPS.discard(child.pid)
        return problems
