"""Bus messages as JSON: JSON Schemas generated from the contract's tables, and decoders.

Shared by the recorder (MCAP channels), the live Foxglove view and ``formation top``/``report``:
:func:`json_schema` turns a ``bus_schemas`` message table into a JSON Schema (the contract stays
the single source), :func:`decode_sample` decodes one sample strictly by its key, and the
derived channels (tracking error, liveliness) have their schemas here too.
"""

from __future__ import annotations

import base64
import math
from collections.abc import Mapping
from typing import Any, Final, NamedTuple

import msgpack

from bus_schemas import (
    MAX_PAYLOAD_BYTES,
    VERSION,
    DecodeError,
    Message,
    Status,
    from_map,
    keys,
    message_type_for_key,
    spec_of,
)
from bus_schemas.spec import FLOAT64_MAX, UINT64_MAX, FieldSpec, Kind

SCHEMA_PREFIX: Final = "formation."
"""Prefix of the JSON Schema names (``formation.Pose``)."""
DERIVED_PREFIX: Final = "/derived/robot/"
"""Topic prefix of the derived per-robot channels (tracking error, latency)."""

# --------------------------------------------------------------------------------------------
# JSON Schemas generated from the bus_schemas message tables
# --------------------------------------------------------------------------------------------


def _field_schema(fs: FieldSpec) -> dict[str, Any]:
    """JSON Schema of one field (without nil); bounds are the wire bounds of the spec."""
    out: dict[str, Any]
    if fs.kind in (Kind.FLOAT, Kind.INT):
        out = {"type": "number" if fs.kind is Kind.FLOAT else "integer"}
        if fs.lo is not None and abs(fs.lo) < FLOAT64_MAX and fs.lo > -(2**63):
            out["minimum"] = fs.lo
        if fs.hi is not None and abs(fs.hi) < FLOAT64_MAX and fs.hi < UINT64_MAX:
            out["maximum"] = fs.hi
    elif fs.kind is Kind.BOOL:
        out = {"type": "boolean"}
    elif fs.kind is Kind.STR:
        out = {"type": "string"}
        if fs.max_len is not None:
            out["maxLength"] = fs.max_len
        if fs.pattern is not None:
            out["pattern"] = f"^{fs.pattern}$"
    elif fs.kind is Kind.ENUM:
        out = {"type": "string", "enum": list(fs.choices)}
    elif fs.kind is Kind.FLOAT_LIST:
        item: dict[str, Any] = {"type": "number"}
        if fs.lo is not None and abs(fs.lo) < FLOAT64_MAX:
            item["minimum"] = fs.lo
        if fs.hi is not None and abs(fs.hi) < FLOAT64_MAX:
            item["maximum"] = fs.hi
        out = {"type": "array", "items": item, "maxItems": fs.max_len}
    elif fs.kind is Kind.INT_LIST:
        int_item: dict[str, Any] = {"type": "integer"}
        if fs.lo is not None and fs.lo > -(2**63):
            int_item["minimum"] = fs.lo
        if fs.hi is not None and fs.hi < UINT64_MAX:
            int_item["maximum"] = fs.hi
        out = {"type": "array", "items": int_item, "maxItems": fs.max_len}
    elif fs.kind is Kind.STR_LIST:
        out = {
            "type": "array",
            "items": {"type": "string", "pattern": f"^{fs.pattern}$"},
            "maxItems": fs.max_len,
        }
    elif fs.kind is Kind.STR_INT_MAP:
        value: dict[str, Any] = {"type": "integer"}
        if fs.value_lo is not None:
            value["minimum"] = fs.value_lo
        if fs.value_hi is not None and fs.value_hi < UINT64_MAX:
            value["maximum"] = fs.value_hi
        out = {
            "type": "object",
            "additionalProperties": value,
            "propertyNames": {"pattern": f"^{fs.pattern}$"},
            "maxProperties": fs.max_len,
        }
    else:  # pragma: no cover - every Kind is handled above
        raise TypeError(f"unhandled field kind {fs.kind}")
    text = fs.description + (f" [{fs.unit}]" if fs.unit and fs.unit != "1" else "")
    out["description"] = text
    return out


def json_schema(cls: type[Message]) -> dict[str, Any]:
    """The JSON Schema (draft 2020-12) of a bus message type, from its ``bus_schemas`` table.

    Required fields are the ones the codec requires; ``nil allowed`` fields accept ``null``;
    unknown extra properties are allowed (a newer publisher may add fields).
    """
    spec = spec_of(cls)
    props: dict[str, Any] = {}
    required: list[str] = []
    for f in spec.fields:
        prop = _field_schema(f.spec)
        if f.spec.nullable:
            prop["type"] = [prop["type"], "null"]
        props[f.name] = prop
        if not f.optional:
            required.append(f.name)
    return {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "title": schema_name(cls),
        "description": spec.summary + f"\n\nBus key: {spec.key} (bus contract v{VERSION}).",
        "type": "object",
        "properties": props,
        "required": required,
        "additionalProperties": True,
    }


def schema_name(cls: type[Message]) -> str:
    """``formation.<Type>``, e.g. ``formation.Pose``: the MCAP / Foxglove schema name."""
    return SCHEMA_PREFIX + cls.__name__


def _object_schema(title: str, description: str, props: Mapping[str, Any]) -> dict[str, Any]:
    return {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "title": title,
        "description": description,
        "type": "object",
        "properties": dict(props),
        "required": list(props),
    }


