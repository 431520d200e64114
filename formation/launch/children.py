"""The child processes of a ``formation up`` run: spawn (fork+exec), wait for the ready line,
watch, stop (SIGTERM, then SIGKILL after a bounded wait), each with its log files.

The children share one process group of their own, so a terminal's Ctrl-C reaches only the
launcher, which is then the only one signalling them."""

from __future__ import annotations

import asyncio
import contextlib
import os
import signal
import sys
import time
from collections import deque
from collections.abc import Awaitable, Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any, Final, TextIO

from formation.launch.plan import LaunchError

REPO_ROOT: Final = Path(__file__).resolve().parents[1]
STOP_PATIENCE_S: Final = 2.0
"""How long a child gets between SIGTERM and SIGKILL, seconds."""
ABORT_PATIENCE_S: Final = 0.5
"""After the stop bound: how long a child's faulthandler gets to write its stacks on SIGABRT."""


# ---------------------------------------------------------------------------------------------


def child_env(extra: Mapping[str, str] | None = None) -> dict[str, str]:
    """The environment of a child: this process's, the repository on the path, ``extra`` for
    what the user did not set (``ZENOH_RUNTIME`` in lockstep: ProcessTable)."""
    env = dict(os.environ)
    for key, value in (extra or {}).items():
        env.setdefault(key, value)
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(REPO_ROOT), env.get("PYTHONPATH")) if p)
    env["PYTHONUNBUFFERED"] = "1"
    # a child stuck past its stop bound gets SIGABRT before SIGKILL: faulthandler writes every
    # thread's Python stack to its log (no GIL needed), so the hang can be diagnosed
    env["PYTHONFAULTHANDLER"] = "1"
    # runtime.lifecycle.bind_to_parent (formation/__main__.py): the child dies with this process
    env["FORMATION_PARENT_PID"] = str(os.getpid())
    return env


def tail_of(path: Path, lines: int = 12) -> str:
    try:
        text = path.read_text(errors="replace")
    except OSError:
        return "(no stderr log)"
    tail = text.rstrip("\n").splitlines()[-lines:]
    return "\n".join("    " + line for line in tail) if tail else "    (stderr empty)"


