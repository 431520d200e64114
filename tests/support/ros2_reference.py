"""Test support: rosbags as the independent reference for bus_schemas.ros2 (never on a robot).

- :func:`typestore`: ROS 2 Jazzy's message types plus std_srvs/srv/Trigger and
  example_interfaces/srv/AddTwoInts registered as rosidl describes a service (request, response,
  event), so :func:`service_hash` computes a service's RIHS01 hash with rosbags' own hasher.
- :func:`to_rosbags`: one of our dataclasses as the rosbags object of the same ROS type, driven
  by rosbags' field definitions (so a field we forgot or misnamed fails loudly).
- :func:`msgdef`: the definition text and hash zenoh-ros2-sdk needs to run offline.
"""

from __future__ import annotations

import dataclasses
from functools import cache
from typing import Any

import numpy as np
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.base import Nodetype
from rosbags.typesys.store import Typestore

_NUMPY = {
    "float64": np.float64,
    "float32": np.float32,
    "uint8": np.uint8,
    "int8": np.int8,
    "char": np.uint8,
}

SERVICES = {
    "std_srvs/srv/Trigger": ("", "bool success\nstring message\n"),
    "example_interfaces/srv/AddTwoInts": ("int64 a\nint64 b\n", "int64 sum\n"),
}


def _service_types(name: str, request: str, response: str) -> dict[str, Any]:
    types: dict[str, Any] = {}
    types.update(get_types_from_msg(request, f"{name}_Request"))
    types.update(get_types_from_msg(response, f"{name}_Response"))
    types.update(
        get_types_from_msg(
            f"service_msgs/ServiceEventInfo info\n{name}_Request[<=1] request\n"
            f"{name}_Response[<=1] response\n",
            f"{name}_Event",
        )
    )
    types.update(
        get_types_from_msg(
            f"{name}_Request request_message\n{name}_Response response_message\n"
            f"{name}_Event event_message\n",
            name,
        )
    )

    # rosbags files "pkg/srv/X" under "pkg/srv/msg/X"; a service's parts are "pkg/srv/X_..."
    def fix(obj: Any) -> Any:
        if isinstance(obj, str):
            return obj.replace("/srv/msg/", "/srv/")
        if isinstance(obj, tuple | list):
            return type(obj)(fix(x) for x in obj)
        return obj

    return {fix(k): fix(v) for k, v in types.items()}


@cache
def typestore() -> Typestore:
    """Jazzy's types + our two services. ServiceEventInfo.client_gid is ``char[16]`` in rosbags'
    store but ``uint8[16]`` in the type description rosidl hashes (``char`` is an alias of
    ``uint8`` in ROS 2 IDL): with it, AddTwoInts' hash equals the one rmw_zenoh's design
    document shows."""
    from rosbags.typesys.stores.ros2_jazzy import FIELDDEFS

    ts = get_typestore(Stores.EMPTY)
    defs = dict(FIELDDEFS)
    defs.update(
        get_types_from_msg(
            "uint8 event_type\nbuiltin_interfaces/Time stamp\nuint8[16] client_gid\n"
            "int64 sequence_number\n",
            "service_msgs/msg/ServiceEventInfo",
        )
    )
    ts.register(defs)
    for name, (req, resp) in SERVICES.items():
        ts.register(_service_types(name, req, resp))
    return ts


def service_hash(name: str) -> str:
    return typestore().hash_rihs01(name)


def _convert(value: Any, node: tuple[Any, Any]) -> Any:
    kind, desc = node
    ts = typestore()
    if kind == Nodetype.NAME:
        return to_rosbags(value, desc)
    if kind == Nodetype.BASE:
        return value
    sub, _size = desc
    sub_kind, sub_desc = sub
    if sub_kind == Nodetype.BASE and sub_desc[0] in _NUMPY:
        if isinstance(value, bytes | bytearray):
            return np.frombuffer(bytes(value), dtype=np.uint8).copy()
        return np.array(value, dtype=_NUMPY[sub_desc[0]])
    assert ts is not None
    return [_convert(v, sub) for v in value]


def to_rosbags(msg: Any, typename: str) -> Any:
    """Our dataclass ``msg`` as rosbags' object of ROS type ``typename``."""
    ts = typestore()
    fields = ts.fielddefs[typename][1]
    ours = {f.name for f in dataclasses.fields(msg)}
    theirs = {name for name, _ in fields if name != "structure_needs_at_least_one_member"}
    assert ours == theirs, f"{typename}: ours {sorted(ours)} vs rosbags {sorted(theirs)}"
    kwargs = {name: _convert(getattr(msg, name), node) for name, node in fields if name in ours}
    if not ours and fields:
        kwargs = {name: 0 for name, _ in fields}
    return ts.types[typename](**kwargs)


def serialize(msg: Any, typename: str) -> bytes:
    ts = typestore()
    return bytes(ts.serialize_cdr(to_rosbags(msg, typename), typename))


def msgdef(typename: str) -> tuple[str, str]:
    """(definition text, RIHS01 hash) of a message type, for zenoh-ros2-sdk offline."""
    ts = typestore()
    return ts.generate_msgdef(typename, ros_version=2)[0], ts.hash_rihs01(typename)
