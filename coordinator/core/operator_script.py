"""The scenario's scripted operator commands (``[[operator]]``, scenario/operator.py) played into
a coordinator core at its ticks (issue 28). Pure: no clock, no I/O; time is passed in.

One :class:`OperatorScript` per coordinator core: the in-process simulator
(formation/sim/simulate.py) and the coordinator node (lockstep and realtime) call
:meth:`OperatorScript.play` right before ``CoordinatorCore.tick`` with the same run time and
the same robots counted, so the same commands reach the same core at the same tick and a
lockstep run equals the in-process one bit for bit.

* ``shape``: :meth:`CoordinatorCore.reshape` with the robots counted at that tick as the robots
  alive; a refusal is counted in :attr:`OperatorScript.rejects` (``shape-<reason>``).
* ``teleop``: the twist is given to the leader on every tick of ``[t_s, t_s + duration_s)``,
  received at that tick (the operator's tool streams it); after it the leader's deadman stops it.
* ``goal``, ``path``, ``stop``: the leader's command, once; a refusal is counted.
* ``obstacle``: :meth:`CoordinatorCore.obstacle` with the table the coordinator node builds from
  an ``Obstacle`` message (``coordinator.core.planning.replan.obstacle_table``), once; a
  degenerate polygon is refused as ``obstacle-degenerate``, as the node's operator input does.

A command is due at the first tick at or after its ``t_s`` (within :data:`EPS_S`). A coordinator
that takes over skips the one-shot commands due before its first tick (the previous active
applied them: the leader and the reshape carry on from its state) with :meth:`skip_until`.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Final, Protocol

from coordinator.core.coordinator import CoordinatorCore

__all__ = ["EPS_S", "OperatorScript"]

EPS_S: Final = 1e-9


class _Event(Protocol):
    """An ``[[operator]]`` entry (scenario.operator.OperatorEvent), read only."""

    @property
    def t_s(self) -> float: ...
    @property
    def command(self) -> str: ...
    @property
    def kind(self) -> str | None: ...
    @property
    def spacing_m(self) -> float | None: ...
    @property
    def slots(self) -> int | None: ...
    @property
    def v_mps(self) -> float | None: ...
    @property
    def omega_radps(self) -> float | None: ...
    @property
    def duration_s(self) -> float | None: ...
    @property
    def x(self) -> float | None: ...
    @property
    def y(self) -> float | None: ...
    @property
    def heading(self) -> float | None: ...
    @property
    def waypoints(self) -> tuple[tuple[float, float], ...]: ...
    @property
    def oid(self) -> str | None: ...
    @property
    def action(self) -> str | None: ...
    @property
    def shape(self) -> str | None: ...
    @property
    def radius_m(self) -> float | None: ...
    @property
    def points(self) -> tuple[tuple[float, float], ...]: ...

    def as_dict(self) -> dict[str, Any]: ...


class OperatorScript:
    """Plays scripted operator commands into a core (module docstring)."""

    def __init__(self, events: Sequence[_Event], safety_m: float) -> None:
        self._once = [e for e in events if e.command != "teleop"]
        self._teleop = [e for e in events if e.command == "teleop"]
        self.safety_m = safety_m
        """Least distance (m) between two slots along a reshape."""
        self._next = 0
        self.applied: list[dict[str, Any]] = []
        """The one-shot commands applied: the entry, the run time and the refusal or None."""
        self.rejects: dict[str, int] = {}

    @property
    def active(self) -> bool:
        """Something is left to play."""
        return self._next < len(self._once) or bool(self._teleop)

    def skip_until(self, run_t_s: float) -> None:
        """A takeover at ``run_t_s``: the one-shot commands due before are not played again."""
        while self._next < len(self._once) and self._once[self._next].t_s < run_t_s - EPS_S:
            self._next += 1

    def play(
        self, core: CoordinatorCore, run_t_s: float, now_s: float, robots: int
    ) -> list[tuple[str, str]]:
        """Give ``core`` the commands due at run time ``run_t_s`` (tick clock ``now_s``) with
        ``robots`` robots counted; returns the refusals as ``(command, reason)``."""
        refused: list[tuple[str, str]] = []
        leader = core.leader
        while self._next < len(self._once) and self._once[self._next].t_s <= run_t_s + EPS_S:
            e = self._once[self._next]
            self._next += 1
            why = self._apply(core, e, robots)
            self.applied.append({**e.as_dict(), "applied_s": run_t_s, "refused": why})
            if why is not None:
                refused.append((e.command, why))
        if self._teleop:
            for e in self._teleop:
                assert e.duration_s is not None and e.v_mps is not None
                assert e.omega_radps is not None
                if e.t_s <= run_t_s + EPS_S and run_t_s < e.t_s + e.duration_s - EPS_S:
                    why = leader.command_twist(e.v_mps, e.omega_radps, now_s)
                    if why is not None:
                        refused.append(("teleop", why))
            self._teleop = [e for e in self._teleop if run_t_s < e.t_s + (e.duration_s or 0.0)]
        for command, why in refused:
            key = f"{command}-{why}"
            self.rejects[key] = self.rejects.get(key, 0) + 1
        return refused

    def _apply(self, core: CoordinatorCore, e: _Event, robots: int) -> str | None:
        leader = core.leader
        if e.command == "shape":
            assert e.kind is not None
            spacing = e.spacing_m if e.spacing_m is not None else core.reshaper.spacing_m
            return core.reshape(e.kind, spacing, self.safety_m, e.slots, robots)
        if e.command == "goal":
            assert e.x is not None and e.y is not None
            return leader.command_goal(e.x, e.y, e.heading)
        if e.command == "path":
            return leader.command_path(list(e.waypoints), e.heading)
        if e.command == "stop":
            leader.command_stop()
            return None
        if e.command == "obstacle":
            return _obstacle(core, e)
        return f"unknown command {e.command!r}"


def _obstacle(core: CoordinatorCore, e: _Event) -> str | None:
    """A scripted planning obstacle, built and applied as the node's ``Obstacle`` input does
    (coordinator.node.operator_io)."""
    from coordinator.core.planning.replan import obstacle_table

    assert e.oid is not None and e.action is not None
    table = None
    if e.action != "remove":
        try:
            table = obstacle_table(
                e.shape or "", x=e.x, y=e.y, radius_m=e.radius_m,
                xs=[p[0] for p in e.points] if e.points else None,
                ys=[p[1] for p in e.points] if e.points else None,
            )  # fmt: skip
        except ValueError:
            return "degenerate"
    return core.obstacle(e.action, e.oid, table)
