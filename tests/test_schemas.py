"""Tests of bus_schemas: round trips, every rejection reason for every type, fuzzing, keys, docs."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import msgpack
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bus_schemas import (
    MAX_LIST_LEN,
    MAX_MAP_LEN,
    MAX_PAYLOAD_BYTES,
    MESSAGE_TYPES,
    Assignment,
    CameraStatus,
    Clock,
    CoordinatorStatus,
    DecodeError,
    Disturbance,
    DisturbanceKind,
    Estop,
    Heartbeat,
    Leader,
    Mode,
    PlantStatus,
    Pose,
    PoseBatch,
    Reason,
    Role,
    SchemaError,
    Setpoint,
    SetpointBatch,
    Slot,
    Status,
    StatusBatch,
    Truth,
    TruthBatch,
    Wheels,
    WheelsBatch,
    decode,
    decode_or_raise,
    encode,
    from_map,
    keys,
    message_type,
    message_type_for_key,
    spec_of,
    to_map,
    validate,
)
from bus_schemas.docs import render_markdown
from bus_schemas.spec import (
    ANGLE_HI,
    ANGLE_LO,
    POSITION_MAX_M,
    TIME_MAX_S,
    FieldInfo,
    Kind,
    RequiredWhen,
    SameLength,
    Together,
    f_float,
    message,
)

REPO = Path(__file__).resolve().parents[1]
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

# One valid instance of every type, with every optional field set where there is one.
SAMPLES: dict[type, Any] = {
    Leader: Leader(t=1.0, seq=1, x=0.5, y=-0.25, theta=0.1, v_mps=0.1, omega_radps=0.02),
    Slot: Slot(
        t=1.0,
        seq=2,
        slot=1,
        role="subleader",
        stage=1,
        parent=0,
        x=0.1,
        y=0.2,
        theta=0.3,
        vx=0.01,
        vy=-0.02,
    ),
    Setpoint: Setpoint(
        t=1.0,
        seq=3,
        robot="r2",
        slot=2,
        role="follower",
        stage=1,
        parent=0,
        x=0.1,
        y=0.2,
        theta=-0.3,
        vx=0.0,
        vy=0.0,
    ),
    Assignment: Assignment(t=1.0, seq=4, leader="r1", robots={"r1": 0, "r2": 1, "r3": 2}),
    Pose: Pose(t=1.0, seq=5, x=0.1, y=0.2, theta=3.0, robot="r1", pub_t=1.03),
    Truth: Truth(t=1.0, seq=6, x=0.1, y=0.2, theta=-3.0, robot="r1"),
    Wheels: Wheels(
        t=1.0,
        seq=7,
        omega_r=5.0,
        omega_l=-5.0,
        power_r=0.5,
        power_l=-0.5,
        pose_t=0.98,
        tick=99,
        saturated=False,
        mode="tracking",
    ),
    Status: Status(
        t=1.0,
        seq=8,
        mode="tracking",
        slot=1,
        pid=1234,
        host="pi-1",
        rejected=0,
        ex=0.01,
        ey=-0.02,
        role="follower",
        rx={"pose": 10, "setpoint": 9},
        robot="r2",
        filter={"ticks": 10, "active": 2},
        min_clearance_m=0.05,
    ),
    Estop: Estop(t=1.0, engage=True, robot="r3"),
    Clock: Clock(
        t=1.0,
        seq=9,
        tick=100,
        tracking=("r1", "r2"),
        enc_robots=("r1", "r2"),
        enc_wr=(1.5, -0.25),
        enc_wl=(1.0, 0.0),
    ),
    Disturbance: Disturbance(
        t=1.0,
        robot="r1",
        kind="teleport",
        dx=0.0,
        dy=0.0,
        duration_s=0.0,
        x=1.0,
        y=2.0,
        theta=0.5,
    ),
    Heartbeat: Heartbeat(t=1.0, seq=10, name="primary", active=True, epoch=3, leader_t0=0.5),
    PoseBatch: PoseBatch(
        t=1.0,
        seq=11,
        robots=("r1", "r2"),
        x=(0.1, 0.2),
        y=(0.3, 0.4),
        theta=(0.0, -1.0),
        stamp=0.99,
    ),
    TruthBatch: TruthBatch(
        t=1.0, seq=12, robots=("r1", "r2"), x=(0.1, 0.2), y=(0.3, 0.4), theta=(0.0, 1.0), stamp=1.0
    ),
    SetpointBatch: SetpointBatch(
        t=1.0,
        seq=13,
        robots=("r1", "r2"),
        slot=(0, 1),
        role=("leader", "follower"),
        stage=(0, 1),
        x=(0.1, 0.2),
        y=(0.3, 0.4),
        theta=0.5,
        vx=(0.1, 0.1),
        vy=(0.0, 0.0),
        tick=7,
    ),
    WheelsBatch: WheelsBatch(
        t=1.0,
        seq=14,
        robots=("r1", "r2"),
        omega_r=(5.0, 1.0),
        omega_l=(-5.0, 1.0),
        power_r=(0.5, 0.1),
        power_l=(-0.5, 0.1),
        pose_t=(0.98, -1.0),
        tick=7,
        mode=("tracking", "hold"),
    ),
    StatusBatch: StatusBatch(
        t=1.0,
        seq=15,
        pid=1234,
        host="ws-1",
        robots=("r1", "r2"),
        mode=("tracking", "idle"),
        slot=(0, -1),
        rejected=(0, 3),
        ex=(0.01, 0.0),
        ey=(-0.02, 0.0),
        filter_active=(5, 0),
        filter_violations=(0, 0),
        filter_infeasible=(1, 0),
        filter_tiebreaks=(0, 2),
    ),
    CoordinatorStatus: CoordinatorStatus(
        t=12.5,
        seq=63,
        name="main",
        mode="lockstep",
        role="active",
        epoch=1,
        takeovers=1,
        stepdowns=0,
        ticks=625,
        alive=("r1", "r2"),
        assignment={"r2": 1, "r1": 0},
        leader="r1",
        estop_fleet=False,
        estop_robots=("r2",),
        rejected=2,
        rejects={"pose-malformed": 2},
        internal_errors=0,
        rx={"pose": 1250, "clock": 625},
        pid=4244,
        host="ws-1",
        tick_p50_ms=0.25,
        tick_max_ms=1.5,
    ),
    PlantStatus: PlantStatus(
        t=12.5,
        seq=64,
        mode="lockstep",
        state="running",
        tick=625,
        sim_t=12.5,
        timeouts=0,
        alive=("r1", "r2"),
        coordinators=("main",),
        link_sent=1250,
        link_dropped=3,
        min_separation_m=None,
        collisions=0,
        frames=375,
        batch=False,
        ignored=0,
        rejected=0,
        rejects={},
        internal_errors=0,
        rx={"wheels": 1250},
    ),
    CameraStatus: CameraStatus(
        t=12.5,
        seq=25,
        state="running",
        detector="apriltag",
        source="rendered",
        frames=375,
        dropped=2,
        fps=29.5,
        detect_p50_ms=4.5,
        detect_p99_ms=9.0,
        detect_max_ms=12.0,
        latency_p50_ms=6.0,
        latency_p99_ms=11.5,
        latency_max_ms=15.0,
        detections={"r1": 375, "r2": 370},
        published={"r1": 375, "r2": 369},
        misses={"r1": 0, "r2": 5},
        rejects={"jump": 1, "bad_size": 0, "unknown": 0, "duplicate": 0},
        reacquired=0,
        internal_errors=0,
        truth_rejected=0,
    ),
}

TYPES = list(MESSAGE_TYPES)
TYPE_IDS = [cls.__name__ for cls in TYPES]
ALL_FIELDS = [(cls, f) for cls in TYPES for f in spec_of(cls).fields]
ALL_FIELD_IDS = [f"{cls.__name__}.{f.name}" for cls, f in ALL_FIELDS]


def wire_map(cls: type) -> dict[str, Any]:
    """The valid wire map of the sample of `cls` (a plain dict to mutate)."""
    return dict(msgpack.unpackb(encode(SAMPLES[cls])))


def pack(obj: Any) -> bytes:
    return msgpack.packb(obj, use_bin_type=True)


def rejected(data: bytes, cls: type) -> DecodeError:
    result = decode(data, cls)
    assert isinstance(result, DecodeError), f"accepted: {result!r}"
    assert isinstance(result.detail, str) and result.detail
    return result


# --- hypothesis strategies derived from the field tables -------------------------------------

FLOAT_OK = st.floats(allow_nan=False, allow_infinity=False)
# The id alphabets as plain text strategies (much faster to draw than st.from_regex).
ROBOT_IDS = st.text("abcdefghijklmnopqrstuvwxyz0123456789_-", min_size=1, max_size=64)
NAMES = st.text(
    "abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789_-", min_size=1, max_size=64
)


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
        return _same_length_batch(cls)
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
    ]
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


# --- the contract itself -----------------------------------------------------------------------

# The contract (docs/bus-contract.md): required fields besides v, t, seq (an independent copy).
CONTRACT_REQUIRED = {
    Leader: {"x", "y", "theta", "v_mps", "omega_radps"},
    Slot: {"slot", "role", "stage", "parent", "x", "y", "theta", "vx", "vy"},
    Setpoint: {"slot", "role", "stage", "parent", "x", "y", "theta", "vx", "vy", "robot"},
    Assignment: {"leader", "robots"},
    Pose: {"x", "y", "theta"},
    Truth: {"x", "y", "theta"},
    Wheels: {"omega_r", "omega_l", "power_r", "power_l", "pose_t"},
    Status: {"mode", "slot", "pid", "host", "rejected"},
    Estop: {"engage", "robot"},
    Clock: {"tick"},
}

# Fields the contract says may be nil ("slot or nil", "robot id or nil", ...).
CONTRACT_NULLABLE = {
    Slot: {"parent"},
    Setpoint: {"parent"},
    Assignment: {"leader"},
    Status: {"slot"},
    Estop: {"robot"},
}


@pytest.mark.parametrize("cls", list(CONTRACT_REQUIRED), ids=lambda c: c.__name__)
def test_contract_required_fields_are_required(cls: type) -> None:
    spec = spec_of(cls)
    required = {f.name for f in spec.fields if not f.optional}
    assert CONTRACT_REQUIRED[cls] | {"v", "t"} <= required
    assert ("seq" in required) == spec.periodic
    nullable = {f.name for f in spec.fields if f.spec.nullable}
    assert CONTRACT_NULLABLE.get(cls, set()) <= nullable


def test_docs_are_generated_from_the_tables() -> None:
    text = (REPO / "docs" / "bus.md").read_text(encoding="utf-8")
    assert text == render_markdown(), "run: python -m bus_schemas.docs > docs/bus.md"
    assert "time.monotonic()" in text and "sim time" in text
    for cls in MESSAGE_TYPES:
        spec = spec_of(cls)
        for f in spec.fields:
            assert f"| `{f.name}` |" in text
        assert spec.key.replace("{", "<").replace("}", ">").replace("<robot>", "<id>") in text


# --- keys ------------------------------------------------------------------------------------


def test_key_builders() -> None:
    f = "demo"
    assert keys.leader_key(f) == "formation/demo/leader"
    assert keys.slot_key(f, 0) == "formation/demo/slot/0"
    assert keys.slot_key(f, 12) == "formation/demo/slot/12"
    assert keys.setpoint_key(f, "r1") == "formation/demo/robot/r1/setpoint"
    assert keys.assignment_key(f) == "formation/demo/assignment"
    assert keys.pose_key(f, "r1") == "formation/demo/robot/r1/pose"
    assert keys.truth_key(f, "r1") == "formation/demo/robot/r1/truth"
    assert keys.wheels_key(f, "r-2_b") == "formation/demo/robot/r-2_b/wheels"
    assert keys.status_key(f, "r1") == "formation/demo/robot/r1/status"
    assert keys.estop_key(f) == "formation/demo/estop"
    assert keys.clock_key(f) == "formation/demo/clock"
    assert keys.disturbance_key(f) == "formation/demo/disturbance"
    assert keys.heartbeat_key(f, "standby") == "formation/demo/coordinator/standby/heartbeat"
    assert keys.poses_key(f) == "formation/demo/poses"
    assert keys.alive_robot_key(f, "r1") == "formation/demo/alive/robot/r1"
    assert keys.alive_coordinator_key(f, "main") == "formation/demo/alive/coordinator/main"
    assert keys.alive_plant_key(f) == "formation/demo/alive/plant"
    assert keys.all_poses_pattern(f) == "formation/demo/robot/*/pose"
    assert keys.all_truth_pattern(f) == "formation/demo/robot/*/truth"
    assert keys.all_wheels_pattern(f) == "formation/demo/robot/*/wheels"
    assert keys.all_status_pattern(f) == "formation/demo/robot/*/status"
    assert keys.all_setpoints_pattern(f) == "formation/demo/robot/*/setpoint"
    assert keys.all_slots_pattern(f) == "formation/demo/slot/*"
    assert keys.all_heartbeats_pattern(f) == "formation/demo/coordinator/*/heartbeat"
    assert keys.alive_robots_pattern(f) == "formation/demo/alive/robot/*"
    assert keys.alive_coordinators_pattern(f) == "formation/demo/alive/coordinator/*"
    assert keys.alive_pattern(f) == "formation/demo/alive/**"
    assert keys.fleet_pattern(f) == "formation/demo/**"
    assert keys.robot_pattern(f, "r1") == "formation/demo/robot/r1/*"
    assert keys.DEFAULT_FLEET == "demo"


BAD_IDS = ["", "R1", "r/1", "r*", "r 1", "$r", "r?", "r#", "x" * 65, "r1\n", "é", "..", "r.1"]
BAD_FLEETS = ["", "a/b", "*", "**", "a b", "$f", "x" * 65, "f.1", "fleet\n"]


def test_invalid_ids_and_names_are_rejected() -> None:
    robot_builders = [
        keys.setpoint_key,
        keys.pose_key,
        keys.truth_key,
        keys.wheels_key,
        keys.status_key,
        keys.alive_robot_key,
        keys.robot_pattern,
    ]
    for bad in BAD_IDS:
        for build in robot_builders:
            with pytest.raises(ValueError, match="robot id"):
                build("demo", bad)
    bad_names: list[Any] = [*BAD_FLEETS, None, 3]
    for bad in bad_names:
        with pytest.raises(ValueError, match="fleet"):
            keys.leader_key(bad)  # type: ignore[arg-type]
        with pytest.raises(ValueError, match="fleet"):
            keys.pose_key(bad, "r1")  # type: ignore[arg-type]
        with pytest.raises(ValueError, match="coordinator name"):
            keys.heartbeat_key("demo", bad)  # type: ignore[arg-type]
    for bad_slot in (-1, 65536, True, 1.0, "1"):
        with pytest.raises(ValueError, match="slot"):
            keys.slot_key("demo", bad_slot)  # type: ignore[arg-type]
    assert keys.is_robot_id("r1") and not keys.is_robot_id(b"r1") and not keys.is_robot_id(1)


@HYP
@given(fleet=NAMES, robot=ROBOT_IDS, name=NAMES, slot=st.integers(0, keys.MAX_SLOT))
def test_key_parse_round_trip(fleet: str, robot: str, name: str, slot: int) -> None:
    for build, leaf, cls in [
        (keys.setpoint_key, keys.SETPOINT, Setpoint),
        (keys.pose_key, keys.POSE, Pose),
        (keys.truth_key, keys.TRUTH, Truth),
        (keys.wheels_key, keys.WHEELS, Wheels),
        (keys.status_key, keys.STATUS, Status),
    ]:
        key = build(fleet, robot)
        assert keys.parse_robot_key(key) == (fleet, robot, leaf)
        assert keys.parse_key(key) == keys.KeyInfo(fleet, leaf, robot=robot)
        assert message_type_for_key(key) is cls
    for build_f, cls in [
        (keys.leader_key, Leader),
        (keys.assignment_key, Assignment),
        (keys.estop_key, Estop),
        (keys.clock_key, Clock),
        (keys.disturbance_key, Disturbance),
        (keys.poses_key, PoseBatch),
        (keys.setpoints_key, SetpointBatch),
        (keys.truths_key, TruthBatch),
    ]:
        key = build_f(fleet)
        assert keys.parse_key(key) == keys.KeyInfo(fleet, spec_of(cls).name)
        assert keys.parse_robot_key(key) is None
        assert message_type_for_key(key) is cls
    key = keys.slot_key(fleet, slot)
    assert keys.parse_key(key) == keys.KeyInfo(fleet, keys.SLOT, slot=slot)
    assert message_type_for_key(key) is Slot
    for build_h, leaf, cls in [
        (keys.host_wheels_key, keys.HOST_WHEELS, WheelsBatch),
        (keys.host_status_key, keys.HOST_STATUS, StatusBatch),
    ]:
        key = build_h(fleet, name)
        assert keys.parse_key(key) == keys.KeyInfo(fleet, leaf, name=name)
        assert message_type_for_key(key) is cls
    key = keys.heartbeat_key(fleet, name)
    assert keys.parse_key(key) == keys.KeyInfo(fleet, keys.HEARTBEAT, name=name)
    assert message_type_for_key(key) is Heartbeat
    key = keys.coordinator_status_key(fleet, name)
    assert keys.parse_key(key) == keys.KeyInfo(fleet, keys.COORDINATOR_STATUS, name=name)
    assert message_type_for_key(key) is CoordinatorStatus
    key = keys.plant_status_key(fleet)
    assert keys.parse_key(key) == keys.KeyInfo(fleet, keys.PLANT_STATUS)
    assert message_type_for_key(key) is PlantStatus
    key = keys.camera_status_key(fleet, name)
    assert keys.parse_key(key) == keys.KeyInfo(fleet, keys.CAMERA_STATUS, name=name)
    assert message_type_for_key(key) is CameraStatus
    assert keys.parse_alive_key(keys.alive_robot_key(fleet, robot)) == (fleet, "robot", robot)
    assert keys.parse_alive_key(keys.alive_coordinator_key(fleet, name)) == (
        fleet,
        "coordinator",
        name,
    )
    assert keys.parse_alive_key(keys.alive_plant_key(fleet)) == (fleet, "plant", None)
    assert keys.parse_robot_key(keys.alive_robot_key(fleet, robot)) is None
    assert message_type_for_key(keys.alive_robot_key(fleet, robot)) is None


def test_parse_rejects_foreign_and_malformed_keys() -> None:
    for key in [
        "",
        "formation",
        "formation/demo",
        "other/demo/leader",
        "formation/demo/robot/*/pose",
        "formation/demo/robot/R1/pose",
        "formation/demo/robot/r1",
        "formation/demo/robot/r1/pose/extra",
        "formation/de mo/robot/r1/pose",
        "formation/demo/slot/01",
        "formation/demo/slot/-1",
        "formation/demo/slot/65536",
        "formation/demo/slot/x",
        "formation/demo/unknown",
        "formation/demo/coordinator/a/b",
        "formation/demo/coordinator/a b/status",
        "formation/demo/plant/truth",
        "formation/demo/plant/status/x",
        "formation/demo/alive/robot/R1",
        "formation/demo/alive/thing/x",
        "formation/**",
    ]:
        assert keys.parse_key(key) is None, key
        assert keys.parse_robot_key(key) is None
        assert keys.parse_alive_key(key) is None
        assert message_type_for_key(key) is None
    assert keys.parse_key(None) is None  # type: ignore[arg-type]
    # A robot leaf this version does not know still names the robot; it maps to no type.
    assert keys.parse_robot_key("formation/demo/robot/r1/battery") == ("demo", "r1", "battery")
    assert message_type_for_key("formation/demo/robot/r1/battery") is None
    assert message_type_for_key("formation/demo/robot/r1/leader") is None
    assert keys.parse_alive_key(keys.pose_key("demo", "r1")) is None


def test_message_key_templates_match_builders() -> None:
    for cls in MESSAGE_TYPES:
        spec = spec_of(cls)
        key = spec.key.format(fleet="f1", robot="r9", slot=3, name="c1")
        assert message_type_for_key(key) is cls


def test_schema_modules_import_only_stdlib_and_msgpack() -> None:
    """bus_schemas runs on a robot: standard library + msgpack only (no zenoh, no asyncio)."""
    import ast
    import sys

    package = REPO / "bus_schemas"
    for path in sorted(package.glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Import):
                names = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names = [node.module]
            else:
                continue
            for name in names:
                top = name.split(".")[0]
                assert top in sys.stdlib_module_names or top in ("msgpack", "bus_schemas"), (
                    f"{path.name} imports {name}"
                )
                assert top != "asyncio", f"{path.name} imports asyncio"
