"""Formation geometry: a staged tree of slots around the virtual leader (paper eqs 3-5, Fig 2).

Slot 0 is the virtual leader. Every other slot ``i`` hangs off a parent slot ``p`` (the leader or
a sub-leader of an earlier stage) at distance ``b_i`` (m) and angle ``phi_i`` (rad), and its
position follows eqs 3-5 (corrected, see docs/paper-errata.md)::

    gamma_i = phi_i + theta_p - pi/2
    x_i = x_p - b_i cos(gamma_i)
    y_i = y_p - b_i sin(gamma_i)

With the parent heading +x, ``phi = pi/3`` puts the slot behind-left, ``pi/2`` straight behind and
``2 pi/3`` behind-right. The formation is rigid: every slot's heading is the leader's, so
``gammadot = omega`` and the feed-forward velocity used by the tracking law (eqs 21-22) is::

    vx_i = vx_p + b_i omega sin(gamma_i)
    vy_i = vy_p - b_i omega cos(gamma_i)

Roles: slot 0 is ``"leader"``; a slot with children is a ``"subleader"`` (the paper's first-stage
followers that lead the second stage); a leaf is a ``"follower"``.

A formation from a scenario table (``FormationSpec.from_dict``) is read by
:func:`coordinator.core.formation_table.read_table` and built here.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from typing import Any, Final

import numpy as np
import numpy.typing as npt

from coordinator.core.formation_table import BuilderForm, read_table
from coordinator.core.shapes import chevron_rows, grow_rows, lattice_rows
from coordinator.core.slots import (
    FORMATION_KINDS,
    LEADER_SLOT,
    ROLES,
    SlotSpec,
    SlotState,
    _count,
    _finite,
    _role,
)
from coordinator.core.trajectory import LeaderState, wrap_angle

__all__ = [
    "FORMATION_KINDS",
    "LEADER_SLOT",
    "ROLES",
    "FormationSpec",
    "SlotSpec",
    "SlotState",
    "first_stage_pattern",
    "formation_spacing_m",
    "grow_staged",
    "morphed_slot_rows",
    "resized_formation_table",
    "slot_arrays",
    "slot_rows",
    "slot_states",
    "states_from_rows",
]


_SQRT3_2: Final = math.sqrt(3.0) / 2.0
_HALF_PI: Final = math.pi / 2.0

FloatArray = npt.NDArray[np.float64]
SlotRow = tuple[float, float, float, float]
"""One slot's ``(x, y, vx, vy)``: position (m) and feed-forward velocity (m/s)."""
_Turn = tuple[float, float, float, float, tuple[tuple[float, float], ...]]
"""slot_rows' memo: heading theta (rad), its sign (copysign(1, theta): 0.0 and -0.0 differ in
sin), cos and sin of theta, and per definition row cos and sin of gamma (eq 3)."""


