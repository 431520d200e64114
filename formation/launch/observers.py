"""The observers a ``formation up`` run may start on the launcher's Zenoh session: the MCAP
recorder (``--record``, :mod:`formation.record.command`) and the Foxglove live server
(``--foxglove``,
:mod:`formation.live.foxglove`). :mod:`formation.launch.launcher` starts them as soon as its
session is open
and stops them, after the nodes, before it closes the session."""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from typing import Any

from bus_schemas import keys
from formation.launch.plan import LaunchError, Plan, UpConfig

__all__ = ["RunObservers"]


class RunObservers:
    """``--record`` and ``--foxglove`` of one run (``say`` / ``warn``: the run's output)."""

    def __init__(
        self,
        cfg: UpConfig,
        plan: Plan,
        say: Callable[[str], None],
        warn: Callable[[str], None],
    ) -> None:
        self.cfg = cfg
        self.plan = plan
        self.say = say
        self.warn = warn
        self.recorder: Any = None  # formation.record.command.RecorderHandle with --record
        self.live: Any = None  # formation.live.foxglove.LiveHandle with --foxglove
        self.record_stats: Any = None  # the recorder's stats once it is closed
        self.failures: list[str] = []
        """What could not be done cleanly (an incomplete recording): failures of the run."""

    def start(self, session: Any, commands: Any = None) -> None:
        """Start what the run asks for on ``session`` (the launcher's, open; ``commands``: the
        session the live view's client publishes are put with, issue 28): raises
        :class:`~formation.launch.plan.LaunchError` if one cannot start (the ones started before
        it are kept, for :meth:`stop`)."""
        if self.cfg.record is not None:
            from formation.record.command import run_info, start_recorder

            run = run_info(
                self.plan.scenario_arg,
                lockstep=self.cfg.lockstep,
                settle_s=self.plan.settle_s,
                seed=self.plan.seed,
                duration_s=self.plan.duration_s,
                endpoint=self.cfg.endpoint,
            )
            try:
                self.recorder = start_recorder(session, self.cfg.fleet, self.cfg.record, run=run)
            except OSError as exc:
                raise LaunchError(f"--record {self.cfg.record}: {exc}") from exc
            self.say(f"  recording    {keys.fleet_pattern(self.cfg.fleet)} to {self.cfg.record}")
        if self.cfg.foxglove_port is not None:
            from formation.live.foxglove import start_live

            geom = self.plan.scenario.agent.geometry
            try:
                self.live = start_live(
                    session,
                    self.cfg.fleet,
                    host=self.cfg.foxglove_host,
                    port=self.cfg.foxglove_port,
                    ref_offset_m=geom.ref_offset_m,
                    body_radius_m=geom.body_radius_m,
                    world=self.plan.scenario.agent.world,
                    commands=commands,
                    trajectory=self.plan.scenario.trajectory,  # its plan in the scene
                )
            except RuntimeError as exc:
                raise LaunchError(f"--foxglove {self.cfg.foxglove_port}: {exc}") from exc
            # printed even with --quiet: a client needs the address
            print(f"foxglove live view on {self.live.url}", flush=True)

    async def stop(self) -> None:
        """Close the live server and finalize the recording (before the session closes); never
        raises: what went wrong is in :attr:`failures` (the run exits 1) and warned."""
        live, self.live = self.live, None
        if live is not None:
            try:
                await asyncio.to_thread(live.close)
            except Exception as exc:
                self._failed(f"--foxglove: the live server did not close cleanly: {exc!r}")
        recorder, self.recorder = self.recorder, None
        if recorder is None:
            return
        try:
            stats = await asyncio.to_thread(recorder.close)
        except Exception as exc:  # never seen; a recorder that cannot close must not hang us
            self._failed(f"recording {recorder.path}: closing failed: {exc!r}")
            return
        self.record_stats = stats
        if stats.dropped or stats.handler_errors:
            self.warn(
                f"recording {recorder.path}: {stats.dropped} samples dropped, "
                f"{stats.handler_errors} write errors"
            )
        if stats.error is not None:  # a full or read-only disk: named, and the run fails
            from formation.record.command import incomplete

            self._failed(incomplete(recorder.path, stats))
        self.say(
            f"recorded {stats.samples} samples ({stats.rejected} rejected, "
            f"{stats.liveliness} liveliness changes) to {recorder.path}"
        )

    def _failed(self, text: str) -> None:
        self.failures.append(text)
        self.warn(text)
