"""Test support: an independent rmw_zenoh client (zenoh-ros2-sdk from PyPI) as a subprocess.

``python -m tests.support.ros2_sdk_client ROUTER_PORT DOMAIN_ID [full|watch]`` does what a ROS 2
user would with ``ros2 topic list -t``, ``ros2 topic echo /r1/odom``, ``ros2 topic pub
/formation/cmd_vel`` and ``ros2 service call /formation/estop std_srvs/srv/Trigger``, and prints
one JSON line per result (``watch``: the first two only). Offline: every definition and hash
comes from rosbags (tests/support/ros2_reference.py), so the SDK fetches nothing. A subprocess
because the SDK keeps a process-wide session.
"""

from __future__ import annotations

import json
import os
import sys
import threading
import time
from typing import Any


def say(**fields: Any) -> None:
    print(json.dumps(fields), flush=True)


def main(port: int, domain_id: int, mode: str) -> None:
    from zenoh_ros2_sdk import (
        ROS2Publisher,
        ROS2ServiceClient,
        ROS2Subscriber,
        get_service_names_and_types,
        get_topic_names_and_types,
    )

    from tests.support import ros2_reference as ref

    router = {"router_ip": "127.0.0.1", "router_port": port}
    start = time.monotonic()
    deadline = start + 30.0
    wanted = {"/r1/odom", "/tf", "/formation/slots", "/formation/cmd_vel"}
    topics: dict[str, list[str]] = {}
    while time.monotonic() < deadline:
        topics = dict(get_topic_names_and_types(domain_id=domain_id, timeout=1.0, **router))
        if wanted <= set(topics):
            break
        time.sleep(0.2)
    say(what="topics", topics=topics, after_s=round(time.monotonic() - start, 2))
    services = dict(get_service_names_and_types(domain_id=domain_id, timeout=1.0, **router))
    say(what="services", services=services)

    got = threading.Event()
    odoms: list[dict[str, float | str]] = []

    def on_odom(msg: Any) -> None:
        odoms.append(
            {
                "frame_id": msg.header.frame_id,
                "child_frame_id": msg.child_frame_id,
                "x": float(msg.pose.pose.position.x),
                "y": float(msg.pose.pose.position.y),
                "v": float(msg.twist.twist.linear.x),
                "omega": float(msg.twist.twist.angular.z),
                "cov_vx": float(msg.twist.covariance[0]),
            }
        )
        got.set()

    odom_def, odom_hash = ref.msgdef("nav_msgs/msg/Odometry")
    sub = ROS2Subscriber(
        "/r1/odom", "nav_msgs/msg/Odometry", on_odom, msg_definition=odom_def,
        type_hash=odom_hash, domain_id=domain_id, **router,
    )  # fmt: skip
    got.wait(10.0)
    time.sleep(1.0)  # a few more (the robots' status twists arrive at 5 Hz)
    say(what="odom", samples=odoms[-1:])
    sub.close()
    if mode == "watch":
        return

    twist_def, twist_hash = ref.msgdef("geometry_msgs/msg/Twist")
    pub = ROS2Publisher(
        "/formation/cmd_vel", "geometry_msgs/msg/Twist", msg_definition=twist_def,
        type_hash=twist_hash, domain_id=domain_id, **router,
    )  # fmt: skip
    time.sleep(0.5)  # let the bridge's subscription match the new publisher
    vector3 = pub.session_mgr.store.types["geometry_msgs/msg/Vector3"]
    for _ in range(5):
        pub.publish(linear=vector3(x=0.15, y=0.0, z=0.0), angular=vector3(x=0.0, y=0.0, z=-0.25))
        time.sleep(0.1)
    say(what="published")
    pub.close()

    client = ROS2ServiceClient(
        "/formation/estop", "std_srvs/srv/Trigger", request_definition="", response_definition=
        "bool success\nstring message\n", type_hash=ref.service_hash("std_srvs/srv/Trigger"),
        domain_id=domain_id, timeout=8.0, **router,
    )  # fmt: skip
    response = client.call()
    say(
        what="trigger",
        response=None
        if response is None
        else {"success": bool(response.success), "message": str(response.message)},
    )
    client.close()


if __name__ == "__main__":
    try:
        main(int(sys.argv[1]), int(sys.argv[2]), sys.argv[3] if len(sys.argv) > 3 else "full")
    except Exception as exc:
        say(what="error", error=f"{type(exc).__name__}: {exc}")
    finally:
        sys.stdout.flush()
        os._exit(0)  # the SDK's process-wide session may keep threads alive