class Child:
    """One node process: spawn, ready line, stdout drain, stop."""

    def __init__(
        self, name: str, args: Sequence[str], ready: str, log_dir: Path, generation: int = 0
    ) -> None:
        self.name = name
        self.generation = generation  # respawns of this node (--respawn)
        self.argv = [sys.executable, "-m", "formation", *args]
        self.ready_prefix = ready
        suffix = f".{generation}" if generation else ""
        self.log_path = log_dir / f"{name}{suffix}.log"
        self.out_path = log_dir / f"{name}{suffix}.out"
        self.proc: asyncio.subprocess.Process | None = None
        self.ready_s: float | None = None
        self.started_s = 0.0
        self.stop_sent = False
        self.killed = False
        self.stop_s: float | None = None  # from this launcher's SIGTERM to the exit it saw
        self._out: TextIO | None = None
        self.out_error: str | None = None
        """Why ``<name>.out`` stopped being written (a full or read-only disk), or None."""
        self.resumed_to_stop = False
        """It was stopped (SIGSTOP, ``formation fault pause``) when the run ended: resumed."""
        self._drain: asyncio.Task[None] | None = None
        self.stdout_tail: deque[str] = deque(maxlen=20)

    @property
    def pid(self) -> int | None:
        return None if self.proc is None else self.proc.pid

    @property
    def returncode(self) -> int | None:
        return None if self.proc is None else self.proc.returncode

    async def spawn(self, env: Mapping[str, str], process_group: int) -> None:
        with open(self.log_path, "wb") as err:
            self.proc = await asyncio.create_subprocess_exec(
                *self.argv,
                stdin=asyncio.subprocess.DEVNULL,
                stdout=asyncio.subprocess.PIPE,
                stderr=err,
                env=dict(env),
                cwd=os.getcwd(),
                process_group=process_group,
            )
        self.started_s = time.monotonic()
        self._out = open(self.out_path, "w", encoding="utf-8")  # noqa: SIM115 (closed in close())

    def _record(self, line: str) -> None:
        self.stdout_tail.append(line)
        if self._out is not None:
            try:
                self._out.write(line + "\n")
                self._out.flush()
            except OSError as exc:  # a full disk: the tail stays in memory, the run goes on
                self.out_error = f"{type(exc).__name__}: {exc.strerror or exc}"
                with contextlib.suppress(OSError):
                    self._out.close()
                self._out = None

    def _failure(self, what: str) -> LaunchError:
        return LaunchError(
            f"{self.name} (pid {self.pid}, `{' '.join(self.argv[2:])}`) {what}; "
            f"stderr ({self.log_path}):\n{tail_of(self.log_path)}"
        )

    async def wait_ready(self, timeout_s: float) -> None:
        """Read stdout until the ready line; raise LaunchError on exit or timeout."""
        assert self.proc is not None and self.proc.stdout is not None
        stdout = self.proc.stdout
        deadline = self.started_s + timeout_s
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                raise self._failure(f"printed no {self.ready_prefix!r} line within {timeout_s} s")
            try:
                raw = await asyncio.wait_for(stdout.readline(), timeout=left)
            except TimeoutError:
                continue
            if not raw:
                rc = await self.proc.wait()
                raise self._failure(f"exited with status {rc} before it was ready")
            line = raw.decode(errors="replace").rstrip("\r\n")
            self._record(line)
            if line.startswith(self.ready_prefix):
                self.ready_s = time.monotonic() - self.started_s
                self._drain = asyncio.ensure_future(self._drain_stdout())
                return

    async def _drain_stdout(self) -> None:
        assert self.proc is not None and self.proc.stdout is not None
        while raw := await self.proc.stdout.readline():
            self._record(raw.decode(errors="replace").rstrip("\r\n"))

    def signal(self, sig: int) -> None:
        if self.proc is not None and self.proc.returncode is None:
            with contextlib.suppress(ProcessLookupError):
                self.proc.send_signal(sig)

    async def stop(self, patience_s: float = STOP_PATIENCE_S) -> str | None:
        """SIGTERM, wait ``patience_s``, SIGKILL. Returns a problem description, or None."""
        if self.proc is None:
            return None
        if self.proc.returncode is None:
            self.stop_sent = True
            sent = time.monotonic()
            self.signal(signal.SIGTERM)
            if process_state(self.proc.pid).startswith(("state T", "state t")):
                # paused (`formation fault pause`, a job-control stop): not hung; the SIGTERM
                # waits for it to run again (docs/runtime.md, "A paused node at the end")
                self.resumed_to_stop = True
                self.signal(signal.SIGCONT)
            try:
                await asyncio.wait_for(self.proc.wait(), timeout=patience_s)
            except TimeoutError:
                state = process_state(self.proc.pid)
                if state.startswith(("state Z", "state X", "gone")):
                    # it has exited (a zombie: the kernel is still tearing down its threads
                    # and memory, or this loop has not reaped it yet): in time, not a hang
                    await self.proc.wait()
                else:
                    return await self._abort(patience_s, state)
            self.stop_s = time.monotonic() - sent
        rc = self.proc.returncode
        if self.stop_sent and rc not in (0, -signal.SIGTERM):
            return f"{self.name} exited with status {rc} after SIGTERM (expected 0)"
        return None

    async def _abort(self, patience_s: float, state: str) -> str:
        """A child still running ``patience_s`` after SIGTERM: SIGABRT, then SIGKILL."""
        assert self.proc is not None
        self.killed = True
        self.signal(signal.SIGABRT)  # faulthandler: the stacks to the log, then abort
        try:
            await asyncio.wait_for(self.proc.wait(), timeout=ABORT_PATIENCE_S)
        except TimeoutError:
            self.signal(signal.SIGKILL)
            await self.proc.wait()
        return (
            f"{self.name} (pid {self.pid}) did not exit {patience_s} s after SIGTERM: "
            f"killed ({state}; its threads' stacks are in {self.log_path})"
        )

    async def close(self) -> None:
        if self._drain is not None:
            with contextlib.suppress(asyncio.TimeoutError, asyncio.CancelledError):
                await asyncio.wait_for(self._drain, timeout=0.5)
        if self._out is not None:
            try:
                self._out.close()
            except OSError as exc:
                self.out_error = self.out_error or f"{type(exc).__name__}: {exc.strerror or exc}"
            self._out = None


def process_state(pid: int) -> str:
    """What a process is doing, from /proc: its state and its threads' kernel wait channels
    (e.g. ``state S, 9 threads: futex_wait_queue x8, do_epoll_wait x1``), for a stuck child."""
    try:
        raw = Path(f"/proc/{pid}/stat").read_text(errors="replace")
        state = raw[raw.rfind(")") + 2 :].split()[0]
        waits: dict[str, int] = {}
        tids = os.listdir(f"/proc/{pid}/task")
        for tid in tids:
            try:
                wchan = Path(f"/proc/{pid}/task/{tid}/wchan").read_text().strip() or "running"
            except OSError:
                continue
            waits[wchan] = waits.get(wchan, 0) + 1
    except OSError:
        return "gone"
    detail = ", ".join(f"{w} x{n}" for w, n in sorted(waits.items(), key=lambda kv: -kv[1]))
    return f"state {state}, {len(tids)} threads: {detail}"


async def all_or_first_error(aws: Iterable[Awaitable[Any]]) -> None:
    """Await all of ``aws``; on the first exception cancel the rest and raise it."""
    tasks = [asyncio.ensure_future(a) for a in aws]
    try:
        done, _ = await asyncio.wait(tasks, return_when=asyncio.FIRST_EXCEPTION)
        for t in done:
            if t.exception() is not None:
                raise t.exception()  # type: ignore[misc]
    finally:
        for t in tasks:
            if not t.done():
                t.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)


def group_members(pgid: int) -> list[int]:
    """Live (non-zombie) processes of process group ``pgid``, from /proc."""
    found = []
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/stat", encoding="ascii", errors="replace") as f:
                raw = f.read()
        except OSError:
            continue
        fields = raw[raw.rfind(")") + 2 :].split()
        if fields[0] not in ("Z", "X") and int(fields[2]) == pgid:
            found.append(int(entry))
    return found


# ---------------------------------------------------------------------------------------------
# Display
