"""What this process knows of the other robots: their latest poses and which are cooperative.

Pure and stdlib only, time passed in. One table serves ``formation agent`` (one robot) and
``formation agent-host`` (many robots): the shells decode the pose frames and the status
messages and write here; the firmware's neighbour list is read back by the rules of
:mod:`robot_agent.core.neighbours` (:meth:`NeighbourTable.neighbours` for the agent; the host's
spatial hash :class:`robot_agent.core.host_grid.NeighbourGrid` reads :attr:`NeighbourTable.seen`
and :meth:`NeighbourTable.cooperative`).

* **Poses** (rule 1 and 2): :meth:`~NeighbourTable.store` keeps each robot's latest pose with its
  capture time on the local clock and its receive time; in lockstep a pose is *pending* (receive
  time None) until the next clock, whose ``t`` :meth:`~NeighbourTable.settle` makes its receive
  time. At most ``max_robots`` ids are kept: when full, stale ones go first, then new ids are
  dropped (a flood of made-up ids cannot grow memory).
* **Cooperative** (rule 3): in lockstep the ids the clock relays (:meth:`~NeighbourTable.relay`);
  in realtime a robot run by this process says its own mode (``local_tracking``), any other
  robot's latest status said TRACKING and is fresh (:meth:`~NeighbourTable.note_mode`).
* **Motion claims** (rule 4): with ``motion`` (the robots enforce motion bounds), each robot's
  latest claims, their tick times on the local clock (:meth:`~NeighbourTable.note_claim`); the
  entries carry their view (:func:`robot_agent.core.neighbour_motion.motion_view`).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping

from robot_agent.core.host_grid import Seen
from robot_agent.core.lockstep import Arrivals
from robot_agent.core.neighbour_motion import Claim, MotionView, motion_view
from robot_agent.core.neighbours import (
    NEIGHBOUR_STALE_S,
    ClaimRing,
    is_cooperative,
    is_current,
    mover,
    neighbour,
)
from robot_agent.core.safety_filter import Neighbour

__all__ = ["LocalTracking", "NeighbourTable"]

LocalTracking = Callable[[str], "bool | None"]
"""``local_tracking(rid)``: whether robot ``rid``, run by this process, is TRACKING now; None
when this process does not run ``rid`` (its mode then comes from its status messages)."""


class NeighbourTable:
    """The other robots' latest poses (:attr:`seen`) and modes, by robot id.

    Args:
        lockstep: cooperative means relayed by the clock (else: a fresh status or the local mode).
        max_robots: distinct ids kept, for poses and for modes each.
        local_tracking: the mode of the robots this process runs (see :data:`LocalTracking`);
            their status messages are ignored. None: no robot is run here.
        motion: ``(ref_offset_m, top_speed_mps, claim_max_age_s)`` when the robots publish
            motion claims (``SafetyFilterParams.accel_bound_mps2`` > 0); None: no claims.
    """

    __slots__ = (
        "_claims",
        "_local",
        "_modes",
        "_motion",
        "_next_order",
        "_pending",
        "lockstep",
        "max_robots",
        "seen",
        "tracking_ids",
    )

    def __init__(
        self,
        *,
        lockstep: bool,
        max_robots: int,
        local_tracking: LocalTracking | None = None,
        motion: tuple[float, float, float] | None = None,
    ) -> None:
        self.lockstep = lockstep
        self._motion = motion
        self._claims: dict[str, ClaimRing] = {}  # id -> its latest claims (local clock)
        self.max_robots = max_robots
        self._local = local_tracking
        self.seen: dict[str, Seen] = {}
        """Robot id -> its latest pose, in first-seen (frame) order."""
        self._next_order = 0
        self._pending: Arrivals[Seen] = Arrivals()  # lockstep: received since the last clock
        self._modes: dict[str, tuple[bool, float]] = {}  # realtime: id -> (tracking, rx_s)
        self.tracking_ids: frozenset[str] = frozenset()
        """Lockstep: the robots the current clock relays as cooperative."""

    # -- poses -----------------------------------------------------------------------------

    def store(
        self,
        rid: str,
        x_m: float,
        y_m: float,
        theta_rad: float,
        capture_s: float,
        rx_s: float | None,
        now_s: float,
    ) -> Seen | None:
        """Keep robot ``rid``'s pose captured at ``capture_s`` and received at ``rx_s`` (local
        clock; None: pending until :meth:`settle`); ``now_s`` ages the entries pruned when the
        table is full. Returns the entry, or None when the table is full of current ids."""
        seen = self.seen
        e = seen.get(rid)
        if e is None:
            if len(seen) >= self.max_robots:
                self._prune(now_s)
                if len(seen) >= self.max_robots:
                    return None
            e = seen[rid] = Seen(x_m, y_m, theta_rad, capture_s, rx_s, self._next_order)
            self._next_order += 1
        else:
            e.x, e.y, e.theta, e.capture_s, e.rx_s = x_m, y_m, theta_rad, capture_s, rx_s
        if rx_s is None:
            self._pending.add(e)
        return e

    def end_frame(self) -> None:
        """After a frame's :meth:`store` calls: bound the pending list (no clock for ages)."""
        if len(self._pending) > 4 * self.max_robots:
            self._pending.compact(key=id)

    def settle(self, t_s: float) -> bool:
        """Lockstep clock at ``t_s``: the poses pending since the last clock count as received
        at ``t_s``. Returns whether any was pending."""
        if not self._pending:
            return False
        for e in self._pending.take():
            if e.rx_s is None:
                e.rx_s = t_s
        return True

    def clear(self) -> None:
        """Forget every pose and claim (this process resumed from a stop: old ones must not
        count)."""
        self.seen.clear()
        self._claims.clear()
        self._pending.take()

    def _prune(self, now_s: float) -> None:
        stale = [
            rid
            for rid, e in self.seen.items()
            if e.rx_s is not None and now_s - e.rx_s > NEIGHBOUR_STALE_S
        ]
        for rid in stale:
            del self.seen[rid]

    def neighbours(
        self, now_s: float, movers: Mapping[str, tuple[float, float]] | None = None
    ) -> list[Neighbour]:
        """Every robot whose pose was received within ``NEIGHBOUR_STALE_S`` of ``now_s``, in
        first-seen order, as the safety filter sees it (``robot_agent.core.neighbours``);
        ``movers``: the coordinator's moving obstacles, id -> velocity (m/s; rule 4)."""
        coop = self.cooperative
        current = [
            (rid, e)
            for rid, e in self.seen.items()
            if e.rx_s is not None and is_current(now_s, e.rx_s)
        ]
        out = [
            neighbour(
                e.x, e.y, e.theta, e.capture_s, now_s, coop(rid, now_s), self._view(rid, e, now_s)
            )
            for rid, e in current
        ]
        if movers:
            for i, (rid, _) in enumerate(current):
                v = movers.get(rid)
                if v is not None:
                    out[i] = mover(out[i], v[0], v[1])
        return out

    def _view(self, rid: str, e: Seen, now_s: float) -> MotionView | None:
        """What robot ``rid``'s motion claims say at ``now_s`` (None: no claims configured or
        kept for it, the worst case)."""
        if self._motion is None:
            return None
        ring = self._claims.get(rid)
        if ring is None:
            return None
        l_m, vmax, max_age = self._motion
        return motion_view(ring.claims, e.capture_s, now_s, l_m, vmax, max_age)

    # -- motion claims ---------------------------------------------------------------------

    def note_claim(self, rid: str, claim: Claim, now_s: float) -> bool:
        """Robot ``rid``'s motion claim (``t_s`` on the local clock), received at ``now_s``;
        False when not kept (no claims configured, the table full of current ids, or not newer
        than the last one: counted in that ring's ``dropped``)."""
        if self._motion is None:
            return False
        claims = self._claims
        ring = claims.get(rid)
        if ring is None:
            if len(claims) >= self.max_robots:
                for old in [
                    r
                    for r, g in claims.items()
                    if not g.claims or now_s - g.claims[-1].t_s > NEIGHBOUR_STALE_S
                ]:
                    del claims[old]
                if len(claims) >= self.max_robots:
                    return False
            ring = claims[rid] = ClaimRing()
        return ring.add(claim)

    # -- modes -----------------------------------------------------------------------------

    def relay(self, tracking: Iterable[str]) -> None:
        """Lockstep: the robots the current clock relays as TRACKING on the previous tick."""
        self.tracking_ids = frozenset(tracking)

    def note_mode(self, rid: str, tracking: bool, rx_s: float) -> None:
        """Realtime: robot ``rid``'s status said (``tracking``), received at ``rx_s``; ignored
        for a robot this process runs."""
        if self._local is not None and self._local(rid) is not None:
            return
        modes = self._modes
        if rid not in modes and len(modes) >= self.max_robots:
            for old in [r for r, (_, t) in modes.items() if rx_s - t > NEIGHBOUR_STALE_S]:
                del modes[old]
            if len(modes) >= self.max_robots:
                return
        modes[rid] = (tracking, rx_s)

    def cooperative(self, rid: str, now_s: float) -> bool:
        """Rule 3 of ``robot_agent.core.neighbours`` for robot ``rid`` at ``now_s``: relayed by
        the clock (lockstep); realtime, the local mode of a robot run here, else a fresh
        status saying TRACKING."""
        if self.lockstep:
            return rid in self.tracking_ids
        if self._local is not None:
            own = self._local(rid)
            if own is not None:
                return own
        entry = self._modes.get(rid)
        return entry is not None and is_cooperative(now_s, entry[0], entry[1])
