"""Golden bytes: the version-1 wire format is frozen.

Each fixed message below must encode to exactly the pinned bytes, and the pinned bytes must decode
back to the message. If this test fails, the wire format changed: that is a new schema version
(bus-contract.md), not a test to update.
"""

from __future__ import annotations

import math
import struct
from typing import Any

import msgpack
import pytest

from bus_schemas import (
    MESSAGE_TYPES,
    Assignment,
    CameraStatus,
    Clock,
    CmdVel,
    CoordinatorStatus,
    Disturbance,
    Estop,
    Fault,
    Goal,
    Heartbeat,
    Leader,
    Movers,
    Obstacle,
    Path,
    PlantStatus,
    Pose,
    PoseBatch,
    Setpoint,
    SetpointBatch,
    Shape,
    Slot,
    Status,
    StatusBatch,
    Truth,
    TruthBatch,
    Wheels,
    WheelsBatch,
    decode,
    encode,
)

GOLDEN_MESSAGES: dict[str, Any] = {
    # issue 28: a leader driven by the operator, and the operator's commands
    "leader_operator": Leader(
        t=12.5,
        seq=251,
        x=1.25,
        y=-0.5,
        theta=math.pi / 4,
        v_mps=0.1,
        omega_radps=-0.05,
        mode="teleop",
        progress_s=3.5,
        rate=0.75,
        target=0,
        deadman=True,
        shape="column",
        reshape=0.25,
    ),
    "shape": Shape(t=12.5, kind="column", spacing_m=0.5),
    # issue 28 (slots): a reshape into a chevron of five slots running, as a standby reads it
    "leader_reshape": Leader(
        t=12.5,
        seq=252,
        x=1.25,
        y=-0.5,
        theta=0.0,
        v_mps=0.1,
        omega_radps=0.0,
        mode="script",
        shape="chevron",
        reshape=0.5,
        slots=5,
        spacing_m=0.4,
        reshape_from="triangle",
        reshape_t0=8.0,
        reshape_s=6.25,
    ),
    "shape_slots": Shape(t=12.5, kind="chevron", spacing_m=0.4, slots=5),
    "obstacle": Obstacle(
        t=12.5, id="box1", action="move", shape="circle", x=1.5, y=-0.5, radius_m=0.25
    ),
    "cmd_vel": CmdVel(t=12.5, seq=42, v_mps=0.1, omega_radps=-0.25),
    "goal": Goal(t=12.5, x=1.5, y=-2.0, heading=math.pi / 2),
    "path": Path(t=12.5, xs=(0.5, 1.0), ys=(0.25, -0.25)),
    "leader": Leader(
        t=12.5, seq=250, x=1.25, y=-0.5, theta=math.pi / 4, v_mps=0.1, omega_radps=-0.05
    ),
    "slot": Slot(
        t=12.5,
        seq=250,
        slot=2,
        role="follower",
        stage=1,
        parent=0,
        x=0.9,
        y=-0.75,
        theta=math.pi,
        vx=0.1,
        vy=-0.002,
    ),
    "slot0": Slot(
        t=12.5,
        seq=250,
        slot=0,
        role="leader",
        stage=0,
        parent=None,
        x=1.25,
        y=-0.5,
        theta=0.0,
        vx=0.0,
        vy=0.0,
    ),
    "setpoint": Setpoint(
        t=12.5,
        seq=251,
        robot="r2",
        slot=1,
        role="subleader",
        stage=1,
        parent=0,
        x=0.9,
        y=-0.25,
        theta=-1.5,
        vx=0.07,
        vy=0.07,
    ),
    "assignment": Assignment(t=12.5, seq=3, leader="r1", robots={"r3": 2, "r1": 0, "r2": 1}),
    "assignment_empty": Assignment(t=0.0, seq=0, leader=None, robots={}),
    "pose": Pose(t=12.48, seq=624, x=0.123, y=-0.456, theta=1.2, robot="r1"),
    "pose_min": Pose(t=12.48, seq=624, x=0.123, y=-0.456, theta=1.2),
    "truth": Truth(t=12.5, seq=625, x=0.125, y=-0.455, theta=1.19),
    "wheels": Wheels(
        t=12.51,
        seq=1250,
        omega_r=4.5,
        omega_l=-1.25,
        power_r=0.45,
        power_l=-0.125,
        pose_t=12.48,
        tick=625,
        saturated=False,
    ),
    "wheels_idle": Wheels(
        t=0.5, seq=0, omega_r=0.0, omega_l=0.0, power_r=0.0, power_l=0.0, pose_t=None
    ),
    "status": Status(
        t=12.5,
        seq=62,
        mode="tracking",
        slot=1,
        pid=4242,
        host="pi-r2",
        rejected=3,
        ex=0.01,
        ey=-0.02,
        role="subleader",
        rx={"setpoint": 600, "pose": 620},
        robot="r2",
    ),
    "status_min": Status(t=1.0, seq=1, mode="idle", slot=None, pid=0, host="", rejected=0),
    "status_twist": Status(
        t=2.0,
        seq=10,
        mode="tracking",
        slot=0,
        pid=7,
        host="pi-r1",
        rejected=0,
        v_mps=0.125,
        omega_radps=-0.5,
    ),
    "estop": Estop(t=30.0, engage=True, robot=None),
    "estop_robot": Estop(t=31.0, engage=False, robot="r3"),
    "clock": Clock(t=0.02, seq=1, tick=1),
    "fault_notice": Fault(t=7.48, tick=374, fault=0, kind="kill", robot="r1"),
    "fault_request": Fault(t=12.0, request=True, kind="estop", duration_s=2.0),
    "fault_request_role": Fault(t=30.0, request=True, kind="kill", role="leader"),
    "disturbance_drag": Disturbance(
        t=20.0, robot="r1", kind="drag", dx=-0.4, dy=0.0, duration_s=2.0
    ),
    "disturbance_teleport": Disturbance(
        t=21.0,
        robot="r1",
        kind="teleport",
        dx=0.0,
        dy=0.0,
        duration_s=0.0,
        x=0.5,
        y=0.5,
        theta=-math.pi,
    ),
    "heartbeat": Heartbeat(t=100.25, seq=401, name="primary", active=True, epoch=2, leader_t0=3.5),
    "poses": PoseBatch(
        t=12.49,
        seq=624,
        robots=("r1", "r2"),
        x=(0.123, 0.9),
        y=(-0.456, -0.25),
        theta=(1.2, -1.5),
        stamp=12.48,
    ),
    "truths": TruthBatch(
        t=12.5,
        seq=625,
        robots=("r1", "r2"),
        x=(0.125, 0.875),
        y=(-0.5, -0.25),
        theta=(1.25, -1.5),
        stamp=12.5,
    ),
    "setpoints": SetpointBatch(
        t=12.5,
        seq=626,
        robots=("r2", "r1"),
        slot=(1, 0),
        role=("subleader", "leader"),
        stage=(1, 0),
        x=(0.9, 1.25),
        y=(-0.25, -0.5),
        theta=-1.5,
        vx=(0.07, 0.07),
        vy=(0.0, 0.0),
        tick=625,
    ),
    "movers": Movers(
        t=12.5, seq=3, robots=("r4",), x=(0.5,), y=(-0.25,), vx=(-0.25,), vy=(0.0,), tick=625
    ),
    "host_wheels": WheelsBatch(
        t=12.5,
        seq=627,
        robots=("r1", "r2"),
        omega_r=(5.25, 0.0),
        omega_l=(4.75, 0.0),
        power_r=(0.5, 0.0),
        power_l=(0.25, 0.0),
        pose_t=(12.48, -1.0),
        tick=625,
    ),
    "host_status": StatusBatch(
        t=12.5,
        seq=63,
        pid=4243,
        host="ws-1",
        robots=("r1", "r2"),
        mode=("tracking", "idle"),
        slot=(0, -1),
        rejected=(0, 2),
        ex=(0.01, 0.0),
        ey=(-0.02, 0.0),
    ),
    "host_status_twist": StatusBatch(
        t=2.0,
        seq=11,
        pid=7,
        host="ws-1",
        robots=("r1", "r2"),
        mode=("tracking", "idle"),
        slot=(0, -1),
        rejected=(0, 0),
        ex=(0.0, 0.0),
        ey=(0.0, 0.0),
        twist_robots=("r1",),
        v_mps=(0.125,),
        omega_radps=(-0.5,),
    ),
    "coordinator_status": CoordinatorStatus(
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
    "plant_status": PlantStatus(
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
        min_separation_m=0.5,
        collisions=0,
        frames=375,
        batch=False,
        ignored=0,
        rejected=0,
        rejects={},
        internal_errors=0,
        rx={"wheels": 1250},
    ),
    "camera_status": CameraStatus(
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

# fmt: off
GOLDEN_HEX: dict[str, str] = {
    "leader_operator": (
        "8fa17601a174cb4029000000000000a3736571ccfba178cb3ff4000000000000a179cbbfe0000000000000a57468657461cb3fe921fb54442d18a5765f6d7073cb3fb999999999999aab6f6d6567615f7261647073cbbfa999999999999aa46d6f6465a674656c656f70aa70726f67726573735f73cb400c000000000000a472617465cb3fe8000000000000a674617267657400a7646561646d616ec3a57368617065a6636f6c756d6ea772657368617065cb3fd0000000000000"
    ),
    "shape": (
        "84a17601a174cb4029000000000000a46b696e64a6636f6c756d6ea973706163696e675f6dcb3fe0000000000000"
    ),
    "leader_reshape": (
        "de0010a17601a174cb4029000000000000a3736571ccfca178cb3ff4000000000000a179cbbfe0000000000000a57468657461cb0000000000000000a5765f6d7073cb3fb999999999999aab6f6d6567615f7261647073cb0000000000000000a46d6f6465a6736372697074a57368617065a763686576726f6ea772657368617065cb3fe0000000000000a5736c6f747305a973706163696e675f6dcb3fd999999999999aac726573686170655f66726f6da8747269616e676c65aa726573686170655f7430cb4020000000000000a9726573686170655f73cb4019000000000000"
    ),
    "shape_slots": (
        "85a17601a174cb4029000000000000a46b696e64a763686576726f6ea973706163696e675f6dcb3fd999999999999aa5736c6f747305"
    ),
    "obstacle": (
        "88a17601a174cb4029000000000000a26964a4626f7831a6616374696f6ea46d6f7665a57368617065a6636972636c65a178cb3ff8000000000000a179cbbfe0000000000000a87261646975735f6dcb3fd0000000000000"
    ),
    "cmd_vel": (
        "85a17601a174cb4029000000000000a37365712aa5765f6d7073cb3fb999999999999aab6f6d6567615f7261647073cbbfd0000000000000"
    ),
    "goal": (
        "85a17601a174cb4029000000000000a178cb3ff8000000000000a179cbc000000000000000a768656164696e67cb3ff921fb54442d18"
    ),
    "path": (
        "84a17601a174cb4029000000000000a2787392cb3fe0000000000000cb3ff0000000000000a2797392cb3fd0000000000000cbbfd0000000000000"
    ),
    "leader": (
        "88a17601a174cb4029000000000000a3736571ccfaa178cb3ff4000000000000a179cbbfe0000000000000a57468657461cb3fe921fb54442d18a5765f6d7073cb3fb999999999999aab6f6d6567615f7261647073cbbfa999999999999a"
    ),
    "slot": (
        "8ca17601a174cb4029000000000000a3736571ccfaa4736c6f7402a4726f6c65a8666f6c6c6f776572a5737461676501a6706172656e7400a178cb3feccccccccccccda179cbbfe8000000000000a57468657461cb400921fb54442d18a27678cb3fb999999999999aa27679cbbf60624dd2f1a9fc"
    ),
    "slot0": (
        "8ca17601a174cb4029000000000000a3736571ccfaa4736c6f7400a4726f6c65a66c6561646572a5737461676500a6706172656e74c0a178cb3ff4000000000000a179cbbfe0000000000000a57468657461cb0000000000000000a27678cb0000000000000000a27679cb0000000000000000"
    ),
    "setpoint": (
        "8da17601a174cb4029000000000000a3736571ccfba5726f626f74a27232a4736c6f7401a4726f6c65a97375626c6561646572a5737461676501a6706172656e7400a178cb3feccccccccccccda179cbbfd0000000000000a57468657461cbbff8000000000000a27678cb3fb1eb851eb851eca27679cb3fb1eb851eb851ec"
    ),
    "assignment": (
        "85a17601a174cb4029000000000000a373657103a66c6561646572a27231a6726f626f747383a2723100a2723201a2723302"
    ),
    "assignment_empty": (
        "85a17601a174cb0000000000000000a373657100a66c6561646572c0a6726f626f747380"
    ),
    "pose": (
        "87a17601a174cb4028f5c28f5c28f6a3736571cd0270a178cb3fbf7ced916872b0a179cbbfdd2f1a9fbe76c9a57468657461cb3ff3333333333333a5726f626f74a27231"
    ),
    "pose_min": (
        "86a17601a174cb4028f5c28f5c28f6a3736571cd0270a178cb3fbf7ced916872b0a179cbbfdd2f1a9fbe76c9a57468657461cb3ff3333333333333"
    ),
    "truth": (
        "86a17601a174cb4029000000000000a3736571cd0271a178cb3fc0000000000000a179cbbfdd1eb851eb851fa57468657461cb3ff30a3d70a3d70a"
    ),
    "wheels": (
        "8aa17601a174cb4029051eb851eb85a3736571cd04e2a76f6d6567615f72cb4012000000000000a76f6d6567615f6ccbbff4000000000000a7706f7765725f72cb3fdccccccccccccda7706f7765725f6ccbbfc0000000000000a6706f73655f74cb4028f5c28f5c28f6a47469636bcd0271a9736174757261746564c2"
    ),
    "wheels_idle": (
        "88a17601a174cb3fe0000000000000a373657100a76f6d6567615f72cb0000000000000000a76f6d6567615f6ccb0000000000000000a7706f7765725f72cb0000000000000000a7706f7765725f6ccb0000000000000000a6706f73655f74c0"
    ),
    "status": (
        "8da17601a174cb4029000000000000a37365713ea46d6f6465a8747261636b696e67a4736c6f7401a3706964cd1092a4686f7374a570692d7232a872656a656374656403a26578cb3f847ae147ae147ba26579cbbf947ae147ae147ba4726f6c65a97375626c6561646572a2727882a4706f7365cd026ca8736574706f696e74cd0258a5726f626f74a27232"
    ),
    "status_min": (
        "88a17601a174cb3ff0000000000000a373657101a46d6f6465a469646c65a4736c6f74c0a370696400a4686f7374a0a872656a656374656400"
    ),
    "status_twist": (
        "8aa17601a174cb4000000000000000a37365710aa46d6f6465a8747261636b696e67a4736c6f7400a370696407a4686f7374a570692d7231a872656a656374656400a5765f6d7073cb3fc0000000000000ab6f6d6567615f7261647073cbbfe0000000000000"
    ),
    "estop": (
        "84a17601a174cb403e000000000000a6656e67616765c3a5726f626f74c0"
    ),
    "estop_robot": (
        "84a17601a174cb403f000000000000a6656e67616765c2a5726f626f74a27233"
    ),
    "clock": (
        "84a17601a174cb3f947ae147ae147ba373657101a47469636b01"
    ),
    "fault_notice": (
        "86a17601a174cb401deb851eb851eca47469636bcd0176a56661756c7400a46b696e64a46b696c6ca5726f626f74a27231"
    ),
    "fault_request_role": (
        "85a17601a174cb403e000000000000a772657175657374c3a46b696e64a46b696c6ca4726f6c65a66c6561646572"
    ),
    "fault_request": (
        "85a17601a174cb4028000000000000a772657175657374c3a46b696e64a56573746f70aa6475726174696f6e5f73cb4000000000000000"
    ),
    "disturbance_drag": (
        "87a17601a174cb4034000000000000a5726f626f74a27231a46b696e64a464726167a26478cbbfd999999999999aa26479cb0000000000000000aa6475726174696f6e5f73cb4000000000000000"
    ),
    "disturbance_teleport": (
        "8aa17601a174cb4035000000000000a5726f626f74a27231a46b696e64a874656c65706f7274a26478cb0000000000000000a26479cb0000000000000000aa6475726174696f6e5f73cb0000000000000000a178cb3fe0000000000000a179cb3fe0000000000000a57468657461cbc00921fb54442d18"
    ),
    "heartbeat": (
        "87a17601a174cb4059100000000000a3736571cd0191a46e616d65a77072696d617279a6616374697665c3a565706f636802a96c65616465725f7430cb400c000000000000"
    ),
    "poses": (
        "88a17601a174cb4028fae147ae147ba3736571cd0270a6726f626f747392a27231a27232a17892cb3fbf7ced916872b0cb3feccccccccccccda17992cbbfdd2f1a9fbe76c9cbbfd0000000000000a5746865746192cb3ff3333333333333cbbff8000000000000a57374616d70cb4028f5c28f5c28f6"
    ),
    "truths": (
        "88a17601a174cb4029000000000000a3736571cd0271a6726f626f747392a27231a27232a17892cb3fc0000000000000cb3fec000000000000a17992cbbfe0000000000000cbbfd0000000000000a5746865746192cb3ff4000000000000cbbff8000000000000a57374616d70cb4029000000000000"
    ),
    "setpoints": (
        "8da17601a174cb4029000000000000a3736571cd0272a6726f626f747392a27232a27231a4736c6f74920100a4726f6c6592a97375626c6561646572a66c6561646572a57374616765920100a17892cb3feccccccccccccdcb3ff4000000000000a17992cbbfd0000000000000cbbfe0000000000000a57468657461cbbff8000000000000a2767892cb3fb1eb851eb851eccb3fb1eb851eb851eca2767992cb0000000000000000cb0000000000000000a47469636bcd0271"
    ),
    "movers": (
        "89a17601a174cb4029000000000000a373657103a6726f626f747391a27234a17891cb3fe0000000000000"
        "a17991cbbfd0000000000000a2767891cbbfd0000000000000a2767991cb0000000000000000a47469636bcd0271"
    ),
    "host_wheels": (
        "8aa17601a174cb4029000000000000a3736571cd0273a6726f626f747392a27231a27232a76f6d6567615f7292cb4015000000000000cb0000000000000000a76f6d6567615f6c92cb4013000000000000cb0000000000000000a7706f7765725f7292cb3fe0000000000000cb0000000000000000a7706f7765725f6c92cb3fd0000000000000cb0000000000000000a6706f73655f7492cb4028f5c28f5c28f6cbbff0000000000000a47469636bcd0271"
    ),
    "host_status": (
        "8ba17601a174cb4029000000000000a37365713fa3706964cd1093a4686f7374a477732d31a6726f626f747392a27231a27232a46d6f646592a8747261636b696e67a469646c65a4736c6f749200ffa872656a6563746564920002a2657892cb3f847ae147ae147bcb0000000000000000a2657992cbbf947ae147ae147bcb0000000000000000"
    ),
    "host_status_twist": (
        "8ea17601a174cb4000000000000000a37365710ba370696407a4686f7374a477732d31a6726f626f747392a27231a27232a46d6f646592a8747261636b696e67a469646c65a4736c6f749200ffa872656a6563746564920000a2657892cb0000000000000000cb0000000000000000a2657992cb0000000000000000cb0000000000000000ac74776973745f726f626f747391a27231a5765f6d707391cb3fc0000000000000ab6f6d6567615f726164707391cbbfe0000000000000"
    ),
    "coordinator_status": (
        "de0017a17601a174cb4029000000000000a37365713fa46d6f6465a86c6f636b73746570a872656a656374656402a772656a6563747381ae706f73652d6d616c666f726d656402af696e7465726e616c5f6572726f727300a2727882a5636c6f636bcd0271a4706f7365cd04e2a46e616d65a46d61696ea4726f6c65a6616374697665a565706f636801a974616b656f7665727301a973746570646f776e7300a57469636b73cd0271a5616c69766592a27231a27232aa61737369676e6d656e7482a2723100a2723201a66c6561646572a27231ab6573746f705f666c656574c2ac6573746f705f726f626f747391a27232a3706964cd1094a4686f7374a477732d31ab7469636b5f7035305f6d73cb3fd0000000000000ab7469636b5f6d61785f6d73cb3ff8000000000000"
    ),
    "plant_status": (
        "de0015a17601a174cb4029000000000000a373657140a46d6f6465a86c6f636b73746570a872656a656374656400a772656a6563747380af696e7465726e616c5f6572726f727300a2727881a6776865656c73cd04e2a57374617465a772756e6e696e67a47469636bcd0271a573696d5f74cb4029000000000000a874696d656f75747300a5616c69766592a27231a27232ac636f6f7264696e61746f727391a46d61696ea96c696e6b5f73656e74cd04e2ac6c696e6b5f64726f7070656403b06d696e5f73657061726174696f6e5f6dcb3fe0000000000000aa636f6c6c6973696f6e7300a66672616d6573cd0177a56261746368c2a769676e6f72656400"
    ),
    "camera_status": (
        "de0016a17601a174cb4029000000000000a373657119a57374617465a772756e6e696e67a86465746563746f72a8617072696c746167a6736f75726365a872656e6465726564a66672616d6573cd0177a764726f7070656402a3667073cb403d800000000000ad6465746563745f7035305f6d73cb4012000000000000ad6465746563745f7039395f6d73cb4022000000000000ad6465746563745f6d61785f6d73cb4028000000000000ae6c6174656e63795f7035305f6d73cb4018000000000000ae6c6174656e63795f7039395f6d73cb4027000000000000ae6c6174656e63795f6d61785f6d73cb402e000000000000aa646574656374696f6e7382a27231cd0177a27232cd0172a97075626c697368656482a27231cd0177a27232cd0171a66d697373657382a2723100a2723205a772656a6563747384a86261645f73697a6500a96475706c696361746500a46a756d7001a7756e6b6e6f776e00aa7265616371756972656400af696e7465726e616c5f6572726f727300ae74727574685f72656a656374656400"
    ),
}
# fmt: on


@pytest.mark.parametrize("name", list(GOLDEN_MESSAGES))
def test_encode_matches_golden_bytes(name: str) -> None:
    assert encode(GOLDEN_MESSAGES[name]).hex() == GOLDEN_HEX[name]


@pytest.mark.parametrize("name", list(GOLDEN_MESSAGES))
def test_golden_bytes_decode_to_the_message(name: str) -> None:
    msg = GOLDEN_MESSAGES[name]
    assert decode(bytes.fromhex(GOLDEN_HEX[name]), type(msg)) == msg


def test_golden_covers_every_type() -> None:
    assert {type(m) for m in GOLDEN_MESSAGES.values()} == set(MESSAGE_TYPES)
    assert set(GOLDEN_HEX) == set(GOLDEN_MESSAGES)


def test_wire_map_as_a_generic_decoder_sees_it() -> None:
    assert msgpack.unpackb(bytes.fromhex(GOLDEN_HEX["pose"])) == {
        "v": 1,
        "t": 12.48,
        "seq": 624,
        "x": 0.123,
        "y": -0.456,
        "theta": 1.2,
        "robot": "r1",
    }
    assert list(msgpack.unpackb(bytes.fromhex(GOLDEN_HEX["status"]))["rx"]) == ["pose", "setpoint"]
    assert msgpack.unpackb(bytes.fromhex(GOLDEN_HEX["estop"])) == {
        "v": 1,
        "t": 30.0,
        "engage": True,
        "robot": None,
    }


def test_clock_bytes_assembled_from_the_msgpack_spec() -> None:
    """The Clock golden, built by hand from the MessagePack spec (no msgpack library involved)."""

    def fixstr(s: str) -> bytes:
        return bytes([0xA0 | len(s)]) + s.encode()

    expected = (
        b"\x84"  # fixmap, 4 entries
        + fixstr("v")
        + b"\x01"  # positive fixint 1
        + fixstr("t")
        + b"\xcb"
        + struct.pack(">d", 0.02)  # float 64, big endian
        + fixstr("seq")
        + b"\x01"
        + fixstr("tick")
        + b"\x01"
    )
    assert encode(GOLDEN_MESSAGES["clock"]) == expected
    assert expected.hex() == GOLDEN_HEX["clock"]


def test_twist_fields_as_a_generic_decoder_sees_them() -> None:
    """The estimator's twist (issue 29) as plain MessagePack: float64 0.125 and -0.5 under the
    keys `v_mps` and `omega_radps`; the older goldens, without them, still decode (above)."""
    st = msgpack.unpackb(bytes.fromhex(GOLDEN_HEX["status_twist"]))
    assert (st["v_mps"], st["omega_radps"]) == (0.125, -0.5)
    assert bytes.fromhex(GOLDEN_HEX["status_twist"]).endswith(
        b"\xa5v_mps\xcb" + bytes.fromhex("3fc0000000000000")
        + b"\xabomega_radps\xcb" + bytes.fromhex("bfe0000000000000")
    )  # fmt: skip
    hb = msgpack.unpackb(bytes.fromhex(GOLDEN_HEX["host_status_twist"]))
    assert (hb["twist_robots"], hb["v_mps"], hb["omega_radps"]) == (["r1"], [0.125], [-0.5])