class FormationSpec:
    """A validated staged tree of slots, immutable.

    ``slots`` must start with slot 0 (parent None, stage 0, ``b_m = phi_rad = 0``, role
    ``"leader"``), list every parent before its children (so there are no cycles), use unique
    ids, ``b_m > 0`` for non-leader slots, ``stage = parent's stage + 1`` and the role implied by
    the tree. :meth:`from_tree` derives stage and role for you.
    """

    __slots__ = (
        "_by_id",
        "_children",
        "_index",
        "_least_spacing",
        "_offsets",
        "_parent_index",
        "_priority",
        "_priority_rows",
        "_slot_ids",
        "_slots",
        "_tree",
        "_turn",
    )

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> FormationSpec:
        """Build from a scenario's ``[formation]`` table (ValueError naming the key if wrong);
        the table's forms are documented in :func:`coordinator.core.formation_table.read_table`."""
        form = read_table(d)
        if isinstance(form, BuilderForm):
            build: dict[str, Callable[..., FormationSpec]] = {
                "triangle": cls.triangle, "chevron": cls.chevron, "lattice": cls.lattice,
            }  # fmt: skip
            # (called as a value: mypyc's direct call of a classmethod with ** fails)
            return build[form.kind](**dict(form.params))
        spec = cls.from_tree(form.rows)
        form.check(spec.slots)
        return spec

    def __init__(self, slots: Sequence[SlotSpec]) -> None:
        owner = "FormationSpec"
        slots_t = tuple(slots)
        if not slots_t:
            raise ValueError(f"{owner}: needs at least the leader slot 0")
        for s in slots_t:
            if not isinstance(s, SlotSpec):
                raise ValueError(f"{owner}: slots must be SlotSpec, got {s!r}")
        root = slots_t[0]
        if root.slot != LEADER_SLOT or root.parent is not None:
            raise ValueError(
                f"{owner}: the first slot must be the leader slot 0 with parent None, "
                f"got slot {root.slot} with parent {root.parent}"
            )
        if root.stage != 0 or root.b_m != 0.0 or root.phi_rad != 0.0:
            raise ValueError(f"{owner}: leader slot 0 must have stage 0, b_m 0 and phi_rad 0")
        index: dict[int, int] = {}
        children: dict[int, list[int]] = {s.slot: [] for s in slots_t}
        for i, s in enumerate(slots_t):
            if s.slot in index:
                raise ValueError(f"{owner}: duplicate slot id {s.slot}")
            if i > 0:
                if s.parent is None:
                    raise ValueError(
                        f"{owner}: slot {s.slot} has no parent; only slot 0 may be the root"
                    )
                if s.parent == s.slot:
                    raise ValueError(f"{owner}: slot {s.slot} is its own parent (a cycle)")
                if s.parent not in index:
                    where = "later" if s.parent in children else "nowhere"
                    raise ValueError(
                        f"{owner}: slot {s.slot} has parent {s.parent}, which is defined "
                        f"{where}; parents must come before their children (no cycles)"
                    )
                if s.b_m <= 0.0:
                    raise ValueError(f"{owner}: slot {s.slot} needs b_m > 0, got {s.b_m}")
                parent_stage = slots_t[index[s.parent]].stage
                if s.stage != parent_stage + 1:
                    raise ValueError(
                        f"{owner}: slot {s.slot} has stage {s.stage} but its parent {s.parent} "
                        f"is stage {parent_stage}; expected {parent_stage + 1}"
                    )
                children[s.parent].append(s.slot)
            index[s.slot] = i
        for s in slots_t:
            expected = _role(s.slot, bool(children[s.slot]))
            if s.role != expected:
                raise ValueError(
                    f"{owner}: slot {s.slot} must have role {expected!r}, not {s.role!r}"
                )
        # Body-frame offset of every slot from the leader (theta = 0), accumulated down the tree:
        # eqs 4-5 with theta_p = 0 give (dx, dy) = (-b sin(phi), b cos(phi)).
        offsets = np.zeros((len(slots_t), 2), dtype=np.float64)
        parent_index = np.full(len(slots_t), -1, dtype=np.int64)
        for i, s in enumerate(slots_t[1:], start=1):
            assert s.parent is not None
            p = index[s.parent]
            parent_index[i] = p
            offsets[i, 0] = offsets[p, 0] - s.b_m * math.sin(s.phi_rad)
            offsets[i, 1] = offsets[p, 1] + s.b_m * math.cos(s.phi_rad)
        offsets.setflags(write=False)
        self._slots = slots_t
        self._index = index
        self._by_id = {s.slot: s for s in slots_t}
        self._children = {k: tuple(v) for k, v in children.items()}
        self._offsets = offsets
        self._parent_index = parent_index
        self._priority = tuple(
            s.slot for s in sorted(slots_t, key=lambda s: (s.slot != LEADER_SLOT, s.stage, s.slot))
        )
        # Hot-path tables (plain tuples, no per-tick attribute lookups): per slot in definition
        # order (parent row or -1, b_m, phi_rad), and the definition rows in priority order.
        self._tree = tuple(
            (-1 if s.parent is None else index[s.parent], s.b_m, s.phi_rad) for s in slots_t
        )
        self._priority_rows = tuple(index[sid] for sid in self._priority)
        self._slot_ids = tuple(s.slot for s in slots_t)
        self._turn: _Turn | None = None  # slot_rows' memo of the last heading's cos and sin
        self._least_spacing: float | None = None  # least_spacing_m, computed on first use

    # -- construction helpers ------------------------------------------------------------------

    @classmethod
    def from_tree(cls, entries: Iterable[tuple[int, int | None, float, float]]) -> FormationSpec:
        """Build from ``(slot, parent, b_m, phi_rad)`` entries (parents first, slot 0 first with
        parent None); stages and roles are derived."""
        rows = list(entries)
        stage: dict[int, int] = {}
        has_child: set[int] = set()
        for slot, parent, _b, _phi in rows:
            if parent is not None:
                has_child.add(parent)
                if parent not in stage:
                    raise ValueError(
                        f"FormationSpec: slot {slot} has parent {parent}, which is not defined "
                        "before it; parents must come before their children (no cycles)"
                    )
                stage[slot] = stage[parent] + 1
            else:
                stage[slot] = 0
        return cls(
            [
                SlotSpec(slot, parent, b, phi, stage[slot], _role(slot, slot in has_child))
                for slot, parent, b, phi in rows
            ]
        )

    @classmethod
    def triangle(
        cls, b_m: object = 0.4, phi: Sequence[float] = (math.pi / 3.0, 2.0 * math.pi / 3.0)
    ) -> FormationSpec:
        """The paper's Fig 2a: slots 1 and 2 follow the leader at ``b_m`` (m) and angles ``phi``
        (rad; default behind-left and behind-right, an equilateral triangle of side ``b_m``)."""
        b = _finite("FormationSpec.triangle", "b_m", b_m)
        if len(phi) != 2:
            raise ValueError(f"FormationSpec.triangle: phi must be a pair, got {phi!r}")
        return cls.from_tree([(0, None, 0.0, 0.0), (1, 0, b, phi[0]), (2, 0, b, phi[1])])

    @classmethod
    def chevron(cls, n: object, b_m: object = 0.4) -> FormationSpec:
        """A filled chevron (wedge) of ``n`` slots, leader included, neighbours ``b_m`` (m) apart.

        Stage 1 is the paper's triangle (slots 1, 2 at phi = pi/3, 2 pi/3). Stage ``s >= 2`` is a
        row of ``2 s`` slots one ``b_m`` behind the previous row, ``b_m`` apart across: each slot
        of stage ``s - 1`` has a child straight behind (phi = pi/2, ``b_m``) and the two outermost
        also an outer child that widens the V (phi = pi/4 left, 3 pi/4 right, ``sqrt(2) b_m``).
        So ``n = 7`` is two stages, slots 1, 2 then 3..6, two children per stage-1 slot. Within a
        stage slots are numbered from the centre out, left before right, so a partial last stage
        stays centred. No two slots are closer than ``b_m``.
        """
        owner = "FormationSpec.chevron"
        return cls.from_tree(chevron_rows(_count(owner, n), _finite(owner, "b_m", b_m)))

    @classmethod
    def lattice(cls, n: object, b_m: object = 0.4) -> FormationSpec:
        """A triangular lattice of ``n`` slots, leader included, nearest neighbours ``b_m`` apart.

        Stage ``s`` is a row of ``s + 1`` slots ``s sqrt(3)/2 b_m`` behind the leader (the last
        stage may be partial). Each slot hangs off the neighbour ahead of it on the centre side
        (phi = pi/3 on the left half, 2 pi/3 on the right half and the centre), so the tree
        spreads out from the leader. Within a stage slots are numbered from the centre out, left
        before right. ``lattice(3)`` is the triangle.
        """
        owner = "FormationSpec.lattice"
        return cls.from_tree(lattice_rows(_count(owner, n), _finite(owner, "b_m", b_m)))

    def to_dict(self) -> dict[str, Any]:
        """The explicit form accepted by :meth:`from_dict` (the root's parent key is omitted)."""
        out: list[dict[str, Any]] = []
        for s in self._slots:
            row: dict[str, Any] = {"slot": s.slot}
            if s.parent is not None:
                row.update(parent=s.parent, b_m=s.b_m, phi_rad=s.phi_rad)
            row.update(stage=s.stage, role=s.role)
            out.append(row)
        return {"kind": "explicit", "slots": out}

    # -- queries ---------------------------------------------------------------------------------

    @property
    def slots(self) -> tuple[SlotSpec, ...]:
        """Slots in definition order (parents before children)."""
        return self._slots

    @property
    def slot_ids(self) -> tuple[int, ...]:
        """Slot ids in definition order."""
        return self._slot_ids

    @property
    def n_stages(self) -> int:
        """Number of stages including the leader's stage 0."""
        return 1 + max(s.stage for s in self._slots)

    @property
    def least_spacing_m(self) -> float:
        """The least distance (m) between two slots of the rigid formation (+inf with one
        slot): the same in every pose of :func:`slot_rows`, up to rounding (1e-16 of the
        coordinates). The role assigner's proof that the incumbents hold
        (``coordinator.core.matching.kept_by_spacing``) reads it."""
        least = self._least_spacing
        if least is None:
            off = self._offsets
            least = math.inf
            for i in range(1, len(off)):
                d = np.hypot(off[:i, 0] - off[i, 0], off[:i, 1] - off[i, 1])
                least = min(least, float(d.min()))
            self._least_spacing = least
        return least

    @property
    def body_offsets_m(self) -> FloatArray:
        """(n, 2) read-only offsets (m) of the slots from the leader with the leader heading +x,
        in definition order."""
        return self._offsets

    def __len__(self) -> int:
        return len(self._slots)

    def __iter__(self) -> Iterator[SlotSpec]:
        return iter(self._slots)

    def __getitem__(self, slot: int) -> SlotSpec:
        try:
            return self._by_id[slot]
        except KeyError:
            raise KeyError(f"no slot {slot} in this formation") from None

    def __contains__(self, slot: object) -> bool:
        return slot in self._by_id

    def __eq__(self, other: object) -> bool:
        return isinstance(other, FormationSpec) and self._slots == other._slots

    def __hash__(self) -> int:
        return hash(self._slots)

    def __repr__(self) -> str:
        return f"FormationSpec(n={len(self)}, stages={self.n_stages})"

    def children(self, slot: int) -> tuple[int, ...]:
        """Slots whose parent is ``slot``."""
        return self._children[self[slot].slot]

    def priority_order(self) -> list[int]:
        """Slot ids in fill priority: the leader first, then by stage, then by slot id."""
        return list(self._priority)

    def index_of(self, slot: int) -> int:
        """Row of ``slot`` in definition order (and in :func:`slot_arrays`)."""
        return self._index[slot]

    def grown(self, n: object) -> FormationSpec:
        """This formation grown (or cut) to ``n`` slots by the paper's staged rule (Fig 2b);
        see :func:`grow_staged`."""
        return grow_staged(self, n)

    @property
    def priority_slots(self) -> tuple[int, ...]:
        """Slot ids in fill priority (as :meth:`priority_order`, as a shared tuple)."""
        return self._priority

    @property
    def priority_rows(self) -> tuple[int, ...]:
        """Definition-order rows (as in :func:`slot_rows`) of the slots in fill priority."""
        return self._priority_rows


