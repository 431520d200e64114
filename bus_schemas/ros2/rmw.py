"""rmw_zenoh's wire conventions as pure functions: key expressions, attachments, liveliness
tokens, QoS strings and GIDs (ros2/rmw_zenoh ``docs/design.md``, Jazzy and later).

- A topic or service travels on ``<domain_id>/<fully_qualified_name>/<dds_type>/<type_hash>``
  (``0/r1/odom/nav_msgs::msg::dds_::Odometry_/RIHS01_3cc9...``). A different domain, type or
  hash is silence, not an error: :func:`topic_key` is the only place keys are built.
- Every put (and every service request and reply) carries a 33-byte attachment: int64 sequence
  number, int64 source timestamp (ns since the UNIX epoch), one byte GID length (16), the GID.
  A service reply echoes the request's sequence number and client GID.
- The ROS graph (``ros2 node list``, ``ros2 topic list -t``) is read from liveliness tokens in
  the hermetic ``@ros2_lv`` namespace (``*`` and ``**`` never match that chunk): one per node
  and one per publisher / subscription / service server / client, with names mangled
  (``/`` -> ``%``, empty -> ``%``) and the QoS in a compact string where every component equal
  to rmw_zenoh's default is left empty.
- An entity's GID is the XXH3-128 hash of its liveliness key string.

No I/O, no clock: timestamps are arguments. Standard library only (this runs on a robot).
"""

from __future__ import annotations

import re
import struct
from dataclasses import dataclass
from enum import StrEnum

from bus_schemas.errors import DecodeError, Reason
from bus_schemas.ros2.msgs import RosType
from bus_schemas.ros2.xxh3 import xxh3_128

__all__ = [
    "ADMIN_SPACE",
    "ATTACHMENT_BYTES",
    "DEFAULT_QOS",
    "GID_BYTES",
    "Attachment",
    "EntityKind",
    "LivelinessToken",
    "Qos",
    "decode_attachment",
    "demangle",
    "encode_attachment",
    "endpoint_token",
    "entity_gid",
    "graph_pattern",
    "mangle",
    "node_token",
    "parse_qos",
    "parse_token",
    "qos_string",
    "topic_key",
]

ADMIN_SPACE = "@ros2_lv"
GID_BYTES = 16
ATTACHMENT_BYTES = 8 + 8 + 1 + GID_BYTES
_INT64_MAX = 2**63 - 1
DURATION_INFINITE_NS = 9_223_372_036 * 1_000_000_000 + 854_775_807
"""RMW_DURATION_INFINITE ({9223372036 s, 854775807 ns}): no deadline, lifespan or lease."""

_NAME_CHUNK = re.compile(r"^[A-Za-z0-9_~]+$")
_ZID = re.compile(r"^[0-9a-f]{1,32}$")


# --- names and keys ----------------------------------------------------------------------------


def _check_fqn(name: str) -> str:
    """A fully qualified ROS name without its leading ``/`` (``r1/odom``); ValueError if it is
    not one (empty, ``//``, a trailing ``/``, or characters ROS names do not allow)."""
    stripped = name[1:] if name.startswith("/") else name
    chunks = stripped.split("/")
    if not stripped or any(not _NAME_CHUNK.match(c) for c in chunks):
        raise ValueError(f"{name!r} is not a ROS name (alphanumerics and _ between single /)")
    if chunks[0][0].isdigit():
        raise ValueError(f"{name!r}: a ROS name may not start with a digit")
    return stripped


def topic_key(domain_id: int, name: str, rtype: RosType) -> str:
    """The data key of topic or service ``name`` (``/r1/odom`` or ``r1/odom``) in a domain."""
    _check_domain(domain_id)
    return f"{domain_id}/{_check_fqn(name)}/{rtype.dds_name}/{rtype.type_hash}"


def mangle(name: str) -> str:
    """A name as one key chunk: every ``/`` becomes ``%``; the empty name is ``%``."""
    return name.replace("/", "%") if name else "%"