LIVELINESS_SCHEMA: Final = _object_schema(
    "formation.Liveliness",
    "A liveliness token appeared (alive) or disappeared (process ended, crashed or its link "
    "lease expired).",
    {
        "alive": {"type": "boolean", "description": "true: token present; false: gone"},
        "kind": {"type": "string", "enum": ["robot", "coordinator", "plant", "other"]},
        "id": {"type": ["string", "null"], "description": "robot id or coordinator name"},
        "key": {"type": "string", "description": "the token's key expression"},
    },
)
TRACKING_ERROR_SCHEMA: Final = _object_schema(
    "formation.TrackingError",
    "Tracking error of one robot as its agent reports it (status ex, ey: eqs 17-18).",
    {
        "t": {"type": "number", "description": "status t [s]"},
        "ex": {"type": "number", "description": "setpoint x - reference point x [m]"},
        "ey": {"type": "number", "description": "setpoint y - reference point y [m]"},
        "norm_m": {"type": "number", "description": "hypot(ex, ey) [m]"},
        "slot": {"type": "integer", "description": "assigned slot, -1 if none"},
        "mode": {"type": "string", "description": "firmware mode"},
    },
)
LATENCY_SCHEMA: Final = _object_schema(
    "formation.Latency",
    "Latency of one wheel command: rx_latency_ms = recorder receive time of the wheels minus "
    "recorder receive time of the pose it was computed from (one clock); pose_age_ms = wheels "
    "receive time minus the pose's capture time pose_t (realtime, same host) or wheels t minus "
    "pose_t (lockstep, sim time).",
    {
        "t": {"type": "number", "description": "wheels t [s]"},
        "pose_t": {"type": "number", "description": "t of the pose used [s]"},
        "rx_latency_ms": {"type": ["number", "null"], "description": "[ms], null if unseen"},
        "pose_age_ms": {"type": ["number", "null"], "description": "[ms]"},
    },
)
REJECTED_SCHEMA: Final = _object_schema(
    "formation.Rejected",
    "A sample on a fleet key that failed the strict bus_schemas decode.",
    {
        "key": {"type": "string"},
        "reason": {"type": "string"},
        "detail": {"type": "string"},
        "field": {"type": ["string", "null"]},
        "payload_b64": {"type": "string", "description": "the payload bytes, base64"},
    },
)


# --------------------------------------------------------------------------------------------
# Decoding one sample
# --------------------------------------------------------------------------------------------


class Decoded(NamedTuple):
    """A sample that passed strict decoding: its type, the typed message and the wire map."""

    cls: type[Message]
    msg: Message
    obj: dict[str, Any]


def jsonable(value: Any) -> Any:
    """A msgpack-decoded value as JSON-ready data (bytes -> base64 str, tuples -> lists)."""
    if isinstance(value, dict):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [jsonable(v) for v in value]
    if isinstance(value, bytes | bytearray | memoryview):
        return base64.b64encode(bytes(value)).decode("ascii")
    if isinstance(value, float) and not math.isfinite(value):
        return None  # only in unknown extra fields: known fields reject non-finite values
    if isinstance(value, msgpack.ExtType):
        return {"ext": value.code, "data": base64.b64encode(value.data).decode("ascii")}
    return value


def decode_sample(key: str, payload: bytes) -> Decoded | DecodeError | None:
    """Strictly decode a sample of ``key``; None if the key carries no known message type.

    Unlike ``bus_schemas.decode`` this also returns the wire map (extra fields included), which
    is what the recorder writes as JSON.
    """
    cls = message_type_for_key(key)
    if cls is None:
        return None
    obj = unpack_map(payload)
    if isinstance(obj, DecodeError):
        return obj
    msg = from_map(obj, cls)
    if isinstance(msg, DecodeError):
        return msg
    return Decoded(cls, msg, obj)


def unpack_map(payload: bytes) -> dict[str, Any] | DecodeError:
    """Unpack one msgpack map (size-checked like ``bus_schemas.decode``) or say why not."""
    from bus_schemas import Reason

    if len(payload) > MAX_PAYLOAD_BYTES:
        return DecodeError(Reason.TOO_LARGE, f"{len(payload)} bytes", None)
    try:
        obj = msgpack.unpackb(payload, use_list=False, strict_map_key=False)
    except Exception as exc:  # any msgpack failure
        return DecodeError(Reason.MALFORMED, f"{type(exc).__name__}: {exc}"[:200], None)
    if type(obj) is not dict:
        return DecodeError(Reason.NOT_A_MAP, f"top-level object is {type(obj).__name__}", None)
    return obj


def tracking_error(msg: Status) -> dict[str, Any] | None:
    """The ``formation.TrackingError`` record of a status (None without ex, ey)."""
    if msg.ex is None or msg.ey is None:
        return None
    return {
        "t": msg.t,
        "ex": msg.ex,
        "ey": msg.ey,
        "norm_m": math.hypot(msg.ex, msg.ey),
        "slot": -1 if msg.slot is None else msg.slot,
        "mode": msg.mode,
    }


def alive_kind(key: str) -> tuple[str, str | None]:
    """``(kind, id)`` of a liveliness key: robot/coordinator/plant (or ``other``, None)."""
    parsed = keys.parse_alive_key(key)
    if parsed is None:
        return "other", None
    return parsed[1], parsed[2]
