"""JSON Schemas of the recorded channels (formation.outputs.bus_json): generated from the
bus_schemas
message tables, they accept every message's wire map and carry its ranges, enums and patterns.
``schema_errors`` (a checker for the subset json_schema emits) also validates what
tests/unit/formation/test_record_report.py records."""

from __future__ import annotations

import json
import math
from typing import Any

import pytest
from support.json_schema import schema_errors

from bus_schemas import (
    MESSAGE_TYPES,
    Assignment,
    Clock,
    CmdVel,
    Goal,
    Leader,
    Obstacle,
    Path,
    Pose,
    Shape,
    Slot,
    Status,
    Truth,
    Wheels,
    to_map,
)
from bus_schemas.messages import (
    CameraStatus,
    CoordinatorStatus,
    Disturbance,
    Estop,
    Fault,
    Heartbeat,
    Movers,
    PlantStatus,
    PoseBatch,
    Setpoint,
    SetpointBatch,
    StatusBatch,
    TruthBatch,
    WheelsBatch,
)
from formation.outputs.bus_json import json_schema, schema_name

FLEET = "demo"
DT = 0.02
EXIT_BOUND_S = 1.5  # requirement: exit within 1 s of SIGINT; 0.5 s margin for a loaded CI box


# ---------------------------------------------------------------------------------------------
# JSON Schemas from the bus_schemas tables
# ---------------------------------------------------------------------------------------------

EXAMPLES = [
    Leader(t=1.0, seq=1, x=0.1, y=0.2, theta=math.pi, v_mps=0.02, omega_radps=0.0),
    Slot(
        t=1.0,
        seq=1,
        slot=1,
        role="follower",
        stage=1,
        parent=0,
        x=0.1,
        y=0.2,
        theta=0.0,
        vx=0.02,
        vy=0.0,
    ),
    Setpoint(
        t=1.0,
        seq=1,
        robot="r1",
        slot=0,
        role="leader",
        stage=0,
        parent=None,
        x=0.1,
        y=0.2,
        theta=-1.0,
        vx=0.02,
        vy=0.0,
    ),
    Assignment(t=1.0, seq=1, leader="r1", robots={"r1": 0, "r2": 1}),
    Pose(t=1.0, seq=1, x=0.1, y=0.2, theta=0.3, robot="r1"),
    Truth(t=1.0, seq=1, x=0.1, y=0.2, theta=0.3),
    Wheels(
        t=1.0,
        seq=1,
        omega_r=3.0,
        omega_l=-3.0,
        power_r=0.3,
        power_l=-0.3,
        pose_t=0.96,
        tick=50,
        saturated=False,
    ),
    Status(
        t=1.0,
        seq=1,
        mode="tracking",
        slot=None,
        pid=123,
        host="h",
        rejected=0,
        ex=0.01,
        ey=-0.02,
        role="follower",
        rx={"pose": 30},
    ),
    Status(  # issue 29: the estimator's twist
        t=1.0,
        seq=2,
        mode="tracking",
        slot=0,
        pid=123,
        host="h",
        rejected=0,
        v_mps=0.1,
        omega_radps=-0.2,
    ),
    Estop(t=1.0, engage=True, robot=None),
    Clock(t=1.0, seq=50, tick=50),
    Disturbance(
        t=1.0, robot="r1", kind="teleport", dx=0.0, dy=0.0, duration_s=0.0, x=1.0, y=2.0, theta=0.0
    ),
    Heartbeat(t=1.0, seq=1, name="main", active=True, epoch=1, leader_t0=0.5),
    Fault(t=7.5, tick=375, fault=0, kind="kill", robot="r1", undo=False),
    CmdVel(t=1.0, seq=1, v_mps=0.05, omega_radps=-0.1),
    Goal(t=1.0, x=1.0, y=-0.5, heading=0.3),
    Path(t=1.0, xs=(0.0, 1.0, 1.0), ys=(0.0, 0.0, 1.0), heading=None),
    Shape(t=1.0, kind="column", spacing_m=0.3),
    Obstacle(t=1.0, id="box1", action="add", shape="circle", x=1.0, y=0.5, radius_m=0.2),
    PoseBatch(
        t=1.0, seq=1, robots=("r1", "r2"), x=(0.1, 0.2), y=(0.3, 0.4), theta=(0.0, 1.0), stamp=0.97
    ),
    TruthBatch(
        t=1.0, seq=1, robots=("r1", "r2"), x=(0.1, 0.2), y=(0.3, 0.4), theta=(0.0, 1.0), stamp=1.0
    ),
    SetpointBatch(
        t=1.0,
        seq=1,
        robots=("r1",),
        slot=(0,),
        role=("leader",),
        stage=(0,),
        x=(0.1,),
        y=(0.2,),
        theta=0.0,
        vx=(0.1,),
        vy=(0.0,),
    ),
    WheelsBatch(
        t=1.0,
        seq=1,
        robots=("r1",),
        omega_r=(1.0,),
        omega_l=(2.0,),
        power_r=(0.1,),
        power_l=(0.2,),
        pose_t=(-1.0,),
    ),
    StatusBatch(
        t=1.0,
        seq=1,
        pid=7,
        host="h",
        robots=("r1",),
        mode=("hold",),
        slot=(-1,),
        rejected=(0,),
        ex=(0.0,),
        ey=(0.0,),
    ),
    StatusBatch(  # issue 29: the estimator's twist of the robots that know it
        t=1.0,
        seq=2,
        pid=7,
        host="h",
        robots=("r1", "r2"),
        mode=("tracking", "hold"),
        slot=(0, -1),
        rejected=(0, 0),
        ex=(0.0, 0.0),
        ey=(0.0, 0.0),
        twist_robots=("r1",),
        v_mps=(0.1,),
        omega_radps=(-0.2,),
    ),
    CoordinatorStatus(
        t=1.0, seq=1, name="main", mode="realtime", role="standby", epoch=0, takeovers=0,
        stepdowns=0, ticks=0, alive=(), assignment={}, leader=None, estop_fleet=True,
        estop_robots=(), rejected=0, rejects={}, internal_errors=0, rx={}, pid=8, host="h",
    ),
    PlantStatus(
        t=1.0, seq=1, mode="lockstep", state="waiting", tick=0, sim_t=0.0, timeouts=0,
        alive=("r1",), coordinators=("main",), link_sent=0, link_dropped=0,
        min_separation_m=None, collisions=0, frames=0, batch=True, ignored=0, rejected=0,
        rejects={}, internal_errors=0, rx={"wheels": 0},
    ),
    CameraStatus(
        t=1.0, seq=1, state="done", detector="aruco", source="scene.avi", frames=3, dropped=0,
        fps=30.0, latency_p50_ms=-2.5, detections={"r1": 3}, published={"r1": 3},
        misses={"r1": 0}, rejects={"jump": 0}, reacquired=0, internal_errors=0, truth_rejected=0,
    ),
    Movers(
        t=1.0, seq=15, robots=("r4", "tag9"), x=(0.1, 0.2), y=(0.3, 0.4), vx=(0.3, 0.0),
        vy=(0.0, -0.1), tick=7,
    ),
]  # fmt: skip


