"""Field specs of the bus contract: the limits, field kinds, ``FieldSpec`` and its constructors
(``f_float``, ``f_int``, ``f_robot_id``, ...) and the cross-field rules, all declarative.

Each message field carries a ``FieldSpec`` in its dataclass metadata (type, unit, range or enum,
nil allowed, description); :mod:`bus_schemas.checks` compiles them into validators and
:mod:`bus_schemas.spec` into message specs. Presence of a field: *required* (no dataclass
default; absent -> missing_field), *required, nil allowed* (``nullable=True``, no default; must be
present, may be nil), *optional* (dataclass default None; may be absent; nil on the wire is read
as absent). Encoders omit optional fields that are None, so old decoders never see them.
"""

from __future__ import annotations

import math
import re
import sys
from collections.abc import Mapping
from dataclasses import dataclass
from enum import StrEnum
from typing import Any, Protocol

from bus_schemas import keys
from bus_schemas.errors import Invalid, Reason

VERSION = 1
MAX_PAYLOAD_BYTES = 64 * 1024
MAX_LIST_LEN = 1024
MAX_MAP_LEN = 1024
MAX_STR_LEN = 255
ANGLE_TOL_RAD = 1e-9

# Plausibility bounds (docs/bus.md): a value outside them is no measurement or command any real or
# simulated fleet of this project produces, so the decoder refuses it (out_of_range) before a
# controller can act on it (x = 1e300 saturated the wheels; epoch = 2^64-1 overflowed the
# election). They are generous on purpose: an arena-scale position bound, not the arena.
POSITION_MAX_M = 1000.0
"""|x|, |y| of every position, slot, setpoint, drag and teleport (a 2 km square arena)."""
SPEED_MAX_MPS = 20.0
"""|v| of every linear velocity (leader speed, slot feed-forward): the robots do < 1 m/s."""
TURN_RATE_MAX_RADPS = 100.0
"""|omega| of a body turn rate (the virtual leader's)."""
WHEEL_RATE_MAX_RADPS = 1000.0
"""|omega| of a wheel angular speed command (~10,000 rpm)."""
TIME_MAX_S = 1e9
"""Upper bound of every timestamp (sim time, or time.monotonic(): 31 years of uptime)."""
DURATION_MAX_S = 3600.0
"""Upper bound of a duration (a drag's)."""
EPOCH_MAX = 2**31 - 1
"""Largest leadership epoch: +1 per takeover, so never reached, and never an overflow."""

FLOAT64_MAX = sys.float_info.max
INT64_MIN = -(2**63)
UINT64_MAX = 2**64 - 1
ANGLE_LO = -math.pi - ANGLE_TOL_RAD
ANGLE_HI = math.pi + ANGLE_TOL_RAD

META_KEY = "bus_schemas"


class Kind(StrEnum):
    """Wire type of a field (the MessagePack type a generic decoder sees in brackets)."""

    FLOAT = "float"  # float64 (ints accepted on decode, converted)
    INT = "int"  # int (never bool)
    BOOL = "bool"  # bool (never int)
    STR = "str"  # UTF-8 str
    ENUM = "enum"  # str from a fixed set
    FLOAT_LIST = "list[float]"  # array of float64
    STR_LIST = "list[str]"  # array of str
    INT_LIST = "list[int]"  # array of int (never bool)
    STR_INT_MAP = "map[str, int]"  # map str -> int


