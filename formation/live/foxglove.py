"""Live view of a fleet in Foxglove: a WebSocket server (foxglove-sdk) fed from the bus.

``formation up --foxglove`` calls :func:`start_live` on its session; anything else with a Zenoh
session can too. Then open Foxglove (app or https://app.foxglove.dev), "Open connection",
"Foxglove WebSocket", ``ws://127.0.0.1:8765``.

Channels (the same topics and JSON Schemas as an MCAP recording of ``formation record``, so one
Foxglove layout serves both):

* ``/<key>`` for every bus key of the fleet (``/formation/demo/robot/r1/pose``, ...): the message
  as JSON, schema ``formation.<Type>`` generated from ``bus_schemas``; liveliness tokens as
  ``formation.Liveliness``; ``/derived/robot/<id>/tracking_error`` (hypot of the status ex, ey).
* ``/scene`` (``foxglove.SceneUpdate``, protobuf), redrawn at ``scene_hz``, in frame ``world``:
  each robot as a cylinder (its body radius) with a heading arrow and a label (id, slot, role,
  mode), grey when its liveliness token is gone; its reference point (eqs 10-11) as a small
  sphere; every slot as a sphere coloured by role (leader, subleader, follower) labelled
  ``v<k+1>`` as in the paper's figures; the virtual leader as an arrow; lines from each slot's
  parent to the slot (the leader-follower tree, eqs 3-5) and from each robot's reference point to
  its assigned slot (the tracking error vector, eqs 17-18); the scenario's obstacles and
  arena; for a planned trajectory (issue 27) the planned leader path (a green line) and the
  footprint corridor (a translucent green surface with its outline), replaced when the plan
  changes (:meth:`LiveServer.show_plan`).
* ``/tf`` (``foxglove.FrameTransforms``): ``world`` -> ``<robot id>`` for each robot's latest pose,
  so a 3D panel can follow one robot.

Robots are drawn at their measured ``pose`` (what the controllers see), or at ``truth`` when no
pose has arrived (simulation only). Threading: a :class:`runtime.tap.BusTap` worker decodes
and logs; the SDK's server runs on its own threads.
"""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Callable, Iterable, Mapping
from dataclasses import replace
from typing import Any, Final

import foxglove
import numpy as np
import zenoh
from foxglove import Channel
from foxglove.channels import FrameTransformsChannel, SceneUpdateChannel
from foxglove.websocket import Capability

from bus_schemas import (
    CoordinatorStatus,
    DecodeError,
    Status,
    keys,
)
from formation.live.foxglove_ops import OperatorListener
from formation.live.scene import SCENE_TOPIC, TF_TOPIC, SceneModel
from formation.outputs.bus_json import (
    DERIVED_PREFIX,
    LIVELINESS_SCHEMA,
    TRACKING_ERROR_SCHEMA,
    alive_kind,
    decode_sample,
    json_schema,
    jsonable,
    tracking_error,
    unpack_map,
)
from formation.outputs.plan_view import REPLAN_LABEL, PlanMesh, plan_mesh, plan_view
from robot_agent.core.params import RobotGeometry
from runtime.tap import BusItem, BusTap

DEFAULT_HOST: Final = "127.0.0.1"
DEFAULT_PORT: Final = 8765
SUBPROTOCOL: Final = "foxglove.sdk.v1"
"""WebSocket subprotocol the SDK's server speaks (clients must offer it)."""

# --------------------------------------------------------------------------------------------
# The server
# --------------------------------------------------------------------------------------------


