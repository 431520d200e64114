"""The running formation and its reshapes over time (issue 28): a part the coordinator core owns.
Pure: no clock, no I/O; time is ``now_s``.

Theory of operation
-------------------
:class:`Reshaper` owns the *settled* formation (the scenario's, or the target of the last
reshape over) and at most one running :class:`~coordinator.core.reshape.Transition`:

=========  =======================================================  ============================
state      what the slots are                                        left by
=========  =======================================================  ============================
settled    the settled formation                                    a reshape asked (:meth:`ask`)
pending    the settled formation; the plan starts at the next tick  the next tick (:meth:`advance`)
running    the plan's offsets at ``now - t0`` (:meth:`offsets`)       its end: the target becomes
                                                                     the settled formation at the
                                                                     tick after
=========  =======================================================  ============================

A reshape asked while one runs is planned from the offsets the slots have (no jump) and
replaces it. The number of slots may change (``slots``): fewer drops the rearmost slots at the
end of the transition, more adds slots that stay where they end (coordinator.core.reshape).

**Replication** (a standby that takes over mid-reshape). The active instance publishes
:meth:`state` in its ``leader`` message while a reshape runs: the target kind, spacing and slot
count, the shape it started from, its start ``t0_s`` and its duration. A standby reads the same
operator commands and keeps each one *planned but not started* from the formation the previous
one settled into (:meth:`ask_standby`), which is what the active planned when no reshape was
running at the command. At a takeover (:meth:`take_over`) the standby starts that plan at the
active's ``t0_s`` when its parameters match the state it last read, so the slots go on from where
they were; a plan it cannot match (a reshape asked during a reshape starts from offsets the
standby never saw, or it missed the command) is re-planned from the settled formation when the
state says so, and else taken as done at once (counted by the caller; docs/operate.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Final

import numpy as np

from coordinator.core.formation import FormationSpec
from coordinator.core.reshape import Transition, plan_reshape

__all__ = ["DURATION_TOL_S", "MID_RESHAPE", "ReshapeState", "Reshaper"]

MID_RESHAPE: Final = "reshape"
"""The :attr:`ReshapeState.source` of a reshape asked while another one ran (it starts from the
offsets the slots had then, which only the active instance saw)."""

DURATION_TOL_S: Final = 1e-9
"""A standby's plan matches the active's when their durations agree within this (s): the same
inputs give the same plan, so only float noise of another machine may differ."""


@dataclass(frozen=True)
class ReshapeState:
    """What a standby needs to continue a running reshape (the ``leader`` message's fields)."""

    kind: str
    spacing_m: float
    slots: int
    t0_s: float
    """Start of the transition (s, the active's tick clock)."""
    duration_s: float
    source: str | None = None
    """The shape it started from (None: the scenario's formation; :data:`MID_RESHAPE`: from
    where another reshape had brought the slots)."""

    def matches(self, plan: Transition, source: str | None) -> bool:
        """Is ``plan`` (started from ``source``) the reshape this state describes?"""
        return (
            plan.kind == self.kind
            and plan.spacing_m == self.spacing_m
            and plan.slots == self.slots
            and source == self.source
            and abs(plan.duration_s - self.duration_s) <= DURATION_TOL_S
        )


class Reshaper:
    """The settled formation and the reshape running over it (module docstring)."""

    def __init__(self, formation: FormationSpec) -> None:
        self.formation = formation
        """The settled formation (no reshape running, or the one a running reshape left)."""
        self.shape: str | None = None
        """The kind of the last reshape asked (None: the scenario's formation)."""
        self.transition: Transition | None = None
        self.t0_s: float | None = None
        self.source: str | None = None
        """The shape the running (or pending) reshape started from."""
        self.reshapes: list[dict[str, Any]] = []
        """One record per reshape completed: kind, spacing, slot count, start, transition time
        and the least slot separation along it."""
        self._pending: Transition | None = None
        self._done = False
        self._last_now: float | None = None

    @property
    def running(self) -> FormationSpec:
        """The formation the slots are in now (a running reshape's rows)."""
        return self.transition.spec if self.transition is not None else self.formation

    @property
    def slots(self) -> int:
        """Number of slots once what is asked is over."""
        plan = self._pending or self.transition
        return len(plan.target) if plan is not None else len(self.formation)

    @property
    def spacing_m(self) -> float:
        """The settled formation's spacing (m): its least distance between two slots (0.4 m for
        a single slot): what a reshape that names none keeps."""
        off = self.formation.body_offsets_m.tolist()
        gaps = [math.dist(a, b) for i, a in enumerate(off) for b in off[i + 1 :]]
        return min(gaps, default=0.4)

    @property
    def fraction(self) -> float | None:
        """Fraction of the running reshape done (None: none running)."""
        tr, t0, now = self.transition, self.t0_s, self._last_now
        if tr is None or t0 is None or now is None:
            return None
        return min(max((now - t0) / tr.duration_s, 0.0), 1.0)

    def state(self) -> ReshapeState | None:
        """The running reshape as a standby needs it (None: none running)."""
        tr, t0 = self.transition, self.t0_s
        if tr is None or t0 is None:
            return None
        return ReshapeState(tr.kind, tr.spacing_m, tr.slots, t0, tr.duration_s, self.source)

    # -- asking ----------------------------------------------------------------------------------

    def ask(
        self,
        kind: str,
        spacing_m: float,
        safety_m: float,
        slots: int | None = None,
        robots: int | None = None,
    ) -> str | None:
        """Reshape into ``kind`` with ``slots`` slots (None: as many as now) ``spacing_m`` apart,
        never closer than ``safety_m`` (m); starts at the next tick. Returns why it is refused
        (``too_many_slots``: more than the ``robots`` alive; ``bad_slots``, ``bad_shape``,
        ``unsafe``: coordinator.core.reshape), or None."""
        if slots is not None and robots is not None and slots > robots:
            return "too_many_slots"
        self._settle()
        tr = self.transition
        running, current = self.formation, None
        if tr is not None and self._last_now is not None and self.t0_s is not None:
            running, current = tr.spec, tr.progress(self._last_now - self.t0_s)[0]
        n = self.slots if slots is None else slots
        plan = plan_reshape(running, kind, spacing_m, safety_m, current, n)
        if isinstance(plan, str):
            return plan
        if self._pending is None:
            self.source = self.shape if tr is None else MID_RESHAPE
        self._pending = plan
        self.shape = kind
        return None

    def ask_standby(
        self,
        kind: str,
        spacing_m: float,
        safety_m: float,
        slots: int | None = None,
        robots: int | None = None,
    ) -> str | None:
        """A standby's :meth:`ask`: the previous reshape asked is taken as settled, this one is
        planned from there and kept pending until a takeover (module docstring)."""
        self.finish()
        return self.ask(kind, spacing_m, safety_m, slots, robots)

    def finish(self) -> None:
        """Take what is asked or running as done at once."""
        plan = self._pending or self.transition
        if plan is not None:
            self.formation = plan.target
        self._pending = self.transition = self.t0_s = None
        self._done = False

    def take_over(self, state: ReshapeState | None, safety_m: float) -> str:
        """This instance becomes active; ``state``: the running reshape of the previous active
        (its last ``leader`` message), None if none ran. Returns what was done: ``none``,
        ``continued`` (the plan starts at ``state.t0_s``), ``replanned`` (the same, from a plan
        made now from the settled formation) or ``finished`` (taken as done at once)."""
        plan, source = self._pending, self.source
        if state is None:
            if plan is None:
                return "none"
            self.finish()
            return "finished"
        if plan is None or not state.matches(plan, source):
            again = plan_reshape(
                self.formation, state.kind, state.spacing_m, safety_m, None, state.slots
            )
            if (
                isinstance(again, Transition)
                and state.source != MID_RESHAPE  # it started from offsets only the active saw
                and state.matches(again, state.source)
            ):
                self._pending, self.transition = None, again
                self.t0_s, self.source, self.shape = state.t0_s, state.source, state.kind
                self._done = False
                return "replanned"
            # not to be continued: the shape asked, taken as done at once (this standby's own
            # plan of the same command if it has one, else the one made now)
            asked = plan is not None and (plan.kind, plan.spacing_m, plan.slots) == (
                state.kind,
                state.spacing_m,
                state.slots,
            )
            if not asked and isinstance(again, Transition):
                self._pending = again
            self.shape = state.kind
            self.finish()
            return "finished"
        self._pending, self.transition, self.t0_s = None, plan, state.t0_s
        self._done = False
        return "continued"

    # -- the tick ------------------------------------------------------------------------------

    def _settle(self) -> None:
        if self._done and self.transition is not None:
            self.formation = self.transition.target
            self.transition = self.t0_s = None
        self._done = False

    def advance(self, now_s: float) -> Transition | None:
        """At a tick at ``now_s``: a reshape over at the last tick settles, a pending one starts;
        the reshape running now, or None."""
        self._last_now = now_s
        if self._done:  # (else _settle has nothing to do: a Python call spared every tick)
            self._settle()
        if self._pending is not None:
            self.transition, self._pending, self.t0_s = self._pending, None, now_s
        return self.transition

    def offsets(self, now_s: float) -> tuple[np.ndarray, np.ndarray]:
        """Offsets and rates of the running reshape's slots at ``now_s`` (rows of its ``spec``);
        at its end it is recorded and settles at the next tick."""
        tr, t0 = self.transition, self.t0_s
        assert tr is not None and t0 is not None
        off, rates, done = tr.progress(now_s - t0)
        if done and not self._done:
            self._done = True
            self.reshapes.append(
                {
                    "kind": tr.kind,
                    "spacing_m": tr.spacing_m,
                    "slots": tr.slots,
                    "dropped": list(tr.dropped),
                    "added": list(tr.added),
                    "started_s": t0,
                    "transition_s": tr.duration_s,
                    "least_separation_m": tr.least_separation_m
                    if math.isfinite(tr.least_separation_m)
                    else None,
                    "schedule": tr.schedule,
                }
            )
        return off, rates