def slot_rows(spec: FormationSpec, leader: LeaderState) -> tuple[float, list[SlotRow]]:
    """The numbers of :func:`slot_states` without the objects: ``(theta, rows)``.

    ``theta`` (rad) is the formation heading (the leader's, wrapped), shared by every slot;
    ``rows[i]`` is ``(x, y, vx, vy)`` (m, m/s) of the slot in definition row ``i``. Eqs 1-5
    applied recursively from each slot's parent, plus the rigid-formation feed-forward velocity.
    This is the per-tick hot path of the coordinator: plain floats and tuples, and exactly the
    arithmetic of :func:`slot_states` (which is built on it), so both give the same bits.
    """
    theta = wrap_angle(leader.theta)
    omega = leader.omega_radps
    v = leader.v_mps
    turn = spec._turn
    if (
        turn is None or turn[0] != theta or (theta == 0.0 and math.copysign(1.0, theta) != turn[1])
    ):  # a new heading: its trigonometry (the same calls, so the same bits, as every tick;
        # math.cos and math.sin spelled out: compiled, C's, where a local alias is a Python call)
        trig: list[tuple[float, float]] = []
        for _, _, phi in spec._tree:
            gamma = phi + theta - _HALF_PI  # eq 3
            trig.append((math.cos(gamma), math.sin(gamma)))
        turn = (theta, math.copysign(1.0, theta), math.cos(theta), math.sin(theta), tuple(trig))
        spec._turn = turn
    _, _, cth, sth, cs = turn
    tree = spec._tree  # (cs holds one (cos, sin) per entry of tree: made from it above)
    rows: list[SlotRow] = []
    # (compiled: a native loop, zip(..., strict=True) is a call; rows.append is C's list
    # append, where a bound method kept in a local is a Python call)
    for i in range(len(tree)):
        parent, b, _ = tree[i]
        cg, sg = cs[i]
        if parent < 0:
            rows.append((leader.x, leader.y, v * cth, v * sth))  # eqs 1-2
        else:
            xp, yp, vxp, vyp = rows[parent]
            rows.append(
                (
                    xp - b * cg,  # eq 4 (corrected)
                    yp - b * sg,  # eq 5 (corrected)
                    vxp + b * omega * sg,  # d/dt of eq 4 with gammadot = omega
                    vyp - b * omega * cg,  # d/dt of eq 5
                )
            )
    return theta, rows


