"""Bytes <-> messages. `decode` never raises on bad data: it returns a `DecodeError` value.

Wire format (version 1): one MessagePack map with str keys, written in the field order of the
message's table (v, t, seq, then the fields), optional fields left out when None, nested maps
sorted by key, floats always float64, str as UTF-8 str, bin type for bytes (unused). The same
message therefore always encodes to the same bytes (tests/unit/bus_schemas/test_schemas_golden.py
pins them).

Decoding is strict about types (bool is not int, int is not bool, only float fields accept ints),
rejects NaN/inf everywhere, checks ranges (including the plausibility bounds of positions,
velocities, times and epochs declared in bus_schemas.spec), enums, ids, sizes and the version,
refuses any map (top-level or nested) with a non-str key or a key given twice, and ignores unknown
extra fields with str keys (forward compatible: a newer publisher may add fields).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from typing import Any, TypeVar

import msgpack

from bus_schemas.errors import DecodeError, Invalid, Reason, SchemaError
from bus_schemas.messages import MESSAGE_TYPES, Estop, Message
from bus_schemas.spec import MAX_PAYLOAD_BYTES, spec_of

M = TypeVar("M")

_DECODE_MAPS: dict[type, Callable[[Mapping[Any, Any]], Any]] = {
    cls: spec_of(cls).decode_map for cls in MESSAGE_TYPES
}
_ENCODE_MAPS: dict[type, Callable[[Any], dict[str, Any]]] = {
    cls: spec_of(cls).encode_map for cls in MESSAGE_TYPES
}

_unpackb = msgpack.unpackb
_packb = msgpack.packb


def _strict_map(pairs: list[tuple[Any, Any]]) -> dict[str, Any]:
    """msgpack ``object_pairs_hook``: every map, top-level or nested, goes through here.

    A plain ``unpackb`` keeps the last of two equal keys and accepts int, bin or nil keys, so a
    forged payload could show one value to a generic decoder (a recorder, a dashboard) and act
    with another; both are refused with their own reason instead.
    """
    obj = dict(pairs)
    if len(obj) != len(pairs):
        seen: set[Any] = set()
        for k, _ in pairs:
            if k in seen:
                raise Invalid(Reason.DUPLICATE_KEY, f"key {str(k)[:80]!r} appears twice", None)
            seen.add(k)
    for k in obj:
        if type(k) is not str:
            raise Invalid(Reason.NON_STRING_KEY, f"map key of type {type(k).__name__}", None)
    return obj


def _short(exc: BaseException) -> str:
    return f"{type(exc).__name__}: {exc}"[:200]


def decode(data: bytes | bytearray | memoryview, expected: type[M]) -> M | DecodeError:
    """Decode and validate one payload as a message of type `expected`.

    Returns the message, or a DecodeError (reason: malformed, not_a_map, missing_field,
    wrong_type, non_finite, out_of_range, unknown_version, too_large, inconsistent,
    non_string_key, duplicate_key) for any bad input; never raises on data. Raises TypeError only
    if `expected` is not a message type (a bug).
    """
    decode_map = _DECODE_MAPS.get(expected)
    if decode_map is None:
        raise TypeError(f"{expected!r} is not a bus message type")
    try:
        size = len(data)
        if size > MAX_PAYLOAD_BYTES:
            return DecodeError(Reason.TOO_LARGE, f"{size} bytes, at most {MAX_PAYLOAD_BYTES}", None)
        # use_list=False: arrays arrive as tuples (the messages' list type). strict_map_key=False
        # lets every key reach _strict_map, which refuses non-str and duplicate keys with a
        # reason of their own (msgpack's strict mode would call an int key merely malformed).
        obj = _unpackb(data, use_list=False, strict_map_key=False, object_pairs_hook=_strict_map)
    except Invalid as exc:  # from _strict_map
        return exc.error
    except Exception as exc:  # any msgpack failure (truncated, extra data, bad UTF-8, depth, ...)
        return DecodeError(Reason.MALFORMED, _short(exc), None)
    if type(obj) is not dict:
        return DecodeError(Reason.NOT_A_MAP, f"top-level object is {type(obj).__name__}", None)
    try:
        msg: M = decode_map(obj)
    except Invalid as exc:
        return exc.error
    return msg


def decode_or_raise(data: bytes | bytearray | memoryview, expected: type[M]) -> M:
    """Like `decode`, but raise SchemaError (a ValueError) instead of returning a DecodeError."""
    result = decode(data, expected)
    if isinstance(result, DecodeError):
        raise SchemaError(result)
    return result


def encode_estop_entries(
    entries: Iterable[tuple[bool, str | None, int | None]], t: float
) -> tuple[bytes, ...]:
    """``(engage, robot, id)`` entries (``EstopLatch.answer`` or ``EstopLatch.engagements``) as
    the payloads of a query's answer, one ``Estop`` each, stamped ``t`` (clamped to >= 0)."""
    t = max(t, 0.0)
    return tuple(encode(Estop(t=t, engage=e, robot=r, id=i)) for e, r, i in entries)


