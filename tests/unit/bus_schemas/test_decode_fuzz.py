"""Fuzz of the decoder: whatever arrives, `decode` returns a valid message or a typed DecodeError.

Three generators, each over every message type:
- random bytes (and random prefixes/mutations of valid payloads);
- random MessagePack objects of any shape (nested maps with int/bin/nil/str keys, lists, floats
  including NaN/inf, huge ints);
- valid wire maps with one to three fields replaced by random values, extra keys, non-str keys
  or duplicated keys.

Properties: `decode` never raises; an error carries a `Reason`; a returned message is valid
(`validate` is None: inside every range and plausibility bound of the contract) and re-encodes to
a payload that decodes to the same message. Short here (`make test`); the seeds are fixed
(derandomize) so a failure reproduces.
"""

from __future__ import annotations

import math
from typing import Any

import msgpack
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from support.bus_samples import SAMPLES

from bus_schemas import (
    MESSAGE_TYPES,
    DecodeError,
    Heartbeat,
    Reason,
    decode,
    encode,
    spec_of,
    to_map,
    validate,
)
from bus_schemas.spec import (
    EPOCH_MAX,
    POSITION_MAX_M,
    SPEED_MAX_MPS,
    Kind,
)

FUZZ = settings(
    max_examples=60,
    deadline=None,
    derandomize=True,
    database=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)

TYPES = list(MESSAGE_TYPES)
IDS = [c.__name__ for c in TYPES]

_scalars = (
    st.none()
    | st.booleans()
    | st.integers(min_value=-(2**63), max_value=2**64 - 1)
    | st.floats()  # NaN and +-inf included
    | st.text(max_size=20)
    | st.binary(max_size=20)
)
_keys = st.text(max_size=8) | st.integers(-5, 5) | st.binary(max_size=4) | st.none()
ANY_OBJECT = st.recursive(
    _scalars,
    lambda inner: st.lists(inner, max_size=5) | st.dictionaries(_keys, inner, max_size=5),
    max_leaves=30,
)


def _check(data: bytes, cls: type) -> None:
    result = decode(data, cls)
    if isinstance(result, DecodeError):
        assert isinstance(result.reason, Reason)
        return
    assert type(result) is cls
    assert validate(result) is None
    assert decode(encode(result), cls) == result


@pytest.mark.parametrize("cls", TYPES, ids=IDS)
@FUZZ
@given(data=st.binary(max_size=256))
def test_random_bytes(cls: type, data: bytes) -> None:
    _check(data, cls)


@pytest.mark.parametrize("cls", TYPES, ids=IDS)
@FUZZ
@given(obj=ANY_OBJECT)
def test_random_msgpack_objects(cls: type, obj: Any) -> None:
    _check(msgpack.packb(obj, use_bin_type=True), cls)


@pytest.mark.parametrize("cls", TYPES, ids=IDS)
@FUZZ
@given(cut=st.integers(min_value=0), flips=st.lists(st.tuples(st.integers(0), st.integers(0, 255))))
def test_mutated_valid_payloads(cls: type, cut: int, flips: list[tuple[int, int]]) -> None:
    good = bytearray(encode(SAMPLES[cls]))
    for pos, value in flips:
        good[pos % len(good)] = value
    _check(bytes(good[: len(good) - cut % (len(good) + 1)]), cls)


def _pack_pairs(pairs: list[tuple[Any, Any]]) -> bytes:
    packer = msgpack.Packer(use_bin_type=True)
    out = packer.pack_map_header(len(pairs))
    for k, v in pairs:
        out += packer.pack(k) + packer.pack(v)
    return out


@st.composite
def _forged_map(draw: st.DrawFn, cls: type) -> tuple[bytes, str]:
    """A valid wire map of `cls` with random damage; returns (payload, what was done)."""
    pairs: list[tuple[Any, Any]] = list(to_map(SAMPLES[cls]).items())
    names = [k for k, _ in pairs]
    for _ in range(draw(st.integers(1, 3))):
        action = draw(st.sampled_from(["replace", "drop", "extra", "non_str", "duplicate"]))
        if action == "replace":
            i = draw(st.integers(0, len(pairs) - 1))
            pairs[i] = (pairs[i][0], draw(ANY_OBJECT))
        elif action == "drop" and pairs:
            pairs.pop(draw(st.integers(0, len(pairs) - 1)))
        elif action == "extra":
            pairs.append((draw(st.text(min_size=1, max_size=8)), draw(ANY_OBJECT)))
        elif action == "non_str":
            key = draw(st.integers(-3, 3) | st.binary(max_size=3) | st.none())
            pairs.insert(draw(st.integers(0, len(pairs))), (key, draw(ANY_OBJECT)))
        else:
            name = draw(st.sampled_from(names))
            pairs.append((name, draw(ANY_OBJECT | st.just(dict(pairs).get(name)))))
    return _pack_pairs(pairs), ",".join(str(k) for k, _ in pairs)


