"""ROS 2 on the wire without ROS: CDR messages and rmw_zenoh's conventions, standard library only.

- :mod:`bus_schemas.ros2.msgs`: the message types the fleet speaks (Twist, Odometry, TFMessage,
  PoseArray, PoseStamped, MarkerArray, Header, Time, std_srvs/Trigger) with CDR encode/decode
  and their RIHS01 type hashes;
- :mod:`bus_schemas.ros2.rmw`: rmw_zenoh key expressions, put attachments, liveliness tokens
  (graph discovery), QoS strings and GIDs;
- :mod:`bus_schemas.ros2.cdr`: the CDR byte layer; :mod:`bus_schemas.ros2.xxh3`: XXH3-128.

Nothing here opens a socket or reads a clock: the Zenoh shells (``robot_agent.motors.ros2``,
``formation.live.ros2_bridge``) do. docs/ros2.md shows the whole picture.
"""

from bus_schemas.ros2 import msgs, rmw
from bus_schemas.ros2.msgs import RosType, decode, encode
from bus_schemas.ros2.rmw import Attachment, EntityKind, Qos

__all__ = ["Attachment", "EntityKind", "Qos", "RosType", "decode", "encode", "msgs", "rmw"]
