"""Scripted faults of a scenario (``[[fault]]``): the parser, its validation and the pure
scheduler every runner shares.

A fault entry names *what* happens (``kind``), *to whom* (``robot``, or ``role`` resolved when
the fault fires, e.g. the agent of whoever is the leader then) and *when* (``t_s`` of sim time,
or a condition ``when`` with an earliest time ``after_s`` and an extra ``delay_s``)::

    [[fault]]
    kind = "kill"          # kill | pause | resume | cut_link | restore_link | estop | release |
                           # kill_coordinator | camera_loss
    role = "leader"        # or robot = "r2"
    when = "in_formation"  # or t_s = 12.0
    after_s = 5.0          # (conditions) not before this sim time
    delay_s = 1.0          # (conditions) this long after the condition first holds

    [[fault]]
    kind = "pause"
    robot = "r3"
    t_s = 8.0
    duration_s = 2.0       # pause, cut_link, estop, camera_loss: undone this long after

Theory of operation
-------------------
:func:`parse_faults` turns the TOML array into frozen :class:`Fault` values and refuses, with
one line naming the field, what cannot run: an unknown kind, robot, role or condition, a time
past the run, two ways of saying when, a kill of a robot already killed, a kill that leaves no
robot (a role-kill counts as one robot), a ``resume``/``restore_link`` with nothing to undo.

:class:`FaultScheduler` is a pure state machine: no clock, no I/O. The runner calls
:meth:`FaultScheduler.due` once per control tick with the tick's sim time, the current leader
and whether every live robot is in formation; it returns the :class:`FaultAction` values to
apply at that tick (timed faults first in file order, then conditions, then the automatic
undo of a ``duration_s``), each with its role resolved to a robot. The same scenario, the same
inputs per tick, give the same actions at the same tick: that is what makes ``formation sim``
and a lockstep ``formation up`` apply a fault at the same tick.

:class:`FleetFaults` is the state the faults leave: robots offline (killed, paused or cut off,
which the coordinator no longer counts and whose wheels the plant stops), robots frozen
(paused: the firmware does not step), the latched e-stop scopes and whether the coordinator is
down. Stdlib only.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Final

__all__ = [
    "CONDITIONS",
    "FAULT_KINDS",
    "ROLES",
    "Fault",
    "FaultAction",
    "FaultScheduler",
    "FleetFaults",
    "fleet_view",
    "parse_faults",
]

FAULT_KINDS: Final = (
    "kill",
    "pause",
    "resume",
    "cut_link",
    "restore_link",
    "estop",
    "release",
    "kill_coordinator",
    "camera_loss",
)
ROBOT_KINDS: Final = frozenset(
    {"kill", "pause", "resume", "cut_link", "restore_link", "camera_loss"}
)
"""Kinds that need a robot (or a role); estop/release take one optionally (none: the fleet)."""
UNDO: Final = {"pause": "resume", "cut_link": "restore_link", "estop": "release"}
"""What a ``duration_s`` schedules after the fault (camera_loss ends by itself)."""
ROLES: Final = ("leader",)
CONDITIONS: Final = ("in_formation",)
KEYS: Final = frozenset(
    {"kind", "robot", "role", "t_s", "when", "after_s", "delay_s", "duration_s", "takeover_s"}
)
DEFAULT_TAKEOVER_S: Final = 0.0
"""kill_coordinator: the hot standby ticks this long after the active died (0: the next tick)."""


class FaultSpecError(ValueError):
    """A ``[[fault]]`` entry is invalid; the message names the field (scenario.ScenarioError
    wraps it)."""


@dataclass(frozen=True)
class Fault:
    """One ``[[fault]]`` entry (times in sim seconds from the run's start)."""

    index: int  # position in the file: fault[index]
    kind: str
    robot: str | None = None
    role: str | None = None
    t_s: float | None = None
    when: str | None = None
    after_s: float = 0.0
    delay_s: float = 0.0
    duration_s: float | None = None
    takeover_s: float | None = None  # kill_coordinator: the hot standby's delay (None: default)

    @property
    def where(self) -> str:
        return f"fault[{self.index}]"

    def describe(self) -> str:
        """One line, e.g. ``kill of the leader at t=12 s``."""
        who = (
            f" of {self.robot}"
            if self.robot
            else f" of the {self.role}"
            if self.role
            else " of the fleet"
            if self.kind in ("estop", "release")
            else ""
        )
        at = (
            f"at t={self.t_s:g} s"
            if self.t_s is not None
            else f"when {self.when} (not before {self.after_s:g} s, +{self.delay_s:g} s)"
        )
        return f"{self.kind}{who} {at}"


@dataclass(frozen=True)
class FaultAction:
    """A fault firing at one tick, its role resolved: what the runner applies."""

    fault: int  # index of the [[fault]] entry (an automatic undo carries its fault's index)
    kind: str
    robot: str | None
    t_s: float
    planned_s: float | None  # the entry's t_s (None: a condition)
    role: str | None = None
    undo: bool = False  # the automatic end of a duration_s
    duration_s: float | None = None
    takeover_s: float | None = None

    def as_dict(self) -> dict[str, Any]:
        """The metrics.json entry of a fault sent (what its bus notice carries too, so
        ``formation sim`` and ``formation up`` list the same; ``fault`` indexes the scenario's
        ``[[fault]]`` entries)."""
        return {
            "fault": self.fault,
            "kind": self.kind,
            "robot": self.robot,
            "t_s": self.t_s,
            "undo": self.undo,
        }


# ---------------------------------------------------------------------------------------------
# parsing


def _number(d: dict[str, Any], key: str, where: str, *, lo: float = 0.0) -> float | None:
    if key not in d:
        return None
    v = d[key]
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(float(v)):
        raise FaultSpecError(f"{where}.{key}: expected a finite number, got {v!r}")
    if float(v) < lo:
        raise FaultSpecError(f"{where}.{key}: {float(v):g} must be >= {lo:g}")
    return float(v)


def _entry(j: int, d: Any, robot_ids: tuple[str, ...], duration_s: float) -> Fault:
    where = f"fault[{j}]"
    if not isinstance(d, dict):
        raise FaultSpecError(f"{where}: expected a table")
    unknown = set(d) - KEYS
    if unknown:
        raise FaultSpecError(
            f"{where}: unknown key(s) {', '.join(sorted(unknown))}; allowed: "
            f"{', '.join(sorted(KEYS))}"
        )
    kind = d.get("kind")
    if kind not in FAULT_KINDS:
        raise FaultSpecError(f"{where}.kind: {kind!r} is not one of {', '.join(FAULT_KINDS)}")
    robot = d.get("robot")
    role = d.get("role")
    if robot is not None and robot not in robot_ids:
        raise FaultSpecError(
            f"{where}.robot: {robot!r} is not one of the scenario's robots "
            f"({', '.join(robot_ids[:8])}{', ...' if len(robot_ids) > 8 else ''})"
        )
    if role is not None and role not in ROLES:
        raise FaultSpecError(f"{where}.role: {role!r} is not one of {', '.join(ROLES)}")
    if robot is not None and role is not None:
        raise FaultSpecError(f"{where}: give robot or role, not both")
    if kind == "kill_coordinator" and (robot is not None or role is not None):
        raise FaultSpecError(f"{where}: kill_coordinator takes no robot or role")
    if kind in ROBOT_KINDS and robot is None and role is None:
        raise FaultSpecError(f'{where}.robot: required for {kind} (or role = "leader")')
    if kind in ("resume", "restore_link") and role is not None:
        raise FaultSpecError(
            f"{where}.role: {kind} needs a robot (a role moves on; give the pause a duration_s)"
        )
    t_s = _number(d, "t_s", where)
    when = d.get("when")
    if (t_s is None) == (when is None):
        raise FaultSpecError(f"{where}: give exactly one of t_s or when")
    if when is not None and when not in CONDITIONS:
        raise FaultSpecError(f"{where}.when: {when!r} is not one of {', '.join(CONDITIONS)}")
    if t_s is not None and t_s > duration_s:
        raise FaultSpecError(f"{where}.t_s: {t_s:g} s is past the run's end ({duration_s:g} s)")
    after_s = _number(d, "after_s", where) or 0.0
    delay_s = _number(d, "delay_s", where) or 0.0
    if t_s is not None and ("after_s" in d or "delay_s" in d):
        raise FaultSpecError(f"{where}: after_s and delay_s go with when, not with t_s")
    if after_s + delay_s > duration_s:
        raise FaultSpecError(
            f"{where}.after_s: {after_s + delay_s:g} s (with delay_s) is past the run's end "
            f"({duration_s:g} s)"
        )
    dur = _number(d, "duration_s", where)
    if dur is not None and kind not in UNDO and kind != "camera_loss":
        raise FaultSpecError(f"{where}.duration_s: not for {kind}")
    if kind == "camera_loss" and dur is None:
        dur = 1.0
    takeover = _number(d, "takeover_s", where)
    if takeover is not None and kind != "kill_coordinator":
        raise FaultSpecError(f"{where}.takeover_s: only for kill_coordinator")
    return Fault(
        index=j,
        kind=kind,
        robot=robot,
        role=role,
        t_s=t_s,
        when=when,
        after_s=after_s,
        delay_s=delay_s,
        duration_s=dur,
        takeover_s=takeover,
    )


def _order_key(f: Fault) -> tuple[float, int]:
    """Timed faults in time order; conditions after every timed one (their time is unknown)."""
    return (f.t_s if f.t_s is not None else math.inf, f.index)


def _check_sequence(faults: list[Fault], robot_ids: tuple[str, ...]) -> None:
    """Kills that leave no robot, a robot killed twice, an undo of nothing (in time order)."""
    killed: set[str] = set()
    role_kills = 0
    held: dict[str, set[str]] = {"pause": set(), "cut_link": set()}
    for f in sorted(faults, key=_order_key):
        if f.kind == "kill":
            if f.robot is not None:
                if f.robot in killed:
                    raise FaultSpecError(f"{f.where}.robot: {f.robot} is already killed")
                killed.add(f.robot)
            else:
                role_kills += 1
            if len(killed) + role_kills >= len(robot_ids):
                raise FaultSpecError(
                    f"{f.where}: kills the last robot ({len(robot_ids)} robot(s), "
                    f"{len(killed) + role_kills} kill(s)); a fleet needs one robot left"
                )
        elif f.kind in held and f.robot is not None and f.duration_s is None:
            held[f.kind].add(f.robot)
        elif f.kind in ("resume", "restore_link"):
            cause = "pause" if f.kind == "resume" else "cut_link"
            if f.robot not in held[cause]:
                raise FaultSpecError(
                    f"{f.where}.robot: {f.kind} of {f.robot}, but no earlier {cause} of it "
                    "without a duration_s"
                )
            held[cause].discard(str(f.robot))


def parse_faults(raw: Any, robot_ids: tuple[str, ...], duration_s: float) -> tuple[Fault, ...]:
    """The ``fault`` array of a scenario dictionary, validated (raises FaultSpecError)."""
    if raw is None:
        return ()
    if not isinstance(raw, list):
        raise FaultSpecError("fault: expected an array of tables [[fault]]")
    faults = [_entry(j, d, robot_ids, duration_s) for j, d in enumerate(raw)]
    _check_sequence(faults, robot_ids)
    return tuple(faults)


# ---------------------------------------------------------------------------------------------
# scheduling


@dataclass
class _Waiting:
    fault: Fault
    since_s: float | None = None  # the condition first held at this time (then + delay_s)


class FaultScheduler:
    """Which faults fire at each tick (see the module docstring). Pure: the caller passes the
    tick's sim time and what the fleet looks like."""

    EPS_S: Final = 1e-9

    def __init__(self, faults: tuple[Fault, ...], end_s: float = math.inf) -> None:
        self._timed = sorted((f for f in faults if f.t_s is not None), key=_order_key)
        self._cond = [_Waiting(f) for f in faults if f.when is not None]
        self._undo: list[tuple[float, FaultAction]] = []
        self.end_s = end_s
        self.sent: list[FaultAction] = []

    @property
    def active(self) -> bool:
        """Something is left to fire or to undo."""
        return bool(self._timed or self._cond or self._undo)

    def add(self, fault: Fault) -> None:
        """Schedule one more timed fault (an operator's request, ``formation fault --at T``);
        one whose time is past fires at the next call of :meth:`due`."""
        if fault.t_s is None:
            raise ValueError("an added fault needs t_s")
        self._timed.append(fault)
        self._timed.sort(key=_order_key)

    def due(self, t_s: float, *, leader: str | None, in_formation: bool) -> list[FaultAction]:
        """The actions of the tick at ``t_s`` (each at most once over a run), role resolved
        to ``leader``; a role that nobody holds now waits for the next tick."""
        out: list[FaultAction] = []
        eps = self.EPS_S
        while self._timed and (self._timed[0].t_s or 0.0) <= t_s + eps:
            f = self._timed[0]
            act = self._fire(f, t_s, leader)
            if act is None:
                break  # nobody holds the role yet: try again next tick
            self._timed.pop(0)
            out.append(act)
        for w in list(self._cond):
            f = w.fault
            if t_s + eps < f.after_s:
                continue
            if w.since_s is None:
                if not in_formation:
                    continue
                w.since_s = t_s
            if t_s + eps < w.since_s + f.delay_s:
                continue
            act = self._fire(f, t_s, leader)
            if act is not None:
                self._cond.remove(w)
                out.append(act)
        while self._undo and self._undo[0][0] <= t_s + eps:
            out.append(self._undo.pop(0)[1])
        for act in out:
            if act.duration_s is not None and act.kind in UNDO:
                undo = FaultAction(
                    act.fault,
                    UNDO[act.kind],
                    act.robot,
                    t_s + act.duration_s,
                    act.planned_s,
                    act.role,
                    undo=True,
                )
                self._undo.append((t_s + act.duration_s, undo))
                self._undo.sort(key=lambda u: (u[0], u[1].fault))
        self.sent.extend(out)
        return out

    def _fire(self, f: Fault, t_s: float, leader: str | None) -> FaultAction | None:
        robot = f.robot
        if f.role == "leader":
            if leader is None:
                return None
            robot = leader
        return FaultAction(
            f.index,
            f.kind,
            robot,
            t_s,
            f.t_s,
            f.role,
            duration_s=f.duration_s,
            takeover_s=f.takeover_s,
        )

    def pending(self) -> list[dict[str, Any]]:
        """The faults that never fired (a condition that never came, a role nobody held, a time
        past a shortened run): the end-of-run report."""
        left = [f for f in self._timed] + [w.fault for w in self._cond]
        return [
            {"fault": f.index, "kind": f.kind, "why": f"never fired: {f.describe()}"}
            for f in sorted(left, key=lambda f: f.index)
        ]


@dataclass
class FleetFaults:
    """What the faults fired so far leave (see the module docstring)."""

    killed: set[str] = field(default_factory=set)
    paused: set[str] = field(default_factory=set)
    cut: set[str] = field(default_factory=set)
    estop_fleet: bool = False
    estop_robots: set[str] = field(default_factory=set)
    coordinator_down_until_s: float | None = None  # the hot standby ticks from then

    def offline(self) -> set[str]:
        """Robots the coordinator does not count and whose wheels the plant stops."""
        return self.killed | self.paused | self.cut

    def stopped(self, robot: str) -> bool:
        """The robot's e-stop scopes (the fleet's or its own) are latched."""
        return self.estop_fleet or robot in self.estop_robots

    def coordinator_down(self, t_s: float) -> bool:
        until = self.coordinator_down_until_s
        return until is not None and t_s + FaultScheduler.EPS_S < until

    def apply(self, act: FaultAction) -> None:
        """Update the state with one action (camera_loss leaves it alone: the camera's)."""
        r = act.robot
        k = act.kind
        if k == "kill" and r is not None:
            self.killed.add(r)
            self.paused.discard(r)
            self.cut.discard(r)
        elif k == "pause" and r is not None and r not in self.killed:
            self.paused.add(r)
        elif k == "resume" and r is not None:
            self.paused.discard(r)
        elif k == "cut_link" and r is not None and r not in self.killed:
            self.cut.add(r)
        elif k == "restore_link" and r is not None:
            self.cut.discard(r)
        elif k == "estop":
            if r is None:
                self.estop_fleet = True
            else:
                self.estop_robots.add(r)
        elif k == "release":
            if r is None:
                self.estop_fleet = False
            else:
                self.estop_robots.discard(r)
        elif k == "kill_coordinator":
            takeover = DEFAULT_TAKEOVER_S if act.takeover_s is None else act.takeover_s
            self.coordinator_down_until_s = act.t_s + takeover


def fleet_view(
    assignment: Mapping[str, int],
    rows: Sequence[Sequence[float]],
    slot_ids: Sequence[int],
    poses: Mapping[str, tuple[float, float, float]],
    ref_offset_m: float,
    tol_m: float,
) -> tuple[str | None, bool]:
    """What the scheduler needs after a coordinator tick: who holds slot 0, and whether every
    robot the coordinator counted (``poses``: its measured poses, offline robots left out) is
    assigned with its reference point (eq. 3: ``ref_offset_m`` ahead of the axle) within
    ``tol_m`` of its slot (``rows``: ``(x, y, ...)`` per slot in ``slot_ids`` order). The
    coordinator's own inputs, so the in-process run and the coordinator node decide alike."""
    leader = None
    row_of = {s: k for k, s in enumerate(slot_ids)}
    ok = bool(poses)
    for rid, (x, y, th) in poses.items():
        slot = assignment.get(rid)
        if slot is None:
            ok = False
            continue
        if slot == 0:
            leader = rid
        sx, sy = rows[row_of[slot]][:2]
        rx = x + ref_offset_m * math.cos(th)
        ry = y + ref_offset_m * math.sin(th)
        if math.hypot(rx - sx, ry - sy) > tol_m:
            ok = False
    return leader, ok
