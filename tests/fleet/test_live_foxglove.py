"""formation.live.foxglove: a Foxglove WebSocket server fed from a real Zenoh bus, read by a real
WebSocket client speaking the SDK's protocol (subprotocol ``foxglove.sdk.v1``).

A background thread publishes a small fleet (two robots, slots, leader, assignment, status,
liveliness) through a ``formation router`` on loopback; the test subscribes over WebSocket and
checks what arrives: the bus messages as JSON with their schemas, and the 3D scene (protobuf,
read with a minimal wire-format parser: no protobuf dependency).
"""

from __future__ import annotations

import asyncio
import json
import math
import re
import signal
import struct
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import websockets
import zenoh
from support.foxglove_fleet import FLEET, POSES, FleetPublisher, pb_fields, scene_entities
from support.spawn import Spawner, free_port

from bus_schemas import Assignment, Pose, Slot, keys
from formation.live.foxglove import SUBPROTOCOL, LiveServer, SceneModel, start_live

pytestmark = pytest.mark.shares_cpu

# ---------------------------------------------------------------------------------------------
# Reading the SceneUpdate (the wire-format reader: support.foxglove_fleet.pb_fields)
# ---------------------------------------------------------------------------------------------


def position_of(cylinder: bytes) -> tuple[float, float]:
    """CylinderPrimitive.pose (1) -> Pose.position (1) -> Vector3 x (1), y (2)."""
    pose = next(v for n, v in pb_fields(cylinder) if n == 1)
    pos = next(v for n, v in pb_fields(pose) if n == 1)
    xyz = dict(pb_fields(pos))
    return xyz.get(1, 0.0), xyz.get(2, 0.0)


# ---------------------------------------------------------------------------------------------
# A Foxglove WebSocket client
# ---------------------------------------------------------------------------------------------


Accept = Callable[[str, bytes], bool]
RESUBSCRIBE_S = 3.0
"""A subscribed topic without data this long is subscribed again (:func:`receive`)."""


async def receive(
    url: str,
    topics: list[str],
    timeout_s: float = 10.0,
    *,
    after_subscribe: Callable[[], object] | None = None,
    accept: Accept | None = None,
) -> dict[str, Any]:
    """Connect, wait until every topic is advertised, subscribe (then call ``after_subscribe``)
    and return the first message of each topic that ``accept(topic, data)`` takes:
    {topic: (channel advertisement, payload bytes)}.

    A topic still without data :data:`RESUBSCRIBE_S` after its subscription is subscribed again
    (a new subscription id, the channel as last advertised): a subscription sent the moment
    the last channel's advertisement arrived was once refused by the server as "unknown
    channel" (foxglove-sdk 0.30, logged by the server; the channel then worked), and the test
    waited 30 s for data that was never coming."""
    async with websockets.connect(url, subprotocols=[websockets.Subprotocol(SUBPROTOCOL)]) as ws:
        assert ws.subprotocol == SUBPROTOCOL
        channels: dict[str, dict[str, Any]] = {}
        got: dict[str, Any] = {}
        sub_topic: dict[int, str] = {}
        deadline = time.monotonic() + timeout_s
        subscribed_s: float | None = None

        async def subscribe(wanted: list[str]) -> None:
            first = len(sub_topic)
            subs = [{"id": first + n, "channelId": channels[t]["id"]} for n, t in enumerate(wanted)]
            sub_topic.update({first + n: t for n, t in enumerate(wanted)})
            await ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))

        while len(got) < len(topics):
            left = deadline - time.monotonic()
            assert left > 0, f"advertised {sorted(channels)}, received {sorted(got)}"
            if subscribed_s is not None and time.monotonic() - subscribed_s > RESUBSCRIBE_S:
                await subscribe([t for t in topics if t not in got])
                subscribed_s = time.monotonic()
            try:
                frame = await asyncio.wait_for(ws.recv(), timeout=min(left, 0.5))
            except TimeoutError:
                continue
            if isinstance(frame, str):
                msg = json.loads(frame)
                if msg["op"] == "advertise":
                    for ch in msg["channels"]:
                        channels[ch["topic"]] = ch
                if subscribed_s is None and all(t in channels for t in topics):
                    await subscribe(topics)
                    subscribed_s = time.monotonic()
                    if after_subscribe is not None:
                        after_subscribe()
            elif frame[0] == 1:  # MessageData: opcode, u32 subscription id, u64 log time, data
                _, sub_id, _log_ns = struct.unpack_from("<BIQ", frame)
                topic = sub_topic[sub_id]
                data = bytes(frame[13:])
                if topic not in got and (accept is None or accept(topic, data)):
                    got[topic] = (channels[topic], data)
        return got


