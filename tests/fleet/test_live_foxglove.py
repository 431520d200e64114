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

import pytest
import websockets
import zenoh
from support.foxglove_fleet import FLEET, POSES, FleetPublisher, pb_fields, scene_entities
from support.spawn import Spawner, free_port

from bus_schemas import Assignment, Pose, Slot, keys
from formation.live.foxglove import SUBPROTOCOL, LiveServer, SceneModel, start_live

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
        first = asyncio.run(receive(live.url, ["/scene"]))
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
# formation up --foxglove PORT: the launcher's live server, a real run, a real client
# ---------------------------------------------------------------------------------------------


@pytest.mark.zenoh
@pytest.mark.slow
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
