"""One valid instance of every bus message type (every optional field set where there is one),
and the small helpers the contract tests share (wire maps, packing, asserting a rejection)."""

from __future__ import annotations

from typing import Any

import msgpack
from hypothesis import strategies as st

from bus_schemas import (
    MESSAGE_TYPES,
    Assignment,
    CameraStatus,
    Clock,
    CoordinatorStatus,
    DecodeError,
    Disturbance,
    Estop,
    Fault,
    Heartbeat,
    Leader,
    PlantStatus,
    Pose,
    PoseBatch,
    Setpoint,
    SetpointBatch,
    Slot,
    Status,
    StatusBatch,
    Truth,
    TruthBatch,
    Wheels,
    WheelsBatch,
    decode,
    encode,
    spec_of,
)

# One valid instance of every type, with every optional field set where there is one.
SAMPLES: dict[type, Any] = {
    Leader: Leader(t=1.0, seq=1, x=0.5, y=-0.25, theta=0.1, v_mps=0.1, omega_radps=0.02),
    Slot: Slot(
        t=1.0,
        seq=2,
        slot=1,
        role="subleader",
        stage=1,
        parent=0,
        x=0.1,
        y=0.2,
        theta=0.3,
        vx=0.01,
        vy=-0.02,
    ),
    Setpoint: Setpoint(
        t=1.0,
        seq=3,
        robot="r2",
        slot=2,
        role="follower",
        stage=1,
        parent=0,
        x=0.1,
        y=0.2,
        theta=-0.3,
        vx=0.0,
        vy=0.0,
    ),
    Assignment: Assignment(t=1.0, seq=4, leader="r1", robots={"r1": 0, "r2": 1, "r3": 2}),
    Pose: Pose(t=1.0, seq=5, x=0.1, y=0.2, theta=3.0, robot="r1", pub_t=1.03),
    Truth: Truth(t=1.0, seq=6, x=0.1, y=0.2, theta=-3.0, robot="r1"),
    Wheels: Wheels(
        t=1.0,
        seq=7,
        omega_r=5.0,
        omega_l=-5.0,
        power_r=0.5,
        power_l=-0.5,
        pose_t=0.98,
        tick=99,
        saturated=False,
        mode="tracking",
    ),
    Status: Status(
        t=1.0,
        seq=8,
        mode="tracking",
        slot=1,
        pid=1234,
        host="pi-1",
        rejected=0,
        ex=0.01,
        ey=-0.02,
        role="follower",
        rx={"pose": 10, "setpoint": 9},
        robot="r2",
        filter={"ticks": 10, "active": 2},
        min_clearance_m=0.05,
    ),
    Estop: Estop(t=1.0, engage=True, robot="r3", id=2**62 + 12345),
    Clock: Clock(
        t=1.0,
        seq=9,
        tick=100,
        tracking=("r1", "r2"),
        enc_robots=("r1", "r2"),
        enc_wr=(1.5, -0.25),
        enc_wl=(1.0, 0.0),
    ),
    Fault: Fault(
        t=1.0,
        tick=50,
        request=False,
        fault=2,
        kind="pause",
        robot="r2",
        duration_s=1.5,
        undo=False,
    ),
    Disturbance: Disturbance(
        t=1.0,
        robot="r1",
        kind="teleport",
        dx=0.0,
        dy=0.0,
        duration_s=0.0,
        x=1.0,
        y=2.0,
        theta=0.5,
    ),
    Heartbeat: Heartbeat(t=1.0, seq=10, name="primary", active=True, epoch=3, leader_t0=0.5),
    PoseBatch: PoseBatch(
        t=1.0,
        seq=11,
        robots=("r1", "r2"),
        x=(0.1, 0.2),
        y=(0.3, 0.4),
        theta=(0.0, -1.0),
        stamp=0.99,
    ),
    TruthBatch: TruthBatch(
        t=1.0, seq=12, robots=("r1", "r2"), x=(0.1, 0.2), y=(0.3, 0.4), theta=(0.0, 1.0), stamp=1.0
    ),
    SetpointBatch: SetpointBatch(
        t=1.0,
        seq=13,
        robots=("r1", "r2"),
        slot=(0, 1),
        role=("leader", "follower"),
        stage=(0, 1),
        x=(0.1, 0.2),
        y=(0.3, 0.4),
        theta=0.5,
        vx=(0.1, 0.1),
        vy=(0.0, 0.0),
        tick=7,
    ),
    WheelsBatch: WheelsBatch(
        t=1.0,
        seq=14,
        robots=("r1", "r2"),
        omega_r=(5.0, 1.0),
        omega_l=(-5.0, 1.0),
        power_r=(0.5, 0.1),
        power_l=(-0.5, 0.1),
        pose_t=(0.98, -1.0),
        tick=7,
        mode=("tracking", "hold"),
    ),
    StatusBatch: StatusBatch(
        t=1.0,
        seq=15,
        pid=1234,
        host="ws-1",
        robots=("r1", "r2"),
        mode=("tracking", "idle"),
        slot=(0, -1),
        rejected=(0, 3),
        ex=(0.01, 0.0),
        ey=(-0.02, 0.0),
        filter_active=(5, 0),
        filter_violations=(0, 0),
        filter_infeasible=(1, 0),
        filter_tiebreaks=(0, 2),
    ),
    CoordinatorStatus: CoordinatorStatus(
        t=12.5,
        seq=63,
        name="main",
        mode="lockstep",
        role="active",
        epoch=1,
        takeovers=1,
        stepdowns=0,
        ticks=625,
        alive=("r1", "r2"),
        assignment={"r2": 1, "r1": 0},
        leader="r1",
        estop_fleet=False,
        estop_robots=("r2",),
        rejected=2,
        rejects={"pose-malformed": 2},
        internal_errors=0,
        rx={"pose": 1250, "clock": 625},
        pid=4244,
        host="ws-1",
        tick_p50_ms=0.25,
        tick_max_ms=1.5,
    ),
    PlantStatus: PlantStatus(
        t=12.5,
        seq=64,
        mode="lockstep",
        state="running",
        tick=625,
        sim_t=12.5,
        timeouts=0,
        alive=("r1", "r2"),
        coordinators=("main",),
        link_sent=1250,
        link_dropped=3,
        min_separation_m=None,
        collisions=0,
        frames=375,
        batch=False,
        ignored=0,
        rejected=0,
        rejects={},
        internal_errors=0,
        rx={"wheels": 1250},
    ),
    CameraStatus: CameraStatus(
        t=12.5,
        seq=25,
        state="running",
        detector="apriltag",
        source="rendered",
        frames=375,
        dropped=2,
        fps=29.5,
        detect_p50_ms=4.5,
        detect_p99_ms=9.0,
        detect_max_ms=12.0,
        latency_p50_ms=6.0,
        latency_p99_ms=11.5,
        latency_max_ms=15.0,
        detections={"r1": 375, "r2": 370},
        published={"r1": 375, "r2": 369},
        misses={"r1": 0, "r2": 5},
        rejects={"jump": 1, "bad_size": 0, "unknown": 0, "duplicate": 0},
        reacquired=0,
        internal_errors=0,
        truth_rejected=0,
    ),
}

TYPES = list(MESSAGE_TYPES)
TYPE_IDS = [cls.__name__ for cls in TYPES]
ALL_FIELDS = [(cls, f) for cls in TYPES for f in spec_of(cls).fields]
ALL_FIELD_IDS = [f"{cls.__name__}.{f.name}" for cls, f in ALL_FIELDS]


def wire_map(cls: type) -> dict[str, Any]:
    """The valid wire map of the sample of `cls` (a plain dict to mutate)."""
    return dict(msgpack.unpackb(encode(SAMPLES[cls])))


def pack(obj: Any) -> bytes:
    return msgpack.packb(obj, use_bin_type=True)


def rejected(data: bytes, cls: type) -> DecodeError:
    result = decode(data, cls)
    assert isinstance(result, DecodeError), f"accepted: {result!r}"
    assert isinstance(result.detail, str) and result.detail
    return result


# The id alphabets as plain text strategies (much faster to draw than st.from_regex).
ROBOT_IDS = st.text("abcdefghijklmnopqrstuvwxyz0123456789_-", min_size=1, max_size=64)
NAMES = st.text(
    "abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789_-", min_size=1, max_size=64
)
