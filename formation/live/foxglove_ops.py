"""The operator's commands from Foxglove (issue 28): client publishes of the live WebSocket server
(:mod:`formation.live.foxglove`) turned into bus messages.

A Foxglove client (the app's Teleop panel, a Publish panel) advertises a channel with JSON
encoding and publishes on it; :class:`OperatorListener` translates each message with
:func:`translate` and puts the result on the bus with the session it was given (the operator's
under ``--secure``: the router admits operator commands from the operator identity only, so a
server holding only an observer session cannot command, and says so by refusing the publishes).

Topics (JSON, the ROS message shapes Foxglove's panels publish):

===========================  ===========================================  =====================
topic                        JSON                                          bus message
===========================  ===========================================  =====================
``/cmd_vel``,                ``geometry_msgs/Twist``: ``{"linear": {"x":  ``CmdVel`` on
``/operator/cmd_vel``        v}, "angular": {"z": omega}}``               ``operator/cmd_vel``
``/goal``,                   ``{"x", "y"[, "heading"]}`` or a             ``Goal`` on
``/operator/goal``           ``geometry_msgs/PoseStamped`` (``pose.``     ``operator/goal``
                             ``position``, ``pose.orientation`` yaw)
``/estop``                   ``std_msgs/Bool`` ``{"data": true}``: e-stop  ``Estop`` (fleet)
                             the fleet; ``false``: release it
===========================  ===========================================  =====================

The Teleop panel publishes while a button is held; when it stops, the coordinator's deadman stops
the leader (coordinator.core.leader). Anything else (another topic, not JSON, a NaN, a field
missing) is refused and counted in :attr:`OperatorListener.rejects` by reason; the coordinator
validates again what it receives.
"""

from __future__ import annotations

import json
import math
import threading
import time
from collections.abc import Callable
from typing import Any, Final

from foxglove.websocket import Client, ClientChannel, ServerListener

from bus_schemas import CmdVel, Estop, Goal, Message, encode, keys, new_estop_id

__all__ = ["CMD_VEL_TOPICS", "ESTOP_TOPIC", "GOAL_TOPICS", "OperatorListener", "translate"]

CMD_VEL_TOPICS: Final = ("/cmd_vel", "/operator/cmd_vel")
GOAL_TOPICS: Final = ("/goal", "/operator/goal")
ESTOP_TOPIC: Final = "/estop"
MAX_MESSAGE_BYTES: Final = 64 * 1024
MAX_CLIENT_CHANNELS: Final = 256

Publish = Callable[[str, bytes], object]


def _number(obj: Any, *path: str) -> float:
    """``obj[path[0]][path[1]]...`` as a finite float (ValueError naming the path)."""
    for p in path:
        if not isinstance(obj, dict) or p not in obj:
            raise ValueError(f"missing {'.'.join(path)}")
        obj = obj[p]
    if isinstance(obj, bool) or not isinstance(obj, int | float) or not math.isfinite(obj):
        raise ValueError(f"{'.'.join(path)} is not a finite number")
    return float(obj)


def _yaw(q: Any) -> float:
    """The heading (rad) of a quaternion ``{"x", "y", "z", "w"}``."""
    x, y, z, w = (_number(q, k) for k in ("x", "y", "z", "w"))
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def translate(topic: str, data: bytes, fleet: str, now_s: float, seq: int) -> tuple[str, Message]:
    """A client publish on ``topic`` as ``(bus key, message)``; ValueError says why not."""
    if len(data) > MAX_MESSAGE_BYTES:
        raise ValueError("message too large")
    try:
        obj = json.loads(data)
    except (UnicodeDecodeError, json.JSONDecodeError):
        raise ValueError("not JSON") from None
    t = max(now_s, 0.0)
    if topic in CMD_VEL_TOPICS:
        v = _number(obj, "linear", "x")
        w = _number(obj, "angular", "z")
        return keys.cmd_vel_key(fleet), CmdVel(t=t, seq=seq, v_mps=v, omega_radps=w)
    if topic in GOAL_TOPICS:
        if isinstance(obj, dict) and "pose" in obj:
            x = _number(obj, "pose", "position", "x")
            y = _number(obj, "pose", "position", "y")
            heading: float | None = _yaw(obj["pose"].get("orientation"))
        else:
            x, y = _number(obj, "x"), _number(obj, "y")
            heading = (
                _number(obj, "heading") if isinstance(obj, dict) and "heading" in obj else None
            )
        if heading is not None:
            heading = math.remainder(heading, 2.0 * math.pi)
        return keys.goal_key(fleet), Goal(t=t, x=x, y=y, heading=heading)
    if topic == ESTOP_TOPIC:
        if not isinstance(obj, dict) or not isinstance(obj.get("data"), bool):
            raise ValueError('expected {"data": true|false}')
        engage = obj["data"]
        eid = new_estop_id() if engage else None
        return keys.estop_key(fleet), Estop(t=t, engage=engage, robot=None, id=eid)
    raise ValueError(f"not an operator topic: {topic[:100]!r}")


class OperatorListener(ServerListener):
    """Client publishes -> bus messages (module docstring). Runs on the SDK's threads."""

    def __init__(self, fleet: str, publish: Publish | None) -> None:
        self.fleet = keys.check_fleet(fleet)
        self._publish = publish
        self._lock = threading.Lock()
        self._seq = 0
        self._channels: dict[tuple[int, int], tuple[str, str]] = {}  # (client, id) -> topic, enc
        self.accepted = 0
        self.rejects: dict[str, int] = {}

    def on_client_advertise(self, client: Client, channel: ClientChannel) -> None:
        """A client announces a channel it will publish on."""
        with self._lock:
            if len(self._channels) < MAX_CLIENT_CHANNELS:
                self._channels[(client.id, channel.id)] = (channel.topic, channel.encoding)

    def on_client_unadvertise(self, client: Client, client_channel_id: int) -> None:
        with self._lock:
            self._channels.pop((client.id, client_channel_id), None)

    def _reject(self, reason: str) -> None:
        with self._lock:
            self.rejects[reason] = self.rejects.get(reason, 0) + 1

    def on_message_data(self, client: Client, client_channel_id: int, data: bytes) -> None:
        """One client publish (the SDK's callback; never raises)."""
        try:
            with self._lock:
                channel = self._channels.get((client.id, client_channel_id))
            if channel is None:
                self._reject("unadvertised")
                return
            topic, encoding = channel
            if encoding != "json":
                self._reject("encoding")
                return
            if self._publish is None:
                self._reject("no_operator_session")
                return
            with self._lock:
                self._seq += 1
                seq = self._seq
            try:
                key, msg = translate(topic, data, self.fleet, time.monotonic(), seq)
            except ValueError as exc:
                reason = str(exc).split(":")[0].replace(" ", "_")[:40]
                self._reject(reason)
                return
            self._publish(key, encode(msg))
            with self._lock:
                self.accepted += 1
        except Exception:  # a callback of a foreign thread must not raise into the SDK
            self._reject("internal")