class LiveServer:
    """A Foxglove WebSocket server publishing a fleet's bus traffic and its scene.

    ``port=0`` picks a free port (read it back from :attr:`port`). Uses its own
    ``foxglove.Context``, so several servers (or tests) in one process do not share channels.
    :meth:`handle` and :meth:`tick` are called by one thread (the tap's worker).
    """

    def __init__(
        self,
        fleet: str = keys.DEFAULT_FLEET,
        *,
        host: str = DEFAULT_HOST,
        port: int = DEFAULT_PORT,
        scene_hz: float = 10.0,
        ref_offset_m: float = RobotGeometry().ref_offset_m,
        body_radius_m: float = RobotGeometry().body_radius_m,
        world: Any = None,
        commands: Callable[[str, bytes], object] | None = None,
    ) -> None:
        if not scene_hz > 0:
            raise ValueError(f"scene_hz must be > 0, got {scene_hz!r}")
        self.fleet = keys.check_fleet(fleet)
        self.scene_period_s = 1.0 / scene_hz
        self.model = SceneModel(fleet, ref_offset_m, body_radius_m, world=world)
        self.context = foxglove.Context()
        # issue 28: a client's publishes (Teleop panel, e-stop, goal) become the operator's
        # commands, put with ``commands`` (formation.live.foxglove_ops)
        self.operator = OperatorListener(fleet, commands)
        self.server = foxglove.start_server(
            name=f"formation {fleet}",
            host=host,
            port=port,
            context=self.context,
            capabilities=[Capability.ClientPublish],
            supported_encodings=["json"],
            server_listener=self.operator,
        )
        self.host = host
        self._plan_mesh: PlanMesh | None = None  # the plan of show_plan (None: none)
        self._plans_seen: dict[str, int] = {}  # coordinator name -> plans its status counted
        self._plan_marks: list[tuple[float, float, str]] = []  # the run-time plans seen
        self.messages = 0
        self.rejected = 0
        self._channels: dict[str, Channel] = {}
        self._scene = SceneUpdateChannel(SCENE_TOPIC, context=self.context)
        self._tf = FrameTransformsChannel(TF_TOPIC, context=self.context)
        self._tap: BusTap | None = None
        self._closed = False
        self._lock = threading.Lock()

    @property
    def port(self) -> int:
        """The TCP port the server listens on."""
        return self.server.port

    @property
    def url(self) -> str:
        """``ws://host:port``: what to open in Foxglove."""
        return f"ws://{self.host}:{self.port}"

    def _channel(self, topic: str, schema: dict[str, Any] | None) -> Channel:
        ch = self._channels.get(topic)
        if ch is None:
            ch = Channel(topic, schema=schema, context=self.context)
            self._channels[topic] = ch
        return ch

    @staticmethod
    def _log(ch: Channel, obj: Any, wall_ns: int) -> None:
        if ch.has_sinks():  # nobody subscribed: skip the JSON encoding
            data = json.dumps(obj, separators=(",", ":"), allow_nan=False).encode()
            ch.log(data, log_time=wall_ns)

    def handle(self, item: BusItem) -> None:
        """Publish one bus observation (called on the tap's worker thread)."""
        wall_ns = time.time_ns()
        if item.kind in ("alive", "dead"):
            alive = item.kind == "alive"
            self.model.set_alive(item.key, alive)
            kind, ident = alive_kind(item.key)
            ch = self._channel("/" + item.key, LIVELINESS_SCHEMA)
            self._log(ch, {"alive": alive, "kind": kind, "id": ident, "key": item.key}, wall_ns)
            return
        if item.kind != "put":
            return
        decoded = decode_sample(item.key, item.payload)
        if decoded is None:  # a key this bus version does not know: schemaless JSON
            obj = unpack_map(item.payload)
            if not isinstance(obj, DecodeError):
                self._log(self._channel("/" + item.key, None), jsonable(obj), wall_ns)
            return
        if isinstance(decoded, DecodeError):
            self.rejected += 1
            return
        cls, msg, obj = decoded
        self.messages += 1
        self.model.update(item.key, msg)
        self._log(self._channel("/" + item.key, json_schema(cls)), jsonable(obj), wall_ns)
        if isinstance(msg, CoordinatorStatus) and msg.plans is not None:
            self._on_plans(msg)
        if isinstance(msg, Status):
            parsed = keys.parse_robot_key(item.key)
            body = tracking_error(msg)
            if parsed is not None and body is not None:
                topic = f"{DERIVED_PREFIX}{parsed[1]}/tracking_error"
                self._log(self._channel(topic, TRACKING_ERROR_SCHEMA), body, wall_ns)

    def show_plan(
        self, trajectory: Mapping[str, Any] | None, replans: Iterable[Mapping[str, Any]] = ()
    ) -> None:
        """Show the plan of ``trajectory`` (a scenario's trajectory table; not a plan or None:
        no plan) in the scene from its next redraw: the planned leader path, the footprint
        corridor (translucent) and the ``replans`` (``RunLog.replans`` events; issue 27).
        Call it again when the plan changes (a replan): the ``plan`` entity is replaced. May
        be called from any thread. Raises ValueError if the table does not plan."""
        view = plan_view(trajectory, replans, timed=False) if trajectory is not None else None
        self._plan_mesh = None if view is None else plan_mesh(view)
        self._show_plan()

    def _on_plans(self, msg: CoordinatorStatus) -> None:
        """A coordinator's status counted a new run-time plan (an operator's goal, a replan):
        the scene's ``plan`` entity is redrawn with a mark, labelled with the status's reason,
        where the virtual leader is. The status carries no path (docs/planning.md): the leader's
        track shows the path it follows."""
        assert msg.plans is not None
        seen = self._plans_seen.get(msg.name, 0)
        self._plans_seen[msg.name] = max(seen, msg.plans)
        leader = self.model.leader
        if msg.plans <= seen or leader is None:
            return
        n = len(self._plan_marks) + 1
        why = msg.plan_why or "?"
        label = f"{REPLAN_LABEL} {n}: " + (f"no way: {why}" if msg.plan == "no_way" else why)
        self._plan_marks.append((float(leader.x), float(leader.y), label))
        self._show_plan()

    def _show_plan(self) -> None:
        """The plan of show_plan with the run-time plans' marks (an empty plan with only the
        marks for a trajectory that is not planned); nothing while there is neither."""
        mesh = self._plan_mesh
        if not self._plan_marks:
            self.model.set_plan(mesh)
            return
        if mesh is None:
            empty = np.empty((0, 2))
            mesh = PlanMesh(empty, empty, np.empty((0, 3), dtype=np.int64), ())
        self.model.set_plan(replace(mesh, marks=(*mesh.marks, *self._plan_marks)))

    def tick(self, _now_ns: int = 0) -> None:
        """Publish the scene and the transforms (called every ``1 / scene_hz`` s)."""
        wall_ns = time.time_ns()
        self._scene.log(self.model.scene(wall_ns), log_time=wall_ns)
        self._tf.log(self.model.transforms(wall_ns), log_time=wall_ns)

    def attach(self, session: zenoh.Session) -> BusTap:
        """Subscribe to the fleet on ``session`` and start publishing."""
        if self._tap is not None:
            raise RuntimeError("LiveServer.attach: already attached")
        self._tap = BusTap(
            session,
            self.fleet,
            self.handle,
            tick=self.tick,
            tick_s=self.scene_period_s,
            name="foxglove-live",
        )
        return self._tap

    def close(self) -> None:
        """Stop the tap (if attached) and the server (idempotent)."""
        with self._lock:
            tap, self._tap = self._tap, None
            if tap is not None:
                tap.close()
            if not self._closed:
                self._closed = True
                self.server.stop()