@dataclass(frozen=True, slots=True)
class FieldSpec:
    """One field of a message: wire type, unit, allowed values, description.

    `lo`/`hi` bound numbers and list elements (inclusive); `max_len` bounds str length (chars),
    list length and map size; `pattern` (full match) constrains str values, list elements and map
    keys; `choices` are the values of an enum; `range_text` overrides the range shown in the docs.
    """

    kind: Kind
    description: str
    unit: str = ""
    lo: int | float | None = None
    hi: int | float | None = None
    choices: tuple[str, ...] = ()
    pattern: str | None = None
    max_len: int | None = None
    nullable: bool = False
    range_text: str = ""
    value_lo: int | None = None  # STR_INT_MAP values
    value_hi: int | None = None

    def python_type(self) -> Any:
        """The annotation the dataclass field must have (without `| None`)."""
        return {
            Kind.FLOAT: float,
            Kind.INT: int,
            Kind.BOOL: bool,
            Kind.STR: str,
            Kind.ENUM: str,
            Kind.FLOAT_LIST: tuple[float, ...],
            Kind.STR_LIST: tuple[str, ...],
            Kind.INT_LIST: tuple[int, ...],
            Kind.STR_INT_MAP: Mapping[str, int],
        }[self.kind]

    def describe_range(self) -> str:
        """Human-readable allowed values, for docs/bus.md."""
        if self.range_text:
            return self.range_text
        if self.kind is Kind.ENUM:
            return " \\| ".join(f"`{c}`" for c in self.choices)
        parts: list[str] = []
        if self.kind in (Kind.FLOAT, Kind.INT, Kind.FLOAT_LIST, Kind.INT_LIST):
            if self.kind in (Kind.FLOAT_LIST, Kind.INT_LIST):
                parts.append(f"len <= {self.max_len}")
            elem = Kind.INT if self.kind is Kind.INT_LIST else self.kind
            bounds = _fmt_range(self.lo, self.hi, elem)
            if bounds:
                parts.append(bounds)
            if self.kind not in (Kind.INT, Kind.INT_LIST):
                parts.append("finite")
        elif self.kind in (Kind.STR, Kind.STR_LIST):
            if self.kind is Kind.STR_LIST:
                parts.append(f"len <= {self.max_len}")
            if self.pattern is not None:
                parts.append(f"`{self.pattern}`")
            elif self.max_len is not None:
                parts.append(f"<= {self.max_len} chars")
        elif self.kind is Kind.STR_INT_MAP:
            parts.append(f"<= {self.max_len} entries")
            parts.append(f"keys `{self.pattern}`")
            parts.append("values " + _fmt_range(self.value_lo, self.value_hi, Kind.INT))
        return ", ".join(parts)


def _fmt_range(lo: int | float | None, hi: int | float | None, kind: Kind) -> str:
    a, b = _fmt_bound(lo, kind), _fmt_bound(hi, kind)
    if a and b:
        return f"= {a}" if a == b else f"[{a}, {b}]"
    if a:
        return f">= {a}"
    if b:
        return f"<= {b}"
    return ""


def _fmt_bound(b: int | float | None, kind: Kind) -> str:
    if b is None:
        return ""
    if kind is Kind.INT:
        named = {UINT64_MAX: "2^64-1", INT64_MIN: "-2^63", 2**31 - 1: "2^31-1", 2**63 - 1: "2^63-1"}
        return named.get(int(b), str(b))
    if abs(b) == FLOAT64_MAX:
        return ""
    return f"{b:g}"


# --- metadata builders (used in the dataclass bodies of bus_schemas.messages) ---------------


def _meta(fs: FieldSpec) -> dict[str, FieldSpec]:
    return {META_KEY: fs}


def f_float(
    description: str,
    unit: str,
    *,
    lo: float | None = None,
    hi: float | None = None,
    nullable: bool = False,
) -> dict[str, FieldSpec]:
    """A finite float64 in [lo, hi] (None = unbounded)."""
    return _meta(FieldSpec(Kind.FLOAT, description, unit, lo=lo, hi=hi, nullable=nullable))


def f_angle(description: str) -> dict[str, FieldSpec]:
    """An angle in rad, wrapped to (-pi, pi]; accepted in [-pi-1e-9, pi+1e-9]."""
    return _meta(
        FieldSpec(
            Kind.FLOAT,
            description,
            "rad",
            lo=ANGLE_LO,
            hi=ANGLE_HI,
            range_text="(-pi, pi] (accepted within 1e-9 of +-pi), finite",
        )
    )


