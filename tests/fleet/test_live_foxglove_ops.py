"""The operator's commands from Foxglove (issue 28, formation/live/foxglove_ops.py): a WebSocket
client's publishes (what Foxglove's Teleop panel sends) drive a real ``formation coordinator``'s
virtual leader through the live server; hostile publishes are refused and counted; a server
without an operator session refuses every command."""

from __future__ import annotations

import asyncio
import json
import math
import time
from collections.abc import Callable

import pytest
import zenoh
from support.bus_watch import Recorder, decoder_of
from support.foxglove_fleet import publish_twists
from support.routers import RouterHandle
from support.spawn import Spawner

import runtime as rt
from bus_schemas import CmdVel, Estop, Goal, Leader, Pose, encode, keys
from formation.live.foxglove import start_live
from formation.live.foxglove_ops import translate
from scenario import load

pytestmark = [pytest.mark.zenoh, pytest.mark.shares_cpu]

FLEET = "demo"
START = dict(zip(load("paper-exp2").robot_ids, load("paper-exp2").initial, strict=True))


# -- translate: pure ------------------------------------------------------------------------


def test_a_twist_a_goal_and_an_estop_are_translated() -> None:
    twist = json.dumps({"linear": {"x": 0.05, "y": 0, "z": 0}, "angular": {"z": -0.2}})
    key, msg = translate("/cmd_vel", twist.encode(), FLEET, 3.0, 7)
    assert key == keys.cmd_vel_key(FLEET)
    assert msg == CmdVel(t=3.0, seq=7, v_mps=0.05, omega_radps=-0.2)
    q = {"x": 0.0, "y": 0.0, "z": math.sin(0.25), "w": math.cos(0.25)}  # yaw 0.5 rad
    pose = {"pose": {"position": {"x": 1.0, "y": -0.5, "z": 0.0}, "orientation": q}}
    key, goal = translate("/goal", json.dumps(pose).encode(), FLEET, 3.0, 8)
    assert key == keys.goal_key(FLEET) and isinstance(goal, Goal)
    assert (goal.x, goal.y) == (1.0, -0.5) and goal.heading == pytest.approx(0.5)
    _, plain = translate("/operator/goal", b'{"x": 1, "y": 2}', FLEET, 3.0, 9)
    assert isinstance(plain, Goal) and plain.heading is None
    key, stop = translate("/estop", b'{"data": true}', FLEET, 3.0, 10)
    assert key == keys.estop_key(FLEET) and isinstance(stop, Estop)
    assert stop.engage and stop.robot is None and stop.id is not None
    _, release = translate("/estop", b'{"data": false}', FLEET, 3.0, 11)
    assert isinstance(release, Estop) and not release.engage and release.id is None


@pytest.mark.parametrize(
    ("topic", "data"),
    [
        ("/cmd_vel", b'{"linear": {"x": NaN}, "angular": {"z": 0}}'),
        ("/cmd_vel", b'{"linear": {"x": Infinity}, "angular": {"z": 0}}'),
        ("/cmd_vel", b'{"linear": {"x": "fast"}, "angular": {"z": 0}}'),
        ("/cmd_vel", b'{"angular": {"z": 0}}'),
        ("/cmd_vel", b"\xff\xfe not json"),
        ("/goal", b'{"x": 1}'),
        ("/goal", b'{"x": 1, "y": true}'),
        ("/estop", b'{"data": 1}'),
        ("/somewhere/else", b"{}"),
        ("/cmd_vel", b"[" * 70_000),
    ],
)
def test_hostile_publishes_are_refused(topic: str, data: bytes) -> None:
    with pytest.raises(ValueError):
        translate(topic, data, FLEET, 1.0, 1)


# -- a WebSocket client drives a real coordinator ---------------------------------------------


@pytest.fixture
def client(session: Callable[..., zenoh.Session]) -> zenoh.Session:
    return session()


def _feed_poses(pubs: rt.Publishers, k: int) -> None:
    for rid, (x, y, th) in START.items():
        msg = Pose(t=time.monotonic(), seq=k, x=x, y=y, theta=th, robot=rid)
        pubs.put(keys.pose_key(FLEET, rid), encode(msg), rt.QOS_CRITICAL)


def test_a_teleop_panel_drives_the_leader_through_the_live_server(
    spawn: Spawner, router: RouterHandle, client: zenoh.Session
) -> None:
    tokens = [rt.declare_token(client, keys.alive_robot_key(FLEET, r)) for r in START]
    leaders = Recorder(client, keys.leader_key(FLEET), decoder_of(Leader))
    spawn(
        "coordinator", "--scenario", "paper-exp2", "--endpoint", router.endpoint,
        ready="coordinator ready",
    )  # fmt: skip
    live = start_live(client, FLEET, port=0, commands=client)
    mute = start_live(client, FLEET, port=0)  # no operator session: commands refused
    pubs = rt.Publishers(client)
    try:
        _feed_poses(pubs, 1)
        leaders.wait_for(lambda *_: True)
        twist = {"linear": {"x": 0.06, "y": 0.0, "z": 0.0}, "angular": {"x": 0, "y": 0, "z": 0.1}}
        asyncio.run(publish_twists(mute.url, twist, 0.5, "/cmd_vel"))
        hostile = {"linear": {"x": "NaN"}, "angular": {"z": 0}}
        asyncio.run(publish_twists(live.url, hostile, 0.3, "/cmd_vel"))
        t_pub = time.monotonic()
        asyncio.run(publish_twists(live.url, twist, 2.0, "/cmd_vel"))
        _, _, driven = leaders.wait_for(
            lambda r, _k, m: r > t_pub and m.mode == "teleop" and m.v_mps > 0.05, timeout_s=5.0
        )
    finally:
        live.close()
        mute.close()
    assert driven.omega_radps > 0.0
    assert live.live.operator.accepted >= 20
    assert live.live.operator.rejects.get("linear.x_is_not_a_finite_number", 0) >= 3, (
        live.live.operator.rejects
    )
    assert mute.live.operator.accepted == 0
    assert mute.live.operator.rejects.get("no_operator_session", 0) >= 5
    # before the live server's twists nobody drove the leader: the mute server sent nothing
    assert all(m.mode in (None, "script") for r, _, m in leaders.snapshot() if r < t_pub)
    del tokens
