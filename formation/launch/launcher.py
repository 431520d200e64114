"""The ``formation up`` launcher: spawn the fleet's processes, collect, display, stop, report.

:func:`run_up` runs one planned run (:mod:`formation.launch.plan`) with the children of
:mod:`formation.launch.children`; the theory of operation is in :mod:`formation.launch.up`."""

from __future__ import annotations

import asyncio
import contextlib
import os
import signal
import time
from collections.abc import Awaitable
from typing import Any, Final

from bus_schemas import keys
from formation.launch.children import (
    Child,
    all_or_first_error,
    child_env,
    group_members,
    tail_of,
)
from formation.launch.fault_actions import RealtimeFaults
from formation.launch.nodes import make_secure, node_commands, router_args
from formation.launch.observers import RunObservers
from formation.launch.plan import LaunchError, Plan, UpConfig, UpResult, plan_run
from formation.launch.results import run_meta, write_results
from formation.outputs.live_table import RunDisplay
from formation.record.collector import RunCollector, key_patterns
from runtime.files import os_error_text, write_atomic
from runtime.lifecycle import OUTPUT_ERROR_EXIT

DRAIN_S: Final = 0.25
LOCKSTEP_DRAIN_MAX_S: Final = 30.0
"""Lockstep: how long (wall s) the launcher waits, after the plant ran its duration, for the
plant's last tick to reach the collector (an overloaded machine can hold samples for seconds)."""
"""Lockstep: time given to the last messages in flight after the plant ended, seconds."""
REALTIME_END_GRACE_S: Final = 1.5
"""Realtime: how long after --duration the launcher stops a plant that did not end the run."""
FIFO_CAPACITY: Final = 1 << 14
"""Samples buffered per collector key expression (the inbox holds this many per pattern, drained
every CONSUME_PERIOD_S): a bound on the launcher's memory (each sample is at most
runtime.transport.MAX_MESSAGE_BYTES); a 300-robot batched fleet puts ~10 samples per key
expression in one period. Overflow drops the oldest and counts (``inbox.dropped``)."""
COLLECTOR_MAX_ENTRIES: Final = 1_500_000
"""Realtime: values the collector keeps before it thins the run's history
(formation.record.collector,
``max_entries``; ~200 MiB at most). 300 robots fill it in ~30 s, 10 robots in ~50 min."""
CONSUME_PERIOD_S: Final = 0.02
LAUNCHER_NICE: Final = 5
"""Realtime: how much the launcher lowers its own scheduling priority (``nice``) once its
children run (:meth:`_Launcher._lower_priority`): its collector, display, recorder and live
view are off the control loop, so on a busy machine the plant, the agents, the router and the
coordinator get the CPU first (weight 335 against their 1024 under Linux's fair scheduler;
enough for the collector's ~15 % of a core next to other busy processes)."""
EXIT_INTERRUPTED: Final = 130


class _Interrupted(Exception):
    """The launcher was asked to stop (SIGINT/SIGTERM)."""