def f_int(
    description: str,
    *,
    unit: str = "",
    lo: int = 0,
    hi: int = UINT64_MAX,
    nullable: bool = False,
) -> dict[str, FieldSpec]:
    """An int (not bool) in [lo, hi]."""
    return _meta(FieldSpec(Kind.INT, description, unit, lo=lo, hi=hi, nullable=nullable))


def f_slot(description: str, *, nullable: bool = False) -> dict[str, FieldSpec]:
    """A slot number, 0 = virtual leader."""
    return f_int(description, hi=keys.MAX_SLOT, nullable=nullable)


def f_bool(description: str) -> dict[str, FieldSpec]:
    """A bool (not int)."""
    return _meta(FieldSpec(Kind.BOOL, description))


def f_str(description: str, *, max_len: int = MAX_STR_LEN) -> dict[str, FieldSpec]:
    """Free text of at most `max_len` characters."""
    return _meta(FieldSpec(Kind.STR, description, max_len=max_len))


def f_robot_id(description: str, *, nullable: bool = False) -> dict[str, FieldSpec]:
    """A robot id, ``[a-z0-9_-]{1,64}``."""
    return _meta(
        FieldSpec(
            Kind.STR,
            description,
            pattern=keys.ROBOT_ID_PATTERN,
            max_len=keys.ID_MAX_LEN,
            nullable=nullable,
        )
    )


def f_name(description: str) -> dict[str, FieldSpec]:
    """A fleet or coordinator name, ``[A-Za-z0-9_-]{1,64}``."""
    return _meta(
        FieldSpec(Kind.STR, description, pattern=keys.NAME_PATTERN, max_len=keys.ID_MAX_LEN)
    )


def f_enum(
    description: str, choices: type[StrEnum], *, nullable: bool = False
) -> dict[str, FieldSpec]:
    """A str from the values of a StrEnum."""
    values = tuple(str(c.value) for c in choices)
    return _meta(FieldSpec(Kind.ENUM, description, choices=values, nullable=nullable))


def f_float_list(
    description: str, unit: str, *, lo: float | None = None, hi: float | None = None
) -> dict[str, FieldSpec]:
    """An array of at most MAX_LIST_LEN finite floats, each in [lo, hi]."""
    return _meta(FieldSpec(Kind.FLOAT_LIST, description, unit, lo=lo, hi=hi, max_len=MAX_LIST_LEN))


def f_angle_list(description: str) -> dict[str, FieldSpec]:
    """An array of angles (rad), each in [-pi-1e-9, pi+1e-9]."""
    return _meta(
        FieldSpec(
            Kind.FLOAT_LIST,
            description,
            "rad",
            lo=ANGLE_LO,
            hi=ANGLE_HI,
            max_len=MAX_LIST_LEN,
            range_text=f"len <= {MAX_LIST_LEN}, each in (-pi, pi] (+-1e-9), finite",
        )
    )


def f_int_list(
    description: str, *, unit: str = "", lo: int = 0, hi: int = UINT64_MAX
) -> dict[str, FieldSpec]:
    """An array of at most MAX_LIST_LEN ints (not bools), each in [lo, hi]."""
    return _meta(FieldSpec(Kind.INT_LIST, description, unit, lo=lo, hi=hi, max_len=MAX_LIST_LEN))


def f_enum_list(description: str, choices: type[StrEnum]) -> dict[str, FieldSpec]:
    """An array of at most MAX_LIST_LEN strs, each one of the values of a StrEnum (a
    ``list[str]`` on the wire whose elements match ``(a|b|...)``)."""
    values = tuple(str(c.value) for c in choices)
    return _meta(
        FieldSpec(
            Kind.STR_LIST,
            description,
            pattern="(" + "|".join(re.escape(v) for v in values) + ")",
            max_len=MAX_LIST_LEN,
            range_text=f"len <= {MAX_LIST_LEN}, each " + " \\| ".join(f"`{v}`" for v in values),
        )
    )