def test_every_message_type_has_an_example() -> None:
    assert {type(m) for m in EXAMPLES} == set(MESSAGE_TYPES)


@pytest.mark.parametrize("msg", EXAMPLES, ids=lambda m: type(m).__name__)
def test_json_schema_follows_the_message_table_and_accepts_the_wire_map(msg: Any) -> None:
    cls = type(msg)
    schema = json_schema(cls)
    assert schema["title"] == schema_name(cls) == f"formation.{cls.__name__}"
    fields = [f for f in cls.__dataclass_fields__]
    assert list(schema["properties"]) == fields
    for name in schema["required"]:  # v, t (and seq) are always required
        assert cls.__dataclass_fields__[name].default is not None or name == "v"
    assert {"v", "t"} <= set(schema["required"])
    wire = json.loads(json.dumps(to_map(msg)))
    assert schema_errors(schema, wire) == []
    # and it rejects what the codec rejects: a wrong version, a missing required field
    assert schema_errors(schema, {**wire, "v": 2}) != []
    assert schema_errors(schema, {k: v for k, v in wire.items() if k != "t"}) != []


def test_json_schema_carries_ranges_enums_and_patterns() -> None:
    wheels = json_schema(Wheels)["properties"]
    assert (wheels["power_r"]["minimum"], wheels["power_r"]["maximum"]) == (-1.0, 1.0)
    assert wheels["pose_t"]["type"] == ["number", "null"]  # required, nil allowed
    assert "rad/s" in wheels["omega_r"]["description"]
    slot = json_schema(Slot)["properties"]
    assert slot["role"]["enum"] == ["leader", "subleader", "follower"]
    assert slot["theta"]["maximum"] == pytest.approx(math.pi, abs=1e-8)
    pose = json_schema(Pose)
    assert schema_errors(pose, {"v": 1, "t": 1.0, "seq": 0, "x": 0, "y": 0, "theta": 4.0}) != []
    assert (
        schema_errors(
            pose, {"v": 1, "t": 1.0, "seq": 0, "x": 0, "y": 0, "theta": 0.0, "robot": "R1!"}
        )
        != []
    )