class LiveHandle:
    """What :func:`start_live` returns: ``.url``, ``.port``, ``.close()`` (idempotent)."""

    def __init__(self, live: LiveServer) -> None:
        self.live = live

    @property
    def port(self) -> int:
        """The TCP port of the WebSocket server."""
        return self.live.port

    @property
    def url(self) -> str:
        """``ws://host:port``."""
        return self.live.url

    def close(self) -> None:
        """Unsubscribe and stop the server."""
        self.live.close()


def start_live(
    session: zenoh.Session,
    fleet: str = keys.DEFAULT_FLEET,
    host: str = DEFAULT_HOST,
    port: int = DEFAULT_PORT,
    *,
    scene_hz: float = 10.0,
    ref_offset_m: float = RobotGeometry().ref_offset_m,
    body_radius_m: float = RobotGeometry().body_radius_m,
    world: Any = None,
    commands: zenoh.Session | None = None,
    trajectory: Mapping[str, Any] | None = None,
) -> LiveHandle:
    """Start a Foxglove WebSocket server for ``fleet`` fed from ``session``.

    ``port=0`` picks a free port. Raises ``RuntimeError`` if the port is taken. The caller keeps
    owning the session and must call ``handle.close()`` before closing it. ``commands``: the
    session a client's publishes are put with as operator commands (issue 28,
    :mod:`formation.live.foxglove_ops`); None: they are refused. ``trajectory``: the
    scenario's trajectory table, whose plan (``kind = "plan"``) the scene shows
    (:meth:`LiveServer.show_plan`).
    ``formation up --foxglove``::

        live = start_live(session, cfg.fleet, port=8765,
                          ref_offset_m=geom.ref_offset_m, body_radius_m=geom.body_radius_m)
        print(f"foxglove: {live.url}")
        ...
        live.close()
    """
    live = LiveServer(
        fleet,
        host=host,
        port=port,
        scene_hz=scene_hz,
        ref_offset_m=ref_offset_m,
        body_radius_m=body_radius_m,
        world=world,
        commands=None if commands is None else commands.put,
    )
    try:
        live.show_plan(trajectory)
        live.attach(session)
    except BaseException:
        live.close()
        raise
    return LiveHandle(live)