def demangle(chunk: str) -> str:
    """The inverse of :func:`mangle` (``%`` alone is the empty name)."""
    return "" if chunk == "%" else chunk.replace("%", "/")


def _check_domain(domain_id: int) -> None:
    # ROS_DOMAIN_ID is 0..232 for DDS; rmw_zenoh takes any size_t, we keep the ROS range.
    if type(domain_id) is not int or not 0 <= domain_id <= 232:
        raise ValueError(f"domain id {domain_id!r} outside 0..232")


def graph_pattern(domain_id: int) -> str:
    """The key expression that matches every liveliness token of a domain."""
    _check_domain(domain_id)
    return f"{ADMIN_SPACE}/{domain_id}/**"


# --- attachments -------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Attachment:
    """What rmw_zenoh attaches to every put, request and reply.

    Attributes:
        seq: the publisher's (or client's) sequence number, int64, +1 per message.
        timestamp_ns: the source timestamp, ns since the UNIX epoch (int64).
        gid: the publisher's (or, in a request and its reply, the client's) 16-byte GID.
    """

    seq: int
    timestamp_ns: int
    gid: bytes


def encode_attachment(att: Attachment) -> bytes:
    """The 33 bytes of ``att``; ValueError for a GID that is not 16 bytes or an out-of-range
    int64."""
    if len(att.gid) != GID_BYTES:
        raise ValueError(f"GID of {len(att.gid)} bytes, expected {GID_BYTES}")
    for name, v in (("seq", att.seq), ("timestamp_ns", att.timestamp_ns)):
        if type(v) is not int or not -(2**63) <= v <= _INT64_MAX:
            raise ValueError(f"{name} {v!r} is not an int64")
    return struct.pack("<qqB", att.seq, att.timestamp_ns, GID_BYTES) + bytes(att.gid)


def decode_attachment(data: bytes | bytearray | memoryview | None) -> Attachment | DecodeError:
    """The attachment in ``data``, or a DecodeError (absent, wrong length, GID length not 16)."""
    if data is None:
        return DecodeError(Reason.MISSING_FIELD, "no attachment", "attachment")
    try:
        raw = bytes(data)
    except Exception as exc:
        return DecodeError(Reason.MALFORMED, f"{type(exc).__name__}", "attachment")
    if len(raw) != ATTACHMENT_BYTES:
        return DecodeError(
            Reason.MALFORMED, f"{len(raw)} bytes, expected {ATTACHMENT_BYTES}", "attachment"
        )
    seq, stamp, gid_len = struct.unpack_from("<qqB", raw, 0)
    if gid_len != GID_BYTES:
        return DecodeError(Reason.MALFORMED, f"GID length {gid_len}", "attachment")
    return Attachment(seq, stamp, raw[17:])


# --- QoS ---------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Qos:
    """An endpoint's QoS as rmw enumerates it.

    Attributes:
        reliability: 1 reliable, 2 best effort.
        durability: 1 transient local, 2 volatile.
        history: 1 keep last, 2 keep all.
        depth: the keep-last depth.
        deadline_ns, lifespan_ns, lease_ns: durations in ns (DURATION_INFINITE_NS: none).
        liveliness: 1 automatic, 3 manual by topic.
    """

    reliability: int = 1
    durability: int = 2
    history: int = 1
    depth: int = 42
    deadline_ns: int = DURATION_INFINITE_NS
    lifespan_ns: int = DURATION_INFINITE_NS
    liveliness: int = 1
    lease_ns: int = DURATION_INFINITE_NS


DEFAULT_QOS = Qos()
"""rmw_zenoh's default profile: reliable, volatile, keep last 42, no deadline/lifespan/lease."""


