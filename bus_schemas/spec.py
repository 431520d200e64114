"""The declarative schema machinery: field specs, cross-field rules, message specs, validators.

Each message type is a frozen, slotted dataclass (bus_schemas.messages) whose fields carry a
`FieldSpec` in their metadata (type, unit, range or enum, nil allowed, description), decorated
with `@message(...)` (name, key, publisher, periodic, rules). At import the decorator checks the
dataclass against its specs and compiles, once per type, a decoder and an encoder out of small
per-field closures, so a decode does no reflection: one dict lookup and one closure call per field.
Encode, decode, validation and docs/bus.md all derive from these tables.

Presence of a field: *required* (no dataclass default; absent -> missing_field), *required, nil
allowed* (`nullable=True`, no default; must be present, may be nil), *optional* (dataclass default
None; may be absent; nil on the wire is read as absent). Encoders omit optional fields that are
None, so old decoders never see them.
"""

from __future__ import annotations

import dataclasses
import inspect
import math
import re
import sys
import typing
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from enum import StrEnum
from operator import attrgetter
from typing import Any, Protocol, TypeVar

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
        return {UINT64_MAX: "2^64-1", INT64_MIN: "-2^63", 2**31 - 1: "2^31-1"}.get(int(b), str(b))
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
        """Raise `Invalid(inconsistent)` unless all listed fields have the same length."""
        lengths = {name: len(getattr(msg, name)) for name in self.fields}
        if len(set(lengths.values())) > 1:
            raise Invalid(Reason.INCONSISTENT, f"list lengths differ: {lengths}", self.fields[0])

    def describe(self) -> str:
        """One line for docs/bus.md."""
        return "`" + "`, `".join(self.fields) + "` have the same length"


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


# --- per-field validators --------------------------------------------------------------------
# A validator takes a raw value (from msgpack, or from a dataclass being encoded) and returns the
# normalised value (ints in float fields -> float, lists -> tuples, str subclasses -> str, maps
# sorted by key) or raises Invalid. The fast path tests exact types; subclasses (numpy.float64,
# StrEnum members, IntEnum) take a slow path so publishers can pass them; bool is never a number.

Check = Callable[[Any], Any]


def _wrong_type(name: str, expected: str, raw: object) -> Invalid:
    return Invalid(Reason.WRONG_TYPE, f"expected {expected}, got {type(raw).__name__}", name)


def _float_slow(raw: object, name: str) -> float:
    if isinstance(raw, bool) or not isinstance(raw, float | int):
        raise _wrong_type(name, "float", raw)
    try:
        return float(raw)
    except OverflowError:
        raise Invalid(Reason.OUT_OF_RANGE, "int too large for a float64", name) from None


def _float_error(name: str, x: float, lo: float, hi: float) -> Invalid:
    if not math.isfinite(x):
        return Invalid(Reason.NON_FINITE, f"{x!r} is not finite", name)
    return Invalid(Reason.OUT_OF_RANGE, f"{x!r} not in [{lo!r}, {hi!r}]", name)


def _float_check(name: str, lo: float, hi: float) -> Check:
    def check(raw: Any) -> float:
        x = raw if type(raw) is float else _float_slow(raw, name)  # ints converted here
        if lo <= x <= hi:  # also False for NaN; +-inf fails the +-FLOAT64_MAX default bounds
            return x
        raise _float_error(name, x, lo, hi)

    return check


def _int_check(name: str, lo: int, hi: int) -> Check:
    def check(raw: Any) -> int:
        if type(raw) is not int:
            if isinstance(raw, bool) or not isinstance(raw, int):
                raise _wrong_type(name, "int", raw)
            raw = int(raw)
        if lo <= raw <= hi:
            return raw
        raise Invalid(Reason.OUT_OF_RANGE, f"{raw!r} not in [{lo}, {hi}]", name)

    return check


def _bool_check(name: str) -> Check:
    def check(raw: Any) -> bool:
        if raw is True or raw is False:
            return raw
        raise _wrong_type(name, "bool", raw)

    return check


