"""Bytes <-> messages. `decode` never raises on bad data: it returns a `DecodeError` value.

Wire format (version 1): one MessagePack map with str keys, written in the field order of the
message's table (v, t, seq, then the fields), optional fields left out when None, nested maps
sorted by key, floats always float64, str as UTF-8 str, bin type for bytes (unused). The same
message therefore always encodes to the same bytes (tests/test_schemas_golden.py pins them).

Decoding is strict about types (bool is not int, int is not bool, only float fields accept ints),
rejects NaN/inf everywhere, checks ranges, enums, ids, sizes and the version, and ignores unknown
extra fields (forward compatible: a newer publisher may add fields).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any, TypeVar

import msgpack

from bus_schemas.errors import DecodeError, Invalid, Reason, SchemaError
from bus_schemas.messages import MESSAGE_TYPES, Message
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


def _short(exc: BaseException) -> str:
    return f"{type(exc).__name__}: {exc}"[:200]


def decode(data: bytes | bytearray | memoryview, expected: type[M]) -> M | DecodeError:
    """Decode and validate one payload as a message of type `expected`.

    Returns the message, or a DecodeError (reason: malformed, not_a_map, missing_field,
    wrong_type, non_finite, out_of_range, unknown_version, too_large, inconsistent) for any bad
    input; never raises on data. Raises TypeError only if `expected` is not a message type (a bug).
    """
    decode_map = _DECODE_MAPS.get(expected)
    if decode_map is None:
        raise TypeError(f"{expected!r} is not a bus message type")
    try:
        size = len(data)
        if size > MAX_PAYLOAD_BYTES:
            return DecodeError(Reason.TOO_LARGE, f"{size} bytes, at most {MAX_PAYLOAD_BYTES}", None)
        # use_list=False: arrays arrive as tuples (the messages' list type); strict_map_key=False:
        # non-str keys are not a reason to fail the whole payload (unknown top-level keys are
        # ignored, nested maps check their keys themselves).
        obj = _unpackb(data, use_list=False, strict_map_key=False)
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


def from_map(obj: Mapping[Any, Any], expected: type[M]) -> M | DecodeError:
    """Validate an already-unpacked map (e.g. from JSON or a recording) as `expected`."""
    decode_map = _DECODE_MAPS.get(expected)
    if decode_map is None:
        raise TypeError(f"{expected!r} is not a bus message type")
    if not isinstance(obj, Mapping):
        return DecodeError(Reason.NOT_A_MAP, f"top-level object is {type(obj).__name__}", None)
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