def qos_string(qos: Qos) -> str:
    """The QoS chunk of a token: six ``:``-separated fields
    ``reliability:durability:history,depth:deadline_s,ns:lifespan_s,ns:liveliness,lease_s,ns``
    where each component equal to :data:`DEFAULT_QOS`'s is left empty (``::,10:,:,:,,``)."""
    d = DEFAULT_QOS

    def part(value: int, default: int) -> str:
        return "" if value == default else str(value)

    def dur(ns: int, default_ns: int) -> str:
        s, n = divmod(ns, 1_000_000_000)
        ds, dn = divmod(default_ns, 1_000_000_000)
        return f"{part(s, ds)},{part(n, dn)}"

    return ":".join(
        (
            part(qos.reliability, d.reliability),
            part(qos.durability, d.durability),
            f"{part(qos.history, d.history)},{part(qos.depth, d.depth)}",
            dur(qos.deadline_ns, d.deadline_ns),
            dur(qos.lifespan_ns, d.lifespan_ns),
            f"{part(qos.liveliness, d.liveliness)},{dur(qos.lease_ns, d.lease_ns)}",
        )
    )


def parse_qos(text: str) -> Qos | DecodeError:
    """A QoS chunk back to a :class:`Qos`. Reads the current six-field form and the short form
    of older releases (``reliability:durability:history,depth``, e.g. ``1:2:1,10``)."""
    parts = text.split(":")
    d = DEFAULT_QOS
    try:

        def num(s: str, default: int) -> int:
            if s == "":
                return default
            if not s.isdigit() or len(s) > 20:
                raise ValueError(s)
            return int(s)

        def pair(s: str, default_ns: int) -> int:
            sec_s, ns_s = s.split(",")
            ds, dn = divmod(default_ns, 1_000_000_000)
            return num(sec_s, ds) * 1_000_000_000 + num(ns_s, dn)

        if len(parts) == 3:
            history, depth = parts[2].split(",")
            return Qos(num(parts[0], 1), num(parts[1], 2), num(history, 1), num(depth, 10))
        if len(parts) != 6:
            raise ValueError("expected 6 fields")
        history, depth = parts[2].split(",")
        live, lease_s, lease_n = parts[5].split(",")
        ls, ln = divmod(d.lease_ns, 1_000_000_000)
        return Qos(
            reliability=num(parts[0], d.reliability),
            durability=num(parts[1], d.durability),
            history=num(history, d.history),
            depth=num(depth, d.depth),
            deadline_ns=pair(parts[3], d.deadline_ns),
            lifespan_ns=pair(parts[4], d.lifespan_ns),
            liveliness=num(live, d.liveliness),
            lease_ns=num(lease_s, ls) * 1_000_000_000 + num(lease_n, ln),
        )
    except ValueError as exc:
        return DecodeError(Reason.MALFORMED, f"QoS {text[:80]!r}: {exc}"[:200], "qos")


# --- liveliness tokens -------------------------------------------------------------------------


class EntityKind(StrEnum):
    """The entity kind chunk of a liveliness token."""

    NODE = "NN"
    PUBLISHER = "MP"
    SUBSCRIPTION = "MS"
    SERVICE = "SS"
    CLIENT = "SC"


@dataclass(frozen=True, slots=True)
class LivelinessToken:
    """A parsed ``@ros2_lv`` token (names demangled: ``namespace`` is ``/r1`` or ``""``)."""

    domain_id: int
    session_id: str
    node_id: int
    entity_id: int
    kind: EntityKind
    enclave: str
    namespace: str
    node_name: str
    topic: str | None = None
    dds_type: str | None = None
    type_hash: str | None = None
    qos: Qos | None = None

    @property
    def ros_type(self) -> str | None:
        """``geometry_msgs/msg/Twist`` from ``geometry_msgs::msg::dds_::Twist_``."""
        if self.dds_type is None:
            return None
        parts = self.dds_type.split("::")
        if len(parts) != 4 or parts[2] != "dds_" or not parts[3].endswith("_"):
            return None
        return f"{parts[0]}/{parts[1]}/{parts[3][:-1]}"


def _check_zid(session_id: str) -> None:
    if not _ZID.match(session_id):
        raise ValueError(f"session id {session_id!r} is not a Zenoh id (lowercase hex)")