_KNOWN_MAX = 4096
_known_good: dict[str, set[str]] = {}  # pattern -> strings that matched it (ids repeat a lot)


def _plain_str(raw: object, name: str) -> str:
    if not isinstance(raw, str):
        raise _wrong_type(name, "str", raw)
    return str.__str__(raw)  # plain str with the same characters (e.g. a StrEnum member)


def _str_check(
    name: str,
    max_len: int,
    pattern: str | None,
    choices: tuple[str, ...],
) -> Check:
    if choices:
        allowed = frozenset(choices)

        def check_enum(raw: Any) -> str:
            if type(raw) is not str:
                raw = _plain_str(raw, name)
            if raw in allowed:
                return raw
            raise Invalid(Reason.OUT_OF_RANGE, f"{raw[:80]!r} not one of {sorted(allowed)}", name)

        return check_enum

    if pattern is not None:
        match = re.compile(pattern).fullmatch
        # A regex match costs ~0.5 us; ids repeat, so remember (a bounded number of) good ones.
        known = _known_good.setdefault(pattern, set())

        def check_pattern(raw: Any) -> str:
            if type(raw) is not str:
                raw = _plain_str(raw, name)
            if raw in known:
                return raw
            if len(raw) > max_len:
                raise Invalid(Reason.OUT_OF_RANGE, f"longer than {max_len} characters", name)
            if match(raw) is None:
                raise Invalid(Reason.OUT_OF_RANGE, f"{raw[:80]!r} does not match {pattern}", name)
            if len(known) < _KNOWN_MAX:
                known.add(raw)
            return raw

        return check_pattern

    def check_text(raw: Any) -> str:
        if type(raw) is not str:
            raw = _plain_str(raw, name)
        if len(raw) > max_len:
            raise Invalid(Reason.OUT_OF_RANGE, f"longer than {max_len} characters", name)
        return raw

    return check_text


def _sequence(raw: Any, name: str, expected: str, max_len: int) -> tuple[Any, ...] | list[Any]:
    if type(raw) is not tuple and not isinstance(raw, tuple | list):
        raise _wrong_type(name, expected, raw)
    if len(raw) > max_len:
        raise Invalid(Reason.OUT_OF_RANGE, f"{len(raw)} elements, at most {max_len}", name)
    seq: tuple[Any, ...] | list[Any] = raw
    return seq


def _float_list_check(name: str, lo: float, hi: float, max_len: int) -> Check:
    element = _float_check(name, lo, hi)

    def check(raw: Any) -> tuple[float, ...]:
        seq = _sequence(raw, name, "list[float]", max_len)
        for e in seq:  # fast path: every element an in-range float64
            if type(e) is not float or not lo <= e <= hi:
                break
        else:
            return seq if type(seq) is tuple else tuple(seq)
        return tuple(_elements(element, seq, name))

    return check


def _str_list_check(name: str, pattern: str | None, max_len: int) -> Check:
    element_max = keys.ID_MAX_LEN if pattern is not None else MAX_STR_LEN
    element = _str_check(name, element_max, pattern, ())

    def check(raw: Any) -> tuple[str, ...]:
        return tuple(_elements(element, _sequence(raw, name, "list[str]", max_len), name))

    return check


def _int_list_check(name: str, lo: int, hi: int, max_len: int) -> Check:
    element = _int_check(name, lo, hi)

    def check(raw: Any) -> tuple[int, ...]:
        seq = _sequence(raw, name, "list[int]", max_len)
        for e in seq:  # fast path: every element an in-range int
            if type(e) is not int or not lo <= e <= hi:
                break
        else:
            return seq if type(seq) is tuple else tuple(seq)
        return tuple(_elements(element, seq, name))

    return check


