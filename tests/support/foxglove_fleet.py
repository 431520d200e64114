"""A fleet's traffic for the Foxglove live view (:class:`FleetPublisher` on fleet :data:`FLEET`),
the reading of the protobuf frames it serves (:func:`pb_fields`, :func:`scene_entities`) and a
WebSocket client's publishes, as Foxglove's Teleop panel sends them (:func:`publish_twists`)."""

from __future__ import annotations

import asyncio
import contextlib
import json
import struct
import threading
import time
from typing import Any

import websockets
import zenoh

import runtime as rt
from bus_schemas import Assignment, Leader, Pose, Slot, Status, Truth, encode, keys
from formation.live.foxglove import SUBPROTOCOL

FLEET = "demo"

POSES = {"r1": (0.40, 0.02, 0.05), "r2": (0.10, 0.22, -0.05)}


class FleetPublisher:
    """Publishes a two-robot fleet at ``rate_hz`` from a thread until stopped."""

    def __init__(self, session: zenoh.Session, rate_hz: float = 20.0) -> None:
        self.session = session
        self.period_s = 1.0 / rate_hz
        self.stop_event = threading.Event()
        self.tokens = [
            rt.declare_token(session, keys.alive_robot_key(FLEET, rid)) for rid in POSES
        ] + [rt.declare_token(session, keys.alive_plant_key(FLEET))]
        self.thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        k = 0
        while not self.stop_event.is_set():
            t = 10.0 + k * self.period_s
            put = self.session.put
            for rid, (x, y, th) in POSES.items():
                put(keys.pose_key(FLEET, rid), encode(Pose(t=t, seq=k, x=x, y=y, theta=th)))
                put(keys.truth_key(FLEET, rid), encode(Truth(t=t, seq=k, x=x, y=y, theta=th)))
                slot = 0 if rid == "r1" else 1
                put(
                    keys.status_key(FLEET, rid),
                    encode(
                        Status(
                            t=t,
                            seq=k,
                            mode="tracking",
                            slot=slot,
                            pid=1,
                            host="h",
                            rejected=k % 3,
                            ex=0.03,
                            ey=-0.04,
                        )
                    ),
                )
            for s, (sx, sy) in enumerate(((0.45, 0.0), (0.10, 0.20))):
                put(
                    keys.slot_key(FLEET, s),
                    encode(
                        Slot(
                            t=t,
                            seq=k,
                            slot=s,
                            role="leader" if s == 0 else "follower",
                            stage=s,
                            parent=None if s == 0 else 0,
                            x=sx,
                            y=sy,
                            theta=0.0,
                            vx=0.02,
                            vy=0.0,
                        )
                    ),
                )
            put(
                keys.leader_key(FLEET),
                encode(Leader(t=t, seq=k, x=0.4, y=0.0, theta=0.0, v_mps=0.02, omega_radps=0.0)),
            )
            put(
                keys.assignment_key(FLEET),
                encode(Assignment(t=t, seq=k, leader="r1", robots={"r1": 0, "r2": 1})),
            )
            k += 1
            self.stop_event.wait(self.period_s)

    def __enter__(self) -> FleetPublisher:
        self.thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop_event.set()
        self.thread.join(timeout=2.0)
        for token in self.tokens:
            with contextlib.suppress(zenoh.ZError):  # a test undeclared it already
                token.undeclare()


def _varint(buf: bytes, i: int) -> tuple[int, int]:
    shift = value = 0
    while True:
        b = buf[i]
        i += 1
        value |= (b & 0x7F) << shift
        shift += 7
        if not b & 0x80:
            return value, i


def pb_fields(buf: bytes) -> list[tuple[int, Any]]:
    """(field number, value) pairs: ints for varints, bytes for length-delimited, floats for
    fixed64 (doubles)."""
    out: list[tuple[int, Any]] = []
    i = 0
    while i < len(buf):
        tag, i = _varint(buf, i)
        num, wire = tag >> 3, tag & 7
        if wire == 0:
            v, i = _varint(buf, i)
            out.append((num, v))
        elif wire == 1:
            out.append((num, struct.unpack_from("<d", buf, i)[0]))
            i += 8
        elif wire == 2:
            n, i = _varint(buf, i)
            out.append((num, buf[i : i + n]))
            i += n
        elif wire == 5:
            out.append((num, struct.unpack_from("<f", buf, i)[0]))
            i += 4
        else:
            raise AssertionError(f"unexpected wire type {wire}")
    return out


def scene_entities(buf: bytes) -> dict[str, list[tuple[int, Any]]]:
    """SceneUpdate (entities = field 2) -> {entity id (field 3): its fields}."""
    out: dict[str, list[tuple[int, Any]]] = {}
    for num, value in pb_fields(buf):
        if num == 2:
            fields = pb_fields(value)
            ident = next(v for n, v in fields if n == 3).decode()
            out[ident] = fields
    return out


async def publish_twists(url: str, twist: dict[str, Any], duration_s: float, topic: str) -> None:
    """Connect, advertise ``topic`` (JSON, geometry_msgs/Twist) and publish ``twist`` at 20 Hz
    for ``duration_s`` (what Foxglove's Teleop panel does while a button is held)."""
    async with websockets.connect(url, subprotocols=[websockets.Subprotocol(SUBPROTOCOL)]) as ws:
        channel = {"id": 1, "topic": topic, "encoding": "json", "schemaName": "geometry_msgs/Twist"}
        await ws.send(json.dumps({"op": "advertise", "channels": [channel]}))
        payload = json.dumps(twist).encode()
        end = time.monotonic() + duration_s
        while time.monotonic() < end:
            await ws.send(struct.pack("<BI", 1, 1) + payload)  # ClientMessageData
            await asyncio.sleep(0.05)