@pytest.fixture
def live_server(
    session: Callable[..., zenoh.Session],
) -> Iterator[tuple[LiveServer, zenoh.Session]]:
    s = session()
    handle = start_live(s, FLEET, port=0, scene_hz=20.0)
    try:
        yield handle.live, s
    finally:
        handle.close()


def test_live_server_serves_bus_messages_and_the_scene_over_websocket(
    live_server: tuple[LiveServer, zenoh.Session], session: Callable[..., zenoh.Session]
) -> None:
    live, _ = live_server
    assert live.port > 0 and live.url == f"ws://127.0.0.1:{live.port}"
    pose_topic = f"/formation/{FLEET}/robot/r1/pose"
    err_topic = "/derived/robot/r2/tracking_error"
    with FleetPublisher(session()):
        got = asyncio.run(receive(live.url, [pose_topic, "/scene", err_topic, "/tf"]))
    ch, data = got[pose_topic]
    assert ch["encoding"] == "json" and ch["schemaName"] == "formation.Pose"
    assert ch["schemaEncoding"] == "jsonschema"
    assert json.loads(ch["schema"])["properties"]["theta"]["description"].startswith("heading")
    pose = json.loads(data)
    assert (pose["x"], pose["y"], pose["theta"]) == POSES["r1"]
    err = json.loads(got[err_topic][1])
    assert err["norm_m"] == pytest.approx(0.05) and err["slot"] == 1
    ch, data = got["/scene"]
    assert ch["schemaName"] == "foxglove.SceneUpdate" and ch["encoding"] == "protobuf"
    entities = scene_entities(data)
    assert {"robot/r1", "robot/r2", "slots", "links", "virtual_leader"} <= set(entities)
    cylinder = next(v for n, v in entities["robot/r1"] if n == 10)  # SceneEntity.cylinders
    x, y = position_of(cylinder)
    assert (x, y) == pytest.approx(POSES["r1"][:2])
    lines = [v for n, v in entities["links"] if n == 11]  # tree + one per robot
    assert len(lines) == 3
    assert got["/tf"][0]["schemaName"] == "foxglove.FrameTransforms"
    assert live.messages > 0 and live.rejected == 0


def _label(entity: list[tuple[int, Any]]) -> str:
    texts = [v for n, v in entity if n == 13]  # SceneEntity.texts
    return str(next(v for n, v in pb_fields(texts[0]) if n == 6).decode())  # TextPrimitive.text


def test_liveliness_is_a_channel_and_a_lost_robot_is_marked_in_the_scene(
    live_server: tuple[LiveServer, zenoh.Session], session: Callable[..., zenoh.Session]
) -> None:
    live, _ = live_server
    alive_topic = f"/formation/{FLEET}/alive/robot/r2"

    def lost(topic: str, data: bytes) -> bool:
        if topic == alive_topic:
            return json.loads(data)["alive"] is False
        r2 = scene_entities(data).get("robot/r2")
        return r2 is not None and "(lost)" in _label(r2)

    with FleetPublisher(session()) as fleet:
        # the first scene that shows r2 (one drawn before r2's first messages arrived lacks it:
        # next to a CPU hog the server can draw one before the publisher's first round)
        first = asyncio.run(
            receive(live.url, ["/scene"], accept=lambda _t, d: "robot/r2" in scene_entities(d))
        )
        assert "(lost)" not in _label(scene_entities(first["/scene"][1])["robot/r2"])
        got = asyncio.run(
            receive(
                live.url,
                [alive_topic, "/scene"],
                after_subscribe=fleet.tokens[1].undeclare,  # r2's agent goes away
                accept=lost,
            )
        )
    ch, data = got[alive_topic]
    assert ch["schemaName"] == "formation.Liveliness"
    assert json.loads(data) == {"alive": False, "kind": "robot", "id": "r2", "key": alive_topic[1:]}
    assert _label(scene_entities(got["/scene"][1])["robot/r2"]).startswith("r2  v2 follower")


