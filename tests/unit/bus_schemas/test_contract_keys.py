"""The bus contract itself (required and nullable fields, an independent copy of
docs/bus-contract.md) and the key builders and parsers of bus_schemas.keys."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from support.bus_samples import NAMES, ROBOT_IDS

from bus_schemas import (
    MESSAGE_TYPES,
    Assignment,
    CameraStatus,
    Clock,
    CoordinatorStatus,
    Disturbance,
    Estop,
    Fault,
    Heartbeat,
    Leader,
    Movers,
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
    keys,
    message_type_for_key,
    spec_of,
)
from bus_schemas.docs import render_markdown

REPO = Path(__file__).resolve().parents[3]
# derandomize: the same examples on every run (deterministic CI), no example database.
HYP = settings(
    max_examples=200,
    deadline=None,
    derandomize=True,
    suppress_health_check=[HealthCheck.too_slow],
)
# Properties run once per message type (13 types); 50 examples each keeps the suite fast on a
# 2-core machine (650 generated messages per property in all).
HYP_PER_TYPE = settings(HYP, max_examples=50)


# --- the contract itself -----------------------------------------------------------------------

# The contract (docs/bus-contract.md): required fields besides v, t, seq (an independent copy).
CONTRACT_REQUIRED = {
    Leader: {"x", "y", "theta", "v_mps", "omega_radps"},
    Slot: {"slot", "role", "stage", "parent", "x", "y", "theta", "vx", "vy"},
    Setpoint: {"slot", "role", "stage", "parent", "x", "y", "theta", "vx", "vy", "robot"},
    Assignment: {"leader", "robots"},
    Pose: {"x", "y", "theta"},
    Truth: {"x", "y", "theta"},
    Wheels: {"omega_r", "omega_l", "power_r", "power_l", "pose_t"},
    Status: {"mode", "slot", "pid", "host", "rejected"},
    Estop: {"engage", "robot"},
    Clock: {"tick"},
}

# Fields the contract says may be nil ("slot or nil", "robot id or nil", ...).
CONTRACT_NULLABLE = {
    Slot: {"parent"},
    Setpoint: {"parent"},
    Assignment: {"leader"},
    Status: {"slot"},
    Estop: {"robot"},
}


@pytest.mark.parametrize("cls", list(CONTRACT_REQUIRED), ids=lambda c: c.__name__)
def test_contract_required_fields_are_required(cls: type) -> None:
    spec = spec_of(cls)
    required = {f.name for f in spec.fields if not f.optional}
    assert CONTRACT_REQUIRED[cls] | {"v", "t"} <= required
    assert ("seq" in required) == spec.periodic
    nullable = {f.name for f in spec.fields if f.spec.nullable}
    assert CONTRACT_NULLABLE.get(cls, set()) <= nullable


def test_docs_are_generated_from_the_tables() -> None:
    text = (REPO / "docs" / "bus.md").read_text(encoding="utf-8")
    assert text == render_markdown(), "run: python -m bus_schemas.docs > docs/bus.md"
    assert "time.monotonic()" in text and "sim time" in text
    for cls in MESSAGE_TYPES:
        spec = spec_of(cls)
        for f in spec.fields:
            assert f"| `{f.name}` |" in text
        assert spec.key.replace("{", "<").replace("}", ">").replace("<robot>", "<id>") in text


# --- keys ------------------------------------------------------------------------------------


def test_key_builders() -> None:
    f = "demo"
    assert keys.leader_key(f) == "formation/demo/leader"
    assert keys.slot_key(f, 0) == "formation/demo/slot/0"
    assert keys.slot_key(f, 12) == "formation/demo/slot/12"
    assert keys.setpoint_key(f, "r1") == "formation/demo/robot/r1/setpoint"
    assert keys.assignment_key(f) == "formation/demo/assignment"
    assert keys.pose_key(f, "r1") == "formation/demo/robot/r1/pose"
    assert keys.truth_key(f, "r1") == "formation/demo/robot/r1/truth"
    assert keys.wheels_key(f, "r-2_b") == "formation/demo/robot/r-2_b/wheels"
    assert keys.status_key(f, "r1") == "formation/demo/robot/r1/status"
    assert keys.estop_key(f) == "formation/demo/estop"
    assert keys.clock_key(f) == "formation/demo/clock"
    assert keys.disturbance_key(f) == "formation/demo/disturbance"
    assert keys.fault_key(f) == "formation/demo/fault"
    assert keys.heartbeat_key(f, "standby") == "formation/demo/coordinator/standby/heartbeat"
    assert keys.poses_key(f) == "formation/demo/poses"
    assert keys.alive_robot_key(f, "r1") == "formation/demo/alive/robot/r1"
    assert keys.alive_coordinator_key(f, "main") == "formation/demo/alive/coordinator/main"
    assert keys.alive_plant_key(f) == "formation/demo/alive/plant"
    assert keys.all_poses_pattern(f) == "formation/demo/robot/*/pose"
    assert keys.all_truth_pattern(f) == "formation/demo/robot/*/truth"
    assert keys.all_wheels_pattern(f) == "formation/demo/robot/*/wheels"
    assert keys.all_status_pattern(f) == "formation/demo/robot/*/status"
    assert keys.all_setpoints_pattern(f) == "formation/demo/robot/*/setpoint"
    assert keys.all_slots_pattern(f) == "formation/demo/slot/*"
    assert keys.all_heartbeats_pattern(f) == "formation/demo/coordinator/*/heartbeat"
    assert keys.alive_robots_pattern(f) == "formation/demo/alive/robot/*"
    assert keys.alive_coordinators_pattern(f) == "formation/demo/alive/coordinator/*"
    assert keys.alive_pattern(f) == "formation/demo/alive/**"
    assert keys.fleet_pattern(f) == "formation/demo/**"
    assert keys.robot_pattern(f, "r1") == "formation/demo/robot/r1/*"
    assert keys.DEFAULT_FLEET == "demo"


BAD_IDS = ["", "R1", "r/1", "r*", "r 1", "$r", "r?", "r#", "x" * 65, "r1\n", "é", "..", "r.1"]
BAD_FLEETS = ["", "a/b", "*", "**", "a b", "$f", "x" * 65, "f.1", "fleet\n"]


def test_invalid_ids_and_names_are_rejected() -> None:
    robot_builders = [
        keys.setpoint_key,
        keys.pose_key,
        keys.truth_key,
        keys.wheels_key,
        keys.status_key,
        keys.alive_robot_key,
        keys.robot_pattern,
    ]
    for bad in BAD_IDS:
        for build in robot_builders:
            with pytest.raises(ValueError, match="robot id"):
                build("demo", bad)
    bad_names: list[Any] = [*BAD_FLEETS, None, 3]
    for bad in bad_names:
        with pytest.raises(ValueError, match="fleet"):
            keys.leader_key(bad)  # type: ignore[arg-type]
        with pytest.raises(ValueError, match="fleet"):
            keys.pose_key(bad, "r1")  # type: ignore[arg-type]
        with pytest.raises(ValueError, match="coordinator name"):
            keys.heartbeat_key("demo", bad)  # type: ignore[arg-type]
    for bad_slot in (-1, 65536, True, 1.0, "1"):
        with pytest.raises(ValueError, match="slot"):
            keys.slot_key("demo", bad_slot)  # type: ignore[arg-type]
    assert keys.is_robot_id("r1") and not keys.is_robot_id(b"r1") and not keys.is_robot_id(1)


@HYP
@given(fleet=NAMES, robot=ROBOT_IDS, name=NAMES, slot=st.integers(0, keys.MAX_SLOT))
def test_key_parse_round_trip(fleet: str, robot: str, name: str, slot: int) -> None:
    for build, leaf, cls in [
        (keys.setpoint_key, keys.SETPOINT, Setpoint),
        (keys.pose_key, keys.POSE, Pose),
        (keys.truth_key, keys.TRUTH, Truth),
        (keys.wheels_key, keys.WHEELS, Wheels),
        (keys.status_key, keys.STATUS, Status),
    ]:
        key = build(fleet, robot)
        assert keys.parse_robot_key(key) == (fleet, robot, leaf)
        assert keys.parse_key(key) == keys.KeyInfo(fleet, leaf, robot=robot)
        assert message_type_for_key(key) is cls
    for build_f, cls in [
        (keys.leader_key, Leader),
        (keys.assignment_key, Assignment),
        (keys.estop_key, Estop),
        (keys.clock_key, Clock),
        (keys.disturbance_key, Disturbance),
        (keys.fault_key, Fault),
        (keys.poses_key, PoseBatch),
        (keys.setpoints_key, SetpointBatch),
        (keys.movers_key, Movers),
        (keys.truths_key, TruthBatch),
    ]:
        key = build_f(fleet)
        assert keys.parse_key(key) == keys.KeyInfo(fleet, spec_of(cls).name)
        assert keys.parse_robot_key(key) is None
        assert message_type_for_key(key) is cls
    key = keys.slot_key(fleet, slot)
    assert keys.parse_key(key) == keys.KeyInfo(fleet, keys.SLOT, slot=slot)
    assert message_type_for_key(key) is Slot
    for build_h, leaf, cls in [
        (keys.host_wheels_key, keys.HOST_WHEELS, WheelsBatch),
        (keys.host_status_key, keys.HOST_STATUS, StatusBatch),
    ]:
        key = build_h(fleet, name)
        assert keys.parse_key(key) == keys.KeyInfo(fleet, leaf, name=name)
        assert message_type_for_key(key) is cls
    key = keys.heartbeat_key(fleet, name)
    assert keys.parse_key(key) == keys.KeyInfo(fleet, keys.HEARTBEAT, name=name)
    assert message_type_for_key(key) is Heartbeat
    key = keys.coordinator_status_key(fleet, name)
    assert keys.parse_key(key) == keys.KeyInfo(fleet, keys.COORDINATOR_STATUS, name=name)
    assert message_type_for_key(key) is CoordinatorStatus
    key = keys.plant_status_key(fleet)
    assert keys.parse_key(key) == keys.KeyInfo(fleet, keys.PLANT_STATUS)
    assert message_type_for_key(key) is PlantStatus
    key = keys.camera_status_key(fleet, name)
    assert keys.parse_key(key) == keys.KeyInfo(fleet, keys.CAMERA_STATUS, name=name)
    assert message_type_for_key(key) is CameraStatus
    assert keys.parse_alive_key(keys.alive_robot_key(fleet, robot)) == (fleet, "robot", robot)
    assert keys.parse_alive_key(keys.alive_coordinator_key(fleet, name)) == (
        fleet,
        "coordinator",
        name,
    )
    assert keys.parse_alive_key(keys.alive_plant_key(fleet)) == (fleet, "plant", None)
    assert keys.parse_robot_key(keys.alive_robot_key(fleet, robot)) is None
    assert message_type_for_key(keys.alive_robot_key(fleet, robot)) is None


def test_parse_rejects_foreign_and_malformed_keys() -> None:
    for key in [
        "",
        "formation",
        "formation/demo",
        "other/demo/leader",
        "formation/demo/robot/*/pose",
        "formation/demo/robot/R1/pose",
        "formation/demo/robot/r1",
        "formation/demo/robot/r1/pose/extra",
        "formation/de mo/robot/r1/pose",
        "formation/demo/slot/01",
        "formation/demo/slot/-1",
        "formation/demo/slot/65536",
        "formation/demo/slot/x",
        "formation/demo/unknown",
        "formation/demo/coordinator/a/b",
        "formation/demo/coordinator/a b/status",
        "formation/demo/plant/truth",
        "formation/demo/plant/status/x",
        "formation/demo/alive/robot/R1",
        "formation/demo/alive/thing/x",
        "formation/**",
    ]:
        assert keys.parse_key(key) is None, key
        assert keys.parse_robot_key(key) is None
        assert keys.parse_alive_key(key) is None
        assert message_type_for_key(key) is None
    assert keys.parse_key(None) is None  # type: ignore[arg-type]
    # A robot leaf this version does not know still names the robot; it maps to no type.
    assert keys.parse_robot_key("formation/demo/robot/r1/battery") == ("demo", "r1", "battery")
    assert message_type_for_key("formation/demo/robot/r1/battery") is None
    assert message_type_for_key("formation/demo/robot/r1/leader") is None
    assert keys.parse_alive_key(keys.pose_key("demo", "r1")) is None


def test_message_key_templates_match_builders() -> None:
    for cls in MESSAGE_TYPES:
        spec = spec_of(cls)
        key = spec.key.format(fleet="f1", robot="r9", slot=3, name="c1")
        assert message_type_for_key(key) is cls


def test_schema_modules_import_only_stdlib_and_msgpack() -> None:
    """bus_schemas runs on a robot: standard library + msgpack only (no zenoh, no asyncio)."""
    import ast
    import sys

    package = REPO / "bus_schemas"
    for path in sorted(package.glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Import):
                names = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names = [node.module]
            else:
                continue
            for name in names:
                top = name.split(".")[0]
                assert top in sys.stdlib_module_names or top in ("msgpack", "bus_schemas"), (
                    f"{path.name} imports {name}"
                )
                assert top != "asyncio", f"{path.name} imports asyncio"
