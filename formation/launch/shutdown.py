"""The stop of a ``formation up`` run, in order, bounded: SIGTERM to the nodes (each gets
:data:`formation.launch.children.STOP_PATIENCE_S`, then SIGABRT and SIGKILL; all at once with
a second stop signal (:class:`~formation.launch.stop_request.StopRequest`)), the last
samples to the collector, the recorder and the live view closed, the sessions closed, then the
router, anything left in the run's process group killed, every child's output closed, the run
file removed and the run's keys deleted. A step that raises is a failure of the run and the
sequence goes on (the router must stop and the session close: a step that raised used to leave
both and the launcher hung at exit with its router holding the port).

:func:`shut_down` returns how long it took (``meta.stop_s``)."""

from __future__ import annotations

import asyncio
import contextlib
import os
import signal
import time
from collections.abc import Awaitable
from pathlib import Path
from typing import Any

from formation.launch.children import Child, group_members
from formation.launch.intake import RunIntake
from formation.launch.journal import RunJournal
from formation.launch.observers import RunObservers
from formation.launch.processes import ProcessTable
from formation.launch.registration import RunRegistration
from formation.launch.stop_request import StopRequest

__all__ = ["shut_down", "stop_children"]


async def stop_children(children: list[Child], journal: RunJournal, *, kill_now: bool) -> None:
    """Stop ``children`` together (SIGKILL first with ``kill_now``); a child that had to be
    killed or exited badly is a failure, one resumed from a pause an event."""
    if kill_now:
        for c in children:
            c.signal(signal.SIGKILL)
    problems = await asyncio.gather(*(c.stop() for c in children))
    for c in children:
        if c.resumed_to_stop:  # an injected pause still on: an event, not a failure
            journal.event(f"{c.name} (pid {c.pid}) was paused at the end: resumed to stop it")
    for p in problems:
        if p is not None:
            journal.fail(p)


async def _step(journal: RunJournal, what: str, aw: Awaitable[Any]) -> None:
    """One step of the shutdown: whatever it raises is a failure, and the shutdown goes on."""
    try:
        await aw
    except Exception as exc:
        journal.fail(f"shutdown: {what} failed: {exc!r}")


async def _close_intake(intake: RunIntake, observers: RunObservers, journal: RunJournal) -> None:
    """The last samples to the collector, then the observers and the sessions."""
    try:
        await intake.take_last()
    except Exception as exc:
        journal.fail(f"shutdown: the collector failed: {exc!r}")
    if intake.dropped:
        journal.warn(f"the collector's inbox overflowed: {intake.dropped} samples lost")
    await _step(journal, "closing the recorder and the live view", observers.stop())
    journal.failed_already(observers.failures)  # warned already
    intake.close()


def _kill_group(group: int, journal: RunJournal) -> None:
    leftovers = group_members(group)
    if leftovers:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(group, signal.SIGKILL)
        journal.fail(f"processes left in the run's group killed: {leftovers}")


async def shut_down(
    table: ProcessTable,
    intake: RunIntake,
    observers: RunObservers,
    registration: RunRegistration,
    journal: RunJournal,
    stop: StopRequest,
    *,
    secure_dir: Path | None,
) -> float:
    """Stop the run (module docstring); returns the seconds it took."""
    t0 = time.monotonic()
    await _step(
        journal, "stopping the nodes", stop_children(table.nodes, journal, kill_now=stop.kill_now)
    )
    if intake.session is not None:
        await _close_intake(intake, observers, journal)
    if table.router is not None:
        await _step(
            journal,
            "stopping the router",
            stop_children([table.router], journal, kill_now=stop.kill_now),
        )
    if table.group is not None:
        _kill_group(table.group, journal)
    for c in table.every():
        await _step(journal, f"closing {c.name}'s output", c.close())
        if c.out_error is not None:
            journal.fail(f"{c.out_path} incomplete: {c.out_error}")
    registration.unregister()
    if secure_dir is not None:  # the run's keys die with it
        import shutil

        shutil.rmtree(secure_dir, ignore_errors=True)
    stop_s = time.monotonic() - t0
    from runtime.lifecycle import request_fast_exit

    request_fast_exit()  # every child and session is closed: no interpreter teardown needed
    return stop_s
