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
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

__all__ = ["MAX_PEERS", "STANDBY_SETTLE_S", "Election", "Peer", "Takeover", "rank"]

STANDBY_SETTLE_S: Final = 0.3
"""A standby decides nothing during this long after it started watching (s)."""
MAX_PEERS: Final = 64
"""Distinct coordinator instance names tracked (made-up names cannot grow memory)."""


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
        self.started_s: float | None = None
        self.takeovers = 0
        self.stepdowns = 0

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
        return True

    def heartbeat(self, name: str, active: bool, epoch: int, leader_t0: float) -> str | None:
        """Instance ``name``'s heartbeat; returns why this instance must step down, or None."""
        if name == self.name:
            return None
        peer = self._peer(name)
        if peer is None:
            return None
        peer.active = active
        peer.epoch = epoch
        if active:
            peer.leader_t0 = leader_t0
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
        """Become active: the next epoch and the trajectory origin to continue."""
        known = [p for p in self.peers.values() if p.leader_t0 is not None]
        self.epoch = max([self.epoch, *(p.epoch for p in self.peers.values())]) + 1
        t0 = max(known, key=lambda p: p.epoch).leader_t0 if known else None
        self.active = True
        self.takeovers += 1
        return Takeover(self.epoch, t0)

    def step_down(self, now_s: float) -> bool:
        """Become a standby at ``now_s`` (the settle time restarts); False if already one."""
        if not self.active:
            return False
        self.active = False
        self.stepdowns += 1
        self.started_s = now_s
        return True
