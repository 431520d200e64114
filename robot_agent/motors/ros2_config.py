"""The ``ros2`` motor backend's configuration: ``Ros2MotorConfig`` (the robot config's ``[motor]``
with ``backend = "ros2"``), validated on construction.

Apart from the driver (``robot_agent.motors.ros2``, which re-exports it) so that the table of
backends (``robot_agent.motors.BACKENDS``) can name it without importing the driver and the ROS 2
message definitions: an agent imports those only when its robot drives a ROS 2 base.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

__all__ = ["Ros2MotorConfig"]

_ENDPOINT_PROTOCOLS = ("tcp/", "udp/", "tls/", "quic/", "unixsock-stream/")


@dataclass(frozen=True, slots=True)
class Ros2MotorConfig:
    """How the agent reaches its ROS 2 base (the robot config's ``[motor]`` with
    ``backend = "ros2"``).

    Attributes:
        endpoint: the base's Zenoh router (``ros2 run rmw_zenoh_cpp rmw_zenohd``), default the
            robot's own ``tcp/127.0.0.1:7447``.
        mode: "peer" (what rmw_zenoh's nodes are) or "client".
        domain_id: ROS_DOMAIN_ID of the base (0..232).
        namespace: the base's namespace ("" or e.g. "/tb3_1"); topics below are resolved in it.
        cmd_vel_topic: relative name of the base's velocity command topic.
        odom_topic: relative name of the base's odometry topic.
        node_name: this node's name in the ROS graph.
        odom_timeout_s: odometry older than this is stale: the estimator gets no speeds.
        max_speed_mps: odometry with a |linear speed| above this is implausible and rejected.
        max_turn_radps: same for |angular speed|.
    """

    endpoint: str = "tcp/127.0.0.1:7447"
    mode: str = "peer"
    domain_id: int = field(default=0, metadata={"range": (0, 232)})
    namespace: str = ""
    cmd_vel_topic: str = "cmd_vel"
    odom_topic: str = "odom"
    node_name: str = "formation_agent"
    odom_timeout_s: float = field(default=0.5, metadata={"range": (0.01, 10.0)})
    max_speed_mps: float = field(default=5.0, metadata={"range": (0.01, 20.0)})
    max_turn_radps: float = field(default=20.0, metadata={"range": (0.01, 100.0)})

    def __post_init__(self) -> None:
        # the ROS 2 message and key definitions only when a ros2 config is loaded: an agent of
        # another backend does not import them (about 50 ms of a small board's start)
        from bus_schemas.ros2 import msgs, rmw

        if not self.endpoint.startswith(_ENDPOINT_PROTOCOLS) or " " in self.endpoint:
            raise ValueError(f"endpoint {self.endpoint!r} is not e.g. 'tcp/127.0.0.1:7447'")
        if self.mode not in ("peer", "client"):
            raise ValueError(f"mode must be 'peer' or 'client', got {self.mode!r}")
        # the key and token builders validate names and the domain; fail at load, not at open
        for topic in (self.cmd_vel_topic, self.odom_topic):
            if topic.startswith("/"):
                raise ValueError(f"topic {topic!r} must be relative (it is put in the namespace)")
            rmw.topic_key(self.domain_id, self.fqn(topic), msgs.ros_type(msgs.Twist))
        rmw.node_token(self.domain_id, "0", 0, self.namespace, self.node_name)
        for name in ("odom_timeout_s", "max_speed_mps", "max_turn_radps"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a positive number, got {value!r}")

    def fqn(self, topic: str) -> str:
        """The fully qualified name of a relative topic (``/tb3_1/cmd_vel``)."""
        return f"{self.namespace.rstrip('/')}/{topic}"