def _elements(element: Check, seq: tuple[Any, ...] | list[Any], name: str) -> list[Any]:
    """Validate each element; an error names the element (``x[3]``)."""
    out: list[Any] = []
    for i, e in enumerate(seq):
        try:
            out.append(element(e))
        except Invalid as exc:
            raise Invalid(exc.error.reason, exc.error.detail, f"{name}[{i}]") from None
    return out


def _str_int_map_check(
    name: str, key_pattern: str | None, value_lo: int, value_hi: int, max_len: int
) -> Check:
    key_check = _str_check(f"{name} key", keys.ID_MAX_LEN, key_pattern, ())
    value_check = _int_check(f"{name} value", value_lo, value_hi)

    def check(raw: Any) -> dict[str, int]:
        if type(raw) is not dict and not isinstance(raw, Mapping):
            raise _wrong_type(name, "map", raw)
        if len(raw) > max_len:
            raise Invalid(Reason.OUT_OF_RANGE, f"{len(raw)} entries, at most {max_len}", name)
        items = [(key_check(k), value_check(v)) for k, v in raw.items()]
        items.sort()
        return dict(items)

    return check


def compile_check(name: str, fs: FieldSpec) -> Check:
    """Build the validator of one field from its spec (done once per field, at import)."""
    lo = float(fs.lo) if fs.lo is not None else -FLOAT64_MAX
    hi = float(fs.hi) if fs.hi is not None else FLOAT64_MAX
    if fs.kind is Kind.FLOAT:
        return _float_check(name, lo, hi)
    if fs.kind is Kind.INT:
        ilo = int(fs.lo) if fs.lo is not None else INT64_MIN
        ihi = int(fs.hi) if fs.hi is not None else UINT64_MAX
        return _int_check(name, ilo, ihi)
    if fs.kind is Kind.BOOL:
        return _bool_check(name)
    if fs.kind in (Kind.STR, Kind.ENUM):
        return _str_check(name, fs.max_len or MAX_STR_LEN, fs.pattern, fs.choices)
    if fs.kind is Kind.FLOAT_LIST:
        return _float_list_check(name, lo, hi, fs.max_len or MAX_LIST_LEN)
    if fs.kind is Kind.STR_LIST:
        return _str_list_check(name, fs.pattern, fs.max_len or MAX_LIST_LEN)
    if fs.kind is Kind.INT_LIST:
        ilo = int(fs.lo) if fs.lo is not None else INT64_MIN
        ihi = int(fs.hi) if fs.hi is not None else UINT64_MAX
        return _int_list_check(name, ilo, ihi, fs.max_len or MAX_LIST_LEN)
    if fs.kind is Kind.STR_INT_MAP:
        vlo = fs.value_lo if fs.value_lo is not None else INT64_MIN
        vhi = fs.value_hi if fs.value_hi is not None else UINT64_MAX
        return _str_int_map_check(name, fs.pattern, vlo, vhi, fs.max_len or MAX_MAP_LEN)
    raise TypeError(f"unhandled field kind {fs.kind}")  # pragma: no cover


# --- message specs --------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class FieldInfo:
    """A field of a message type: its name, spec, and whether it may be absent."""

    name: str
    spec: FieldSpec
    optional: bool

    @property
    def presence(self) -> str:
        """``required``, ``required, nil allowed`` or ``optional`` (for the docs)."""
        if self.optional:
            return "optional"
        return "required, nil allowed" if self.spec.nullable else "required"


@dataclass(frozen=True, slots=True)
class MessageSpec:
    """Everything about one message type: identity, key, fields, rules, compiled codec."""

    name: str
    cls: type
    key: str
    publisher: str
    periodic: bool
    rate: str
    summary: str
    fields: tuple[FieldInfo, ...]
    rules: tuple[Rule, ...]
    decode_map: Callable[[Mapping[Any, Any]], Any]  # raises Invalid
    encode_map: Callable[[Any], dict[str, Any]]  # raises Invalid


_REGISTRY: dict[type, MessageSpec] = {}

T = TypeVar("T")

_ABSENT: Any = object()


