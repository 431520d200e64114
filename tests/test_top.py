"""formation top: the fleet status table, as a pure model and as a command on a real router."""

from __future__ import annotations

import re
from collections.abc import Callable

import msgpack
import pytest
import zenoh
from conftest import RouterHandle, Spawner
from test_live_foxglove import FLEET, FleetPublisher

from bus_schemas import (
    Assignment,
    CoordinatorStatus,
    Message,
    PlantStatus,
    Pose,
    Slot,
    Status,
    encode,
    keys,
)
from formation.top import FleetStatus
from formation.top import main as top_main
from runtime.tap import BusItem

S = 1_000_000_000  # ns


PLANT_STATUS = PlantStatus(
    t=2.0, seq=1, mode="realtime", state="running", tick=0, sim_t=2.0, timeouts=0, alive=("r1",),
    coordinators=("main",), link_sent=0, link_dropped=0, min_separation_m=None, collisions=0,
    frames=60, batch=False, ignored=0, rejected=0, rejects={}, internal_errors=0, rx={},
)  # fmt: skip
COORDINATOR_STATUS = CoordinatorStatus(
    t=2.0, seq=1, name="main", mode="realtime", role="active", epoch=2, takeovers=0, stepdowns=0,
    ticks=100, alive=("r1",), assignment={"r1": 0}, leader="r1", estop_fleet=False,
    estop_robots=(), rejected=0, rejects={}, internal_errors=0, rx={}, pid=1, host="h",
)  # fmt: skip


def put(key: str, msg: Message, rx_ns: int) -> BusItem:
    return BusItem("put", key, encode(msg), rx_ns)


def test_fleet_status_rates_roles_errors_and_liveliness() -> None:
    fs = FleetStatus(FLEET, window_s=2.0)
    t0 = 100 * S
    fs.observe(BusItem("alive", keys.alive_robot_key(FLEET, "r1"), b"", t0))
    fs.observe(BusItem("alive", keys.alive_robot_key(FLEET, "r10"), b"", t0))
    fs.observe(BusItem("alive", keys.alive_plant_key(FLEET), b"", t0))
    fs.observe(BusItem("alive", keys.alive_coordinator_key(FLEET, "main"), b"", t0))
    fs.observe(
        put(
            keys.slot_key(FLEET, 0),
            Slot(
                t=1.0,
                seq=0,
                slot=0,
                role="leader",
                stage=0,
                parent=None,
                x=0.0,
                y=0.0,
                theta=0.0,
                vx=0.0,
                vy=0.0,
            ),
            t0,
        )
    )
    fs.observe(
        put(keys.assignment_key(FLEET), Assignment(t=1.0, seq=0, leader="r1", robots={"r1": 0}), t0)
    )
    for k in range(60):  # r1: poses at 30 Hz for 2 s
        fs.observe(
            put(
                keys.pose_key(FLEET, "r1"),
                Pose(t=k / 30, seq=k, x=0.0, y=0.0, theta=0.0),
                t0 + k * S // 30,
            )
        )
    now = t0 + 2 * S
    fs.observe(
        put(
            keys.status_key(FLEET, "r1"),
            Status(
                t=2.0, seq=0, mode="tracking", slot=0, pid=1, host="h", rejected=7, ex=0.03, ey=0.04
            ),
            now,
        )
    )
    fs.observe(BusItem("put", keys.pose_key(FLEET, "r10"), b"\xc1", now))  # rate counts, bad
    fs.observe(BusItem("put", keys.status_key(FLEET, "r10"), msgpack.packb([1]), now))
    fs.observe(BusItem("dead", keys.alive_robot_key(FLEET, "r10"), b"", now))
    r1, r10 = fs.rows(now)
    assert [r1.robot, r10.robot] == ["r1", "r10"]  # natural order
    assert (r1.alive, r1.slot, r1.role, r1.mode, r1.rejected) == (True, 0, "leader", "tracking", 7)
    assert r1.error_m == pytest.approx(0.05)
    assert r1.rates_hz[keys.POSE] == pytest.approx(30.0, abs=0.6)
    assert r1.rates_hz[keys.WHEELS] == 0.0 and r1.age_s == 0.0
    assert (r10.alive, r10.mode, r10.slot) == (False, None, None)
    assert fs.rows(now + 3 * S)[0].rates_hz[keys.POSE] == 0.0  # all older than the window
    text = fs.render(now)
    assert "coordinator/main up, plant up, leader r1" in text
    # the coordinator's and the plant's status (contract messages) add a word each
    fs.observe(put(keys.plant_status_key(FLEET), PLANT_STATUS, now))
    fs.observe(put(keys.coordinator_status_key(FLEET, "main"), COORDINATOR_STATUS, now))
    assert "coordinator/main up (active, epoch 2), plant up (running), leader r1" in fs.header()
    text = fs.render(now)
    assert "1 rejected here" in text
    assert re.search(r"^r10\s+LOST", text, re.M)
    assert re.search(r"^r1\s+yes\s+0 leader\s+tracking\s+5\.0\s+30\.0", text, re.M), text


def test_top_once_shows_the_robots_of_a_live_fleet(
    spawn: Spawner, router: RouterHandle, session: Callable[..., zenoh.Session]
) -> None:
    with FleetPublisher(session(), rate_hz=20.0):
        child = spawn("top", "--once", "--wait", "1.5", "--endpoint", router.endpoint)
        assert child.proc.wait(timeout=20) == 0, child.describe()
    out = child.stdout()
    assert "fleet demo" in out and "plant up" in out and "leader r1" in out
    row1 = re.search(r"^r1\s+yes\s+0 leader\s+tracking\s+5\.0\s+(\S+)", out, re.M)
    row2 = re.search(r"^r2\s+yes\s+1 follower\s+tracking\s+5\.0\s+(\S+)", out, re.M)
    assert row1 and row2, out
    # ~20 Hz poses, measured over the 1.5 s listened (a loaded CI box may publish slower)
    assert 10.0 <= float(row1.group(1)) <= 25.0, out


def test_top_rejects_bad_arguments() -> None:
    assert top_main(["--fleet", "no/slash"]) == 2
    assert top_main(["--once", "--wait", "0"]) == 2
