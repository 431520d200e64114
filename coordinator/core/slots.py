"""One slot of a formation: its declaration (``SlotSpec``: parent, distance ``b``, angle ``phi``,
stage, role) and its state at a time (``SlotState``: position, heading, feed-forward velocity),
with the role names and the checks the formation table uses.

Split out of formation.py (issue 12) so formation.py reads as the formation tree, its geometry
(paper eqs 3-5) and its staged growth; every name here is still importable from
``coordinator.core.formation``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Final

import numpy as np

ROLES: Final = ("leader", "subleader", "follower")


LEADER_SLOT: Final = 0


FORMATION_KINDS: Final = ("triangle", "chevron", "lattice", "explicit")


def _is_int(v: object) -> bool:
    return isinstance(v, int | np.integer) and not isinstance(v, bool)


def _finite(owner: str, name: str, v: object) -> float:
    if isinstance(v, bool) or not isinstance(v, int | float | np.integer | np.floating):
        raise ValueError(f"{owner}: {name} must be a number, got {v!r}")
    f = float(v)
    if not math.isfinite(f):
        raise ValueError(f"{owner}: {name} must be finite, got {v!r}")
    return f


@dataclass(frozen=True, slots=True)
class SlotSpec:
    """One slot of a formation.

    ``slot``: id (>= 0; 0 = virtual leader). ``parent``: the slot it hangs off (None for slot 0).
    ``b_m``: distance to the parent, m (> 0; 0 for the leader). ``phi_rad``: the angle phi of eq 3.
    ``stage``: depth in the tree (0 for the leader). ``role``: one of :data:`ROLES`.
    """

    slot: int
    parent: int | None
    b_m: float
    phi_rad: float
    stage: int
    role: str

    def __post_init__(self) -> None:
        owner = f"SlotSpec(slot={self.slot!r})"
        if not _is_int(self.slot) or self.slot < 0:
            raise ValueError(f"{owner}: slot must be an int >= 0")
        if self.parent is not None and (not _is_int(self.parent) or self.parent < 0):
            raise ValueError(f"{owner}: parent must be None or an int >= 0, got {self.parent!r}")
        if not _is_int(self.stage) or self.stage < 0:
            raise ValueError(f"{owner}: stage must be an int >= 0, got {self.stage!r}")
        if self.role not in ROLES:
            raise ValueError(f"{owner}: role must be one of {ROLES}, got {self.role!r}")
        object.__setattr__(self, "slot", int(self.slot))
        object.__setattr__(self, "parent", None if self.parent is None else int(self.parent))
        object.__setattr__(self, "stage", int(self.stage))
        object.__setattr__(self, "b_m", _finite(owner, "b_m", self.b_m))
        object.__setattr__(self, "phi_rad", _finite(owner, "phi_rad", self.phi_rad))


@dataclass(frozen=True, slots=True)
class SlotState:
    """Where a slot is at one instant: the setpoint of the robot assigned to it.

    ``x``, ``y`` (m) are where that robot's reference point (eqs 10-11) should be; ``theta`` (rad)
    is the formation heading; ``vx``, ``vy`` (m/s) the feed-forward velocity.
    """

    slot: int
    role: str
    stage: int
    parent: int | None
    x: float
    y: float
    theta: float
    vx: float
    vy: float


def _role(slot: int, has_children: bool) -> str:
    if slot == LEADER_SLOT:
        return "leader"
    return "subleader" if has_children else "follower"


def _count(owner: str, n: object) -> int:
    if isinstance(n, bool) or not isinstance(n, int | np.integer) or int(n) < 1:
        raise ValueError(
            f"{owner}: n (number of slots, leader included) must be an int >= 1, got {n!r}"
        )
    return int(n)