def f_robot_id_list(description: str) -> dict[str, FieldSpec]:
    """An array of at most MAX_LIST_LEN robot ids."""
    return _meta(
        FieldSpec(
            Kind.STR_LIST,
            description,
            pattern=keys.ROBOT_ID_PATTERN,
            max_len=MAX_LIST_LEN,
        )
    )


def f_name_list(description: str) -> dict[str, FieldSpec]:
    """A list of fleet / coordinator names (``keys.NAME_PATTERN``)."""
    return _meta(
        FieldSpec(Kind.STR_LIST, description, pattern=keys.NAME_PATTERN, max_len=MAX_LIST_LEN)
    )


def f_count_map(
    description: str,
    *,
    key_pattern: str = keys.NAME_PATTERN,
    value_lo: int = 0,
    value_hi: int = UINT64_MAX,
) -> dict[str, FieldSpec]:
    """A map str -> int of at most MAX_MAP_LEN entries (encoded with keys sorted)."""
    return _meta(
        FieldSpec(
            Kind.STR_INT_MAP,
            description,
            pattern=key_pattern,
            max_len=MAX_MAP_LEN,
            value_lo=value_lo,
            value_hi=value_hi,
        )
    )


# --- cross-field rules ----------------------------------------------------------------------


class Rule(Protocol):
    """A constraint between fields, checked on a message whose fields are each valid."""

    def check(self, msg: Any) -> None:
        """Raise `Invalid` if the message `msg` breaks the rule."""

    def describe(self) -> str:
        """One line for docs/bus.md."""


@dataclass(frozen=True, slots=True)
class SameLength:
    """The listed list fields have equal lengths (parallel arrays)."""

    fields: tuple[str, ...]

    def check(self, msg: Any) -> None:
        """Raise `Invalid(inconsistent)` unless all listed fields have the same length (an
        optional field that is absent is not compared)."""
        lengths = {name: len(v) for name in self.fields if (v := getattr(msg, name)) is not None}
        if len(set(lengths.values())) > 1:
            raise Invalid(Reason.INCONSISTENT, f"list lengths differ: {lengths}", self.fields[0])

    def describe(self) -> str:
        """One line for docs/bus.md."""
        return "`" + "`, `".join(self.fields) + "` have the same length (when present)"


@dataclass(frozen=True, slots=True)
class Together:
    """The listed optional fields are all present or all absent."""

    fields: tuple[str, ...]

    def check(self, msg: Any) -> None:
        """Raise `Invalid(missing_field)` naming the first absent field when some are present."""
        present = [getattr(msg, name) is not None for name in self.fields]
        if any(present) and not all(present):
            raise Invalid(
                Reason.MISSING_FIELD,
                "present together or not at all",
                self.fields[present.index(False)],
            )

    def describe(self) -> str:
        """One line for docs/bus.md."""
        return "`" + "`, `".join(self.fields) + "` are present together or not at all"


@dataclass(frozen=True, slots=True)
class RequiredWhen:
    """The `required` optional fields must be present when `field` equals `value`."""

    field: str
    value: str
    required: tuple[str, ...]

    def check(self, msg: Any) -> None:
        """Raise `Invalid(missing_field)` if the condition holds and a listed field is absent."""
        if getattr(msg, self.field) == self.value:
            for name in self.required:
                if getattr(msg, name) is None:
                    raise Invalid(
                        Reason.MISSING_FIELD,
                        f"required when {self.field} == {self.value!r}",
                        name,
                    )

    def describe(self) -> str:
        """One line for docs/bus.md."""
        req = "`, `".join(self.required)
        return f"`{req}` required when `{self.field}` is `{self.value}`"