def _check_namespace(namespace: str) -> None:
    if namespace not in ("", "/"):
        _check_fqn(namespace)


def _node_chunks(
    domain_id: int, session_id: str, namespace: str, node_name: str, enclave: str
) -> tuple[str, str]:
    """(``@ros2_lv/<domain>/<zid>``, ``<enclave>/<namespace>/<name>``), validated."""
    _check_domain(domain_id)
    _check_zid(session_id)
    _check_namespace(namespace)
    _check_fqn(node_name)
    ns = "" if namespace == "/" else namespace
    return (
        f"{ADMIN_SPACE}/{domain_id}/{session_id}",
        f"{mangle(enclave)}/{mangle(ns)}/{mangle(node_name)}",
    )


def node_token(
    domain_id: int,
    session_id: str,
    node_id: int,
    namespace: str,
    node_name: str,
    enclave: str = "",
) -> str:
    """The liveliness key of a node:
    ``@ros2_lv/<domain>/<zid>/<node_id>/<node_id>/NN/<enclave>/<namespace>/<name>``."""
    head, tail = _node_chunks(domain_id, session_id, namespace, node_name, enclave)
    return f"{head}/{node_id}/{node_id}/{EntityKind.NODE}/{tail}"


def endpoint_token(
    domain_id: int,
    session_id: str,
    node_id: int,
    entity_id: int,
    kind: EntityKind,
    namespace: str,
    node_name: str,
    topic: str,
    rtype: RosType,
    qos: Qos = DEFAULT_QOS,
    enclave: str = "",
) -> str:
    """The liveliness key of a publisher, subscription, service server or client. ``topic``
    is the fully qualified name (``/r1/odom``), mangled in the key (``%r1%odom``)."""
    if kind is EntityKind.NODE:
        raise ValueError("a node's token is node_token()")
    head, tail = _node_chunks(domain_id, session_id, namespace, node_name, enclave)
    fqn = "/" + _check_fqn(topic)
    return (
        f"{head}/{node_id}/{entity_id}/{kind}/{tail}/{mangle(fqn)}/{rtype.dds_name}/"
        f"{rtype.type_hash}/{qos_string(qos)}"
    )


def parse_token(key: str) -> LivelinessToken | DecodeError:
    """A liveliness key back to its parts, or a DecodeError for anything else."""
    parts = str(key).split("/")
    if len(parts) < 9 or parts[0] != ADMIN_SPACE:
        return DecodeError(Reason.MALFORMED, f"not a ROS 2 liveliness key: {key[:120]!r}", "key")
    try:
        kind = EntityKind(parts[5])
        domain_id, node_id, entity_id = int(parts[1]), int(parts[3]), int(parts[4])
    except ValueError as exc:
        return DecodeError(Reason.MALFORMED, f"{exc}"[:200], "key")
    fields = (
        domain_id,
        parts[2],
        node_id,
        entity_id,
        kind,
        demangle(parts[6]),
        demangle(parts[7]),
        demangle(parts[8]),
    )
    if kind is EntityKind.NODE:
        if len(parts) != 9:
            return DecodeError(Reason.MALFORMED, f"node token of {len(parts)} chunks", "key")
        return LivelinessToken(*fields)
    if len(parts) != 13:
        return DecodeError(Reason.MALFORMED, f"endpoint token of {len(parts)} chunks", "key")
    qos = parse_qos(parts[12])
    if isinstance(qos, DecodeError):
        return qos
    return LivelinessToken(*fields, demangle(parts[9]), parts[10], parts[11], qos)


def entity_gid(token_key: str) -> bytes:
    """The 16-byte GID rmw_zenoh gives the entity whose liveliness key is ``token_key``:
    XXH3-128 of the key, low 64 bits then high 64 bits, each little endian."""
    low, high = xxh3_128(token_key.encode("utf-8"))
    return low.to_bytes(8, "little") + high.to_bytes(8, "little")
