"""Lockstep: the rules that make a run over Zenoh equal the in-process simulator bit for bit.

One implementation, used by both runtimes: ``formation/sim/simulate.py`` (one process, no bus) and
the distributed nodes (plant, coordinator, agents, agent hosts) when they run ``--lockstep``
(docs/runtime.md). Pure and stdlib only, time passed in, so the robot agent can use it and the
rules are unit-tested directly (tests/unit/robot_agent/test_lockstep_core.py).

The rules:

1. **Tick time.** Tick k happens at sim time ``t_k = k * dt_s`` (:func:`tick_time`); nothing in
   a lockstep run reads a wall clock.
2. **Setpoint delay.** The setpoints the coordinator computes on tick k are used by the
   firmware on tick k+1, received at ``t_k`` (:data:`SETPOINT_DELAY_TICKS`): over the bus a
   setpoint computed on clock k reaches the agents before clock k+1. :class:`SetpointWindow`
   keeps the last two ticks' setpoints, because setpoint k may already have arrived when clock k
   is handled.
3. **Arrivals.** An input received between two clocks (a pose, a neighbour's position) counts as
   received at the next clock's ``t`` (:class:`Arrivals`), as the simulator delivers the camera's
   poses at the tick they become due.
4. **Repeated clocks.** A clock the plant re-announces (it waits for answers) gets the same answer
   again, without stepping twice (:class:`Replay`).
"""

from __future__ import annotations

from collections.abc import Callable, Hashable
from typing import Final, Generic, TypeVar

__all__ = ["SETPOINT_DELAY_TICKS", "Arrivals", "Replay", "SetpointWindow", "tick_time"]

T = TypeVar("T")

SETPOINT_DELAY_TICKS: Final = 1
"""A setpoint computed on tick k is used on tick k + 1."""

_WINDOW: Final = 2
"""How many ticks' setpoints :class:`SetpointWindow` keeps."""


def tick_time(k: int, dt_s: float) -> float:
    """Sim time (s) of tick ``k`` with period ``dt_s``: exactly ``k * dt_s`` (no accumulation)."""
    return k * dt_s


class SetpointWindow(Generic[T]):
    """The setpoints of the last two ticks (two distinct ticks: a tick added again replaces its
    entry); on clock k, the one computed on tick k - 1.

    A list of at most two entries, not a ``deque(maxlen=2)``: the same entries, and compiled
    (with the firmware, ``robot_agent/core/_accel.py``) a list's operations are C calls where a
    deque's are Python method calls."""

    __slots__ = ("_items",)

    def __init__(self) -> None:
        self._items: list[tuple[int, T]] = []

    def add(self, tick: int, item: T) -> None:
        """Keep ``item``, computed on ``tick``: it replaces an entry of the same tick (the
        coordinator answers a re-announced clock with the same setpoints again, and an agent
        may take several of them before the clock it waits for), else the older of two kept
        ticks is dropped."""
        items = self._items
        for j in range(len(items)):
            if items[j][0] == tick:
                del items[j]
                break
        items.append((tick, item))
        if len(items) > _WINDOW:
            del items[0]

    def for_clock(self, k: int) -> T | None:
        """The item computed on tick ``k - SETPOINT_DELAY_TICKS`` (the newest such), or None."""
        want = k - SETPOINT_DELAY_TICKS
        chosen: T | None = None
        for tick, item in self._items:
            if tick == want:
                chosen = item
        return chosen

    def clear(self) -> None:
        self._items.clear()


class Arrivals(Generic[T]):
    """Inputs received since the last clock; :meth:`take` hands them over at the next clock,
    whose ``t`` becomes their receive time."""

    __slots__ = ("_pending",)

    def __init__(self) -> None:
        self._pending: list[T] = []

    def add(self, key: T) -> None:
        self._pending.append(key)

    def take(self) -> list[T]:
        """Everything received since the previous call, in arrival order."""
        pending, self._pending = self._pending, []
        return pending

    def __bool__(self) -> bool:
        return bool(self._pending)

    def __len__(self) -> int:
        return len(self._pending)

    def compact(self, key: Callable[[T], Hashable] | None = None) -> None:
        """Drop repeated entries (by ``key``, default the entry itself), keeping the first
        position of each (used when no clock came for a long time)."""
        if key is None:
            self._pending = list(dict.fromkeys(self._pending))
        else:
            self._pending = list({key(e): e for e in self._pending}.values())


class Replay(Generic[T]):
    """The answer to the last clock, so a repeated clock is answered again without a step."""

    __slots__ = ("answer", "last_tick")

    def __init__(self) -> None:
        self.last_tick: int | None = None
        self.answer: T | None = None

    def repeat(self, k: int) -> T | None:
        """The recorded answer if clock ``k`` was already answered, else None (step)."""
        if k == self.last_tick and self.answer is not None:
            return self.answer
        return None

    def record(self, k: int, answer: T | None) -> None:
        """Clock ``k`` was handled and answered with ``answer``."""
        self.last_tick = k
        self.answer = answer
