"""``formation coordinator`` as a real process (issue 30): a camera-tracked body that is not a
fleet robot (a tag id outside the scenario's fleet, no liveliness token) moving across the
formation is a mover: the coordinator publishes it on ``formation/<fleet>/movers`` with its
velocity, for the robots' filters, and never assigns it a slot."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

import pytest
import zenoh
from support.bus_watch import Recorder, decoder_of
from support.routers import RouterHandle
from support.spawn import Spawner

import runtime as rt
from bus_schemas import Assignment, Movers, Pose, encode, keys
from scenario import load

FLEET = "demo"
SCENARIO = load("paper-exp2")
START = dict(zip(SCENARIO.robot_ids, SCENARIO.initial, strict=True))
TAG = "tag9"
TAG_SPEED_MPS = 0.2


@pytest.fixture
def client(session: Callable[..., zenoh.Session]) -> zenoh.Session:
    return session()


@pytest.mark.zenoh
def test_a_tracked_tag_outside_the_fleet_is_published_as_a_mover(
    spawn: Spawner, router: RouterHandle, client: zenoh.Session
) -> None:
    pubs = rt.Publishers(client)
    tokens = {r: rt.declare_token(client, keys.alive_robot_key(FLEET, r)) for r in START}
    movers = Recorder(client, keys.movers_key(FLEET), decoder_of(Movers))
    assignments = Recorder(client, keys.assignment_key(FLEET), decoder_of(Assignment))
    spawn("coordinator", "--scenario", "paper-exp2", "--endpoint", router.endpoint, ready="coord")
    stop = threading.Event()

    def feed() -> None:  # the fleet standing, the tag carried along y = 1 m (far from them)
        t0 = time.monotonic()
        seq = 0
        while not stop.is_set():
            seq += 1
            now = time.monotonic()
            for rid, (x, y, th) in START.items():
                msg = Pose(t=now, seq=seq, x=x, y=y, theta=th, robot=rid)
                pubs.put(keys.pose_key(FLEET, rid), encode(msg), rt.QOS_CRITICAL)
            tag = Pose(t=now, seq=seq, x=-1.0 + TAG_SPEED_MPS * (now - t0), y=1.0, theta=0.0)
            pubs.put(keys.pose_key(FLEET, TAG), encode(tag), rt.QOS_CRITICAL)
            stop.wait(0.02)

    thread = threading.Thread(target=feed, daemon=True)
    thread.start()
    try:
        _, _, m = movers.wait_for(lambda _r, _k, msg: TAG in msg.robots, timeout_s=20.0)
        i = m.robots.index(TAG)
        assert m.vx[i] == pytest.approx(TAG_SPEED_MPS, abs=0.05)
        assert m.vy[i] == pytest.approx(0.0, abs=0.05)
        assert m.y[i] == pytest.approx(1.0, abs=1e-9)
        assert all(TAG not in a.robots for _, _, a in assignments.snapshot())
    finally:
        stop.set()
        thread.join(2.0)
        for tok in tokens.values():
            tok.undeclare()
