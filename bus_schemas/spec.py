"""The declarative schema machinery: message specs compiled from the field specs.

Each message type is a frozen, slotted dataclass (bus_schemas.messages) whose fields carry a
`FieldSpec` in their metadata (type, unit, range or enum, nil allowed, description), decorated
with `@message(...)` (name, key, publisher, periodic, rules). At import the decorator checks the
dataclass against its specs and compiles, once per type, a decoder and an encoder out of small
per-field closures, so a decode does no reflection: one dict lookup and one closure call per field.
Encode, decode, validation and docs/bus.md all derive from these tables.

The field specs and their constructors live in :mod:`bus_schemas.fields`, the validators in
:mod:`bus_schemas.checks`; both are re-exported here (``from bus_schemas.spec import f_float``
keeps working).
"""

from __future__ import annotations

import dataclasses
import inspect
import math
import typing
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from operator import attrgetter
from typing import Any, TypeVar

from bus_schemas import keys
from bus_schemas.checks import compile_check, wrong_type
from bus_schemas.errors import Invalid, Reason
from bus_schemas.fields import (
    ANGLE_HI,
    ANGLE_LO,
    DURATION_MAX_S,
    EPOCH_MAX,
    FLOAT64_MAX,
    MAX_LIST_LEN,
    MAX_MAP_LEN,
    MAX_PAYLOAD_BYTES,
    MAX_STR_LEN,
    META_KEY,
    POSITION_MAX_M,
    SPEED_MAX_MPS,
    TIME_MAX_S,
    TURN_RATE_MAX_RADPS,
    UINT64_MAX,
    VERSION,
    WHEEL_RATE_MAX_RADPS,
    FieldSpec,
    Kind,
    RequiredWhen,
    Rule,
    SameLength,
    Together,
    f_angle,
    f_angle_list,
    f_bool,
    f_count_map,
    f_enum,
    f_enum_list,
    f_float,
    f_float_list,
    f_int,
    f_int_list,
    f_name,
    f_name_list,
    f_robot_id,
    f_robot_id_list,
    f_slot,
    f_str,
)

__all__ = [
    "ANGLE_HI",
    "ANGLE_LO",
    "DURATION_MAX_S",
    "EPOCH_MAX",
    "FLOAT64_MAX",
    "MAX_LIST_LEN",
    "MAX_MAP_LEN",
    "MAX_PAYLOAD_BYTES",
    "MAX_STR_LEN",
    "META_KEY",
    "POSITION_MAX_M",
    "SPEED_MAX_MPS",
    "TIME_MAX_S",
    "TURN_RATE_MAX_RADPS",
    "UINT64_MAX",
    "VERSION",
    "WHEEL_RATE_MAX_RADPS",
    "FieldInfo",
    "FieldSpec",
    "Kind",
    "MessageSpec",
    "RequiredWhen",
    "Rule",
    "SameLength",
    "Together",
    "compile_check",
    "f_angle",
    "f_angle_list",
    "f_bool",
    "f_count_map",
    "f_enum",
    "f_enum_list",
    "f_float",
    "f_float_list",
    "f_int",
    "f_int_list",
    "f_name",
    "f_name_list",
    "f_robot_id",
    "f_robot_id_list",
    "f_slot",
    "f_str",
    "message",
    "registered_specs",
    "spec_of",
]


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
        return wrong_type("v", "int", v)
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
    if isinstance(rule, SameLength | Together):
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