def decode_estop_answer(
    payloads: Iterable[bytes], reject: Callable[[DecodeError], None], *, held: bool = False
) -> list[tuple[bool, str | None, int | None]]:
    """A query's answer on the ``estop`` key (the coordinators' latched e-stop state, one
    ``Estop`` per engagement and per released engagement:
    ``robot_agent.core.estop.EstopLatch.answer``)
    as the ``(engage, robot, id)`` entries ``EstopLatch.merge_answer`` takes, in order; each
    invalid payload is handed to ``reject`` and skipped, and so is a robot's release entry
    without an ``id`` (a release record must name the engagement it released; only the fleet's
    "not latched" entry has none). The one decoder of that answer (agents, agent hosts,
    coordinators). Entries repeated across responders are legitimate (the union of every
    coordinator's answer). ``held``: the answer of agents on ``estop/held/*`` (the engagements
    each holds), where every release entry is rejected: only a coordinator's answer may carry a
    release record."""
    out: list[tuple[bool, str | None, int | None]] = []
    for payload in payloads:
        msg = decode(payload, Estop)
        if isinstance(msg, DecodeError):
            reject(msg)
        elif held and not msg.engage:
            reject(DecodeError(Reason.INCONSISTENT, "a release from an agent", "engage"))
        elif not msg.engage and msg.robot is not None and msg.id is None:
            reject(DecodeError(Reason.INCONSISTENT, "a robot's release record without an id", "id"))
        else:
            out.append((msg.engage, msg.robot, msg.id))
    return out


def from_map(obj: Mapping[Any, Any], expected: type[M]) -> M | DecodeError:
    """Validate an already-unpacked map (e.g. from JSON or a recording) as `expected`."""
    decode_map = _DECODE_MAPS.get(expected)
    if decode_map is None:
        raise TypeError(f"{expected!r} is not a bus message type")
    if not isinstance(obj, Mapping):
        return DecodeError(Reason.NOT_A_MAP, f"top-level object is {type(obj).__name__}", None)
    for k in obj:
        if type(k) is not str:
            return DecodeError(Reason.NON_STRING_KEY, f"map key of type {type(k).__name__}", None)
    try:
        msg: M = decode_map(obj)
    except Invalid as exc:
        return exc.error
    return msg


def to_map(msg: Message) -> dict[str, Any]:
    """The validated wire map of `msg` (what `encode` packs), in wire order.

    Raises SchemaError if the message is invalid, TypeError if it is not a message.
    """
    encode_map = _ENCODE_MAPS.get(type(msg))
    if encode_map is None:
        raise TypeError(f"{type(msg)!r} is not a bus message type")
    try:
        return encode_map(msg)
    except Invalid as exc:
        raise SchemaError(exc.error) from None


def validate(msg: Message) -> DecodeError | None:
    """None if `msg` would encode (and decode) cleanly, else why not. Never raises on a message."""
    try:
        to_map(msg)
    except SchemaError as exc:
        return exc.error
    return None


def encode(msg: Message) -> bytes:
    """Validate `msg` and pack it (see the module docstring for the wire format).

    Raises SchemaError for an invalid message (NaN, out of range, bad id, nil where not allowed,
    too large, ...) so that nothing invalid is ever published; TypeError for a non-message.
    """
    obj = to_map(msg)
    try:
        data: bytes = _packb(obj, use_bin_type=True)
    except (ValueError, TypeError, OverflowError) as exc:  # e.g. str with lone surrogates
        raise SchemaError(DecodeError(Reason.WRONG_TYPE, _short(exc), None)) from None
    if len(data) > MAX_PAYLOAD_BYTES:
        raise SchemaError(
            DecodeError(Reason.TOO_LARGE, f"{len(data)} bytes, at most {MAX_PAYLOAD_BYTES}", None)
        )
    return data
