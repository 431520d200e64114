"""The standby election of coordinator instances: a pure core, time passed in, typed peers.

Several coordinator instances may run; exactly one is *active* (ticks and publishes), the others
are hot standbys (docs/faults.md). Every instance publishes a heartbeat (``active``, ``epoch``,
``leader_t0``) and watches the others' liveliness tokens and heartbeats; this module decides
from those observations, and the shell (``coordinator/node.py``) acts on the decisions.

Rules:

* A standby decides nothing for ``settle_s`` after it started watching (or stepped down), so the
  tokens and heartbeats of the instances already running have arrived.
* It takes over only when no live instance is active or of unknown role (token present, no
  heartbeat yet) and no live standby comes before it in :func:`rank` order (``main`` first, then
  by name). It then takes ``epoch`` = the highest seen + 1 and the ``leader_t0`` of the
  highest-epoch instance that was active, so the virtual leader continues without a jump.
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
* ``leader_t0``: an *active* heartbeat whose ``leader_t0`` differs by more than
  :data:`LEADER_T0_TOL_S` from the trajectory origin this instance has observed (its own while
  it ticks, else the first active heartbeat it accepted): the virtual leader is never moved.
  Only the split-brain rule still looks at such a heartbeat from a live, in-bound peer (two
  instances started apart without ``--standby`` have different origins and one must stop); the
  one that steps down keeps its own observed origin, so a takeover never adopts a disagreeing
  one.

Epochs saturate at :data:`bus_schemas.fields.EPOCH_MAX` (never an overflow; at equal epochs the
rank decides), so a heartbeat always encodes.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

from bus_schemas.fields import EPOCH_MAX

__all__ = [
    "EPOCH_JUMP_MAX",
    "LEADER_T0_TOL_S",
    "MAX_PEERS",
    "STANDBY_SETTLE_S",
    "Election",
    "Peer",
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
jump to ``EPOCH_MAX`` (2^31 / 16 accepted steps would be needed)."""
LEADER_T0_TOL_S: Final = 1e-3
"""Largest accepted difference (s) between a heartbeat's ``leader_t0`` and the observed one.
Heartbeats carry the float unchanged, so a real active agrees exactly; 1 ms is slack only."""


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
    """Trajectory time origin from its last heartbeat as active (s, the heartbeat's clock)."""


@dataclass(frozen=True)
class Takeover:
    """The decision to become active."""

    epoch: int
    leader_t0: float | None
    """Origin of the trajectory to continue (None: start at this tick)."""


class Election:
    """State of the election as seen by instance ``name``."""

    def __init__(self, name: str, *, active: bool, settle_s: float = STANDBY_SETTLE_S) -> None:
        self.name = name
        self.active = active
        self.epoch = 0
        self.settle_s = settle_s
        self.peers: dict[str, Peer] = {}
        self.last_refusal: str | None = None
        self.started_s: float | None = None
        self.takeovers = 0
        self.stepdowns = 0
        self.leader_t0: float | None = None
        """The trajectory origin this instance observed (its own, or the active's)."""
        self.max_epoch: int | None = None
        """Highest epoch known (own or accepted); None before the first accepted heartbeat."""
        self.rejects: dict[str, int] = {}
        """Refused heartbeats by reason (module docstring)."""

    def observe_t0(self, leader_t0: float) -> None:
        """This instance started ticking with the trajectory origin ``leader_t0`` (its own)."""
        self.leader_t0 = leader_t0

    def _refuse(self, why: str) -> str:
        self.rejects[why] = self.rejects.get(why, 0) + 1
        return why

    def _known_epoch(self) -> int | None:
        if self.max_epoch is None:
            return None if self.epoch == 0 and not self.active else self.epoch
        return max(self.max_epoch, self.epoch)

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

    def heartbeat(self, name: str, active: bool, epoch: int, leader_t0: float) -> str | None:
        """Instance ``name``'s heartbeat; returns why this instance must step down, or None.

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
        if known is not None and epoch > known + EPOCH_JUMP_MAX:
            self.last_refusal = self._refuse("epoch_jump")
            return None
        observed = self.leader_t0
        if active and observed is not None and abs(leader_t0 - observed) > LEADER_T0_TOL_S:
            self.last_refusal = self._refuse("leader_t0")
            # Split brain only: a live, in-bound peer that outranks this active instance still
            # makes it stop (two actives must not both drive the robots); its origin is not
            # adopted, so a later takeover continues the trajectory observed here.
            if self.active and (epoch, rank(self.name)) > (self.epoch, rank(name)):
                return f"coordinator {name} is active with epoch {epoch} (another origin)"
            return None
        peer.active = active
        peer.epoch = max(peer.epoch, epoch)  # monotonic: a lower one (forged or not) is no step
        self.max_epoch = epoch if self.max_epoch is None else max(self.max_epoch, epoch)
        if active:
            peer.leader_t0 = leader_t0
            if observed is None and not self.active:
                self.leader_t0 = leader_t0
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
        to continue (the observed one; None: none was observed, start at this tick)."""
        highest = max([self.epoch, self.max_epoch or 0])
        self.epoch = min(highest + 1, EPOCH_MAX)
        self.max_epoch = self.epoch
        self.active = True
        self.takeovers += 1
        return Takeover(self.epoch, self.leader_t0)

    def step_down(self, now_s: float) -> bool:
        """Become a standby at ``now_s`` (the settle time restarts); False if already one."""
        if not self.active:
            return False
        self.active = False
        self.stepdowns += 1
        self.started_s = now_s
        return True
