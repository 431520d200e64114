"""A real fleet for fault-injection tests: :class:`FleetRun` (docs/api.md).

``FleetRun`` starts ``formation up`` from a scenario (realtime or lockstep, one agent process
per robot or agent hosts), watches its bus with the same collector ``formation up`` measures a
run with (:class:`formation.record.collector.RunCollector`), injects faults through the
``formation fault`` tool's code (:func:`formation.operate.fault.apply`, so a test does what an
operator does, with the same checks; over the observer's session, in this process) and reads
the run's ``metrics.json`` at the end: :meth:`FleetRun.recovery` is its ``faults`` list, each
fault with its detection, reassignment and recovery times, least separation and peak error.

    async with FleetRun("leader-kill", workdir=tmp, duration_s=30) as fleet:
        await fleet.wait_in_formation()
        await fleet.kill_leader()
        metrics = await fleet.finish()
    assert fleet.recovery()[0]["recovered_s"] < 20

The pytest plugin (:mod:`formation.pytest_plugin`, installed with the package) wraps it as the
``fleet`` fixture. Every child runs in its own process group, killed when the run is closed.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import signal
import socket
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from types import TracebackType
from typing import Any, Final

__all__ = ["FaultCommandError", "FleetRun", "FleetRunError"]

START_TIMEOUT_S: Final = 90.0
"""How long ``start`` waits for every robot's truth on the bus."""
PORT_TRIES: Final = 5
"""Ports tried when the one picked was taken meanwhile (``formation up`` says "port busy")."""

FAULT_TIMEOUT_S: Final = 10.0
"""``formation fault --timeout`` for a robot of the run (its status comes at 5 Hz, late next to a
CPU hog), for the fleet and for the leader."""
UNKNOWN_ROBOT_TIMEOUT_S: Final = 1.0
"""``--timeout`` for a robot the run does not have: the tool's refusal ("no robot ...") is not
waited for 10 s."""
_ROBOT_COMMANDS: Final = frozenset({"kill", "pause", "resume", "drag", "estop", "release"})


class FleetRunError(RuntimeError):
    """The fleet did not start, or ended badly; the message holds the tail of its output."""


