"""The bridge's ROS 2 graph as a contract: its node name, the topics it publishes, the topics it
subscribes, the services it serves, and the Zenoh key expressions that cover each of them for
any domain id and namespace (what the generated access control grants, bus_schemas.acl_rules).

``formation ros2`` (formation.live.ros2_bridge) names its entities from here, and the router's
ACL under ``--secure`` lets only the bridge's identity (CN ``ros2``) publish the topics below and
declare the bridge's liveliness tokens, lets the operator's identity publish the topics the
bridge subscribes and call its services, and lets operators and observers read what it
publishes and watch the ROS graph (docs/security.md, docs/ros2.md).

A key expression here is ``*/**/<name>/<dds type>/<RIHS01 hash>``: any domain (one chunk), any
namespace (``**``), the topic's last chunks, and exactly its type. ``<id>/odom`` is
``*/*/**/odom/...`` (a robot id is at least one chunk).
"""

from __future__ import annotations

from typing import Final

from bus_schemas.ros2.msgs import (
    MARKER_ARRAY,
    ODOMETRY,
    POSE_ARRAY,
    POSE_STAMPED,
    TF_MESSAGE,
    TRIGGER,
    TWIST,
    RosType,
)
from bus_schemas.ros2.rmw import ADMIN_SPACE

__all__ = [
    "NODE_NAME",
    "PUBLISHES",
    "SERVES",
    "SUBSCRIBES",
    "acl_key",
    "published_keys",
    "served_keys",
    "subscribed_keys",
    "token_keys",
]

NODE_NAME: Final = "formation_bridge"
"""The bridge's ROS node name (``ros2 node list`` shows ``/formation_bridge``)."""

ODOM: Final = "odom"
TF: Final = "/tf"
LEADER: Final = "formation/leader"
SLOTS: Final = "formation/slots"
MARKERS: Final = "formation/markers"
CMD_VEL: Final = "formation/cmd_vel"
GOAL: Final = "formation/goal"
ESTOP: Final = "formation/estop"
RELEASE: Final = "formation/release"

PUBLISHES: Final[tuple[tuple[str, RosType], ...]] = (
    (f"*/{ODOM}", ODOMETRY),  # <ns>/<id>/odom
    (TF, TF_MESSAGE),
    (LEADER, POSE_STAMPED),
    (SLOTS, POSE_ARRAY),
    (MARKERS, MARKER_ARRAY),
)
"""(topic relative to the namespace, type) of everything the bridge publishes; ``/tf`` is
absolute (tf2 listens there), ``*`` stands for a robot id."""
SUBSCRIBES: Final[tuple[tuple[str, RosType], ...]] = ((CMD_VEL, TWIST), (GOAL, POSE_STAMPED))
"""What the bridge takes from ROS 2 (forwarded to the operator's keys only)."""
SERVES: Final[tuple[tuple[str, RosType], ...]] = ((ESTOP, TRIGGER), (RELEASE, TRIGGER))
"""The bridge's services (the fleet's latched e-stop path)."""


def acl_key(topic: str, rtype: RosType) -> str:
    """The key expression covering ``topic`` of type ``rtype`` in any domain and namespace."""
    head = topic.lstrip("/")
    if head.startswith("*/"):  # a robot id: one chunk at least, under any namespace
        return f"*/*/**/{head[2:]}/{rtype.dds_name}/{rtype.type_hash}"
    return f"*/**/{head}/{rtype.dds_name}/{rtype.type_hash}"


def published_keys() -> tuple[str, ...]:
    return tuple(acl_key(t, r) for t, r in PUBLISHES)


def subscribed_keys() -> tuple[str, ...]:
    return tuple(acl_key(t, r) for t, r in SUBSCRIBES)


def served_keys() -> tuple[str, ...]:
    return tuple(acl_key(t, r) for t, r in SERVES)


def token_keys() -> tuple[str, ...]:
    """The bridge's liveliness tokens: its node and every endpoint of it (any domain, session,
    entity, enclave and namespace; rmw.node_token / rmw.endpoint_token)."""
    return (f"{ADMIN_SPACE}/*/*/*/*/*/*/*/{NODE_NAME}/**",)


GRAPH_PATTERN: Final = f"{ADMIN_SPACE}/**"
"""Every liveliness token of every domain (``ros2 topic list`` watches it)."""
