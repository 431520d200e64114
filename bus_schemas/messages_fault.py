"""The scripted-fault notice (``formation/<fleet>/fault``), a declarative table like those of
``messages.py`` (see its docstring for the common fields).

Theory of operation (docs/faults.md "Faults in scenarios"): the active coordinator runs the
scenario's fault schedule (``scenario.faults``) and, at the end of the tick before a fault
applies, publishes one notice per action with the ``tick`` it applies at (lockstep) before its
``leader`` message, so the plant (which waits for that leader before the next clock) and every
agent (which gets that clock after it) hold the notice when the tick comes: every node applies
it at the same tick. In realtime ``tick`` is nil and the launcher of the run acts on it (a real
signal). ``request: true`` is an operator's ``formation fault ... --at T``: the active
coordinator adds it to its schedule and publishes the notice when it is due. A notice without
``fault`` (no scenario index) records a fault a tool did at once (``formation fault kill r2``):
nobody acts on it; recorders list it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import StrEnum

from bus_schemas import keys
from bus_schemas.messages_fields import _T, _V
from bus_schemas.spec import DURATION_MAX_S as _DUR
from bus_schemas.spec import f_bool, f_enum, f_float, f_int, f_robot_id, message


class FaultKind(StrEnum):
    """What a scripted fault does (scenario ``[[fault]]`` ``kind``)."""

    KILL = "kill"
    PAUSE = "pause"
    RESUME = "resume"
    CUT_LINK = "cut_link"
    RESTORE_LINK = "restore_link"
    ESTOP = "estop"
    RELEASE = "release"
    KILL_COORDINATOR = "kill_coordinator"
    CAMERA_LOSS = "camera_loss"


class FaultRole(StrEnum):
    """Whom a requested fault hits, resolved by the coordinator when it fires."""

    LEADER = "leader"


@message(
    name=keys.FAULT,
    publisher="coordinator (the scenario's faults, when due) / operator (a request: --at T)",
    periodic=False,
)
@dataclass(frozen=True, slots=True, kw_only=True)
class Fault:
    """A scripted fault: applies at sim time `t` (lockstep: at clock `tick`)."""

    v: int = field(default=1, metadata=_V)
    t: float = field(metadata=_T)
    tick: int | None = field(
        default=None,
        metadata=f_int("lockstep: the clock tick it applies at; absent in realtime or a request"),
    )  # fmt: skip
    request: bool | None = field(
        default=None,
        metadata=f_bool("true: an operator's request for the active coordinator to schedule"),
    )
    fault: int | None = field(
        default=None,
        metadata=f_int("index of the scenario's [[fault]] entry; absent: an operator's",
                       hi=65535),
    )  # fmt: skip
    kind: str = field(metadata=f_enum("what happens", FaultKind))
    robot: str | None = field(
        default=None, metadata=f_robot_id("the robot it hits; absent: the fleet")
    )
    duration_s: float | None = field(
        default=None,
        metadata=f_float("camera_loss: how long; a request's pause/cut/estop: undone after",
                         "s", lo=0.0, hi=_DUR),
    )  # fmt: skip
    role: str | None = field(
        default=None,
        metadata=f_enum("a request's target by role (resolved when it fires); absent: robot",
                        FaultRole),
    )  # fmt: skip
    undo: bool | None = field(
        default=None, metadata=f_bool("true: the automatic end of a duration_s")
    )