def morphed_slot_rows(
    leader: LeaderState, offsets: Sequence[tuple[float, float, float, float]]
) -> tuple[float, list[SlotRow]]:
    """:func:`slot_rows` for a formation whose slot offsets vary in time (a planned squeeze
    through a narrow passage, ``coordinator.core.planning``): ``offsets[i]`` is ``(ox, oy, dox,
    doy)``, slot row ``i``'s offset from the leader in the leader's body frame (m, heading +x)
    and its rate (m/s). Eqs 3-5 summed down the tree are ``p_i = p_L + R(theta) o_i``; their
    derivative adds the squeeze's own rate: ``v_i = v_L + omega J R(theta) o_i + R(theta)
    o_i'``. Constant offsets (``body_offsets_m``, zero rates) give the rigid formation."""
    theta = wrap_angle(leader.theta)
    omega = leader.omega_radps
    c, s = math.cos(theta), math.sin(theta)
    vxl, vyl = leader.v_mps * c, leader.v_mps * s  # eqs 1-2
    rows: list[SlotRow] = []
    for ox, oy, dox, doy in offsets:
        rx, ry = c * ox - s * oy, s * ox + c * oy
        rows.append(
            (
                leader.x + rx,
                leader.y + ry,
                vxl - omega * ry + c * dox - s * doy,
                vyl + omega * rx + s * dox + c * doy,
            )
        )
    return theta, rows