def test_scene_model_draws_the_tree_and_tracking_lines() -> None:
    model = SceneModel(FLEET, ref_offset_m=0.05, body_radius_m=0.075)
    model.update(
        keys.slot_key(FLEET, 0),
        Slot(
            t=0.0,
            seq=0,
            slot=0,
            role="leader",
            stage=0,
            parent=None,
            x=1.0,
            y=0.0,
            theta=0.0,
            vx=0.0,
            vy=0.0,
        ),
    )
    model.update(
        keys.slot_key(FLEET, 1),
        Slot(
            t=0.0,
            seq=0,
            slot=1,
            role="follower",
            stage=1,
            parent=0,
            x=0.6,
            y=0.3,
            theta=0.0,
            vx=0.0,
            vy=0.0,
        ),
    )
    model.update(keys.pose_key(FLEET, "r1"), Pose(t=0.0, seq=0, x=0.9, y=0.0, theta=math.pi / 2))
    model.update(
        keys.assignment_key(FLEET), Assignment(t=0.0, seq=0, leader="r1", robots={"r1": 0})
    )
    assert model.ref_point("r1") == pytest.approx((0.9, 0.05))  # eqs 10-11
    entities = scene_entities(model.scene(1_700_000_000_123_456_789).encode())
    assert set(entities) == {"robot/r1", "slots", "links"}
    lines = [pb_fields(v) for n, v in entities["links"] if n == 11]
    points = [[position for n, position in line if n == 5] for line in lines]  # .points
    assert len(points) == 2 and all(len(p) == 2 for p in points)
    tree_end = dict(pb_fields(points[0][1]))
    assert (tree_end[1], tree_end[2]) == pytest.approx((0.6, 0.3))
    robot_to_slot = [dict(pb_fields(p)) for p in points[1]]
    assert (robot_to_slot[0][1], robot_to_slot[0][2]) == pytest.approx((0.9, 0.05))
    assert (robot_to_slot[1][1], robot_to_slot[1].get(2, 0.0)) == pytest.approx((1.0, 0.0))
    tf = model.transforms(0).encode()
    assert b"world" in tf and b"r1" in tf


# ---------------------------------------------------------------------------------------------
# The plan (issue 27): the planned leader path and the footprint corridor in the scene
# ---------------------------------------------------------------------------------------------

# SceneEntity fields: metadata 6, lines 11, triangles 12, texts 13; KeyValuePair key 1, value
# 2; LinePrimitive points 5; TriangleListPrimitive points 2, color 3, indices 5 (fixed32);
# Point3 x 1, y 2; Color a 4; SceneUpdate deletions 1 (SceneEntityDeletion id 3)


def _fixed32s(buf: bytes) -> list[int]:
    """A packed ``repeated fixed32`` field."""
    return list(struct.unpack(f"<{len(buf) // 4}I", buf))


def plan_of(scene: bytes) -> dict[str, Any] | None:
    """The ``plan`` entity of a SceneUpdate: revision, path points, triangle points and
    indices, corridor alpha, texts; None when the update has none."""
    fields = scene_entities(scene).get("plan")
    if fields is None:
        return None
    meta = {dict(pb_fields(v))[1].decode(): dict(pb_fields(v))[2].decode()
            for n, v in fields if n == 6}  # fmt: skip
    lines = [pb_fields(v) for n, v in fields if n == 11]
    (tri,) = [pb_fields(v) for n, v in fields if n == 12]

    def xy(points: list[bytes]) -> list[tuple[float, float]]:
        return [(dict(pb_fields(p)).get(1, 0.0), dict(pb_fields(p)).get(2, 0.0)) for p in points]

    return {
        "revision": int(meta["revision"]),
        "path": xy([v for n, v in lines[0] if n == 5]),
        "outlines": len(lines) - 1,
        "vertices": xy([v for n, v in tri if n == 2]),
        "indices": _fixed32s(next(v for n, v in tri if n == 5)),
        "alpha": dict(pb_fields(next(v for n, v in tri if n == 3))).get(4, 1.0),
        "texts": [dict(pb_fields(v))[6].decode() for n, v in fields if n == 13],
    }