def _version_error(v: object) -> Invalid:
    if v is _ABSENT:
        return Invalid(Reason.MISSING_FIELD, "required field is absent", "v")
    if type(v) is not int:
        return _wrong_type("v", "int", v)
    return Invalid(Reason.UNKNOWN_VERSION, f"schema version {v}, this decoder knows {VERSION}", "v")


def _compile(
    cls: type, fields: tuple[FieldInfo, ...], rules: tuple[Rule, ...]
) -> tuple[Callable[[Mapping[Any, Any]], Any], Callable[[Any], dict[str, Any]]]:
    """Build the decoder and encoder of one message type (once, at import)."""
    # The decoder builds the instance directly through the slots' member descriptors instead of
    # calling the frozen dataclass __init__ (which costs ~3 us for 7 fields): every field,
    # including absent optional ones (None), is set exactly once, and values are already valid.
    new = object.__new__
    slot_set = {f.name: getattr(cls, f.name).__set__ for f in fields}
    set_v = slot_set["v"]
    # (name, check, nil allowed, optional, setter, lo, hi) of every field but `v`, in wire order.
    # lo/hi let the decoder accept an in-range float64 inline, without calling `check` (most
    # fields are floats); for other kinds lo > hi, so that test is always False.
    plan = tuple(
        (
            f.name,
            compile_check(f.name, f.spec),
            f.spec.nullable,
            f.optional,
            slot_set[f.name],
            *_float_bounds(f.spec),
        )
        for f in fields
        if f.name != "v"
    )
    encode_plan = tuple((p[0], p[1], p[2], p[3]) for p in plan)  # (name, check, nil ok, optional)
    getter = attrgetter("v", *(p[0] for p in plan))

    def decode_map(obj: Mapping[Any, Any]) -> Any:
        v = obj.get("v", _ABSENT)
        if type(v) is not int or v != VERSION:
            raise _version_error(v)
        msg: Any = new(cls)
        set_v(msg, VERSION)
        for name, check, nil_ok, optional, setter, lo, hi in plan:
            raw = obj.get(name)
            if type(raw) is float and lo <= raw <= hi:
                setter(msg, raw)
                continue
            if raw is None:
                if optional or (nil_ok and name in obj):
                    setter(msg, None)
                    continue
                if name not in obj:
                    raise Invalid(Reason.MISSING_FIELD, "required field is absent", name)
                raise Invalid(Reason.WRONG_TYPE, "nil is not allowed", name)
            setter(msg, check(raw))
        for rule in rules:
            rule.check(msg)
        return msg

    def encode_map(msg: Any) -> dict[str, Any]:
        raw_values = getter(msg)
        v = raw_values[0]
        if type(v) is not int or v != VERSION:
            raise _version_error(v)
        out: dict[str, Any] = {"v": VERSION}
        for (name, check, nil_ok, optional), raw in zip(encode_plan, raw_values[1:], strict=True):
            if raw is None:
                if optional:
                    continue
                if nil_ok:
                    out[name] = None
                    continue
                raise Invalid(Reason.MISSING_FIELD, "required field is None", name)
            out[name] = check(raw)
        for rule in rules:
            rule.check(msg)
        return out

    return decode_map, encode_map


def _float_bounds(fs: FieldSpec) -> tuple[float, float]:
    """Inclusive bounds of a FLOAT field for the decoder's inline fast path; (inf, -inf) else."""
    if fs.kind is not Kind.FLOAT:
        return math.inf, -math.inf
    lo = float(fs.lo) if fs.lo is not None else -FLOAT64_MAX
    hi = float(fs.hi) if fs.hi is not None else FLOAT64_MAX
    return lo, hi