def slot_states(spec: FormationSpec, leader: LeaderState) -> list[SlotState]:
    """States of every slot (definition order) for a virtual-leader state.

    Eqs 1-5 applied recursively from each slot's parent, plus the rigid-formation feed-forward
    velocity (computed by :func:`slot_rows`). Positions in m, velocities in m/s, every ``theta``
    equal to the leader's.
    """
    theta, rows = slot_rows(spec, leader)
    return states_from_rows(spec, theta, rows)


def states_from_rows(spec: FormationSpec, theta: float, rows: Sequence[SlotRow]) -> list[SlotState]:
    """:class:`SlotState` objects for the output of :func:`slot_rows` (definition order)."""
    return [
        SlotState(s.slot, s.role, s.stage, s.parent, x, y, theta, vx, vy)
        for s, (x, y, vx, vy) in zip(spec.slots, rows, strict=True)
    ]


def slot_arrays(spec: FormationSpec, leader: LeaderState) -> tuple[FloatArray, FloatArray]:
    """Vectorised :func:`slot_states`: ``(xy, vxy)``, each (n, 2), rows in definition order.

    The tree offsets are precomputed in the leader's body frame, so every slot is the leader plus
    a rotated offset: ``p_i = p_L + R(theta) d_i`` and ``v_i = v_L + omega J R(theta) d_i``
    (``J`` = rotation by +pi/2), which is eqs 3-5 and their derivative summed down the tree.
    """
    c, s = math.cos(leader.theta), math.sin(leader.theta)
    d = spec.body_offsets_m
    rx = c * d[:, 0] - s * d[:, 1]
    ry = s * d[:, 0] + c * d[:, 1]
    xy = np.empty((len(spec), 2), dtype=np.float64)
    xy[:, 0] = leader.x + rx
    xy[:, 1] = leader.y + ry
    vxy = np.empty((len(spec), 2), dtype=np.float64)
    vxy[:, 0] = leader.v_mps * c - leader.omega_radps * ry
    vxy[:, 1] = leader.v_mps * s + leader.omega_radps * rx
    return xy, vxy


# -- staged growth (paper Fig 2b) ----------------------------------------------------------------


def first_stage_pattern(spec: FormationSpec) -> tuple[tuple[float, float], ...]:
    """The ``(b_m, phi_rad)`` of the leader's children (the first stage), in definition order:
    the pattern every sub-leader repeats when the formation grows (paper Fig 2b)."""
    return tuple((s.b_m, s.phi_rad) for s in spec.slots if s.parent == LEADER_SLOT)


COINCIDE_M = 1e-9
"""Two slots closer than this (m) are one point: a formation with such a pair cannot grow."""


