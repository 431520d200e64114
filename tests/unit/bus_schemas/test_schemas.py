"""Tests of bus_schemas: round trips, every rejection reason for every type, fuzzing, keys, docs."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import msgpack
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from support.bus_samples import NAMES, ROBOT_IDS, SAMPLES, TYPE_IDS, TYPES, pack, wire_map

from bus_schemas import (
    MAX_LIST_LEN,
    MESSAGE_TYPES,
    Assignment,
    Estop,
    Mode,
    Pose,
    PoseBatch,
    Reason,
    Role,
    SchemaError,
    Slot,
    Status,
    StatusBatch,
    decode,
    decode_or_raise,
    encode,
    from_map,
    keys,
    message_type,
    spec_of,
    to_map,
    validate,
)
from bus_schemas.spec import (
    ANGLE_HI,
    ANGLE_LO,
    POSITION_MAX_M,
    TIME_MAX_S,
    FieldInfo,
    Kind,
    RequiredWhen,
    SameLength,
    f_float,
    message,
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

# --- hypothesis strategies derived from the field tables -------------------------------------

FLOAT_OK = st.floats(allow_nan=False, allow_infinity=False)


def _pattern_strategy(pattern: str) -> st.SearchStrategy[str]:
    if pattern.startswith("(") and pattern.endswith(")"):  # an enum list: (a|b|c)
        return st.sampled_from(pattern[1:-1].split("|"))
    return {keys.ROBOT_ID_PATTERN: ROBOT_IDS, keys.NAME_PATTERN: NAMES}[pattern]


EXACT_INTS = st.integers(min_value=-(2**53), max_value=2**53)  # exactly representable as float


def _float_strategy(lo: float | None, hi: float | None) -> st.SearchStrategy[Any]:
    floats = st.floats(min_value=lo, max_value=hi, allow_nan=False, allow_infinity=False)
    lo_i = -(2**53) if lo is None else math.ceil(lo)
    hi_i = 2**53 if hi is None else math.floor(hi)
    return st.one_of(floats, st.integers(min_value=lo_i, max_value=hi_i))  # ints become floats


def field_strategy(info: FieldInfo) -> st.SearchStrategy[Any]:
    fs = info.spec
    lo = None if fs.lo is None else float(fs.lo)
    hi = None if fs.hi is None else float(fs.hi)
    s: st.SearchStrategy[Any]
    if fs.kind is Kind.FLOAT:
        s = _float_strategy(lo, hi)
    elif fs.kind is Kind.INT:
        s = st.integers(min_value=fs.lo, max_value=fs.hi)  # type: ignore[arg-type]
    elif fs.kind is Kind.BOOL:
        s = st.booleans()
    elif fs.kind is Kind.ENUM:
        s = st.sampled_from(fs.choices)
    elif fs.kind is Kind.STR:
        if fs.pattern is not None:
            s = _pattern_strategy(fs.pattern)
        else:
            s = st.text(max_size=fs.max_len or 255)
    elif fs.kind is Kind.FLOAT_LIST:
        s = st.lists(_float_strategy(lo, hi), max_size=8).map(tuple)
    elif fs.kind is Kind.STR_LIST:
        assert fs.pattern is not None
        s = st.lists(_pattern_strategy(fs.pattern), max_size=8).map(tuple)
    elif fs.kind is Kind.INT_LIST:
        s = st.lists(st.integers(min_value=fs.lo, max_value=fs.hi), max_size=8).map(tuple)  # type: ignore[arg-type]
    elif fs.kind is Kind.STR_INT_MAP:
        assert fs.pattern is not None
        s = st.dictionaries(
            _pattern_strategy(fs.pattern),
            st.integers(min_value=fs.value_lo, max_value=fs.value_hi),
            max_size=8,
        )
    else:  # pragma: no cover
        raise AssertionError(fs.kind)
    if fs.nullable or info.optional:
        s = st.one_of(st.none(), s)
    return s


@st.composite
def _pose_batch(draw: st.DrawFn) -> PoseBatch:
    n = draw(st.integers(min_value=0, max_value=8))
    ids = ROBOT_IDS
    angle = st.floats(min_value=ANGLE_LO, max_value=ANGLE_HI)
    time_s = st.floats(min_value=0.0, max_value=TIME_MAX_S)
    position = st.floats(min_value=-POSITION_MAX_M, max_value=POSITION_MAX_M)
    return PoseBatch(
        t=draw(time_s),
        seq=draw(st.integers(min_value=0, max_value=2**64 - 1)),
        robots=tuple(draw(st.lists(ids, min_size=n, max_size=n))),
        x=tuple(draw(st.lists(position, min_size=n, max_size=n))),
        y=tuple(draw(st.lists(position, min_size=n, max_size=n))),
        theta=tuple(draw(st.lists(angle, min_size=n, max_size=n))),
        stamp=draw(time_s),
    )


def _list_element(fs: Any) -> st.SearchStrategy[Any]:
    lo = None if fs.lo is None else float(fs.lo)
    hi = None if fs.hi is None else float(fs.hi)
    if fs.kind is Kind.FLOAT_LIST:
        return _float_strategy(lo, hi)
    if fs.kind is Kind.INT_LIST:
        return st.integers(min_value=fs.lo, max_value=fs.hi)
    assert fs.kind is Kind.STR_LIST and fs.pattern is not None
    return _pattern_strategy(fs.pattern)


@st.composite
def _same_length_batch(draw: st.DrawFn, cls: type) -> Any:
    """A batch message whose SameLength fields all have one drawn length."""
    n = draw(st.integers(min_value=0, max_value=8))
    same = {
        name for rule in spec_of(cls).rules if isinstance(rule, SameLength) for name in rule.fields
    }
    values: dict[str, Any] = {}
    for f in spec_of(cls).fields:
        if f.name == "v":
            continue
        if f.name in same:
            values[f.name] = tuple(draw(st.lists(_list_element(f.spec), min_size=n, max_size=n)))
        else:
            values[f.name] = draw(field_strategy(f))
    return cls(**values)


def message_strategy(cls: type) -> st.SearchStrategy[Any]:
    """Any valid message of type `cls`."""
    if cls is PoseBatch:
        return _pose_batch()
    if any(isinstance(r, SameLength) for r in spec_of(cls).rules):
        batch = _same_length_batch(cls)
        if all(isinstance(r, SameLength) for r in spec_of(cls).rules):
            return batch
        return batch.filter(lambda m: validate(m) is None)  # and its other rules (Obstacle)
    fields = {f.name: field_strategy(f) for f in spec_of(cls).fields if f.name != "v"}
    s = st.builds(cls, **fields)
    if spec_of(cls).rules:
        s = s.filter(lambda m: validate(m) is None)
    return s


# --- round trips -----------------------------------------------------------------------------


@pytest.mark.parametrize("cls", TYPES, ids=TYPE_IDS)
@HYP_PER_TYPE
@given(data=st.data())
def test_round_trip_any_valid_message(cls: type, data: st.DataObject) -> None:
    msg = data.draw(message_strategy(cls))
    payload = encode(msg)
    assert decode(payload, cls) == msg
    assert encode(decode_or_raise(payload, cls)) == payload  # canonical: re-encoding is stable
    # A generic decoder reads a map with str keys, in the declared field order.
    plain = msgpack.unpackb(payload)
    assert isinstance(plain, dict) and all(type(k) is str for k in plain)
    declared = [f.name for f in spec_of(cls).fields]
    assert list(plain) == [name for name in declared if name in plain]
    assert all(getattr(msg, name) is None for name in declared if name not in plain)


@pytest.mark.parametrize("cls", TYPES, ids=TYPE_IDS)
def test_samples_round_trip_and_match_to_map(cls: type) -> None:
    msg = SAMPLES[cls]
    assert validate(msg) is None
    assert decode(encode(msg), cls) == msg
    assert msgpack.unpackb(encode(msg), use_list=False) == to_map(msg)
    assert from_map(to_map(msg), cls) == msg


def test_every_type_has_a_sample_and_a_unique_name() -> None:
    assert set(SAMPLES) == set(MESSAGE_TYPES)
    names = [spec_of(cls).name for cls in MESSAGE_TYPES]
    assert len(set(names)) == len(names)
    for cls in MESSAGE_TYPES:
        assert message_type(spec_of(cls).name) is cls
        assert hasattr(cls, "__slots__") and not hasattr(SAMPLES[cls], "__dict__")
        with pytest.raises(AttributeError):
            SAMPLES[cls].t = 2.0  # frozen


def test_floats_are_float64_and_ints_in_float_fields_become_floats() -> None:
    payload = encode(Pose(t=1, seq=0, x=0, y=-2, theta=1))  # type: ignore[arg-type]
    assert payload.count(b"\xcb") == 4  # t, x, y, theta all float64 (0xcb), none as int
    msg = decode_or_raise(payload, Pose)
    assert (msg.t, msg.x, msg.y, msg.theta) == (1.0, 0.0, -2.0, 1.0)
    assert all(type(getattr(msg, n)) is float for n in ("t", "x", "y", "theta"))
    # An int sent by another implementation where a float is expected is accepted.
    m = wire_map(Pose) | {"x": 3, "t": 2}
    decoded = decode_or_raise(pack(m), Pose)
    assert decoded.x == 3.0 and type(decoded.x) is float and type(decoded.t) is float


def test_encoding_is_deterministic_for_maps_in_any_order() -> None:
    a = Assignment(t=1.0, seq=1, leader=None, robots={"r3": 2, "r1": 0, "r2": 1})
    b = Assignment(t=1.0, seq=1, leader=None, robots={"r1": 0, "r2": 1, "r3": 2})
    assert encode(a) == encode(b)
    assert list(msgpack.unpackb(encode(a))["robots"]) == ["r1", "r2", "r3"]


def test_subclasses_accepted_on_encode_and_normalised() -> None:
    class MyFloat(float):
        pass

    msg = Slot(
        t=MyFloat(1.0),
        seq=0,
        slot=0,
        role=Role.LEADER,
        stage=0,
        parent=None,
        x=MyFloat(0.5),
        y=0.0,
        theta=0.0,
        vx=0.0,
        vy=0.0,
    )
    decoded = decode_or_raise(encode(msg), Slot)
    assert decoded == msg
    assert type(decoded.role) is str and decoded.role == "leader"
    status = Status(
        t=0.0, seq=0, mode=Mode.ESTOP, slot=None, pid=1, host="h", rejected=0, role=Role.FOLLOWER
    )
    assert decode_or_raise(encode(status), Status).mode == "estop"
    # Lists are accepted for tuple fields and come back as tuples.
    batch = PoseBatch(t=0.0, seq=0, robots=["r1"], x=[0.0], y=[1], theta=[0.5], stamp=0.0)  # type: ignore[arg-type]
    assert decode_or_raise(encode(batch), PoseBatch).y == (1.0,)


# --- encode side -----------------------------------------------------------------------------


def test_encode_rejects_invalid_messages() -> None:
    cases: list[tuple[Any, Reason, str]] = [
        (Pose(t=0.0, seq=0, x=math.nan, y=0.0, theta=0.0), Reason.NON_FINITE, "x"),
        (Pose(t=0.0, seq=0, x=0.0, y=0.0, theta=4.0), Reason.OUT_OF_RANGE, "theta"),
        (Pose(t=-1.0, seq=0, x=0.0, y=0.0, theta=0.0), Reason.OUT_OF_RANGE, "t"),
        (Pose(t=0.0, seq=0, x=0.0, y=0.0, theta=0.0, robot="R1"), Reason.OUT_OF_RANGE, "robot"),
        (Pose(t=0.0, seq=True, x=0.0, y=0.0, theta=0.0), Reason.WRONG_TYPE, "seq"),
        (Pose(v=2, t=0.0, seq=0, x=0.0, y=0.0, theta=0.0), Reason.UNKNOWN_VERSION, "v"),
        (Pose(t=0.0, seq=0, x=None, y=0.0, theta=0.0), Reason.MISSING_FIELD, "x"),  # type: ignore[arg-type]
        (Pose(t=0.0, seq=0, x=10**400, y=0.0, theta=0.0), Reason.OUT_OF_RANGE, "x"),
        (Estop(t=0.0, engage=1, robot=None), Reason.WRONG_TYPE, "engage"),  # type: ignore[arg-type]
        (
            PoseBatch(t=0.0, seq=0, robots=("r1",), x=(0.0,), y=(), theta=(0.0,), stamp=0.0),
            Reason.INCONSISTENT,
            "robots",
        ),
        # issue 29, the estimator's twist: both or neither, parallel lists in a batch
        (
            Status(t=0.0, seq=0, mode="idle", slot=None, pid=0, host="", rejected=0, v_mps=0.1),
            Reason.MISSING_FIELD,
            "omega_radps",
        ),
        (
            StatusBatch(
                t=0.0, seq=0, pid=0, host="", robots=("r1",), mode=("idle",), slot=(-1,),
                rejected=(0,), ex=(0.0,), ey=(0.0,),
                twist_robots=("r1",), v_mps=(0.1, 0.2), omega_radps=(0.0,),
            ),
            Reason.INCONSISTENT,
            "twist_robots",
        ),
    ]  # fmt: skip
    for msg, reason, field in cases:
        err = validate(msg)
        assert err is not None and (err.reason, err.field) == (reason, field), (msg, err)
        with pytest.raises(SchemaError) as exc_info:
            encode(msg)
        assert exc_info.value.error == err


def test_encode_rejects_unencodable_text_and_oversize() -> None:
    status = Status(t=0.0, seq=0, mode="idle", slot=None, pid=1, host="\ud800", rejected=0)
    with pytest.raises(SchemaError):
        encode(status)
    ids = tuple(f"robot-{i:04d}-{'x' * 50}" for i in range(MAX_LIST_LEN))
    zeros = (0.0,) * MAX_LIST_LEN
    big = PoseBatch(t=0.0, seq=0, robots=ids, x=zeros, y=zeros, theta=zeros, stamp=0.0)
    with pytest.raises(SchemaError) as exc_info:
        encode(big)
    assert exc_info.value.error.reason is Reason.TOO_LARGE


def test_non_messages_are_programming_errors() -> None:
    with pytest.raises(TypeError):
        encode({"v": 1})  # type: ignore[arg-type]
    with pytest.raises(TypeError):
        decode(b"\x80", dict)
    with pytest.raises(TypeError):
        spec_of(int)


def test_declaration_mismatches_are_caught_at_import() -> None:
    from dataclasses import dataclass, field

    with pytest.raises(TypeError, match="annotation"):

        @message(name=keys.CLOCK, publisher="test", periodic=False)
        @dataclass(frozen=True, slots=True, kw_only=True)
        class BadType:
            v: int = field(default=1, metadata=f_float("v", ""))
            t: float = field(metadata=f_float("t", "s"))

    with pytest.raises(TypeError, match="must start with"):

        @message(name=keys.CLOCK, publisher="test", periodic=True)
        @dataclass(frozen=True, slots=True, kw_only=True)
        class NoSeq:
            v: float = field(default=1, metadata=f_float("v", ""))
            t: float = field(metadata=f_float("t", "s"))

    with pytest.raises(TypeError, match="FieldSpec"):

        @message(name=keys.CLOCK, publisher="test", periodic=False)
        @dataclass(frozen=True, slots=True, kw_only=True)
        class NoMeta:
            v: int = 1
            t: float = 0.0

    assert SameLength(("a",)).describe() and RequiredWhen("a", "b", ("c",)).describe()


def test_the_run_logs_mode_codes_cover_the_modes() -> None:
    """``Mode`` is declared once (bus_schemas/modes.py; the firmware imports it); the run log's
    file format numbers each mode in its own table, which must cover them all."""
    from formation.outputs.runlog import MODE_CODES

    assert sorted(MODE_CODES) == sorted(m.value for m in Mode)
    assert len(set(MODE_CODES.values())) == len(MODE_CODES)