def test_scene_model_shows_the_plan_and_replaces_it_when_it_changes() -> None:
    import scenario
    from formation.live.scene import PLAN_REPEAT_S
    from formation.outputs.plan_view import plan_mesh, plan_view

    scn = scenario.load("door")
    view = plan_view(scn.trajectory, timed=False)
    assert view is not None
    mesh = plan_mesh(view)
    model = SceneModel(FLEET, world=scn.agent.world)
    assert plan_of(model.scene(0).encode()) is None
    model.set_plan(mesh)
    t0 = 1_700_000_000 * 10**9
    got = plan_of(model.scene(t0).encode())
    assert got is not None and got["revision"] == 1 and got["texts"] == []
    assert np.allclose(got["path"], mesh.path)
    assert got["path"][-1] == pytest.approx((4.0, 0.0))  # the goal
    assert np.allclose(got["vertices"], mesh.vertices)
    assert got["indices"] == mesh.triangles.reshape(-1).tolist() and 0.0 < got["alpha"] < 0.5
    assert got["outlines"] == len(mesh.outlines) >= 1
    # the viewer keeps it: not sent again until PLAN_REPEAT_S has passed
    assert plan_of(model.scene(t0 + 100_000_000).encode()) is None
    assert plan_of(model.scene(t0 + int(PLAN_REPEAT_S * 1e9)).encode()) is not None
    # a replan: at once, revision 2, the new path, the replan labelled
    moved = plan_view(
        dict(scn.trajectory, goal=[4.0, 0.5]),
        [{"t_s": 5.0, "reason": "goal moved", "path": [[1.0, 0.0], [2.0, 0.4]]}],
        timed=False,
    )
    assert moved is not None
    model.set_plan(plan_mesh(moved))
    got = plan_of(model.scene(t0 + int(PLAN_REPEAT_S * 1e9) + 1).encode())
    assert got is not None and got["revision"] == 2 and got["texts"] == ["replan 1: goal moved"]
    assert got["path"][-1] == pytest.approx((4.0, 0.5))
    # the plan withdrawn: one deletion of the entity, then nothing
    model.set_plan(None)
    gone = pb_fields(model.scene(t0 + 3 * 10**9).encode())
    deletions = [dict(pb_fields(v))[3].decode() for n, v in gone if n == 1]
    assert deletions == ["plan"] and plan_of(model.scene(t0 + 4 * 10**9).encode()) is None
    assert [n for n, _ in pb_fields(model.scene(t0 + 5 * 10**9).encode()) if n == 1] == []


def test_live_server_shows_the_plan_and_refreshes_it_when_the_plan_changes(
    session: Callable[..., zenoh.Session],
) -> None:
    """A real WebSocket client sees the plan of the scenario the server was started with,
    then the new plan after :meth:`LiveServer.show_plan` (what a replan calls)."""
    import scenario

    scn = scenario.load("door")
    handle = start_live(session(), FLEET, port=0, scene_hz=20.0, trajectory=scn.trajectory)
    try:
        live = handle.live

        def revision(n: int) -> Accept:
            def accept(topic: str, data: bytes) -> bool:
                got = plan_of(data)
                return got is not None and got["revision"] == n

            return accept

        first = asyncio.run(receive(live.url, ["/scene"], accept=revision(1)))
        plan1 = plan_of(first["/scene"][1])
        assert plan1 is not None and plan1["path"][-1] == pytest.approx((4.0, 0.0))
        moved = dict(scn.trajectory, goal=[4.0, 0.5])
        second = asyncio.run(
            receive(
                live.url,
                ["/scene"],
                after_subscribe=lambda: live.show_plan(moved),
                accept=revision(2),
            )
        )
        plan2 = plan_of(second["/scene"][1])
        assert plan2 is not None and plan2["path"][-1] == pytest.approx((4.0, 0.5))
        live.show_plan({"kind": "line", "speed_mps": 0.02})  # not a plan: none shown
        assert live.model.plan is None
    finally:
        handle.close()


# ---------------------------------------------------------------------------------------------
# formation up --foxglove PORT: the launcher's live server, a real run, a real client
# ---------------------------------------------------------------------------------------------


