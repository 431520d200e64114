"""The run phase of ``formation up``: watch every child until the run ends, decide what a death
means, and respawn (``--respawn S``).

The run ends when the plant exits after its duration (lockstep and realtime), or in realtime at
the backstop :data:`REALTIME_END_GRACE_S` after the duration (counted from the first truth
frame) for a plant that does not end it. An agent's death is an *event* (the fleet re-forms
without it); so is a coordinator's while another coordinator runs (``--standby``), and with
``--respawn`` the router's and, in realtime, the plant's. Any other death ends the run as a
failure (:class:`~formation.launch.plan.LaunchError`). A stop signal ends it as
:class:`~formation.launch.stop_request.Interrupted`.

:class:`Supervisor` owns nothing but the futures of one watch; the children are the
:class:`~formation.launch.processes.ProcessTable`'s."""

from __future__ import annotations

import asyncio
import signal
from collections.abc import Callable
from typing import Any, Final

from formation.launch.children import Child, tail_of
from formation.launch.intake import RunIntake
from formation.launch.journal import RunJournal
from formation.launch.plan import PLANT_STATS, LaunchError, Plan, UpConfig
from formation.launch.processes import ProcessTable
from formation.launch.stop_request import Interrupted, StopRequest
from runtime.lifecycle import OUTPUT_ERROR_EXIT

__all__ = ["REALTIME_END_GRACE_S", "Supervisor", "respawn_args"]

REALTIME_END_GRACE_S: Final = 1.5
"""Realtime: how long after --duration the launcher stops a plant that did not end the run."""


def respawn_args(old: Child, duration_s: float, ran_s: float) -> list[str]:
    """The ``formation`` arguments of ``old``'s respawn: a coordinator always as a standby (the
    survivor took over and must not be fought); a plant (restarted from the scenario's start
    poses) for what is left of the run's ``duration_s`` after ``ran_s`` (at least 1 s)."""
    args = list(old.argv[3:])
    if old.name.startswith("coordinator") and "--standby" not in args:
        args.append("--standby")
    if old.name == "plant" and "--duration" in args:
        i = args.index("--duration") + 1
        args[i] = repr(max(1.0, duration_s - ran_s))
    return args


class Supervisor:
    """Watches the children of ``table`` until the run ends (module docstring); deaths and
    respawns go to ``journal``; ``on_respawn`` is called after each respawn is ready."""

    def __init__(
        self,
        cfg: UpConfig,
        plan: Plan,
        table: ProcessTable,
        intake: RunIntake,
        journal: RunJournal,
        stop: StopRequest,
        on_respawn: Callable[[], None],
    ) -> None:
        self.cfg = cfg
        self.plan = plan
        self.table = table
        self.intake = intake
        self.journal = journal
        self.stop = stop
        self.on_respawn = on_respawn

    def survivable(self, child: Child) -> bool:
        """An agent's death is an event of the run (issue 4: the fleet re-forms without it); a
        coordinator's too while another coordinator process is running (``--standby``); the
        router's and (realtime) the plant's with ``--respawn`` (every node survives them: the
        clients reconnect, agents HOLD without poses; docs/faults.md)."""
        if child.name.startswith("agent-"):
            return True
        if child is self.table.router:
            return self.cfg.respawn_s is not None
        if child.name == "plant":
            return self.cfg.respawn_s is not None and not self.cfg.lockstep
        if child.name.startswith("coordinator"):
            return self.table.another_running(child, "coordinator")
        return False

    async def respawn(self, old: Child) -> Child:
        """Start ``old``'s command again after ``--respawn`` seconds (:func:`respawn_args`)."""
        assert self.cfg.respawn_s is not None
        await asyncio.sleep(self.cfg.respawn_s)
        args = respawn_args(old, self.plan.duration_s, self.intake.ran_s())
        child = await self.table.replace(old, args)
        await child.wait_ready(self.cfg.ready_timeout_s)
        self.journal.event(
            f"{child.name} respawned (pid {child.pid}), ready in {child.ready_s:.2f} s"
        )
        self.on_respawn()
        return child

    async def _realtime_timer(self) -> asyncio.Future[Any]:
        """Realtime: wait for the first truth frame (the duration counts from it), then the
        backstop timer. The plant ends a realtime run itself after --duration (from its clock
        start, which is the first truth frame); the timer is for a plant that does not, late
        enough not to race with the plant's own clean exit."""
        try:
            await self.stop.or_stop(
                asyncio.wait_for(self.intake.first_truth(), self.cfg.ready_timeout_s)
            )
        except TimeoutError:
            raise LaunchError(
                f"no truth from the plant within {self.cfg.ready_timeout_s} s of start"
            ) from None
        return asyncio.ensure_future(asyncio.sleep(self.plan.duration_s + REALTIME_END_GRACE_S))

    def _exited(self, child: Child) -> bool:
        """``child`` exited: True if that ends the run (the plant ran its duration), False if
        the run goes on (an event), or raise :class:`LaunchError` (a failure)."""
        rc = child.returncode
        if child.name == "plant" and rc in (0, OUTPUT_ERROR_EXIT):
            if rc == OUTPUT_ERROR_EXIT:  # it ran its duration; its file is lost
                self.journal.fail(
                    f"{self.plan.out_dir / PLANT_STATS} not written: the plant "
                    f"could not write it (status {rc}; {child.log_path})"
                )
            return True
        if self.survivable(child):
            what = "killed by SIGKILL" if rc == -signal.SIGKILL else f"status {rc}"
            self.journal.event(f"{child.name} (pid {child.pid}) exited ({what})")
            return False
        raise LaunchError(
            f"{child.name} (pid {child.pid}) exited with status {rc} during the "
            f"run; stderr ({child.log_path}):\n{tail_of(child.log_path)}"
        )

    async def run(self) -> None:
        """Until the run ends (module docstring)."""
        waits: dict[asyncio.Future[Any], Child] = {}

        def watch(child: Child) -> None:
            assert child.proc is not None
            waits[asyncio.ensure_future(child.proc.wait())] = child

        for child in self.table.current():
            watch(child)
        respawns: set[asyncio.Future[Any]] = set()
        timer: asyncio.Future[Any] | None = None
        stopper: asyncio.Future[Any] | None = None
        try:
            if not self.cfg.lockstep:
                timer = await self._realtime_timer()
            stopper = asyncio.ensure_future(self.stop.event.wait())
            while True:
                pending = {*waits, *respawns, stopper, *([timer] if timer is not None else [])}
                done, _ = await asyncio.wait(pending, return_when=asyncio.FIRST_COMPLETED)
                if stopper in done:
                    raise Interrupted
                if timer is not None and timer in done:
                    return
                for fut in done:
                    if fut in respawns:
                        respawns.discard(fut)
                        if fut.exception() is not None:
                            self.journal.event(f"respawn failed: {fut.exception()}")
                        else:
                            watch(fut.result())
                        continue
                    dead = waits.pop(fut, None)
                    if dead is None:
                        continue
                    if self._exited(dead):
                        return  # the plant ran its duration
                    if self.cfg.respawn_s is not None:
                        respawns.add(asyncio.ensure_future(self.respawn(dead)))
        finally:
            leftovers: list[asyncio.Future[Any] | None] = [*waits, *respawns, stopper, timer]
            for pending_fut in leftovers:
                if pending_fut is not None:
                    pending_fut.cancel()
            await asyncio.gather(*respawns, return_exceptions=True)