class _Launcher:
    def __init__(self, cfg: UpConfig, plan: Plan) -> None:
        self.cfg = cfg
        self.plan = plan
        self.scn = plan.scenario
        self.out_dir = plan.out_dir
        self.log_dir = plan.out_dir / "logs"
        self.stop = asyncio.Event()
        self.kill_now = False
        self.signals: list[int] = []
        self.failures: list[str] = []
        self.collector = RunCollector.for_scenario(
            self.scn, fleet=cfg.fleet, lockstep=cfg.lockstep, max_entries=COLLECTOR_MAX_ENTRIES
        )
        self.router: Child | None = None
        self.group: int | None = None  # process group of every child (the first router's pid)
        self.secure: Any = None  # formation.launch.pki.RunConfigs with --secure
        self.secure_dir: Any = None
        self.registered_port: int | None = None
        self.nodes: list[Child] = []
        self.retired: list[Child] = []  # dead nodes replaced by a respawn
        self.events: list[dict[str, Any]] = []  # deaths and respawns during the run
        self.session: Any = None
        self._operator_session: Any = None  # --secure --foxglove: the live view's commands
        self.first_truth_rx: float | None = None
        self.last_truth_rx: float | None = None
        self._subscribers: list[Any] = []
        self._inbox: Any = None  # runtime.Inbox("queue") of the collector's samples
        self.view = RunDisplay(
            self.collector,
            mode=cfg.display,
            quiet=cfg.quiet,
            lockstep=cfg.lockstep,
            dt_s=self.scn.dt_s,
            duration_s=plan.duration_s,
            truth_rx=lambda: (self.first_truth_rx, self.last_truth_rx),
        )
        self.say, self.warn = self.view.say, self.view.warn
        self.stop_s: float | None = None
        self.observers = RunObservers(cfg, plan, self.say, self.warn)  # --record, --foxglove
        self.fault_actions: RealtimeFaults | None = None  # realtime scripted faults

    def _header(self) -> str:
        mode = "lockstep" if self.cfg.lockstep else "realtime"
        return (
            f"formation up: {self.scn.name}, {len(self.scn.robot_ids)} robots, {mode}, "
            f"fleet {self.cfg.fleet} on {self.cfg.endpoint}  (Ctrl-C stops)"
        )

    # -- signals --------------------------------------------------------------------------------

    def _on_signal(self, signum: int) -> None:
        self.signals.append(signum)
        if self.stop.is_set():
            if not self.kill_now:
                self.kill_now = True
                self.warn("second signal: killing every process of the run now")
            for child in self._all_children():
                child.signal(signal.SIGKILL)
            return
        self.stop.set()

    async def _or_stop(self, aw: Awaitable[Any]) -> Any:
        """Await ``aw`` unless a stop signal comes first (then raise _Interrupted)."""
        task = asyncio.ensure_future(aw)
        stopper = asyncio.ensure_future(self.stop.wait())
        try:
            await asyncio.wait({task, stopper}, return_when=asyncio.FIRST_COMPLETED)
        finally:
            stopper.cancel()
        if not task.done():
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await task
            raise _Interrupted
        return task.result()

    def _all_children(self) -> list[Child]:
        return [*self.retired, *self.nodes, *([self.router] if self.router is not None else [])]

    # -- start ----------------------------------------------------------------------------------

    def _bus_args(self, cn: str) -> list[str]:
        """How a node joins the bus: ``--endpoint EP``, or (``--secure``) its identity's client
        config, never both (the config's endpoint is the TLS one)."""
        if self.secure is None:
            return ["--endpoint", self.cfg.endpoint]
        return ["--zenoh-config", str(self.secure.clients[cn])]

    def _register(self) -> None:
        """Write the run file (formation.outputs.runfile) tools use to find this run."""
        from formation.outputs import runfile

        port = runfile.endpoint_port(self.cfg.endpoint)
        if port is None:
            return
        configs = {}
        if self.secure is not None:
            configs = {cn: str(self.secure.clients[cn]) for cn in ("operator", "observer")}
        info = runfile.RunInfo(
            endpoint=self.secure.endpoint if self.secure is not None else self.cfg.endpoint,
            port=port,
            fleet=self.cfg.fleet,
            pid=os.getpid(),
            out=str(self.out_dir.resolve()),
            secure=self.secure is not None,
            configs=configs,
            children={c.name: c.pid for c in self._live_children() if c.pid is not None},
        )
        try:
            runfile.register(info)
            self.registered_port = port
        except OSError as exc:
            self.warn(f"could not write the run file: {exc}")

    def _live_children(self) -> list[Child]:
        return [*self.nodes, *([self.router] if self.router is not None else [])]

    async def _start(self) -> None:
        env = child_env()
        if self.cfg.secure:
            self.secure, self.secure_dir = make_secure(self.cfg, self.plan)
        args = router_args(self.cfg.endpoint, self.secure)
        self.router = Child("router", args, "router listening on ", self.log_dir)
        await self.router.spawn(env, process_group=0)
        assert self.router.pid is not None
        self.group = group = self.router.pid
        await self._or_stop(self.router.wait_ready(self.cfg.ready_timeout_s))
        self.say(f"  router       pid {self.router.pid:<7} ready in {self.router.ready_s:.2f} s")
        for name, node_args, ready in node_commands(self.cfg, self.plan, self._bus_args):
            child = Child(name, node_args, ready, self.log_dir)
            self.nodes.append(child)
            await child.spawn(env, process_group=group)
        self._register()
        self._lower_priority()
        # Every child exists: only now may this process start Zenoh (no fork after Zenoh).
        await self._or_stop(self._open_session())
        await self._or_stop(
            all_or_first_error(c.wait_ready(self.cfg.ready_timeout_s) for c in self.nodes)
        )
        agents = [c for c in self.nodes if c.name.startswith("agent-")]
        for c in self.nodes:
            if not c.name.startswith("agent-"):
                self.say(f"  {c.name:<12} pid {c.pid:<7} ready in {c.ready_s:.2f} s")
        slowest = max((c.ready_s or 0.0) for c in agents)
        what = "agent hosts" if self.plan.hosts > 0 else "agents"
        self.say(f"  {len(agents)} {what:<9} ready in {slowest:.2f} s (slowest)")

    def _lower_priority(self) -> None:
        """Realtime: nice this thread by :data:`LAUNCHER_NICE` (Linux: per thread; the threads
        it starts later, Zenoh's and the recorder's among them, inherit it), after the children
        were spawned (they start at the launcher's priority, since a child inherits it and
        only a privileged process may raise it back). Not with ``--respawn``: a respawned node
        must not start niced; not in lockstep (no real time to keep, and a starved collector
        would only slow the run's end)."""
        if self.cfg.lockstep or self.cfg.respawn_s is not None:
            return
        with contextlib.suppress(OSError, AttributeError):  # AttributeError: no os.setpriority
            now = os.getpriority(os.PRIO_PROCESS, 0)
            os.setpriority(os.PRIO_PROCESS, 0, min(19, now + LAUNCHER_NICE))

    async def _open_session(self) -> None:
        import runtime as rt

        loop = asyncio.get_running_loop()
        if self.secure is None:
            settings = rt.ZenohSettings(connect=(self.cfg.endpoint,), open_timeout_s=5.0)
        else:  # the launcher reads the whole fleet: identity observer
            settings = rt.ZenohSettings(
                connect=(),
                mode=None,
                config_file=str(self.secure.clients["observer"]),
                open_timeout_s=5.0,
            )
        self.session = await rt.open_session_async(settings)
        # The one bridge (runtime.bridge) into a queue inbox that the loop drains every
        # CONSUME_PERIOD_S, and only then (wake=False): a sample does not wake the launcher's
        # loop, so on two cores the launcher takes less from the lockstep it is watching and
        # from the control loop of a realtime fleet (each agent host's batch of wheels used to
        # wake it once, in the middle of the host's next batch).
        patterns = key_patterns(self.cfg.fleet)
        self._inbox = rt.Inbox("queue", maxlen=FIFO_CAPACITY * len(patterns), wake=False)
        self._subscribers = [rt.subscribe(self.session, p, loop, self._inbox) for p in patterns]
        rt.watch_liveliness(
            self.session, keys.alive_pattern(self.cfg.fleet), loop, self.collector.feed_alive
        )
        self.observers.start(self.session, await self._commands_session())
        if not self.cfg.lockstep and self.scn.faults:  # realtime: make the notices real
            acts = RealtimeFaults(lambda: self.nodes, self._event, self._send_estop)
            self.fault_actions = acts
            self._subscribers.append(
                rt.subscribe(
                    self.session, keys.fault_key(self.cfg.fleet), loop,
                    lambda rx: acts.on_notice(rx.payload),
                )
            )  # fmt: skip

    async def _send_estop(self, engage: bool, robot: str | None) -> Any:
        from formation.operate.estop_tool import send_estop

        return await send_estop(self.session, self.cfg.fleet, engage, robot)

    async def _commands_session(self) -> Any:
        """The session a ``--foxglove`` client's publishes are put with (issue 28): the
        launcher's own; with ``--secure`` one as the operator identity (the router admits the
        operator's commands from it only). None without ``--foxglove``."""
        import runtime as rt

        if self.cfg.foxglove_port is None:
            return None
        if self.secure is None:
            return self.session
        settings = rt.ZenohSettings(
            connect=(),
            mode=None,
            config_file=str(self.secure.clients["operator"]),
            open_timeout_s=5.0,
        )
        self._operator_session = await rt.open_session_async(settings)
        return self._operator_session

    def _drain_subscribers(self) -> None:
        """Feed every sample the inbox holds to the collector."""
        truth_leaves = (f"/{keys.TRUTH}", f"/{keys.TRUTHS}")  # per robot, or batched
        feed = self.collector.feed
        if self._inbox is not None:
            for rx in self._inbox.drain():
                key = rx.key
                if feed(key, rx.payload) and key.endswith(truth_leaves):
                    # when Zenoh's thread received it, not when this (niced) loop drained it
                    now = rx.rx_s
                    if self.first_truth_rx is None:
                        self.first_truth_rx = now
                    self.last_truth_rx = now

    async def _drain_lockstep(self) -> None:
        """Lockstep, after the plant ran its duration: wait until the collector holds the
        plant's last tick, its truth and the answers to it (``RunCollector.tick_complete``: a
        condition, not a time: the result of a lockstep run must not depend on how loaded the
        machine is), then :data:`DRAIN_S` for the other nodes' last samples (status).
        Bounded by :data:`LOCKSTEP_DRAIN_MAX_S`; a run cut short says how many ticks it lacks."""
        dt = self.collector.dt_s
        final = None if dt is None else round(self.plan.duration_s / dt)
        deadline = time.monotonic() + LOCKSTEP_DRAIN_MAX_S
        while final is not None:
            self._drain_subscribers()
            if self.collector.tick_complete(final):
                break
            if time.monotonic() > deadline:
                last = self.collector.last_truth_tick
                self.warn(
                    f"the plant's last tick {final} (its truth and answers) did not reach the "
                    f"collector within "
                    f"{LOCKSTEP_DRAIN_MAX_S:g} s (last: {last}): the metrics end early"
                )
                break
            await asyncio.sleep(CONSUME_PERIOD_S)
        await asyncio.sleep(DRAIN_S)  # the other nodes' last messages may be in flight

    async def _consume(self) -> None:
        while True:
            self._drain_subscribers()
            await asyncio.sleep(CONSUME_PERIOD_S)

    # -- run ------------------------------------------------------------------------------------

    async def _first_truth(self) -> None:
        while self.first_truth_rx is None:
            await asyncio.sleep(0.02)

    def _survivable(self, child: Child) -> bool:
        """An agent's death is an event of the run (issue 4: the fleet re-forms without it); a
        coordinator's too while another coordinator process is running (``--standby``); the
        router's and (realtime) the plant's with ``--respawn`` (every node survives them: the
        clients reconnect, agents HOLD without poses; docs/faults.md)."""
        if child.name.startswith("agent-"):
            return True
        if child is self.router:
            return self.cfg.respawn_s is not None
        if child.name == "plant":
            return self.cfg.respawn_s is not None and not self.cfg.lockstep
        if child.name.startswith("coordinator"):
            return any(
                c is not child and c.name.startswith("coordinator") and c.returncode is None
                for c in self.nodes
            )
        return False

    def _event(self, text: str) -> None:
        self.events.append({"t": time.monotonic(), "event": text})
        self.say(f"formation up: {text}")

    async def _respawn(self, old: Child) -> Child:
        """Start ``old``'s command again after ``--respawn`` seconds (a coordinator always as a
        standby: the survivor took over and must not be fought)."""
        assert self.cfg.respawn_s is not None and self.group is not None
        await asyncio.sleep(self.cfg.respawn_s)
        args = list(old.argv[3:])
        if old.name.startswith("coordinator") and "--standby" not in args:
            args.append("--standby")
        if old.name == "plant" and "--duration" in args:
            # the restarted plant (from the scenario's start poses) runs what is left of the run
            i = args.index("--duration") + 1
            ran = 0.0 if self.first_truth_rx is None else time.monotonic() - self.first_truth_rx
            args[i] = repr(max(1.0, self.plan.duration_s - ran))
        child = Child(old.name, args, old.ready_prefix, self.log_dir, generation=old.generation + 1)
        # fork+exec of a fresh interpreter: the child never runs this process's Zenoh state
        # (the fork hazard of the field notes is a forked child *using* it); it joins the run's
        # process group (which outlives its first leader, the first router, while any member
        # lives).
        await child.spawn(child_env(), process_group=self.group)
        self.retired.append(old)
        if old is self.router:
            self.router = child
        else:
            self.nodes[self.nodes.index(old)] = child
        await child.wait_ready(self.cfg.ready_timeout_s)
        self._event(f"{child.name} respawned (pid {child.pid}), ready in {child.ready_s:.2f} s")
        self._register()
        return child

    async def _run(self) -> None:
        assert self.nodes[0].proc is not None
        waits: dict[asyncio.Future[Any], Child] = {
            asyncio.ensure_future(c.proc.wait()): c for c in self.nodes if c.proc is not None
        }
        assert self.router is not None and self.router.proc is not None
        waits[asyncio.ensure_future(self.router.proc.wait())] = self.router
        respawns: set[asyncio.Future[Any]] = set()
        timer: asyncio.Future[Any] | None = None
        stopper: asyncio.Future[Any] | None = None
        try:
            if not self.cfg.lockstep:
                # realtime: the duration counts from the first truth frame
                try:
                    await self._or_stop(
                        asyncio.wait_for(self._first_truth(), self.cfg.ready_timeout_s)
                    )
                except TimeoutError:
                    raise LaunchError(
                        f"no truth from the plant within {self.cfg.ready_timeout_s} s of start"
                    ) from None
                # The plant ends a realtime run itself after --duration (from its clock start,
                # which is the first truth frame); the timer is the backstop for a plant that
                # does not, late enough not to race with the plant's own clean exit.
                timer = asyncio.ensure_future(
                    asyncio.sleep(self.plan.duration_s + REALTIME_END_GRACE_S)
                )
            stopper = asyncio.ensure_future(self.stop.wait())
            while True:
                pending = {*waits, *respawns, stopper, *([timer] if timer is not None else [])}
                done, _ = await asyncio.wait(pending, return_when=asyncio.FIRST_COMPLETED)
                if stopper in done:
                    raise _Interrupted
                if timer is not None and timer in done:
                    return
                for fut in done:
                    if fut in respawns:
                        respawns.discard(fut)
                        if fut.exception() is not None:
                            self._event(f"respawn failed: {fut.exception()}")
                            continue
                        new: Child = fut.result()
                        assert new.proc is not None
                        waits[asyncio.ensure_future(new.proc.wait())] = new
                        continue
                    child = waits.pop(fut, None)
                    if child is None:
                        continue
                    rc = child.returncode
                    if child.name == "plant" and rc in (0, OUTPUT_ERROR_EXIT):
                        if rc == OUTPUT_ERROR_EXIT:  # it ran its duration; its file is lost
                            self._fail(
                                f"{self.out_dir / 'plant_stats.json'} not written: the plant "
                                f"could not write it (status {rc}; {child.log_path})"
                            )
                        return  # the plant ran its duration
                    if self._survivable(child):
                        what = "killed by SIGKILL" if rc == -signal.SIGKILL else f"status {rc}"
                        self._event(f"{child.name} (pid {child.pid}) exited ({what})")
                        if self.cfg.respawn_s is not None:
                            respawns.add(asyncio.ensure_future(self._respawn(child)))
                        continue
                    raise LaunchError(
                        f"{child.name} (pid {child.pid}) exited with status {rc} during the "
                        f"run; stderr ({child.log_path}):\n{tail_of(child.log_path)}"
                    )
        finally:
            leftovers: list[asyncio.Future[Any] | None] = [*waits, *respawns, stopper, timer]
            for pending_fut in leftovers:
                if pending_fut is not None:
                    pending_fut.cancel()
            await asyncio.gather(*respawns, return_exceptions=True)

    # -- stop -----------------------------------------------------------------------------------

    async def _stop_children(self, children: list[Child]) -> None:
        if self.kill_now:
            for c in children:
                c.signal(signal.SIGKILL)
        problems = await asyncio.gather(*(c.stop() for c in children))
        for c in children:
            if c.resumed_to_stop:  # an injected pause still on: an event, not a failure
                self._event(f"{c.name} (pid {c.pid}) was paused at the end: resumed to stop it")
        for p in problems:
            if p is not None:
                self.failures.append(p)
                self.warn(p)

    def _fail(self, text: str) -> None:
        self.failures.append(text)
        self.warn(text)

    async def _step(self, what: str, aw: Awaitable[Any]) -> None:
        """One step of the shutdown: whatever it raises is a failure of the run, and the
        shutdown goes on (the router must stop, the session close: a step that raised used to
        leave both and the launcher hung at exit with its router holding the port)."""
        try:
            await aw
        except Exception as exc:
            self._fail(f"shutdown: {what} failed: {exc!r}")

    async def _shutdown(self) -> None:
        t0 = time.monotonic()
        await self._step("stopping the nodes", self._stop_children(self.nodes))
        if self.session is not None:
            await asyncio.sleep(0)  # the inbox takes what the bridge handed over
            try:
                self._drain_subscribers()  # what arrived before the nodes stopped
            except Exception as exc:
                self._fail(f"shutdown: the collector failed: {exc!r}")
            self._subscribers = []
            if self._inbox is not None and self._inbox.dropped:
                self.warn(f"the collector's inbox overflowed: {self._inbox.dropped} samples lost")
            await self._step("closing the recorder and the live view", self.observers.stop())
            self.failures.extend(self.observers.failures)  # warned already
            with contextlib.suppress(Exception):
                if self._operator_session is not None:
                    self._operator_session.close()
            with contextlib.suppress(Exception):
                self.session.close()
        if self.router is not None:
            await self._step("stopping the router", self._stop_children([self.router]))
        if self.group is not None:
            group = self.group
            leftovers = group_members(group)
            if leftovers:
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(group, signal.SIGKILL)
                msg = f"processes left in the run's group killed: {leftovers}"
                self.failures.append(msg)
                self.warn(msg)
        for c in self._all_children():
            await self._step(f"closing {c.name}'s output", c.close())
            if c.out_error is not None:
                self._fail(f"{c.out_path} incomplete: {c.out_error}")
        if self.registered_port is not None:
            from formation.outputs import runfile

            runfile.unregister(self.registered_port, os.getpid())
        if self.secure_dir is not None:  # the run's keys die with it
            import shutil

            shutil.rmtree(self.secure_dir, ignore_errors=True)
        self.stop_s = time.monotonic() - t0
        from runtime.lifecycle import request_fast_exit

        request_fast_exit()  # every child and session is closed: no interpreter teardown needed

    # -- main -----------------------------------------------------------------------------------

    async def run(self) -> UpResult:
        loop = asyncio.get_running_loop()
        wall0 = time.monotonic()
        try:  # a read-only or full --out: one line, status 1, nothing started
            self.log_dir.mkdir(parents=True, exist_ok=True)
            if self.plan.scenario_toml is not None:
                write_atomic(self.out_dir / "scenario.toml", self.plan.scenario_toml.encode())
        except OSError as exc:
            self._fail(f"cannot write to {self.out_dir}: {os_error_text(exc)}")
            return UpResult(exit_code=1, out_dir=self.out_dir, failures=list(self.failures))
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(sig, self._on_signal, sig)
        mode = "lockstep" if self.cfg.lockstep else "realtime"
        self.say(
            f"formation up: {self.scn.name} ({len(self.scn.robot_ids)} robots, {mode}, "
            f"{self.plan.duration_s:g} s, seed {self.plan.seed}) on {self.cfg.endpoint}, "
            f"fleet {self.cfg.fleet}; logs in {self.log_dir}/"
        )
        self.say(f"  {self.plan.banner()}")
        interrupted = False
        consumer: asyncio.Task[None] | None = None
        display: asyncio.Task[None] | None = None
        try:
            try:
                await self._start()
                consumer = asyncio.ensure_future(self._consume())
                display = asyncio.ensure_future(self.view.loop(self._header()))
                await self._run()
                if self.cfg.lockstep:
                    await self._drain_lockstep()
            except _Interrupted:
                interrupted = True
                name = signal.Signals(self.signals[0]).name if self.signals else "signal"
                self.warn(f"{name}: stopping the run")
            except LaunchError as exc:
                self._fail(str(exc))
            except OSError as exc:  # an output of the launcher's own (a full or read-only disk)
                self._fail(f"the run stopped: {os_error_text(exc)}")
            finally:
                if display is not None:
                    display.cancel()
                self.view.clear_table()
                if consumer is not None:
                    consumer.cancel()
                await self._shutdown()
        finally:
            for sig in (signal.SIGINT, signal.SIGTERM):
                loop.remove_signal_handler(sig)
        return self._results(interrupted, time.monotonic() - wall0)

    def _results(self, interrupted: bool, wall_s: float) -> UpResult:
        run_wall = (
            self.last_truth_rx - self.first_truth_rx
            if self.first_truth_rx is not None and self.last_truth_rx is not None
            else None
        )
        code = 1 if self.failures else (EXIT_INTERRUPTED if interrupted else 0)
        result = UpResult(
            exit_code=code,
            out_dir=self.out_dir,
            failures=list(self.failures),
            interrupted=interrupted,
            wall_s=wall_s,
            run_wall_s=run_wall,
        )
        first = self.collector.first_tick
        if self.cfg.lockstep and first not in (None, 0):
            self.warn(f"the collector joined late: ticks 0..{first - 1} are missing from the log")
        meta = run_meta(
            self.cfg,
            self.plan,
            wall_s=wall_s,
            run_wall_s=run_wall,
            stop_s=self.stop_s,
            interrupted=interrupted,
            failures=self.failures,
            events=self.events,
            children=self._all_children(),
        )
        return write_results(
            self.collector.build(meta), self.cfg, self.plan, result, run_wall, self.warn
        )


async def run_up(cfg: UpConfig, plan: Plan | None = None) -> UpResult:
    """Run the whole system once (see the module docstring); call from an event loop on the
    main thread (it installs SIGINT/SIGTERM handlers for its duration)."""
    plan = plan if plan is not None else plan_run(cfg)
    return await _Launcher(cfg, plan).run()