@pytest.mark.zenoh
@pytest.mark.slow
@pytest.mark.alone
def test_up_foxglove_serves_a_running_fleet_over_websocket(spawn: Spawner, tmp_path: Path) -> None:
    """``formation up --lockstep --foxglove PORT``: a WebSocket client subscribes to bus
    channels, a derived channel and the 3D scene of the running fleet, then SIGINT ends it."""
    fleet, port, endpoint = "live1", free_port(), f"tcp/127.0.0.1:{free_port()}"
    up = spawn(
        "up", "--lockstep", "--scenario", "paper-exp1", "--duration", "600",
        "--endpoint", endpoint, "--fleet", fleet,
        "--out", str(tmp_path / "up"), "--no-figures", "--quiet", "--foxglove", str(port),
        ready="foxglove live view on ",
    )  # fmt: skip
    url = up.wait_for_line("foxglove live view on ").split()[-1]
    assert url == f"ws://127.0.0.1:{port}"
    pose, wheels = f"/formation/{fleet}/robot/r3/pose", f"/formation/{fleet}/robot/r1/wheels"
    status = f"/formation/{fleet}/robot/r2/status"

    def scene_with_robots(topic: str, data: bytes) -> bool:
        if topic != "/scene":
            return True
        return {"robot/r1", "robot/r2", "robot/r3"} <= set(scene_entities(data))

    got = asyncio.run(
        receive(url, [pose, wheels, status, "/scene", "/tf"], 30.0, accept=scene_with_robots)
    )
    ch, data = got[pose]
    assert ch["schemaName"] == "formation.Pose" and ch["schemaEncoding"] == "jsonschema"
    body = json.loads(data)
    assert body["v"] == 1 and all(math.isfinite(body[k]) for k in ("x", "y", "theta"))
    ch, data = got[wheels]
    assert ch["schemaName"] == "formation.Wheels"
    assert -1.0 <= json.loads(data)["power_r"] <= 1.0
    ch, data = got[status]
    assert ch["schemaName"] == "formation.Status"
    assert json.loads(data)["rejected"] == 0
    entities = scene_entities(got["/scene"][1])
    assert {"slots", "links", "virtual_leader"} <= set(entities)
    lines = [pb_fields(v) for n, v in entities["links"] if n == 11]
    assert len(lines) == 4  # the leader-follower tree (one line list) + one line per robot
    assert len([v for n, v in lines[0] if n == 5]) == 4  # triangle: 2 edges slot 0 -> 1, 2
    assert got["/tf"][0]["schemaName"] == "foxglove.FrameTransforms"

    # formation top, from another process on the same router: every robot, rates, rejects
    top = spawn("top", "--once", "--wait", "1.5", "--fleet", fleet, "--endpoint", endpoint)
    assert top.proc.wait(timeout=30) == 0, top.describe()
    text = top.stdout()
    assert re.search(
        r"^fleet live1, coordinator/main up \(active, epoch \d+\), "
        r"plant up \(running\), leader r\d",
        text,
        re.M,
    ), text
    for rid in ("r1", "r2", "r3"):
        row = re.search(
            rf"^{rid}\s+yes\s+\d\s+\w+\s+\w+\s+\S+\s+(\S+)\s+(?:\S+\s+){{4}}(\d+)", text, re.M
        )
        assert row, text
        assert float(row.group(1)) > 1.0 and int(row.group(2)) == 0, text  # pose Hz, rejected

    start = time.monotonic()
    up.send_signal(signal.SIGINT)
    up.proc.wait(timeout=10.0)
    elapsed = time.monotonic() - start
    assert up.proc.returncode == 130, up.describe()
    assert elapsed < 3.0, elapsed  # the bound of test_up's Ctrl-C test; measured ~0.5 s
    with pytest.raises(OSError):  # the server is gone with the launcher
        asyncio.run(receive(url, ["/scene"], 2.0))


def test_up_parses_record_and_foxglove_options(tmp_path: Path) -> None:
    from formation.launch import up

    parse = up.build_parser().parse_args
    cfg = up.config_from_args(parse(["--foxglove", "--record", str(tmp_path / "a.mcap")]))
    assert (cfg.foxglove_port, cfg.foxglove_host, cfg.record) == (
        8765,
        "127.0.0.1",
        tmp_path / "a.mcap",
    )
    cfg = up.config_from_args(parse(["--foxglove", "0", "--foxglove-host", "0.0.0.0"]))
    assert (cfg.foxglove_port, cfg.foxglove_host, cfg.record) == (0, "0.0.0.0", None)
    assert up.config_from_args(parse([])).foxglove_port is None
    assert up.main(["--foxglove", "70000"]) == 2  # before anything starts