def _check_declaration(cls: type, periodic: bool) -> tuple[FieldInfo, ...]:
    """Check the dataclass against its field specs; raise TypeError on any mismatch."""
    if not dataclasses.is_dataclass(cls):
        raise TypeError(f"{cls.__name__}: @message must decorate a dataclass")
    params = getattr(cls, "__dataclass_params__", None)
    if params is None or not params.frozen or not hasattr(cls, "__slots__"):
        raise TypeError(f"{cls.__name__}: must be @dataclass(frozen=True, slots=True)")
    hints = typing.get_type_hints(cls)
    infos: list[FieldInfo] = []
    for f in dataclasses.fields(cls):
        fs = f.metadata.get(META_KEY)
        if not isinstance(fs, FieldSpec):
            raise TypeError(f"{cls.__name__}.{f.name}: no FieldSpec in metadata")
        has_default = f.default is not dataclasses.MISSING
        if f.default_factory is not dataclasses.MISSING:
            raise TypeError(f"{cls.__name__}.{f.name}: default_factory is not supported")
        if f.name == "v":
            optional = False
            if f.default != VERSION:
                raise TypeError(f"{cls.__name__}.v must default to {VERSION}")
        else:
            optional = has_default
            if has_default and f.default is not None:
                raise TypeError(f"{cls.__name__}.{f.name}: an optional field must default to None")
            if optional and fs.nullable:
                raise TypeError(f"{cls.__name__}.{f.name}: optional and nullable are exclusive")
        expected = fs.python_type()
        if optional or fs.nullable:
            expected = expected | None
        if hints[f.name] != expected:
            raise TypeError(
                f"{cls.__name__}.{f.name}: annotation {hints[f.name]} does not match "
                f"spec kind {fs.kind} (expected {expected})"
            )
        infos.append(FieldInfo(f.name, fs, optional))
    head = [i.name for i in infos[: 3 if periodic else 2]]
    if head != (["v", "t", "seq"] if periodic else ["v", "t"]):
        raise TypeError(f"{cls.__name__}: fields must start with v, t{', seq' if periodic else ''}")
    if not periodic and any(i.name == "seq" for i in infos):
        raise TypeError(f"{cls.__name__}: seq only on periodic messages")
    return tuple(infos)


def message(
    *,
    name: str,
    publisher: str,
    periodic: bool,
    rate: str = "",
    rules: tuple[Rule, ...] = (),
) -> Callable[[type[T]], type[T]]:
    """Register a message dataclass: check it, compile its codec, record its spec.

    `name` is also the key leaf (its key template is keys.KEY_TEMPLATES[name]); `publisher` and
    `rate` are documentation; `periodic` messages carry `seq`.
    """

    def decorate(cls: type[T]) -> type[T]:
        if name not in keys.KEY_TEMPLATES:
            raise TypeError(f"{cls.__name__}: no key template named {name!r}")
        fields = _check_declaration(cls, periodic)
        names = {f.name for f in fields}
        for rule in rules:
            for ref in _rule_fields(rule):
                if ref not in names:
                    raise TypeError(f"{cls.__name__}: rule refers to unknown field {ref!r}")
        decode_map, encode_map = _compile(cls, fields, rules)
        _REGISTRY[cls] = MessageSpec(
            name=name,
            cls=cls,
            key=keys.KEY_TEMPLATES[name],
            publisher=publisher,
            periodic=periodic,
            rate=rate,
            summary=inspect.cleandoc(cls.__doc__ or ""),
            fields=fields,
            rules=rules,
            decode_map=decode_map,
            encode_map=encode_map,
        )
        return cls

    return decorate


def _rule_fields(rule: Rule) -> tuple[str, ...]:
    if isinstance(rule, SameLength):
        return rule.fields
    if isinstance(rule, RequiredWhen):
        return (rule.field, *rule.required)
    return ()


def spec_of(cls: type) -> MessageSpec:
    """The MessageSpec of a registered message type; TypeError for anything else."""
    try:
        return _REGISTRY[cls]
    except KeyError:
        raise TypeError(f"{cls!r} is not a bus message type") from None


def registered_specs() -> tuple[MessageSpec, ...]:
    """Every registered message spec, in declaration order."""
    return tuple(_REGISTRY.values())
