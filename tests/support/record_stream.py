"""A synthetic lockstep bus stream and the recorder fed with it (formation.record's tests and
the rosbag2 export's)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import msgpack

from bus_schemas import Assignment, Clock, Leader, Pose, Slot, Status, Truth, Wheels, encode, keys
from formation.record.command import Recorder
from runtime.tap import BusItem

FLEET = "demo"
DT = 0.02


def synthetic_stream(ticks: int = 100) -> list[BusItem]:
    """Two robots in lockstep: clock, truth, pose, slots, leader, setpoints, wheels, status,
    assignment, liveliness (r2 lost at the end), one malformed payload, one unknown key."""
    items: list[BusItem] = []
    rx = 1_000_000_000_000

    def put(key: str, msg: Any) -> None:
        nonlocal rx
        rx += 200_000  # 0.2 ms apart
        items.append(BusItem("put", key, encode(msg), rx))

    for name in ("robot/r1", "robot/r2", "plant"):
        rx += 1000
        items.append(BusItem("alive", f"formation/{FLEET}/alive/{name}", b"", rx))
    for k in range(ticks):
        t = k * DT
        for j, rid in enumerate(("r1", "r2")):
            x, y = 0.1 + 0.02 * t - 0.3 * j, 0.2 * j
            put(keys.truth_key(FLEET, rid), Truth(t=t, seq=k, x=x, y=y, theta=0.0))
            put(keys.pose_key(FLEET, rid), Pose(t=t, seq=k, x=x, y=y, theta=0.0, robot=rid))
        put(keys.clock_key(FLEET), Clock(t=t, seq=k, tick=k))
        for s in (0, 1):
            put(
                keys.slot_key(FLEET, s),
                Slot(
                    t=t,
                    seq=k,
                    slot=s,
                    role="leader" if s == 0 else "follower",
                    stage=s,
                    parent=None if s == 0 else 0,
                    x=0.15 + 0.02 * t - 0.3 * s,
                    y=0.2 * s,
                    theta=0.0,
                    vx=0.02,
                    vy=0.0,
                ),
            )
        if k % 25 == 0:
            put(
                keys.assignment_key(FLEET),
                Assignment(t=t, seq=k, leader="r1", robots={"r1": 0, "r2": 1}),
            )
        put(
            keys.leader_key(FLEET),
            Leader(t=t, seq=k, x=0.15 + 0.02 * t, y=0.0, theta=0.0, v_mps=0.02, omega_radps=0.0),
        )
        for rid in ("r1", "r2"):
            put(
                keys.wheels_key(FLEET, rid),
                Wheels(
                    t=t,
                    seq=k,
                    omega_r=1.0,
                    omega_l=0.5,
                    power_r=0.1 + k / 1000,
                    power_l=0.05,
                    pose_t=t,
                    tick=k,
                ),
            )
            if k % 10 == 0:
                put(
                    keys.status_key(FLEET, rid),
                    Status(
                        t=t,
                        seq=k // 10,
                        mode="tracking",
                        slot=0 if rid == "r1" else 1,
                        pid=1,
                        host="h",
                        rejected=0,
                        ex=0.03,
                        ey=0.04,
                    ),
                )
    rx += 1000
    items.append(BusItem("put", keys.pose_key(FLEET, "r1"), b"\xc1", rx))  # malformed
    rx += 1000
    items.append(
        BusItem("put", f"formation/{FLEET}/lidar/c1/status", msgpack.packb({"v": 1, "t": 2.0}), rx)
    )
    rx += 1000
    items.append(BusItem("dead", f"formation/{FLEET}/alive/robot/r2", b"", rx))
    return items


def record_items(path: Path, items: list[BusItem], **kwargs: Any) -> Recorder:
    rec = Recorder(path, FLEET, **kwargs)
    for item in items:
        rec.write(item)
    rec.close()
    return rec
