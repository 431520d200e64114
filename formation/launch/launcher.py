"""The ``formation up`` launcher: spawn the fleet's processes, collect, display, stop, report.

:func:`run_up` runs one planned run (:mod:`formation.launch.plan`); the theory of operation is
in :mod:`formation.launch.up`. The launcher composes the parts that own each concern:

* :class:`~formation.launch.processes.ProcessTable`: the children (spawn, respawn, who runs);
* :class:`~formation.launch.intake.RunIntake`: the sessions and the collector they feed;
* :class:`~formation.launch.supervisor.Supervisor`: the run phase (deaths, respawns, the end);
* :func:`~formation.launch.shutdown.shut_down`: the stop sequence, bounded;
* :func:`~formation.launch.results.finish_run`: the exit status, metadata and outputs;
* :class:`~formation.launch.stop_request.StopRequest`: SIGINT/SIGTERM;
* :class:`~formation.launch.journal.RunJournal`: failures and events;
* :class:`~formation.launch.registration.RunRegistration`: the run file;
* :class:`~formation.launch.observers.RunObservers`: ``--record`` and ``--foxglove``.
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import time
from typing import Any, Final

from bus_schemas import keys
from formation.launch.children import all_or_first_error
from formation.launch.fault_actions import RealtimeFaults
from formation.launch.intake import RunIntake
from formation.launch.journal import RunJournal
from formation.launch.nodes import make_secure, node_commands, router_args
from formation.launch.observers import RunObservers
from formation.launch.plan import LaunchError, Plan, UpConfig, UpResult, plan_run
from formation.launch.processes import ProcessTable
from formation.launch.registration import RunRegistration
from formation.launch.results import finish_run
from formation.launch.shutdown import shut_down
from formation.launch.stop_request import Interrupted, StopRequest
from formation.launch.supervisor import Supervisor
from formation.outputs.live_table import RunDisplay
from runtime.files import os_error_text, write_atomic
from runtime.transport import LOCKSTEP_ZENOH_RUNTIME, ZENOH_RUNTIME_ENV

__all__ = ["LAUNCHER_NICE", "lower_priority", "run_up"]

LAUNCHER_NICE: Final = 5
"""Realtime: how much the launcher lowers its own scheduling priority (``nice``) once its
children run (:func:`lower_priority`): its collector, display, recorder and live view are off
the control loop, so on a busy machine the plant, the agents, the router and the coordinator
get the CPU first (weight 335 against their 1024 under Linux's fair scheduler; enough for the
collector's ~15 % of a core next to other busy processes)."""


def lower_priority(cfg: UpConfig) -> None:
    """Realtime: nice this thread by :data:`LAUNCHER_NICE` (Linux: per thread; the threads it
    starts later, Zenoh's and the recorder's among them, inherit it), after the children were
    spawned (they start at the launcher's priority, since a child inherits it and only a
    privileged process may raise it back). Not with ``--respawn``: a respawned node must not
    start niced; not in lockstep (no real time to keep, and a starved collector would only slow
    the run's end)."""
    if cfg.lockstep or cfg.respawn_s is not None:
        return
    with contextlib.suppress(OSError, AttributeError):  # AttributeError: no os.setpriority
        now = os.getpriority(os.PRIO_PROCESS, 0)
        os.setpriority(os.PRIO_PROCESS, 0, min(19, now + LAUNCHER_NICE))


class _Launcher:
    """One run: builds the parts (module docstring) and runs start, run, stop, finish."""

    def __init__(self, cfg: UpConfig, plan: Plan) -> None:
        self.cfg = cfg
        self.plan = plan
        self.scn = plan.scenario
        # lockstep: Zenoh on one thread in every child (runtime.transport.LOCKSTEP_ZENOH_RUNTIME)
        env = {ZENOH_RUNTIME_ENV: LOCKSTEP_ZENOH_RUNTIME} if cfg.lockstep else {}
        self.table = ProcessTable(plan.out_dir / "logs", env)
        self.intake = RunIntake(cfg, self.scn)
        self.view = RunDisplay(
            self.intake.collector,
            mode=cfg.display,
            quiet=cfg.quiet,
            lockstep=cfg.lockstep,
            dt_s=self.scn.dt_s,
            duration_s=plan.duration_s,
            truth_rx=self.intake.truth_rx,
        )
        self.journal = RunJournal(self.view.say, self.view.warn)
        self.stop = StopRequest(self.table.kill_all, self.view.warn)
        self.observers = RunObservers(cfg, plan, self.view.say, self.view.warn)
        self.registration = RunRegistration(cfg, plan.out_dir)
        self.secure: Any = None  # formation.launch.pki.RunConfigs with --secure
        self.secure_dir: Any = None
        self.fault_actions: RealtimeFaults | None = None  # realtime scripted faults
        self.stop_s: float | None = None  # how long the shutdown took
        self.supervisor = Supervisor(
            cfg, plan, self.table, self.intake, self.journal, self.stop, self._register
        )

    def _header(self) -> str:
        mode = "lockstep" if self.cfg.lockstep else "realtime"
        return (
            f"formation up: {self.scn.name}, {len(self.scn.robot_ids)} robots, {mode}, "
            f"fleet {self.cfg.fleet} on {self.cfg.endpoint}  (Ctrl-C stops)"
        )

    def _bus_args(self, cn: str) -> list[str]:
        """How a node joins the bus: ``--endpoint EP``, or (``--secure``) its identity's client
        config, never both (the config's endpoint is the TLS one)."""
        if self.secure is None:
            return ["--endpoint", self.cfg.endpoint]
        return ["--zenoh-config", str(self.secure.clients[cn])]

    def _register(self) -> None:
        why = self.registration.register(self.secure, self.table.pids())
        if why is not None:
            self.view.warn(why)

    async def _start(self) -> None:
        say, cfg = self.view.say, self.cfg
        if cfg.secure:
            self.secure, self.secure_dir = make_secure(cfg, self.plan)
        router = await self.table.start_router(router_args(cfg.endpoint, self.secure))
        await self.stop.or_stop(router.wait_ready(cfg.ready_timeout_s))
        say(f"  router       pid {router.pid:<7} ready in {router.ready_s:.2f} s")
        for name, node_args, ready in node_commands(cfg, self.plan, self._bus_args):
            await self.table.start_node(name, node_args, ready)
        self._register()
        lower_priority(cfg)
        # Every child exists: only now may this process start Zenoh (no fork after Zenoh).
        await self.stop.or_stop(self._open_bus())
        nodes = self.table.nodes
        await self.stop.or_stop(
            all_or_first_error(c.wait_ready(cfg.ready_timeout_s) for c in nodes)
        )
        agents = self.table.agents()
        for c in nodes:
            if not c.name.startswith("agent-"):
                say(f"  {c.name:<12} pid {c.pid:<7} ready in {c.ready_s:.2f} s")
        slowest = max((c.ready_s or 0.0) for c in agents)
        what = "agent hosts" if self.plan.hosts > 0 else "agents"
        say(f"  {len(agents)} {what:<9} ready in {slowest:.2f} s (slowest)")

    async def _open_bus(self) -> None:
        await self.intake.open(self.secure)
        self.observers.start(self.intake.session, await self.intake.commands_session(self.secure))
        if not self.cfg.lockstep and self.scn.faults:  # realtime: make the notices real
            acts = RealtimeFaults(lambda: self.table.nodes, self.journal.event, self._send_estop)
            self.fault_actions = acts
            self.intake.subscribe(keys.fault_key(self.cfg.fleet), acts.on_notice)

    async def _send_estop(self, engage: bool, robot: str | None) -> Any:
        from formation.operate.estop_tool import send_estop

        return await send_estop(self.intake.session, self.cfg.fleet, engage, robot)

    def _prepare_out(self) -> bool:
        """Make the log folder and copy the scenario; False (a failure) on a read-only or full
        ``--out``: then nothing is started."""
        try:
            self.table.log_dir.mkdir(parents=True, exist_ok=True)
            if self.plan.scenario_toml is not None:
                write_atomic(self.plan.out_dir / "scenario.toml", self.plan.scenario_toml.encode())
        except OSError as exc:
            self.journal.fail(f"cannot write to {self.plan.out_dir}: {os_error_text(exc)}")
            return False
        return True

    async def _start_and_run(self) -> bool:
        """Start, run, stop; returns whether a stop signal interrupted the run."""
        interrupted = False
        consumer: asyncio.Task[None] | None = None
        display: asyncio.Task[None] | None = None
        try:
            await self._start()
            consumer = asyncio.ensure_future(self.intake.consume())
            display = asyncio.ensure_future(self.view.loop(self._header()))
            await self.supervisor.run()
            if self.cfg.lockstep:
                await self.intake.drain_lockstep(self.plan.duration_s, self.view.warn)
        except Interrupted:
            interrupted = True
            self.view.warn(f"{self.stop.first_name()}: stopping the run")
        except LaunchError as exc:
            self.journal.fail(str(exc))
        except OSError as exc:  # an output of the launcher's own (a full or read-only disk)
            self.journal.fail(f"the run stopped: {os_error_text(exc)}")
        finally:
            if display is not None:
                display.cancel()
            self.view.clear_table()
            if consumer is not None:
                consumer.cancel()
            self.stop_s = await shut_down(
                self.table,
                self.intake,
                self.observers,
                self.registration,
                self.journal,
                self.stop,
                secure_dir=self.secure_dir,
            )
        return interrupted

    async def run(self) -> UpResult:
        loop = asyncio.get_running_loop()
        wall0 = time.monotonic()
        if not self._prepare_out():
            return UpResult(
                exit_code=1, out_dir=self.plan.out_dir, failures=list(self.journal.failures)
            )
        self.stop.install(loop)
        mode = "lockstep" if self.cfg.lockstep else "realtime"
        self.view.say(
            f"formation up: {self.scn.name} ({len(self.scn.robot_ids)} robots, {mode}, "
            f"{self.plan.duration_s:g} s, seed {self.plan.seed}) on {self.cfg.endpoint}, "
            f"fleet {self.cfg.fleet}; logs in {self.table.log_dir}/"
        )
        self.view.say(f"  {self.plan.banner()}")
        try:
            interrupted = await self._start_and_run()
        finally:
            self.stop.remove(loop)
        return finish_run(
            self.cfg,
            self.plan,
            self.intake,
            self.journal,
            self.table.every(),
            interrupted=interrupted,
            wall_s=time.monotonic() - wall0,
            stop_s=self.stop_s,
        )


async def run_up(cfg: UpConfig, plan: Plan | None = None) -> UpResult:
    """Run the whole system once (see the module docstring); call from an event loop on the
    main thread (it installs SIGINT/SIGTERM handlers for its duration)."""
    plan = plan if plan is not None else plan_run(cfg)
    return await _Launcher(cfg, plan).run()
