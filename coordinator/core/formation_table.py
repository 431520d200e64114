"""A formation from a scenario's ``[formation]`` table: a builder kind (``triangle``,
``chevron``, ``lattice``) with its parameters, or an explicit tree of slots, every key and value
checked.

:func:`read_table` only reads the table: it returns what to build (:class:`BuilderForm`: a
builder of :class:`coordinator.core.formation.FormationSpec` and its arguments, or
:class:`TreeForm`: the explicit rows), and ``FormationSpec.from_dict`` builds it. A slot's stage
and role given in the table are checked against the built tree by :meth:`TreeForm.check`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from coordinator.core.slots import FORMATION_KINDS, _finite, _is_int

__all__ = ["BuilderForm", "TreeForm", "read_table"]


@dataclass(frozen=True, slots=True)
class BuilderForm:
    """Build with ``FormationSpec.<kind>(**params)`` (kind: triangle, chevron or lattice)."""

    kind: str
    params: Mapping[str, Any]


@dataclass(frozen=True, slots=True)
class TreeForm:
    """Build with ``FormationSpec.from_tree(rows)``: (slot, parent, b_m, phi_rad) per slot."""

    rows: tuple[tuple[int, int | None, float, float], ...]
    given: tuple[Mapping[str, Any], ...]

    def check(self, built: Sequence[Any]) -> None:
        """Every stage or role the table gave equals the built slot's (ValueError if not)."""
        owner = "formation explicit"
        for item, s in zip(self.given, built, strict=True):
            for k in ("stage", "role"):
                if k in item and item[k] != getattr(s, k):
                    raise ValueError(
                        f"{owner}: slot {s.slot} has {k} {item[k]!r} but the tree gives "
                        f"{getattr(s, k)!r}"
                    )


def read_table(d: Mapping[str, Any]) -> BuilderForm | TreeForm:
    """Read a scenario table (ValueError naming the key if it is wrong).

    Either a builder: ``{"kind": "triangle" | "chevron" | "lattice", ...params}`` (params
    inline or under ``"params"``: triangle ``b_m``, ``phi``; chevron and lattice ``n``,
    ``b_m``), or an explicit tree: ``{"kind": "explicit", "slots": [{"slot": 0}, {"slot": 1,
    "parent": 0, "b_m": 0.4, "phi_rad": 1.047}, ...]}`` (``kind`` may be omitted when
    ``slots`` is given; ``stage`` and ``role`` are derived, and checked if given).
    """
    owner = "formation"
    if not isinstance(d, Mapping):
        raise ValueError(f"{owner}: expected a table/mapping, got {d!r}")
    kind = d.get("kind", "explicit" if "slots" in d else None)
    if kind is None:
        raise ValueError(f"{owner}: missing 'kind' (one of {', '.join(FORMATION_KINDS)})")
    if kind not in FORMATION_KINDS:
        raise ValueError(
            f"{owner}: unknown kind {kind!r}; expected one of {', '.join(FORMATION_KINDS)}"
        )
    if "params" in d:
        extra = sorted(str(k) for k in d if k not in ("kind", "params"))
        if extra:
            raise ValueError(f"{owner}: unexpected key(s) {', '.join(extra)} beside 'params'")
        params = d["params"]
        if not isinstance(params, Mapping):
            raise ValueError(f"{owner}: 'params' must be a table, got {params!r}")
    else:
        params = {k: v for k, v in d.items() if k != "kind"}
    if kind == "explicit":
        return _tree_form(params)
    allowed = {"triangle": ("b_m", "phi"), "chevron": ("n", "b_m"), "lattice": ("n", "b_m")}
    unknown = sorted(str(k) for k in params if k not in allowed[kind])
    if unknown:
        raise ValueError(
            f"{owner} {kind}: unknown parameter(s) {', '.join(unknown)}; "
            f"allowed: {', '.join(allowed[kind])}"
        )
    if kind == "triangle":
        kw: dict[str, Any] = dict(params)
        if "phi" in kw:
            phi = kw["phi"]
            if isinstance(phi, str) or not isinstance(phi, Sequence) or len(phi) != 2:
                raise ValueError(f"{owner} triangle: phi must be a pair of angles, got {phi!r}")
            kw["phi"] = (
                _finite(f"{owner} triangle", "phi[0]", phi[0]),
                _finite(f"{owner} triangle", "phi[1]", phi[1]),
            )
        return BuilderForm("triangle", kw)
    if "n" not in params:
        raise ValueError(f"{owner} {kind}: missing required parameter n (number of slots)")
    return BuilderForm(kind, dict(params))


def _tree_form(params: Mapping[str, Any]) -> TreeForm:
    owner = "formation explicit"
    unknown = sorted(str(k) for k in params if k != "slots")
    if unknown:
        raise ValueError(f"{owner}: unknown key(s) {', '.join(unknown)}; allowed: slots")
    items = params.get("slots")
    if isinstance(items, str) or not isinstance(items, Sequence) or not items:
        raise ValueError(f"{owner}: 'slots' must be a non-empty list of tables, got {items!r}")
    keys = ("slot", "parent", "b_m", "phi_rad", "stage", "role")
    rows: list[tuple[int, int | None, float, float]] = []
    given: list[Mapping[str, Any]] = []
    for i, item in enumerate(items):
        if not isinstance(item, Mapping):
            raise ValueError(f"{owner}: slots[{i}] must be a table, got {item!r}")
        bad = sorted(str(k) for k in item if k not in keys)
        if bad:
            raise ValueError(
                f"{owner}: slots[{i}] has unknown key(s) {', '.join(bad)}; "
                f"allowed: {', '.join(keys)}"
            )
        if "slot" not in item:
            raise ValueError(f"{owner}: slots[{i}] is missing 'slot'")
        slot, parent = item["slot"], item.get("parent")
        if not _is_int(slot) or (parent is not None and not _is_int(parent)):
            raise ValueError(f"{owner}: slots[{i}]: slot and parent must be integers")
        if parent is not None:
            for k in ("b_m", "phi_rad"):
                if k not in item:
                    raise ValueError(f"{owner}: slots[{i}] (slot {slot}) is missing {k!r}")
        rows.append(
            (
                int(slot),
                None if parent is None else int(parent),
                _finite(owner, f"slots[{i}].b_m", item.get("b_m", 0.0)),
                _finite(owner, f"slots[{i}].phi_rad", item.get("phi_rad", 0.0)),
            )
        )
        given.append(item)
    return TreeForm(tuple(rows), tuple(given))