class FaultCommandError(FleetRunError):
    """``formation fault`` refused or failed (its exit status and message)."""


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class FleetRun:
    """One ``formation up`` run of ``scenario`` (a built-in name, a TOML file or the TOML text
    itself) and its bus.

    ``lockstep``: sim time paced by the plant (repeatable); ``hosts``: agent hosts (0: one
    process per robot; None: ``formation up`` decides); ``duration_s``/``seed`` override the
    scenario's; ``extra``: more ``formation up`` options (``--standby``, ``--respawn 1``...).
    """

    def __init__(
        self,
        scenario: str,
        *,
        workdir: Path,
        lockstep: bool = False,
        hosts: int | None = None,
        duration_s: float | None = None,
        seed: int | None = None,
        fleet: str = "test",
        extra: Sequence[str] = (),
    ) -> None:
        import scenario as scenario_mod

        self.workdir = Path(workdir)
        if "\n" in scenario:  # the TOML text itself: written into the work folder
            self.workdir.mkdir(parents=True, exist_ok=True)
            path = self.workdir / "scenario.toml"
            path.write_text(scenario)
            scenario = str(path)
        self.scenario = scenario_mod.load(scenario)
        self.scenario_arg = scenario
        self.lockstep = lockstep
        self.hosts = hosts
        self.duration_s = duration_s
        self.seed = seed
        self.fleet = fleet
        self.extra = list(extra)
        self.endpoint = ""
        self.out = self.workdir / "out"
        self.proc: asyncio.subprocess.Process | None = None
        self.session: Any = None
        self.collector: Any = None
        self.metrics: dict[str, Any] | None = None
        self._subs: list[Any] = []

    # -- start and stop ------------------------------------------------------------------------

    def _up_args(self) -> list[str]:
        args = [
            sys.executable, "-m", "formation", "up", "--scenario", self.scenario_arg,
            "--endpoint", self.endpoint, "--fleet", self.fleet, "--out", str(self.out),
            "--no-figures", "--quiet",
        ]  # fmt: skip
        if self.lockstep:
            args.append("--lockstep")
        if self.hosts is not None:
            args += ["--hosts", str(self.hosts)]
        if self.duration_s is not None:
            args += ["--duration", f"{self.duration_s:g}"]
        if self.seed is not None:
            args += ["--seed", str(self.seed)]
        return args + self.extra

    async def start(self, timeout_s: float = START_TIMEOUT_S) -> FleetRun:
        """Start the fleet and wait until every robot's truth is on the bus, or until the run
        ended well (exit 0, ``metrics.json`` written) if it ended before its truth was seen: a
        short lockstep run does not wait for this observer and, on a loaded machine, may be
        over first (:meth:`finish` then returns its metrics; a fault request says it ended)."""
        self.workdir.mkdir(parents=True, exist_ok=True)
        # the observer's imports (Zenoh, numpy) before the run: next to a 4-process CPU hog they
        # took longer than a 20 s lockstep run, which ended before the observer's session opened
        self._make_collector()
        deadline = time.monotonic() + timeout_s
        for _ in range(PORT_TRIES):
            self.endpoint = f"tcp/127.0.0.1:{_free_port()}"
            log = (self.workdir / "up.log").open("wb")
            try:
                self.proc = await asyncio.create_subprocess_exec(
                    *self._up_args(), stdout=log, stderr=asyncio.subprocess.STDOUT,
                    start_new_session=True,
                )  # fmt: skip
            finally:
                log.close()
            await asyncio.sleep(0.3)
            if self.proc.returncode is None or "port busy" not in self.output():
                break
        await self._observe(deadline)
        while True:
            view = self.collector.live()
            if view.t_s is not None and all(r.alive for r in view.robots if r.robot):
                return self
            if self.proc is not None and self.proc.returncode is not None:
                if self.proc.returncode == 0 and (self.out / "metrics.json").exists():
                    return self  # it ran to its end before its truth was seen
                raise FleetRunError(
                    f"formation up ended at start (exit {self.proc.returncode}):\n"
                    f"{self.output()[-2000:]}"
                )
            if time.monotonic() > deadline:
                raise FleetRunError(f"no truth of the fleet within {timeout_s:g} s")
            await asyncio.sleep(0.1)

    def _make_collector(self) -> None:
        import runtime  # noqa: F401  (imported here, before the run: see start)
        from formation.record.collector import RunCollector

        self.collector = RunCollector.for_scenario(
            self.scenario, fleet=self.fleet, lockstep=self.lockstep
        )

    async def _observe(self, deadline: float) -> None:
        """Open the observer's session on the run's router (it comes up with the run) and feed
        the collector; give up when the run has ended (no router any more) or at ``deadline``."""
        import runtime as rt
        from bus_schemas import keys
        from formation.record.collector import key_patterns

        loop = asyncio.get_running_loop()
        settings = rt.ZenohSettings(connect=(self.endpoint,), open_timeout_s=10.0)
        while self.session is None:
            try:
                self.session = await rt.open_session_async(settings, timeout_s=1.0)
            except rt.TransportError:
                if self.proc is not None and self.proc.returncode is not None:
                    return  # the run is over: start() says how it ended
                if time.monotonic() > deadline:
                    raise FleetRunError(
                        f"no router at {self.endpoint}:\n{self.output()[-2000:]}"
                    ) from None
        feed = self.collector.feed
        self._subs = [
            rt.subscribe(self.session, p, loop, lambda rx: feed(rx.key, rx.payload))
            for p in key_patterns(self.fleet, lockstep=self.lockstep)
        ]
        rt.watch_liveliness(
            self.session, keys.alive_pattern(self.fleet), loop, self.collector.feed_alive
        )

    def output(self) -> str:
        """What ``formation up`` printed so far."""
        try:
            return (self.workdir / "up.log").read_text(errors="replace")
        except OSError:
            return ""

    async def finish(self, timeout_s: float | None = None) -> dict[str, Any]:
        """Wait for the run to end (its duration) and return its ``metrics.json``."""
        assert self.proc is not None, "start() first"
        limit = timeout_s if timeout_s is not None else (self.duration_s or 600.0) * 3 + 60.0
        try:
            rc = await asyncio.wait_for(self.proc.wait(), limit)
        except TimeoutError:
            raise FleetRunError(f"the run did not end within {limit:g} s") from None
        return self._read_metrics(rc)

    async def stop(self) -> dict[str, Any]:
        """End the run now (SIGINT, as Ctrl-C) and return its ``metrics.json``."""
        assert self.proc is not None, "start() first"
        if self.proc.returncode is None:
            self.proc.send_signal(signal.SIGINT)
        rc = await asyncio.wait_for(self.proc.wait(), 60.0)
        return self._read_metrics(rc, interrupted_ok=True)

    def _read_metrics(self, rc: int, interrupted_ok: bool = False) -> dict[str, Any]:
        path = self.out / "metrics.json"
        if (rc != 0 and not (interrupted_ok and rc == 130)) or not path.exists():
            raise FleetRunError(f"formation up exited {rc}:\n{self.output()[-2000:]}")
        self.metrics = json.loads(path.read_text())
        return self.metrics

    async def close(self) -> None:
        """Stop observing; kill whatever of the run is still running (its process group)."""
        for sub in self._subs:
            with contextlib.suppress(Exception):
                sub.undeclare()
        self._subs = []
        if self.session is not None:
            with contextlib.suppress(Exception):
                self.session.close()
            self.session = None
        proc = self.proc
        if proc is not None and proc.returncode is None:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(proc.pid, signal.SIGTERM)
            try:
                await asyncio.wait_for(proc.wait(), 20.0)
            except TimeoutError:
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(proc.pid, signal.SIGKILL)
                await proc.wait()

    async def __aenter__(self) -> FleetRun:
        return await self.start()

    async def __aexit__(
        self, et: type[BaseException] | None, ev: BaseException | None, tb: TracebackType | None
    ) -> None:
        await self.close()

    # -- what the fleet looks like -------------------------------------------------------------

    @property
    def leader(self) -> str | None:
        """The robot holding slot 0 now (from the assignment on the bus)."""
        return self.collector.live().leader if self.collector is not None else None

    def in_formation(self, tol_m: float | None = None) -> bool:
        """Every robot holding a slot has its reference point within ``tol_m`` (default: the
        scenario's ``settle_tol_m``) of it, and some robot holds slot 0."""
        tol = self.scenario.settle_tol_m if tol_m is None else tol_m
        view = self.collector.live()
        held = [r for r in view.robots if r.slot is not None and r.alive is not False]
        return (
            bool(held)
            and view.leader is not None
            and all(r.error_m is not None and r.error_m <= tol for r in held)
        )

    async def wait_in_formation(self, timeout_s: float = 60.0, tol_m: float | None = None) -> float:
        """Until :meth:`in_formation`; returns the run's time then (s)."""
        deadline = time.monotonic() + timeout_s
        while not self.in_formation(tol_m):
            if self.proc is not None and self.proc.returncode is not None:
                raise FleetRunError("the run ended before the fleet was in formation")
            if time.monotonic() > deadline:
                view = self.collector.live()
                errs = {r.robot: r.error_m for r in view.robots}
                raise FleetRunError(f"not in formation within {timeout_s:g} s: errors {errs}")
            await asyncio.sleep(0.05)
        return float(self.collector.live().t_s or 0.0)

    # -- faults --------------------------------------------------------------------------------

    async def fault(self, *args: str) -> str:
        """Run ``formation fault ARGS`` against this fleet; its output line (or raise). An
        ``--at T`` the run has already passed is refused (a lockstep run is fast: schedule
        late enough, or in the scenario), and so is any fault once the run has ended."""
        if self.proc is not None and self.proc.returncode is not None:
            raise FleetRunError(
                f"formation fault {' '.join(args)}: the run has ended (exit {self.proc.returncode})"
            )
        if "--at" in args and self.collector is not None:
            at = float(args[args.index("--at") + 1])
            now = self.collector.live().t_s
            if now is not None and now >= at:
                raise FleetRunError(f"--at {at:g}: the run is already at t = {now:.2f} s")
        timeout_s = UNKNOWN_ROBOT_TIMEOUT_S if self._unknown_robot(args) else FAULT_TIMEOUT_S
        tail = ["--endpoint", self.endpoint, "--fleet", self.fleet, "--timeout", f"{timeout_s:g}"]
        if self.session is None:  # nothing watched yet: the tool itself, with its own session
            return await self._fault_process([*args, *tail])
        import runtime as rt
        from formation.operate import fault as fault_tool

        # over this run's own session, in this process: a `formation fault` process costs 1-2 s
        # to start (its CLI is tested on its own); an `--at T` request goes at once (a lockstep
        # run can pass T while a new process starts up)
        try:
            try:
                ns = fault_tool.build_parser().parse_args([*args, *tail])
            except SystemExit:  # argparse printed why (as the CLI does)
                raise ValueError(f"bad arguments {list(args)}") from None
            if "--at" in args:
                return await fault_tool.request_at(self.session, ns, running=True)
            where = fault_tool.Where.of(self.fleet, rt.ZenohSettings(connect=(self.endpoint,)))
            return await fault_tool.apply(self.session, ns, where)
        except (fault_tool.FaultError, rt.TransportError, ValueError) as exc:
            raise FaultCommandError(f"formation fault {' '.join(args)}: {exc}") from exc

    def _unknown_robot(self, args: tuple[str, ...]) -> bool:
        """``args`` name a robot (``kill r9``, ``estop r2``...) that this run's collector does not
        have (the scenario's robots)."""
        if len(args) < 2 or args[0] not in _ROBOT_COMMANDS or args[1].startswith("-"):
            return False
        robots = {r.robot for r in self.collector.live().robots} if self.collector else set()
        return bool(robots) and args[1] not in robots

    async def _fault_process(self, argv: list[str]) -> str:
        proc = await asyncio.create_subprocess_exec(
            sys.executable, "-m", "formation", "fault", *argv,
            stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE,
        )  # fmt: skip
        out, err = await asyncio.wait_for(proc.communicate(), 60.0)
        if proc.returncode != 0:
            raise FaultCommandError(
                f"formation fault {' '.join(argv)}: exit {proc.returncode}: "
                f"{err.decode(errors='replace').strip()}"
            )
        return out.decode(errors="replace").strip()

    @staticmethod
    def _when(at: float | None, for_s: float | None = None) -> list[str]:
        args = [] if at is None else ["--at", f"{at:g}"]
        return args + ([] if for_s is None else ["--for", f"{for_s:g}"])

    async def kill_leader(self, at: float | None = None) -> str:
        """SIGKILL the leader's agent now, or at sim time ``at`` (the same tick every lockstep
        run: the coordinator schedules it)."""
        return await self.fault("kill-leader", *self._when(at))

    async def kill(self, robot: str, at: float | None = None) -> str:
        return await self.fault("kill", robot, *self._when(at))

    async def pause(self, robot: str, at: float | None = None, for_s: float | None = None) -> str:
        """SIGSTOP a robot's agent (a hang); with ``at``/``for_s`` a scheduled pause."""
        return await self.fault("pause", robot, *self._when(at, for_s))

    async def resume(self, robot: str, at: float | None = None) -> str:
        return await self.fault("resume", robot, *self._when(at))

    async def estop(
        self, robot: str | None = None, at: float | None = None, for_s: float | None = None
    ) -> str:
        """Engage the latched e-stop of the fleet (or of ``robot``)."""
        return await self.fault("estop", *([robot] if robot else []), *self._when(at, for_s))

    async def release(self, robot: str | None = None, at: float | None = None) -> str:
        return await self.fault("release", *([robot] if robot else []), *self._when(at))

    async def kill_coordinator(self, at: float | None = None) -> str:
        return await self.fault("kill-coordinator", *self._when(at))

    def recovery(self) -> list[dict[str, Any]]:
        """Each fault the run sent, with its recovery figures (``metrics.json`` ``faults``;
        after :meth:`finish` or :meth:`stop`)."""
        if self.metrics is None:
            raise FleetRunError("the run has not ended: await finish() or stop() first")
        return list(self.metrics.get("faults", []))
