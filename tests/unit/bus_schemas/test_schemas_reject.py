"""bus_schemas decode: every rejection reason, for every message type (the reason and a detail
naming the field), from the field tables."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import msgpack
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from support.bus_samples import (
    ALL_FIELD_IDS,
    ALL_FIELDS,
    SAMPLES,
    TYPE_IDS,
    TYPES,
    pack,
    rejected,
    wire_map,
)

from bus_schemas import (
    MAX_LIST_LEN,
    MAX_MAP_LEN,
    MAX_PAYLOAD_BYTES,
    Assignment,
    Clock,
    DecodeError,
    Disturbance,
    DisturbanceKind,
    Estop,
    Obstacle,
    Pose,
    PoseBatch,
    Reason,
    SchemaError,
    Status,
    Wheels,
    decode,
    decode_or_raise,
    encode,
    from_map,
    keys,
    spec_of,
)
from bus_schemas.spec import (
    FieldInfo,
    Kind,
    SameLength,
    Together,
)

REPO = Path(__file__).resolve().parents[3]
# derandomize: the same examples on every run (deterministic CI), no example database.
HYP = settings(
    max_examples=200,
    deadline=None,
    derandomize=True,
    suppress_health_check=[HealthCheck.too_slow],
)
# Properties run once per message type (13 types); 50 examples each keeps the suite fast on a
# 2-core machine (650 generated messages per property in all).
HYP_PER_TYPE = settings(HYP, max_examples=50)


# --- every rejection reason, for every message type --------------------------------------------


def _mutate(cls: type, reason: Reason) -> bytes:
    m = wire_map(cls)
    if reason is Reason.MALFORMED:
        return encode(SAMPLES[cls])[:-1]
    if reason is Reason.NOT_A_MAP:
        return pack(list(m.values()))
    if reason is Reason.MISSING_FIELD:
        del m["t"]
    elif reason is Reason.WRONG_TYPE:
        m["t"] = "1.0"
    elif reason is Reason.NON_FINITE:
        m["t"] = math.nan
    elif reason is Reason.OUT_OF_RANGE:
        m["t"] = -1.0
    elif reason is Reason.UNKNOWN_VERSION:
        m["v"] = 2
    elif reason is Reason.TOO_LARGE:
        m["padding"] = "x" * MAX_PAYLOAD_BYTES
    elif reason is Reason.NON_STRING_KEY:
        return pack_pairs([*m.items(), (7, "x")])
    elif reason is Reason.DUPLICATE_KEY:
        return pack_pairs([*m.items(), ("t", m["t"])])  # even with the same value
    return pack(m)


def pack_pairs(pairs: list[tuple[Any, Any]]) -> bytes:
    """A msgpack map written pair by pair: keys may repeat or be of any type."""
    packer = msgpack.Packer(use_bin_type=True)
    out = packer.pack_map_header(len(pairs))
    for k, v in pairs:
        out += packer.pack(k) + packer.pack(v)
    return out


# Every (type, reason) pair; `inconsistent` exists only where a type has a cross-field rule
# that can be broken on the wire by lengths (PoseBatch); Disturbance's rule is `missing_field`.
REASON_CASES = [
    (cls, reason)
    for cls in TYPES
    for reason in Reason
    if reason is not Reason.INCONSISTENT
    or any(isinstance(r, SameLength) for r in spec_of(cls).rules)
]


@pytest.mark.parametrize(
    ("cls", "reason"), REASON_CASES, ids=[f"{c.__name__}-{r}" for c, r in REASON_CASES]
)
def test_every_reason_for_every_type(cls: type, reason: Reason) -> None:
    if reason is Reason.INCONSISTENT:
        first = next(r for r in spec_of(cls).rules if isinstance(r, SameLength)).fields[1]
        data = pack(wire_map(cls) | {first: wire_map(cls)[first][:1]})
    else:
        data = _mutate(cls, reason)
    err = rejected(data, cls)
    assert err.reason == reason
    with pytest.raises(SchemaError) as exc_info:
        decode_or_raise(data, cls)
    assert exc_info.value.error == err
    assert isinstance(exc_info.value, ValueError)


def _wrong_type_values(info: FieldInfo) -> list[Any]:
    kind = info.spec.kind
    if kind is Kind.FLOAT:
        return ["1.0", True, b"\x00", [1.0], {"a": 1.0}]
    if kind is Kind.INT:
        return [1.5, True, False, "1", b"1"]
    if kind is Kind.BOOL:
        return [1, 0, "true", 1.0]
    if kind in (Kind.STR, Kind.ENUM):
        return [5, True, b"r1", ["r1"], 1.5]
    if kind in (Kind.FLOAT_LIST, Kind.STR_LIST, Kind.INT_LIST):
        return ["abc", 1.0, {"a": 1}, b"\x01\x02"]
    if kind is Kind.STR_INT_MAP:
        return [[1, 2], "r1", 3]
    raise AssertionError(kind)  # pragma: no cover


@pytest.mark.parametrize(("cls", "info"), ALL_FIELDS, ids=ALL_FIELD_IDS)
def test_every_field_rejects_wrong_types(cls: type, info: FieldInfo) -> None:
    for bad in _wrong_type_values(info):
        err = rejected(pack(wire_map(cls) | {info.name: bad}), cls)
        assert err.reason is Reason.WRONG_TYPE, (bad, err)
        assert err.field == info.name


@pytest.mark.parametrize(("cls", "info"), ALL_FIELDS, ids=ALL_FIELD_IDS)
def test_every_field_presence(cls: type, info: FieldInfo) -> None:
    m = wire_map(cls)
    absent = {k: v for k, v in m.items() if k != info.name}
    nil = m | {info.name: None}
    if info.optional:
        if cls is Disturbance and info.name in ("x", "y", "theta"):
            # Required by a rule for the teleport sample; optional for a drag.
            for data in (pack(absent), pack(nil)):
                err = rejected(data, cls)
                assert err.reason is Reason.MISSING_FIELD and err.field == info.name
            absent["kind"] = nil["kind"] = "drag"
        if cls is Obstacle and info.name in ("xs", "ys"):
            # Required by a rule for the polygon sample; optional for a circle.
            for data in (pack(absent), pack(nil)):
                err = rejected(data, cls)
                assert err.reason is Reason.MISSING_FIELD and err.field == info.name
            absent["shape"] = nil["shape"] = "circle"
        together = [r.fields for r in spec_of(cls).rules if isinstance(r, Together)]
        group = next((g for g in together if info.name in g), None)
        if group is not None:
            # present together or not at all: alone it is missing; the whole group may go
            for data in (pack(absent), pack(nil)):
                err = rejected(data, cls)
                assert err.reason is Reason.MISSING_FIELD, err
            absent = {k: v for k, v in absent.items() if k not in group}
            nil = m | dict.fromkeys(group)
        ok: Any = decode_or_raise(pack(absent), cls)
        assert getattr(ok, info.name) is None
        assert decode_or_raise(pack(nil), cls) == ok  # nil reads as absent
        return
    err = rejected(pack(absent), cls)
    assert err.reason is Reason.MISSING_FIELD and err.field == info.name
    if info.spec.nullable:
        assert getattr(decode_or_raise(pack(nil), cls), info.name) is None
    else:
        err = rejected(pack(nil), cls)
        assert err.reason is Reason.WRONG_TYPE and err.field == info.name


FLOAT_FIELDS = [(c, f) for c, f in ALL_FIELDS if f.spec.kind in (Kind.FLOAT, Kind.FLOAT_LIST)]


@pytest.mark.parametrize(
    ("cls", "info"), FLOAT_FIELDS, ids=[f"{c.__name__}.{f.name}" for c, f in FLOAT_FIELDS]
)
def test_every_float_rejects_nan_and_inf(cls: type, info: FieldInfo) -> None:
    m = wire_map(cls)
    for bad in (math.nan, math.inf, -math.inf):
        if info.spec.kind is Kind.FLOAT:
            value: Any = bad
            where = info.name
        else:  # a list element, not the first
            value = [0.0] * (len(m[info.name]) - 1) + [bad]
            where = f"{info.name}[{len(value) - 1}]"
        err = rejected(pack(m | {info.name: value}), cls)
        assert err.reason is Reason.NON_FINITE and err.field == where


def _out_of_range_values(info: FieldInfo, current: Any) -> list[Any]:
    fs = info.spec
    if fs.kind is Kind.FLOAT or fs.kind is Kind.INT:
        bad: list[Any] = []
        step: Any = 1 if fs.kind is Kind.INT else 1e-6
        if fs.lo is not None and fs.lo > -1e300:
            bad.append(fs.lo - step)
        if fs.hi is not None and fs.hi < 1e300 and fs.hi != 2**64 - 1:  # 2**64 is not msgpack
            bad.append(fs.hi + step)
        return bad
    if fs.kind is Kind.ENUM:
        return ["nope", fs.choices[0].upper(), ""]
    if fs.kind is Kind.STR:
        if fs.pattern == keys.ROBOT_ID_PATTERN:
            return ["R1", "", "a/b", "*", "r 1", "r.1", "x" * 65]
        if fs.pattern is not None:
            return ["", "a/b", "*", "r 1", "r.1", "x" * 65]
        return ["x" * ((fs.max_len or 255) + 1)]
    if fs.kind is Kind.FLOAT_LIST:
        out = [[0.0] * (MAX_LIST_LEN + 1)]
        if fs.lo is not None:
            out.append([*current[:-1], fs.lo - 1e-6])
        return out
    if fs.kind is Kind.STR_LIST:
        return [["r1"] * (MAX_LIST_LEN + 1), [*current[:-1], "Bad 1"]]
    if fs.kind is Kind.INT_LIST:
        bad_ints: list[Any] = [[0] * (MAX_LIST_LEN + 1)]
        if fs.lo is not None:
            bad_ints.append([*current[:-1], int(fs.lo) - 1])
        return bad_ints
    if fs.kind is Kind.STR_INT_MAP:
        too_many = {f"k{i}": 0 for i in range(MAX_MAP_LEN + 1)}
        bad_maps: list[Any] = [too_many, {"Bad Key": 0}, {"r1": -1}]
        if fs.value_hi is not None and fs.value_hi < 2**64 - 1:
            bad_maps.append({"r1": fs.value_hi + 1})
        return bad_maps
    return []


RANGED = [(c, f) for c, f in ALL_FIELDS if f.spec.kind is not Kind.BOOL]


@pytest.mark.parametrize(("cls", "info"), RANGED, ids=[f"{c.__name__}.{f.name}" for c, f in RANGED])
def test_every_field_rejects_out_of_range(cls: type, info: FieldInfo) -> None:
    m = wire_map(cls)
    bad_values = _out_of_range_values(info, m.get(info.name))
    if info.name == "v":
        for v in (0, 2, -1, 2**40):
            assert rejected(pack(m | {"v": v}), cls).reason is Reason.UNKNOWN_VERSION
        return
    unbounded_float = info.spec.kind is Kind.FLOAT and not bad_values
    if unbounded_float:  # only finiteness applies; the extremes are valid
        for edge in (-1.7976931348623157e308, 1.7976931348623157e308, 5e-324):
            assert decode_or_raise(pack(m | {info.name: edge}), cls) is not None
        return
    assert bad_values, "every non-float field has something out of range"
    for bad in bad_values:
        err = rejected(pack(m | {info.name: bad}), cls)
        if err.reason is Reason.TOO_LARGE:
            continue  # a 1025-element list can exceed the payload cap: rejected either way
        assert err.reason is Reason.OUT_OF_RANGE, (bad if not isinstance(bad, list) else "", err)
        assert err.field is not None and err.field.startswith(info.name)


def test_specific_bounds() -> None:
    m = wire_map(Pose)
    for ok in (math.pi, -math.pi, math.pi + 1e-9, -math.pi - 1e-9, 0.0):
        assert decode_or_raise(pack(m | {"theta": ok}), Pose).theta == ok
    for bad in (math.pi + 1e-8, -math.pi - 1e-8, 4.0, 2 * math.pi):
        assert rejected(pack(m | {"theta": bad}), Pose).reason is Reason.OUT_OF_RANGE
    w = wire_map(Wheels)
    for ok in (1.0, -1.0, 0.0, 1, -1):
        assert decode_or_raise(pack(w | {"power_l": ok}), Wheels).power_l == ok
    for bad in (1.0000001, -1.0000001, 2):
        assert rejected(pack(w | {"power_r": bad}), Wheels).reason is Reason.OUT_OF_RANGE
    b = wire_map(PoseBatch)
    err = rejected(pack(b | {"theta": [0.0, 3.5]}), PoseBatch)
    assert (err.reason, err.field) == (Reason.OUT_OF_RANGE, "theta[1]")
    err = rejected(pack(b | {"robots": ["r1", "R2"]}), PoseBatch)
    assert (err.reason, err.field) == (Reason.OUT_OF_RANGE, "robots[1]")


def test_strict_bool_int_and_version_types() -> None:
    assert rejected(pack(wire_map(Pose) | {"seq": True}), Pose).reason is Reason.WRONG_TYPE
    assert rejected(pack(wire_map(Pose) | {"seq": 1.0}), Pose).reason is Reason.WRONG_TYPE
    assert rejected(pack(wire_map(Estop) | {"engage": 1}), Estop).reason is Reason.WRONG_TYPE
    assert rejected(pack(wire_map(Estop) | {"engage": 0}), Estop).reason is Reason.WRONG_TYPE
    for v in (True, 1.0, "1", None):
        err = rejected(pack(wire_map(Clock) | {"v": v}), Clock)
        assert err.reason is Reason.WRONG_TYPE and err.field == "v"
    m = wire_map(Clock)
    del m["v"]
    assert rejected(pack(m), Clock).reason is Reason.MISSING_FIELD
    # A bad version is reported first, whatever else is wrong: v2 may have other fields.
    assert rejected(pack({"v": 2}), Clock).reason is Reason.UNKNOWN_VERSION
    assert rejected(pack({"v": 1}), Clock).reason is Reason.MISSING_FIELD


def test_unknown_fields_are_ignored_but_not_non_str_keys() -> None:
    m = wire_map(Status) | {"battery_v": 7.4, "future": {"nested": [1, 2]}}
    assert decode_or_raise(pack(m), Status) == SAMPLES[Status]
    # A non-str key anywhere refuses the whole payload (issue 13: a map with an int key was
    # accepted and acted on), even in an unknown field nobody reads.
    odds: list[dict[Any, Any]] = [{7: "x"}, {(1, 2): None}, {b"t": 1.0}, {None: 1}]
    odds.append({"future": {3: 1}})
    for odd in odds:
        raw = msgpack.packb({**wire_map(Clock), **odd}, use_bin_type=True)
        assert rejected(raw, Clock).reason is Reason.NON_STRING_KEY, odd
    assert from_map({**wire_map(Clock), 7: "x"}, Clock).reason is Reason.NON_STRING_KEY  # type: ignore[union-attr]


def test_duplicate_keys_are_refused_at_any_depth() -> None:
    m = wire_map(Wheels)
    # A generic decoder keeps the last value: power 1.0 would win over the first, valid 0.1.
    forged = pack_pairs([*m.items(), ("power_r", 1.0)])
    assert msgpack.unpackb(forged)["power_r"] == 1.0
    err = rejected(forged, Wheels)
    assert err.reason is Reason.DUPLICATE_KEY and "power_r" in err.detail
    a = wire_map(Assignment)
    packer = msgpack.Packer(use_bin_type=True)
    nested = packer.pack_map_header(2) + packer.pack("r1") + packer.pack(0)
    nested += packer.pack("r1") + packer.pack(1)
    top = pack_pairs([(k, v) for k, v in a.items() if k != "robots"])
    # rewrite the top-level header to one more entry and append robots -> nested map
    head = packer.pack_map_header(len(a))
    data = head + top[len(packer.pack_map_header(len(a) - 1)) :] + packer.pack("robots") + nested
    assert msgpack.unpackb(data)["robots"] == {"r1": 1}
    assert rejected(data, Assignment).reason is Reason.DUPLICATE_KEY


def test_nested_map_rejects_bad_keys_and_values() -> None:
    m = wire_map(Assignment)
    assert rejected(pack(m | {"robots": {1: 0}}), Assignment).reason is Reason.NON_STRING_KEY
    assert rejected(pack(m | {"robots": {"r1": True}}), Assignment).reason is Reason.WRONG_TYPE
    assert rejected(pack(m | {"robots": {"r1": 1.0}}), Assignment).reason is Reason.WRONG_TYPE
    assert rejected(pack(m | {"robots": {"r1": 70000}}), Assignment).reason is Reason.OUT_OF_RANGE
    assert decode_or_raise(pack(m | {"robots": {}}), Assignment).robots == {}


def test_disturbance_rule_and_drag_without_target() -> None:
    drag = Disturbance(
        t=2.0, robot="r1", kind=DisturbanceKind.DRAG, dx=-0.3, dy=0.0, duration_s=1.5
    )
    assert decode_or_raise(encode(drag), Disturbance) == drag
    teleport = Disturbance(
        t=2.0, robot="r1", kind="teleport", dx=0.0, dy=0.0, duration_s=0.0, x=1.0, y=1.0
    )
    with pytest.raises(SchemaError) as exc_info:
        encode(teleport)
    assert exc_info.value.error.reason is Reason.MISSING_FIELD
    assert exc_info.value.error.field == "theta"
    m = wire_map(Disturbance)
    del m["x"]
    err = rejected(pack(m), Disturbance)
    assert (err.reason, err.field) == (Reason.MISSING_FIELD, "x")


def test_malformed_variants() -> None:
    good = encode(SAMPLES[Pose])
    for data in (b"", b"\xc1", good + b"\x00", good[:5], b"\x81\xa1v", b"\xa2\xff\xfe"):
        assert rejected(data, Pose).reason is Reason.MALFORMED
    deep = b"\x91" * 5000 + b"\x00"  # nesting deeper than the unpacker's stack
    assert rejected(deep, Pose).reason in (Reason.MALFORMED, Reason.NOT_A_MAP)
    for not_bytes in (None, "abc", 12, object()):
        assert rejected(not_bytes, Pose).reason is Reason.MALFORMED  # type: ignore[arg-type]
    assert decode(bytearray(good), Pose) == SAMPLES[Pose]
    assert decode(memoryview(good), Pose) == SAMPLES[Pose]
    for top in (pack(None), pack(1), pack("pose"), pack([1, 2]), pack(b"\x81")):
        assert rejected(top, Pose).reason is Reason.NOT_A_MAP
    ext = msgpack.packb(wire_map(Pose) | {"x": msgpack.ExtType(5, b"abc")})
    assert rejected(ext, Pose).reason is Reason.WRONG_TYPE


def test_too_large_is_checked_before_parsing() -> None:
    assert rejected(b"\xc1" * (MAX_PAYLOAD_BYTES + 1), Pose).reason is Reason.TOO_LARGE
    ok = pack(wire_map(Pose) | {"pad": "x" * (MAX_PAYLOAD_BYTES - 200)})
    assert len(ok) <= MAX_PAYLOAD_BYTES and decode_or_raise(ok, Pose) == SAMPLES[Pose]


@pytest.mark.parametrize("cls", TYPES, ids=TYPE_IDS)
@HYP_PER_TYPE
@given(data=st.binary(max_size=600))
def test_random_bytes_never_raise(cls: type, data: bytes) -> None:
    result = decode(data, cls)
    assert isinstance(result, DecodeError | cls)


MSGPACK_VALUES = st.recursive(
    st.none()
    | st.booleans()
    | st.integers(min_value=-(2**63), max_value=2**64 - 1)
    | st.floats()
    | st.text(max_size=70)
    | st.binary(max_size=8)
    | st.sampled_from(["r1", "leader", "teleport", "tracking", "R1", ""]),
    lambda inner: (
        st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=5), inner, max_size=4)
    ),
    max_leaves=10,
)


@pytest.mark.parametrize("cls", TYPES, ids=TYPE_IDS)
@HYP_PER_TYPE
@given(data=st.data())
def test_structured_fuzz_never_raises(cls: type, data: st.DataObject) -> None:
    """Valid maps with some fields replaced by arbitrary values: always a message or an error."""
    m = wire_map(cls)
    names = [*m, "v", "t", "junk"]
    changes = data.draw(st.dictionaries(st.sampled_from(names), MSGPACK_VALUES, max_size=4))
    drops = data.draw(st.sets(st.sampled_from(names), max_size=2))
    fuzzed = {k: v for k, v in (m | changes).items() if k not in drops}
    result: Any = decode(pack(fuzzed), cls)
    assert isinstance(result, DecodeError | cls)
    if not isinstance(result, DecodeError):
        accepted: Any = result
        assert decode(encode(accepted), cls) == accepted  # whatever is accepted re-encodes cleanly
