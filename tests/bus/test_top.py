"""formation top: the fleet status table, as a pure model and as a command on a real router."""

from __future__ import annotations

import contextlib
import dataclasses
import re
import threading
import time
from collections.abc import Callable, Iterator

import msgpack
import pytest
import zenoh
from support.foxglove_fleet import FLEET, FleetPublisher
from support.routers import RouterHandle
from support.spawn import Spawner

from bus_schemas import (
    Assignment,
    CameraStatus,
    CoordinatorStatus,
    Message,
    PlantStatus,
    Pose,
    Slot,
    Status,
    encode,
    keys,
)
from formation.live.top import FleetStatus
from formation.live.top import main as top_main
from runtime.tap import BusItem, BusTap

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


def camera_status(k: int) -> CameraStatus:
    """The ``k``-th status of a camera ``cam1`` tracking r1 and r2: 15 frames and 15 detections
    of each robot per status, 0.5 s apart on the camera's clock (60 detections/s exactly)."""
    return CameraStatus(
        t=100.0 + 0.5 * k, seq=k, state="running", detector="apriltag", source="rendered",
        frames=15 * k, dropped=2, fps=29.5, detect_p50_ms=3.25, detect_p99_ms=7.5,
        detect_max_ms=9.0, latency_p50_ms=12.0, latency_p99_ms=21.0, latency_max_ms=30.0,
        detections={"r1": 15 * k, "r2": 15 * k}, published={"r1": 15 * k, "r2": 15 * k},
        misses={"r1": 1, "r2": 0}, rejects={"jump": 3, "bad_size": 1, "unknown": 0},
        reacquired=0, internal_errors=0, truth_rejected=2,
    )  # fmt: skip


CAMERA_LINE = re.compile(
    r"^cam1\s+running\s+29\.5\s+60\.0\s+2\s+3\.2/7\.5\s+12\.0/21\.0\s+4\s+1\s+\d+\.\d"
    r"\s+apriltag, rendered; rejects bad_size 1, jump 3; 2 truth rejected$",
    re.M,
)


@contextlib.contextmanager
def publishing_camera(session: zenoh.Session, rate_hz: float = 20.0) -> Iterator[None]:
    """Publishes :func:`camera_status` ``k`` = 1, 2, ... at ``rate_hz`` from a thread."""
    stop = threading.Event()

    def run() -> None:
        key = keys.camera_status_key(FLEET, "cam1")
        k = 1
        while not stop.wait(1.0 / rate_hz):
            session.put(key, encode(camera_status(k)))
            k += 1

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    try:
        yield
    finally:
        stop.set()
        thread.join(timeout=5.0)


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
    late = dataclasses.replace(PLANT_STATUS, seq=2, mode="lockstep", timeouts=3)  # went on
    fs.observe(put(keys.plant_status_key(FLEET), late, now))
    assert "plant up (running, 3 lockstep timeouts)" in fs.header()
    text = fs.render(now)
    assert "1 rejected here" in text
    assert re.search(r"^r10\s+LOST", text, re.M)
    assert re.search(r"^r1\s+yes\s+0 leader\s+tracking\s+5\.0\s+30\.0", text, re.M), text


def test_fleet_status_camera_rows() -> None:
    """A camera's line: the counters of its last status, detections/s from its last two."""
    fs = FleetStatus(FLEET)
    key = keys.camera_status_key(FLEET, "cam1")
    fs.observe(put(key, camera_status(4), 10 * S))
    (first,) = fs.camera_rows(10 * S)
    assert first.detections_hz is None  # one status: no rate yet
    fs.observe(put(key, camera_status(5), 11 * S))
    fs.observe(BusItem("put", keys.camera_status_key(FLEET, "cam2"), b"\xc1", 11 * S))
    (row,) = fs.camera_rows(12 * S)
    assert (row.name, row.state, row.fps, row.dropped) == ("cam1", "running", 29.5, 2)
    assert row.detections_hz == pytest.approx(60.0)
    assert (row.detect_ms, row.latency_ms) == ((3.25, 7.5), (12.0, 21.0))
    assert (row.rejected, row.rejects, row.misses) == (4, {"bad_size": 1, "jump": 3}, 1)
    assert (row.truth_rejected, row.internal_errors, row.age_s) == (2, 0, 1.0)
    text = fs.render(12 * S)
    assert CAMERA_LINE.search(text), text
    assert "1 rejected here" in text  # cam2's undecodable status
    # a restarted camera (counts back to the start): no rate until its next status
    fs.observe(put(key, camera_status(1), 13 * S))
    assert fs.camera_rows(13 * S)[0].detections_hz is None
    empty = dataclasses.replace(camera_status(6), detect_p50_ms=None)  # before its first frame
    fs.observe(put(key, empty, 14 * S))
    assert " -/7.5 " in fs.render(14 * S)


def test_fleet_status_reads_a_camera_on_a_real_session(
    session: Callable[..., zenoh.Session],
) -> None:
    """The camera's status through Zenoh (loopback router) into the table, via the bus tap."""
    fs = FleetStatus(FLEET)
    tap = BusTap(session(), FLEET, fs.observe, name="top-test")
    try:
        with publishing_camera(session(), rate_hz=20.0):
            deadline = time.monotonic() + 20.0
            while time.monotonic() < deadline:
                rows = fs.camera_rows(time.monotonic_ns())
                if rows and rows[0].detections_hz is not None:
                    break
                time.sleep(0.05)
    finally:
        tap.close()
    (row,) = fs.camera_rows(time.monotonic_ns())
    assert row.name == "cam1" and row.detections_hz == pytest.approx(60.0), row
    assert CAMERA_LINE.search(fs.render(time.monotonic_ns())), fs.render(time.monotonic_ns())


def test_top_once_shows_the_robots_of_a_live_fleet(
    spawn: Spawner, router: RouterHandle, session: Callable[..., zenoh.Session]
) -> None:
    with FleetPublisher(session(), rate_hz=20.0), publishing_camera(session(), rate_hz=20.0):
        child = spawn("top", "--once", "--wait", "1.5", "--endpoint", router.endpoint)
        assert child.proc.wait(timeout=20) == 0, child.describe()
    out = child.stdout()
    assert "fleet demo" in out and "plant up" in out and "leader r1" in out
    assert re.search(r"^cam1\s+running\s+29\.5\s", out, re.M), out  # the camera's line
    row1 = re.search(r"^r1\s+yes\s+0 leader\s+tracking\s+5\.0\s+(\S+)", out, re.M)
    row2 = re.search(r"^r2\s+yes\s+1 follower\s+tracking\s+5\.0\s+(\S+)", out, re.M)
    assert row1 and row2, out
    # ~20 Hz poses, measured over the 1.5 s listened (a loaded CI box may publish slower)
    assert 10.0 <= float(row1.group(1)) <= 25.0, out


def test_top_rejects_bad_arguments() -> None:
    assert top_main(["--fleet", "no/slash"]) == 2
    assert top_main(["--once", "--wait", "0"]) == 2
