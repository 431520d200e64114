"""The standby election of coordinator instances: a pure core, time passed in, typed peers.

Several coordinator instances may run; exactly one is *active* (ticks and publishes), the others
are hot standbys (docs/faults.md). Every instance publishes a heartbeat (``active``, ``epoch``,
``leader_t0``) and watches the others' liveliness tokens and heartbeats; this module decides
from those observations, and the shell (``coordinator/node/coordinator.py``) acts on the decisions.

Rules:

* A standby decides nothing for ``settle_s`` after it started watching (or stepped down), so the
  tokens and heartbeats of the instances already running have arrived.
* It takes over only when no live instance is active or of unknown role (token present, no
  heartbeat yet) and no live standby comes before it in :func:`rank` order (``main`` first, then
  by name). It then takes ``epoch`` = the highest seen + 1 and the trajectory origin it adopted
  (``leader_t0``, checked as below), so the virtual leader continues without a jump.
* Two actives (a split brain, or two instances started without ``--standby``): on the other's
  heartbeat, the one with the lower epoch, then the later name, steps down.

Hardening (no single message hijacks the election; issue 13): a heartbeat is *refused* (counted
in :attr:`Election.rejects` by reason, no effect on the election) when

* ``no_token``: its sender has no liveliness token (a forger's made-up name, or a peer whose
  token is gone): only processes that hold a token take part;
* ``epoch_jump``: its epoch exceeds the highest epoch this instance knows by more than
  :data:`EPOCH_JUMP_MAX` (epochs grow by one per takeover; a forged ``EPOCH_MAX`` is refused).
  The very first heartbeat an instance accepts sets that baseline (a standby joining a fleet
  at epoch 40 must learn it), so the bound applies from then on. Epochs are monotonic: what
  this instance knows of a peer's epoch (and its own) never goes down; a lower one (a forged
  one, or a peer's older heartbeat) is no step back, and refusing it would let one forged
  in-bound epoch lock the real peer's heartbeats out;
* ``epoch_rate``: it would raise the highest epoch known faster than :data:`EPOCH_RATE_PER_S`
  allows (a token bucket of :data:`EPOCH_JUMP_MAX` epochs refilled at that rate; the first
  accepted heartbeat sets the baseline for free). Without it a forger holding a coordinator
  token could push the epoch to ``EPOCH_MAX`` at +16 per accepted heartbeat (seconds); with it
  that takes years. A real peer's rise refused this way is accepted a fraction of a second later;
* ``leader_t0``: an *active* heartbeat whose trajectory origin disagrees with the running
  trajectory. While this instance ticks, the running trajectory is its own (origin
  :attr:`Election.leader_t0`, within :data:`LEADER_T0_TOL_S`). As a standby, it is what the
  ``leader`` messages say (:meth:`Election.observe_leader`): the trajectory is a pure function
  of time, so an origin ``t0`` is *verified* when every ``leader`` message received in the last
  :data:`LEADER_CHECK_AGE_S` (at least :data:`LEADER_CHECK_MIN` of them) lies where the
  trajectory puts the leader at ``t - t0`` (within :data:`LEADER_POS_TOL_M`); it *disagrees*
  when one of them does not. A standby adopts only a verified origin (the latest one), so no
  heartbeat, nor any single forged ``leader`` message (it only blocks a verification while it
  is recent), gives it an origin that would move the virtual leader at a takeover. A heartbeat
  whose origin can be neither verified nor refuted (no recent ``leader`` message yet) is
  accepted for its role and epoch, its origin is not adopted. Only the split-brain rule still
  looks at a refused heartbeat from a live, in-bound peer while this instance is active (two
  instances started apart without ``--standby`` have different origins and one must stop); the
  one that steps down keeps its own origin until it verifies the other's.

Without a ``position_at`` (the trajectory), a standby cannot verify: it then adopts the origin
of the first active heartbeat it accepts and refuses any other (the rule before issue 13's
spoofing fix, kept for cores built without a trajectory). A standby that has a trajectory but
has *never* received a ``leader`` message (lockstep, where it does not subscribe, or an access
control that does not let it read ``leader``) falls back to the same rule at a takeover rather
than restart the trajectory (spoofable on an unauthenticated bus, like the old rule, but such a
standby has nothing to check with; a verified origin always replaces the fallback). A standby
that takes over before it could verify any origin (the active died within a few ``leader``
messages of the standby's start) uses the latest origin of an accepted active heartbeat that
agrees with *every* ``leader`` message it holds (at least one): only an origin that keeps the
leader where it was can pass.

Epochs saturate at :data:`bus_schemas.fields.EPOCH_MAX` (never an overflow; at equal epochs the
rank decides), so a heartbeat always encodes.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Final

from bus_schemas.fields import EPOCH_MAX

__all__ = [
    "EPOCH_JUMP_MAX",
    "EPOCH_RATE_PER_S",
    "LEADER_CHECK_AGE_S",
    "LEADER_CHECK_MIN",
    "LEADER_POS_TOL_M",
    "LEADER_T0_TOL_S",
    "MAX_PEERS",
    "STANDBY_SETTLE_S",
    "Election",
    "Peer",
    "PositionAt",
    "Takeover",
    "rank",
]

STANDBY_SETTLE_S: Final = 0.3
"""A standby decides nothing during this long after it started watching (s)."""
MAX_PEERS: Final = 64
"""Distinct coordinator instance names tracked (made-up names cannot grow memory)."""
EPOCH_JUMP_MAX: Final = 16
"""Largest accepted step of an epoch above the highest one known. One takeover adds 1 and a
takeover needs a token to vanish (milliseconds to a lease), so between two 10 Hz heartbeats a
real fleet moves by 1 or 2; 16 leaves room for a partition healing and refuses any forged
jump to ``EPOCH_MAX`` (2^31 / 16 accepted steps would be needed). It is also the depth of the
epoch-rate bucket (:data:`EPOCH_RATE_PER_S`)."""
EPOCH_RATE_PER_S: Final = 10.0
"""Long-run bound of the rise of the highest epoch known (epochs per second, a token bucket of
:data:`EPOCH_JUMP_MAX`). Why 10: an epoch rises by one per takeover, and an instance that took
over can take over again only after it stepped down and watched for ``STANDBY_SETTLE_S``
(0.3 s) with no live active, so each instance adds at most ~3.3 epochs/s; 10/s covers three
instances flapping at that impossible worst rate. A forger holding a token then needs
2^31 / 10 s (6.8 years) to reach ``EPOCH_MAX``, instead of 2^31 / 16 heartbeats (hours at the
rate a token-holding forger can get accepted)."""
LEADER_T0_TOL_S: Final = 1e-3
"""Largest accepted difference (s) between an active heartbeat's ``leader_t0`` and this active
instance's own origin. Heartbeats carry the float unchanged, so a real active agrees exactly;
1 ms is slack only."""
LEADER_POS_TOL_M: Final = 1e-3
"""Largest distance (m) between a ``leader`` message's position and the trajectory's position
for a candidate origin. Both sides evaluate the same pure function on the same floats, so a
real active's messages agree to ~1e-12 m; 1 mm is slack only, and far below what a moved
origin shows (a trajectory at 0.02 m/s differs by 1 mm after 50 ms of origin shift)."""
LEADER_CHECK_AGE_S: Final = 1.0
"""``leader`` messages received within this long (s, the election's clock) verify an origin."""
LEADER_CHECK_MIN: Final = 3
"""Fewest recent ``leader`` messages that verify an origin (the active publishes 50 per s)."""
LEADER_WINDOW: Final = 64
"""``leader`` messages kept for the check (the newest; memory is bounded)."""

PositionAt = Callable[[float], tuple[float, float]]
"""The virtual leader's position (x, y in m) at trajectory time ``t - t0`` (s)."""


def rank(name: str) -> tuple[int, str]:
    """Election order of instance names: ``main`` first, then by name."""
    return (0 if name == "main" else 1, name)


@dataclass
class Peer:
    """What this instance knows of another one."""

    alive: bool = False
    """Its liveliness token is present."""
    active: bool | None = None
    """Its role from its last heartbeat; None until the first heartbeat after (re)appearing."""
    epoch: int = 0
    leader_t0: float | None = None
    """Trajectory time origin from its last accepted heartbeat as active (s, the heartbeat's
    clock); with a trajectory to check it, only a verified one."""


@dataclass(frozen=True)
class Takeover:
    """The decision to become active."""

    epoch: int
    leader_t0: float | None
    """Origin of the trajectory to continue (None: start at this tick)."""


class Election:
    """State of the election as seen by instance ``name``.

    ``position_at``: the virtual leader's position at a trajectory time (the scenario's
    trajectory, a pure function); with it a standby verifies origins against the ``leader``
    messages it observes (module docstring)."""

    def __init__(
        self,
        name: str,
        *,
        active: bool,
        settle_s: float = STANDBY_SETTLE_S,
        position_at: PositionAt | None = None,
    ) -> None:
        self.name = name
        self.active = active
        self.epoch = 0
        self.settle_s = settle_s
        self.position_at = position_at
        self.peers: dict[str, Peer] = {}
        self.last_refusal: str | None = None
        self.started_s: float | None = None
        self.takeovers = 0
        self.stepdowns = 0
        self.leader_t0: float | None = None
        """The trajectory origin this instance continues (its own, or a verified one)."""
        self.max_epoch: int | None = None
        """Highest epoch known (own or accepted); None before the first accepted heartbeat."""
        self.rejects: dict[str, int] = {}
        """Refused heartbeats by reason (module docstring)."""
        self._leaders: deque[tuple[float, float, float, float]] = deque(maxlen=LEADER_WINDOW)
        """Recent ``leader`` messages: (t, x, y, received at)."""
        self._bucket = float(EPOCH_JUMP_MAX)
        self._bucket_s: float | None = None
        self._leaders_seen = False
        self._candidates: deque[float] = deque(maxlen=8)
        """Origins of active heartbeats accepted unverified (latest last)."""
        self._fallback_t0: float | None = None
        """Origin of the first active heartbeat accepted unverified (used only if no ``leader``
        message was ever observed)."""

    def observe_t0(self, leader_t0: float) -> None:
        """This instance started ticking with the trajectory origin ``leader_t0`` (its own)."""
        self.leader_t0 = leader_t0

    def observe_leader(self, t: float, x: float, y: float, now_s: float) -> None:
        """A ``leader`` message (stamp ``t``, position ``x``, ``y``) received at ``now_s``."""
        if math.isfinite(t) and math.isfinite(x) and math.isfinite(y):
            self._leaders.append((t, x, y, now_s))
            self._leaders_seen = True

    def origin_verdict(self, leader_t0: float, now_s: float) -> bool | None:
        """Does origin ``leader_t0`` agree with the ``leader`` messages of the last
        :data:`LEADER_CHECK_AGE_S`? True: every one of them (at least
        :data:`LEADER_CHECK_MIN`); False: one of them disagrees; None: too few to tell (or no
        trajectory to check with)."""
        position_at = self.position_at
        if position_at is None:
            return None
        recent = [o for o in self._leaders if 0.0 <= now_s - o[3] <= LEADER_CHECK_AGE_S]
        for t, x, y, _ in recent:
            try:
                px, py = position_at(t - leader_t0)
            except (ArithmeticError, ValueError):
                return False
            if not math.hypot(px - x, py - y) <= LEADER_POS_TOL_M:  # NaN disagrees too
                return False
        return True if len(recent) >= LEADER_CHECK_MIN else None

    def _refuse(self, why: str) -> str:
        self.rejects[why] = self.rejects.get(why, 0) + 1
        return why

    def _known_epoch(self) -> int | None:
        if self.max_epoch is None:
            return None if self.epoch == 0 and not self.active else self.epoch
        return max(self.max_epoch, self.epoch)

    def _epoch_budget(self, now_s: float) -> float:
        """Epochs the highest known one may still rise by at ``now_s`` (the token bucket)."""
        if self._bucket_s is not None and now_s > self._bucket_s:
            self._bucket = min(
                float(EPOCH_JUMP_MAX), self._bucket + EPOCH_RATE_PER_S * (now_s - self._bucket_s)
            )
        if self._bucket_s is None or now_s > self._bucket_s:
            self._bucket_s = now_s
        return self._bucket

    def start(self, now_s: float) -> None:
        """Watching began (or restarts after a step-down) at ``now_s``: the settle time runs."""
        self.started_s = now_s

    def _peer(self, name: str) -> Peer | None:
        peer = self.peers.get(name)
        if peer is None and len(self.peers) < MAX_PEERS:
            peer = self.peers[name] = Peer()
        return peer

    def peer_alive(self, name: str, alive: bool) -> bool:
        """Instance ``name``'s token appeared or vanished; True if that changed its liveness."""
        if name == self.name:
            return False
        peer = self._peer(name)
        if peer is None or peer.alive == alive:
            return False
        peer.alive = alive
        if alive:
            peer.active = None  # a (re)started instance: unknown role until its heartbeat
            peer.epoch = 0
        return True

    def _origin_refused(self, leader_t0: float, now_s: float) -> tuple[bool, bool]:
        """(refused, verified) for an active heartbeat's origin (module docstring)."""
        if self.active or self.position_at is None:
            observed = self.leader_t0
            if observed is None:
                return False, not self.active  # no trajectory to check with: first one wins
            return abs(leader_t0 - observed) > LEADER_T0_TOL_S, False
        verdict = self.origin_verdict(leader_t0, now_s)
        return verdict is False, verdict is True

    def heartbeat(
        self, name: str, active: bool, epoch: int, leader_t0: float, *, now_s: float
    ) -> str | None:
        """Instance ``name``'s heartbeat received at ``now_s``; returns why this instance must
        step down, or None.

        A refused heartbeat (module docstring) changes nothing and is counted in
        :attr:`rejects`; :attr:`last_refusal` says why (None if it was accepted)."""
        self.last_refusal = None
        if name == self.name:
            return None
        peer = self.peers.get(name)
        if peer is None or not peer.alive:
            self.last_refusal = self._refuse("no_token")
            return None
        known = self._known_epoch()
        rise = 0 if known is None else epoch - known
        if rise > EPOCH_JUMP_MAX:
            self.last_refusal = self._refuse("epoch_jump")
            return None
        if rise > 0 and rise > self._epoch_budget(now_s):
            self.last_refusal = self._refuse("epoch_rate")
            return None
        refused, verified = self._origin_refused(leader_t0, now_s) if active else (False, False)
        if refused:
            self.last_refusal = self._refuse("leader_t0")
            # Split brain only: a live, in-bound peer that outranks this active instance still
            # makes it stop (two actives must not both drive the robots); its origin is not
            # adopted, so a later takeover continues the trajectory this instance ran.
            if self.active and (epoch, rank(self.name)) > (self.epoch, rank(name)):
                return f"coordinator {name} is active with epoch {epoch} (another origin)"
            return None
        if rise > 0:
            self._bucket -= rise
        peer.active = active
        peer.epoch = max(peer.epoch, epoch)  # monotonic: a lower one (forged or not) is no step
        self.max_epoch = epoch if self.max_epoch is None else max(self.max_epoch, epoch)
        if active:
            if verified or self.active:
                peer.leader_t0 = leader_t0
            if verified:
                self.leader_t0 = leader_t0  # the running trajectory's origin
            elif not self.active:
                if self._fallback_t0 is None:
                    self._fallback_t0 = leader_t0
                if leader_t0 not in self._candidates:
                    self._candidates.append(leader_t0)
            if self.active and (epoch, rank(self.name)) > (self.epoch, rank(name)):
                return f"coordinator {name} is active with epoch {epoch}"
        return None

    def should_take_over(self, now_s: float) -> bool:
        """A standby's decision at ``now_s`` (see the module docstring)."""
        if self.active or self.started_s is None:
            return False
        if now_s - self.started_s < self.settle_s:
            return False
        live = {n: p for n, p in self.peers.items() if p.alive}
        if any(p.active is not False for p in live.values()):
            return False  # an active one, or one whose role we do not know yet
        return not any(rank(n) < rank(self.name) for n in live)

    def take_over(self) -> Takeover:
        """Become active: the next epoch (saturating at ``EPOCH_MAX``) and the trajectory origin
        to continue (its own or the last verified one; None: none, start at this tick)."""
        highest = max([self.epoch, self.max_epoch or 0])
        self.epoch = min(highest + 1, EPOCH_MAX)
        self.max_epoch = self.epoch
        self.active = True
        self.takeovers += 1
        if self.leader_t0 is None:
            self.leader_t0 = self._unverified_origin()
        return Takeover(self.epoch, self.leader_t0)

    def _unverified_origin(self) -> float | None:
        """At a takeover with no verified origin (module docstring): the latest candidate that
        agrees with every ``leader`` message held, or with nothing observed the first
        heartbeat's origin, else None."""
        if not self._leaders_seen:
            return self._fallback_t0
        position_at = self.position_at
        if position_at is None or not self._leaders:
            return None
        for t0 in reversed(self._candidates):
            try:
                ok = all(
                    math.hypot(px - x, py - y) <= LEADER_POS_TOL_M
                    for t, x, y, _ in self._leaders
                    for px, py in (position_at(t - t0),)
                )
            except (ArithmeticError, ValueError):
                ok = False
            if ok:
                return t0
        return None

    def step_down(self, now_s: float) -> bool:
        """Become a standby at ``now_s`` (the settle time restarts); False if already one."""
        if not self.active:
            return False
        self.active = False
        self.stepdowns += 1
        self.started_s = now_s
        return True