def formation_spacing_m(spec: FormationSpec) -> float:
    """The smallest distance (m) between two slots of ``spec`` (inf for a single slot)."""
    d = spec.body_offsets_m
    if len(d) < 2:
        return math.inf
    diff = d[:, None, :] - d[None, :, :]
    dist = np.hypot(diff[..., 0], diff[..., 1])
    np.fill_diagonal(dist, np.inf)
    return float(dist.min())


def grow_staged(spec: FormationSpec, n: object) -> FormationSpec:
    """``spec`` grown (or cut) to exactly ``n`` slots by the paper's staged rule (Fig 2b).

    Every slot of a stage becomes the sub-leader of its own followers in the next stage, placed
    at the first stage's ``(b_m, phi_rad)`` pattern (:func:`first_stage_pattern`). Sub-trees of
    neighbouring sub-leaders overlap (the triangle's pi/3 and 2 pi/3 put the right follower of
    one and the left follower of the other on the same point: the paper's "trajectory 5 can be
    developed from trajectory 2 or 3"), so candidates are merged and filtered:

    * stages are filled in order (stage ``s`` candidates are the pattern children of every
      stage ``s - 1`` slot, the existing ones included, so a partial last stage is completed
      first where the pattern reaches);
    * a point reached from several sub-leaders is one slot; its parent is the sub-leader nearest
      the centre line (smallest ``|y|`` in the leader's frame), left before right on a tie, then
      the first in definition order;
    * within a stage, slots are numbered from the centre out, left (+y) before right, then
      front to back;
    * a candidate closer than the formation's spacing (:func:`formation_spacing_m`, its
      smallest slot-to-slot distance) to any slot already placed is dropped.

    The slots of ``spec`` keep their ids, parents, ``b_m``, ``phi_rad`` and stages; new slots
    get the next ids. ``n`` smaller than ``len(spec)`` keeps the first ``n`` slots in definition
    order; the result for ``n`` is always a prefix of the result for any larger ``n``. Roles are
    derived again (a follower that gets children becomes a sub-leader). ``grow_staged(triangle,
    n)`` is ``FormationSpec.lattice(n)`` exactly. Raises ``ValueError`` if ``n < 1``, if the
    formation has no first stage to repeat (a lone leader), or if the pattern cannot place
    another slot.
    """
    owner = "grow_staged"
    n_i = _count(owner, n)
    rows: list[tuple[int, int | None, float, float]] = [
        (s.slot, s.parent, s.b_m, s.phi_rad) for s in spec.slots
    ]
    if n_i <= len(rows):
        return FormationSpec.from_tree(rows[:n_i])
    pattern = first_stage_pattern(spec)
    if not pattern:
        raise ValueError(
            f"{owner}: the formation has no first stage (only the leader), so there is no "
            "pattern to repeat; give it at least one follower of the leader"
        )
    spacing = formation_spacing_m(spec)
    if not spacing > COINCIDE_M:
        raise ValueError(f"{owner}: two slots of the formation coincide (spacing {spacing} m)")
    stages = [s.stage for s in spec.slots]
    return FormationSpec.from_tree(
        grow_rows(rows, stages, spec.body_offsets_m, pattern, n_i, spacing, owner)
    )
    return FormationSpec.from_tree(rows)


def resized_formation_table(table: Mapping[str, Any], n: object) -> dict[str, Any]:
    """A scenario ``[formation]`` table for exactly ``n`` slots (what ``--robots N`` needs).

    ``chevron`` and ``lattice`` keep their kind with ``n`` replaced (their builders are staged
    and prefix-stable: the first slots of ``lattice(m)`` are ``lattice(n)``); any other kind
    (the paper's ``triangle``, ``explicit``) is grown by :func:`grow_staged` and returned in the
    explicit form of :meth:`FormationSpec.to_dict`. Raises ``ValueError`` for a bad table or n.
    """
    n_i = _count("formation", n)
    if not isinstance(table, Mapping):
        raise ValueError(f"formation: expected a table/mapping, got {table!r}")
    kind = table.get("kind")
    if kind in ("chevron", "lattice"):
        out = dict(table)
        if isinstance(out.get("params"), Mapping):
            out["params"] = {**out["params"], "n": n_i}
        else:
            out["n"] = n_i
        FormationSpec.from_dict(out)  # validate
        return out
    return grow_staged(FormationSpec.from_dict(table), n_i).to_dict()