@pytest.mark.parametrize("cls", TYPES, ids=IDS)
@FUZZ
@given(data=st.data())
def test_forged_maps(cls: type, data: st.DataObject) -> None:
    payload, _ = data.draw(_forged_map(cls))
    _check(payload, cls)
    keys = [k for k, _ in _iter_pairs(payload)]
    result = decode(payload, cls)
    if any(type(k) is not str for k in keys) or len(set(keys)) != len(keys):
        # (which of the two is reported first is the decoder's choice; a nested map may also
        # carry a bad key of its own)
        assert isinstance(result, DecodeError)
        assert result.reason in (Reason.NON_STRING_KEY, Reason.DUPLICATE_KEY)


def _iter_pairs(payload: bytes) -> list[tuple[Any, Any]]:
    """Top-level (key, value) pairs as written, duplicates and odd keys kept."""
    pairs: list[tuple[Any, Any]] = []

    def keep(p: list[tuple[Any, Any]]) -> dict[str, Any]:
        pairs.extend(p)
        return {}

    msgpack.unpackb(payload, strict_map_key=False, object_pairs_hook=keep)
    # the hook also sees nested maps first (depth first): the top-level ones are the last batch
    return pairs[-_top_len(payload) :] if pairs else []


def _top_len(payload: bytes) -> int:
    b = payload[0]
    if 0x80 <= b <= 0x8F:
        return b & 0x0F
    if b == 0xDE:
        return int.from_bytes(payload[1:3], "big")
    return int.from_bytes(payload[1:5], "big")


# --- plausibility bounds, explicitly ------------------------------------------------------------


def _float_fields(cls: type, unit: str) -> list[str]:
    return [
        f.name
        for f in spec_of(cls).fields
        if f.spec.kind in (Kind.FLOAT, Kind.FLOAT_LIST) and f.spec.unit == unit
    ]


@pytest.mark.parametrize("cls", TYPES, ids=IDS)
def test_absurd_positions_and_velocities_are_refused(cls: type) -> None:
    """x = 1e300 saturated the wheels (issue 13): every position and velocity is bounded."""
    base = to_map(SAMPLES[cls])
    checked = 0
    for unit, bound in (("m", POSITION_MAX_M), ("m/s", SPEED_MAX_MPS)):
        for name in _float_fields(cls, unit):
            if name not in base:
                continue
            fs = next(f.spec for f in spec_of(cls).fields if f.name == name)
            distance = fs.lo is not None and fs.lo >= 0.0  # between two positions (< 2 sqrt 2 P)
            limit = (4 if distance else 2) * bound
            assert fs.hi is not None and fs.hi <= limit, (cls.__name__, name)
            edges = (0.0, fs.hi) if distance else (-bound, bound)
            for absurd in (1e300, -1e300, 2.5 * limit):
                value: Any = absurd
                if fs.kind is Kind.FLOAT_LIST:
                    if not base[name]:
                        continue
                    value = [absurd] * len(base[name])
                err = decode(msgpack.packb({**base, name: value}), cls)
                assert isinstance(err, DecodeError), (cls.__name__, name, absurd)
                assert err.reason is Reason.OUT_OF_RANGE
                checked += 1
            for edge in edges:
                value = [edge] * len(base[name]) if fs.kind is Kind.FLOAT_LIST else edge
                ok = decode(msgpack.packb({**base, name: value}), cls)
                assert not isinstance(ok, DecodeError), (cls.__name__, name, ok)
    for f in spec_of(cls).fields:  # nothing but angles and fractions is left unbounded
        if f.spec.kind is Kind.FLOAT:
            assert f.spec.hi is not None and math.isfinite(f.spec.hi), (cls.__name__, f.name)


def test_epoch_is_bounded() -> None:
    base = to_map(SAMPLES[Heartbeat])
    for epoch in (EPOCH_MAX + 1, 2**64 - 1):
        err = decode(msgpack.packb({**base, "epoch": epoch}), Heartbeat)
        assert isinstance(err, DecodeError) and err.reason is Reason.OUT_OF_RANGE
    ok = decode(msgpack.packb({**base, "epoch": EPOCH_MAX}), Heartbeat)
    assert isinstance(ok, Heartbeat) and ok.epoch == EPOCH_MAX
    for t0 in (1e300, -1e300, math.inf):
        err = decode(msgpack.packb({**base, "leader_t0": t0}), Heartbeat)
        assert isinstance(err, DecodeError)


def test_reject_counts_by_reason() -> None:
    from bus_schemas import RejectCounts

    counts = RejectCounts()
    odd: dict[Any, Any] = {**to_map(SAMPLES[Heartbeat]), 7: 1}
    for payload in (b"\xc1", msgpack.packb([1]), msgpack.packb(odd)):
        err = decode(payload, Heartbeat)
        assert isinstance(err, DecodeError)
        counts.add(err)
    counts.add(Reason.DUPLICATE_KEY)
    counts.add("misaddressed")
    assert counts.total == 5
    assert counts.as_dict() == {
        "duplicate_key": 1,
        "malformed": 1,
        "misaddressed": 1,
        "non_string_key": 1,
        "not_a_map": 1,
    }
    for k in range(200):  # bounded: made-up reasons cannot grow it
        counts.add(f"r{k}")
    assert len(counts.as_dict()) <= RejectCounts.MAX_REASONS + 1 and counts.total == 205
