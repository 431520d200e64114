"""What ``formation up`` does with the scenario's scripted faults (``[[fault]]``, docs/faults.md
"Faults in scenarios").

Lockstep: nothing but watch; every node applies each notice at its tick (the agent of a killed
robot SIGKILLs itself, which the launcher reports as a death of the run, as ever).

Realtime: the active coordinator publishes a notice when a fault is due (its time base: the
virtual leader's, ``t`` from the start of the trajectory) and the launcher makes it real with
the process it started: ``kill`` SIGKILLs the robot's agent, ``pause``/``resume`` SIGSTOP and
SIGCONT it, ``kill_coordinator`` SIGKILLs the running coordinator (the first one still alive:
with ``--standby`` the other takes over), ``estop``/``release`` publish the e-stop as
``formation fault estop`` does. A camera loss is the plant's (it occludes on receipt). What has
no realtime meaning here is refused before the fleet starts (:func:`check_layout`).
"""

from __future__ import annotations

import asyncio
import os
import signal
from collections.abc import Callable, Sequence
from typing import Any

from bus_schemas import DecodeError, Fault, decode
from scenario import Scenario

__all__ = ["RealtimeFaults", "check_layout"]

_SIGNALS = {"kill": signal.SIGKILL, "pause": signal.SIGSTOP, "resume": signal.SIGCONT}


def check_layout(scn: Scenario, *, lockstep: bool, hosts: int, standby: bool) -> str | None:
    """Why the scenario's faults cannot run on this layout (one line naming the field), or
    None. Lockstep runs every kind on every layout."""
    if lockstep:
        return None
    for f in scn.faults:
        if f.kind == "kill_coordinator" and not standby:
            return (
                f"{f.where}.kind: a realtime kill_coordinator needs a hot standby to take over: "
                "add --standby (or use --lockstep, where takeover_s models it)"
            )
        if f.kind == "cut_link":
            return (
                f"{f.where}.kind: cut_link has no realtime meaning yet (no network namespace "
                "per robot): run it with --lockstep or `formation sim`"
            )
        if f.kind in _SIGNALS and hosts > 0:
            return (
                f"{f.where}.kind: a realtime {f.kind} signals one robot's agent process, but "
                f"this fleet runs its robots in {hosts} agent host(s): add --hosts 0 (one "
                "process per robot), or use --lockstep"
            )
    return None


class RealtimeFaults:
    """The launcher's hands for realtime notices (module docstring)."""

    def __init__(
        self,
        children: Callable[[], Sequence[Any]],
        event: Callable[[str], None],
        estop: Callable[[bool, str | None], Any],
    ) -> None:
        self.children = children  # the launcher's live nodes (formation.launch.children.Child)
        self.event = event
        self.estop = estop  # async (engage, robot) -> report
        self.done: list[dict[str, Any]] = []
        self.rejected = 0
        self._tasks: set[asyncio.Future[Any]] = set()

    def on_notice(self, payload: bytes) -> None:
        """A ``fault`` message (realtime notices only; never raises)."""
        msg = decode(payload, Fault)
        if isinstance(msg, DecodeError):
            self.rejected += 1
            return
        if msg.request or msg.tick is not None or msg.fault is None:
            return  # a request, a lockstep notice, or the record of a fault done by a tool
        try:
            self._act(msg)
        except Exception as exc:  # a fault tool must not take the run down
            self.event(f"scripted fault {msg.kind}: {exc!r}")

    def _child(self, prefix: str) -> Any:
        for c in self.children():
            if c.name.startswith(prefix) and c.returncode is None and c.pid is not None:
                return c
        return None

    def _act(self, msg: Fault) -> None:
        kind, robot = msg.kind, msg.robot
        if kind in _SIGNALS and robot is not None:
            child = self._child(f"agent-{robot}")
            if child is None or child.name != f"agent-{robot}":
                self.event(f"scripted fault {kind} of {robot}: no agent process of it")
                return
            os.kill(child.pid, _SIGNALS[kind])
            self.event(f"scripted fault: {kind} {robot} (pid {child.pid})")
        elif kind == "kill_coordinator":
            child = self._child("coordinator")
            if child is None:
                self.event("scripted fault kill_coordinator: no coordinator running")
                return
            os.kill(child.pid, signal.SIGKILL)
            self.event(f"scripted fault: killed {child.name} (pid {child.pid})")
        elif kind in ("estop", "release"):
            task = asyncio.ensure_future(self.estop(kind == "estop", robot))
            self._tasks.add(task)
            task.add_done_callback(self._tasks.discard)
            self.event(f"scripted fault: {kind} {robot or 'fleet'}")
        else:
            return  # camera_loss: the plant's
        self.done.append({"kind": kind, "robot": robot, "t": msg.t})
