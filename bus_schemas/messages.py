"""The messages of the bus contract, version 1: one declarative table per message type.

Each class below is that table: the decorator gives the message's name (= key leaf), publisher and
whether it is periodic; each field gives its wire type, unit, range or enum, presence and meaning.
bus_schemas.spec compiles encode/decode from it and bus_schemas.docs renders docs/bus.md from it.

Common fields: `v` (schema version, 1), `t` (float s: sim time in lockstep, the publisher's
``time.monotonic()`` in realtime), and on periodic messages `seq` (+1 per message of that key).
Units: m, s, rad, rad/s; angles wrapped to (-pi, pi]. Construct with keywords:
``Pose(t=1.5, seq=7, x=0.1, y=0.2, theta=0.0)``.
"""

from __future__ import annotations

import secrets
from collections.abc import Mapping
from dataclasses import dataclass, field

from bus_schemas import keys
from bus_schemas.messages_batch import (
    Movers,
    PoseBatch,
    SetpointBatch,
    StatusBatch,
    TruthBatch,
    WheelsBatch,
)
from bus_schemas.messages_fault import Fault
from bus_schemas.messages_fields import (
    _PARENT,
    _POSE_THETA,
    _POSE_X,
    _POSE_Y,
    _ROLE,
    _SEQ,
    _SLOT,
    _SLOT_THETA,
    _SLOT_VX,
    _SLOT_VY,
    _SLOT_X,
    _SLOT_Y,
    _STAGE,
    _T,
    _V,
    _X,
    _Y,
    DisturbanceKind,
    LeaderMode,
    ReshapeSource,
    Role,
    ShapeKind,
)
from bus_schemas.messages_operator import (
    SLOTS_MAX,
    SPACING_MAX_M,
    CmdVel,
    Goal,
    Obstacle,
    Path,
    Shape,
)
from bus_schemas.messages_status import CameraStatus, CoordinatorStatus, PlantStatus
from bus_schemas.modes import Mode
from bus_schemas.spec import DURATION_MAX_S as _DUR
from bus_schemas.spec import EPOCH_MAX as _EPOCH_MAX
from bus_schemas.spec import POSITION_MAX_M as _POS
from bus_schemas.spec import SPEED_MAX_MPS as _SPEED
from bus_schemas.spec import TIME_MAX_S as _TMAX
from bus_schemas.spec import TURN_RATE_MAX_RADPS as _TURN
from bus_schemas.spec import WHEEL_RATE_MAX_RADPS as _WHEEL
from bus_schemas.spec import (
    RequiredWhen,
    SameLength,
    Together,
    f_angle,
    f_bool,
    f_count_map,
    f_enum,
    f_float,
    f_float_list,
    f_int,
    f_name,
    f_robot_id,
    f_robot_id_list,
    f_slot,
    f_str,
    message,
    spec_of,
)


@message(name=keys.LEADER, publisher="coordinator", periodic=True)
@dataclass(frozen=True, slots=True, kw_only=True)
class Leader:
    """State of the virtual leader (a unicycle, eqs 1-3), sampled from its trajectory at `t`."""

    v: int = field(default=1, metadata=_V)
    t: float = field(metadata=_T)
    seq: int = field(metadata=_SEQ)
    x: float = field(metadata=_X)
    y: float = field(metadata=_Y)
    theta: float = field(metadata=f_angle("heading of the virtual leader"))
    v_mps: float = field(
        metadata=f_float("forward speed of the virtual leader", "m/s", lo=-_SPEED, hi=_SPEED)
    )
    omega_radps: float = field(
        metadata=f_float("turn rate of the virtual leader", "rad/s", lo=-_TURN, hi=_TURN)
    )
    tick: int | None = field(
        default=None,
        metadata=f_int("lockstep: the clock `tick` this leader state answers (sent last)"),
    )
    # issue 28: what a standby needs to continue this leader at a takeover (all absent from an
    # older coordinator, which only ran scripts: mode script, progress t - leader_t0, rate 1)
    mode: str | None = field(default=None, metadata=f_enum("what drives the leader", LeaderMode))
    progress_s: float | None = field(
        default=None,
        metadata=f_float(
            "progress time of the scripted trajectory (advances at `rate`); absent: the leader "
            "is the script at `t - leader_t0` (the heartbeat's), as it was from the start",
            "s",
            lo=-_TMAX,
            hi=_TMAX,
        ),
    )
    rate: float | None = field(
        default=None,
        metadata=f_float(
            "progress rate (1: full speed; < 1: waiting for the team)",
            "",
            lo=0.0,
            hi=1.0,
        ),
    )
    target: int | None = field(
        default=None,
        metadata=f_int("mode goal/path: index of the next waypoint", hi=1023),
    )
    deadman: bool | None = field(
        default=None, metadata=f_bool("mode teleop: the deadman has tripped (no recent twist)")
    )
    shape: str | None = field(
        default=None,
        metadata=f_enum("the shape the formation was last reshaped into (absent: none)", ShapeKind),
    )
    reshape: float | None = field(
        default=None,
        metadata=f_float(
            "fraction of the running reshape done (absent: none running)", "", lo=0.0, hi=1.0
        ),
    )
    # the running reshape as a standby needs it to continue it at a takeover (present while one
    # runs; coordinator.core.reshaping)
    slots: int | None = field(
        default=None,
        metadata=f_int("number of slots the running reshape ends with", lo=1, hi=SLOTS_MAX),
    )
    spacing_m: float | None = field(
        default=None,
        metadata=f_float("spacing of the running reshape's shape", "m", lo=0.0, hi=SPACING_MAX_M),
    )
    reshape_from: str | None = field(
        default=None,
        metadata=f_enum("what the running reshape started from", ReshapeSource),
    )
    reshape_t0: float | None = field(
        default=None,
        metadata=f_float(
            "start of the running reshape (the clock of `t`)", "s", lo=-_TMAX, hi=_TMAX
        ),
    )
    reshape_s: float | None = field(
        default=None,
        metadata=f_float("transition time of the running reshape", "s", lo=0.0, hi=_DUR),
    )


@message(name=keys.SLOT, publisher="coordinator", periodic=True)
@dataclass(frozen=True, slots=True, kw_only=True)
class Slot:
    """State of one formation slot (eqs 1-5 with feed-forward), whoever is assigned to it."""

    v: int = field(default=1, metadata=_V)
    t: float = field(metadata=_T)
    seq: int = field(metadata=_SEQ)
    slot: int = field(metadata=_SLOT)
    role: str = field(metadata=_ROLE)
    stage: int = field(metadata=_STAGE)
    parent: int | None = field(metadata=_PARENT)
    x: float = field(metadata=_SLOT_X)
    y: float = field(metadata=_SLOT_Y)
    theta: float = field(metadata=_SLOT_THETA)
    vx: float = field(metadata=_SLOT_VX)
    vy: float = field(metadata=_SLOT_VY)
    tick: int | None = field(
        default=None, metadata=f_int("lockstep: the clock `tick` this slot state was computed on")
    )


@message(name=keys.SETPOINT, publisher="coordinator", periodic=True)
@dataclass(frozen=True, slots=True, kw_only=True)
class Setpoint:
    """The slot assigned to one robot: the slot's fields plus the robot's id.

    `(x, y)` is where the robot's reference point (eqs 10-11, offset l ahead of the axle) should
    be, `(vx, vy)` its feed-forward velocity for the tracking law (eqs 21-22).
    """

    v: int = field(default=1, metadata=_V)
    t: float = field(metadata=_T)
    seq: int = field(metadata=_SEQ)
    robot: str = field(metadata=f_robot_id("robot this setpoint is for (= the key's id)"))
    slot: int = field(metadata=_SLOT)
    role: str = field(metadata=_ROLE)
    stage: int = field(metadata=_STAGE)
    parent: int | None = field(metadata=_PARENT)
    x: float = field(metadata=_SLOT_X)
    y: float = field(metadata=_SLOT_Y)
    theta: float = field(metadata=_SLOT_THETA)
    vx: float = field(metadata=_SLOT_VX)
    vy: float = field(metadata=_SLOT_VY)
    tick: int | None = field(
        default=None, metadata=f_int("lockstep: the clock `tick` this setpoint was computed on")
    )


@message(name=keys.ASSIGNMENT, publisher="coordinator", periodic=True)
@dataclass(frozen=True, slots=True, kw_only=True)
class Assignment:
    """The current role assignment: which robot holds which slot."""

    v: int = field(default=1, metadata=_V)
    t: float = field(metadata=_T)
    seq: int = field(metadata=_SEQ)
    leader: str | None = field(
        metadata=f_robot_id("robot holding slot 0 (the leader), nil if none", nullable=True)
    )
    robots: Mapping[str, int] = field(
        metadata=f_count_map(
            "robot id -> slot number, for every assigned robot (encoded sorted by id)",
            key_pattern=keys.ROBOT_ID_PATTERN,
            value_hi=keys.MAX_SLOT,
        )
    )


@message(
    name=keys.POSE,
    publisher="localization (the plant's camera emulation or a tracker)",
    periodic=True,
)
@dataclass(frozen=True, slots=True, kw_only=True)
class Pose:
    """Measured pose of a robot's axle centre. `t` is the measurement (capture) time."""

    v: int = field(default=1, metadata=_V)
    t: float = field(metadata=_T)
    seq: int = field(metadata=_SEQ)
    x: float = field(metadata=_POSE_X)
    y: float = field(metadata=_POSE_Y)
    theta: float = field(metadata=_POSE_THETA)
    robot: str | None = field(default=None, metadata=f_robot_id("robot measured (= the key's id)"))
    pub_t: float | None = field(
        default=None,
        metadata=f_float(
            "publication time, same clock as `t` (receivers estimate the clock offset from it)",
            "s",
            lo=0.0,
            hi=_TMAX,
        ),
    )


@message(name=keys.TRUTH, publisher="plant only", periodic=True)
@dataclass(frozen=True, slots=True, kw_only=True)
class Truth:
    """True pose of a simulated robot's axle centre (for metrics; controllers must not use it)."""

    v: int = field(default=1, metadata=_V)
    t: float = field(metadata=_T)
    seq: int = field(metadata=_SEQ)
    x: float = field(metadata=_POSE_X)
    y: float = field(metadata=_POSE_Y)
    theta: float = field(metadata=_POSE_THETA)
    robot: str | None = field(default=None, metadata=f_robot_id("robot (= the key's id)"))


_CLAIM = ("ux", "uy", "w", "accel")


@message(name=keys.WHEELS, publisher="agent", periodic=True, rules=(Together(_CLAIM),))
@dataclass(frozen=True, slots=True, kw_only=True)
class Wheels:
    """Wheel command of one robot (eq 8 after saturation); power = omega / max wheel speed.

    A robot with a motion bound (`safety_filter.accel_bound_mps2`) adds its motion claim
    (`ux`, `uy`, `w`, `accel`, all or none): from `t` on its firmware changes the command's
    body twist (v, l omega) by at most `accel` times the elapsed time, in every mode; its
    neighbours' safety filters extrapolate it with this velocity
    (robot_agent/core/neighbour_motion.py).
    """

    v: int = field(default=1, metadata=_V)
    t: float = field(metadata=_T)
    seq: int = field(metadata=_SEQ)
    omega_r: float = field(
        metadata=f_float("right wheel angular speed command", "rad/s", lo=-_WHEEL, hi=_WHEEL)
    )
    omega_l: float = field(
        metadata=f_float("left wheel angular speed command", "rad/s", lo=-_WHEEL, hi=_WHEEL)
    )
    power_r: float = field(
        metadata=f_float("right wheel command as a fraction of max speed", "1", lo=-1.0, hi=1.0)
    )
    power_l: float = field(
        metadata=f_float("left wheel command as a fraction of max speed", "1", lo=-1.0, hi=1.0)
    )
    pose_t: float | None = field(
        metadata=f_float(
            "`t` of the pose this command was computed from; nil if no pose was used (idle)",
            "s",
            lo=0.0,
            hi=_TMAX,
            nullable=True,
        )
    )
    tick: int | None = field(
        default=None, metadata=f_int("lockstep: the clock `tick` this command answers")
    )
    saturated: bool | None = field(
        default=None, metadata=f_bool("the wheel speeds were scaled down to the limit")
    )
    mode: str | None = field(
        default=None, metadata=f_enum("firmware mode after the step of this command", Mode)
    )
    ux: float | None = field(
        default=None,
        metadata=f_float(
            "motion claim: the reference point's velocity this command gives, x (world)",
            "m/s",
            lo=-_SPEED,
            hi=_SPEED,
        ),
    )
    uy: float | None = field(
        default=None,
        metadata=f_float(
            "motion claim: the reference point's velocity this command gives, y (world)",
            "m/s",
            lo=-_SPEED,
            hi=_SPEED,
        ),
    )
    w: float | None = field(
        default=None,
        metadata=f_float(
            "motion claim: the turn rate this command gives", "rad/s", lo=-1000.0, hi=1000.0
        ),
    )
    accel: float | None = field(
        default=None,
        metadata=f_float(
            "motion claim: the bound the firmware enforces on the body twist's change",
            "m/s^2",
            lo=0.0,
            hi=100.0,
        ),
    )


_TWIST = ("v_mps", "omega_radps")


@message(
    name=keys.STATUS,
    publisher="agent",
    periodic=True,
    rate=">= 5 Hz",
    rules=(Together(_TWIST),),
)
@dataclass(frozen=True, slots=True, kw_only=True)
class Status:
    """Health of one robot agent."""

    v: int = field(default=1, metadata=_V)
    t: float = field(metadata=_T)
    seq: int = field(metadata=_SEQ)
    mode: str = field(metadata=f_enum("firmware mode", Mode))
    slot: int | None = field(metadata=f_slot("assigned slot, nil if none", nullable=True))
    pid: int = field(metadata=f_int("OS process id of the agent (0 if none)", hi=2**31 - 1))
    host: str = field(metadata=f_str("host name the agent runs on"))
    rejected: int = field(metadata=f_int("count of received messages rejected by decode"))
    ex: float | None = field(
        default=None,
        metadata=f_float(
            "tracking error along x (eq 17), setpoint - ref. point", "m", lo=-2 * _POS, hi=2 * _POS
        ),
    )
    ey: float | None = field(
        default=None,
        metadata=f_float(
            "tracking error along y (eq 18), setpoint - ref. point", "m", lo=-2 * _POS, hi=2 * _POS
        ),
    )
    role: str | None = field(default=None, metadata=f_enum("role of the assigned slot", Role))
    rx: Mapping[str, int] | None = field(
        default=None, metadata=f_count_map("message name -> count of messages received")
    )
    robot: str | None = field(default=None, metadata=f_robot_id("robot (= the key's id)"))
    rejects: Mapping[str, int] | None = field(
        default=None,
        metadata=f_count_map(
            "`<message>-<reason>` -> count of inputs dropped (decode reasons, `misaddressed`, "
            "`quarantine` after a resume, ...); the values sum to `rejected`"
        ),
    )
    filter: Mapping[str, int] | None = field(
        default=None,
        metadata=f_count_map(
            "safety filter counters: ticks, active, violations, infeasible, tiebreaks, "
            "tiebreak_active (0/1), rescaled, rejected, constraints"
        ),
    )
    min_clearance_m: float | None = field(
        default=None,
        metadata=f_float(
            "safety filter: least barrier value seen (nil while none in range)",
            "m",
            lo=-2 * _POS,
            hi=2 * _POS,
        ),
    )
    # issue 29: the estimator's twist, for a ROS 2 odometry (formation/live/ros2_bridge.py)
    v_mps: float | None = field(
        default=None,
        metadata=f_float(
            "estimator: forward speed of the axle centre (body frame, eq 9's v) at `t`; absent: "
            "unknown (no estimator, no valid estimate)",
            "m/s",
            lo=-_SPEED,
            hi=_SPEED,
        ),
    )
    omega_radps: float | None = field(
        default=None,
        metadata=f_float(
            "estimator: turn rate of the robot (eq 9's omega) at `t`; absent with `v_mps`",
            "rad/s",
            lo=-_TURN,
            hi=_TURN,
        ),
    )


ESTOP_ID_MAX = 2**63 - 1
"""The largest e-stop engagement id (``Estop.id`` is in [1, 2^63-1])."""


@message(name=keys.ESTOP, publisher="operator / tools", periodic=False)
@dataclass(frozen=True, slots=True, kw_only=True)
class Estop:
    """Engage or release the emergency stop of the whole fleet or of one robot."""

    v: int = field(default=1, metadata=_V)
    t: float = field(metadata=_T)
    engage: bool = field(metadata=f_bool("true: stop (wheels zero, latched); false: release"))
    robot: str | None = field(
        metadata=f_robot_id("robot to stop; nil = every robot of the fleet", nullable=True)
    )
    id: int | None = field(
        default=None,
        metadata=f_int(
            "engagement id: on an engage, a fresh random id (`new_estop_id`), the same in every "
            "copy of that engage; absent on a release (or from an older sender). In a query "
            "answer on this key (the coordinators' latched state): with `engage` true, an "
            "engagement holding the scope (absent: one without an id); with `engage` false, "
            "an engagement the coordinator saw released (its release record; only such a "
            "record releases an agent, docs/faults.md); in an agent's answer on "
            "`estop/held/<name>`: an engagement it holds (never a release)",
            lo=1,
            hi=ESTOP_ID_MAX,
        ),
    )


def new_estop_id() -> int:
    """A fresh random engagement id for an ``Estop`` that engages, in [1, 2^63-1]."""
    while True:
        eid = secrets.randbits(63)
        if eid:
            return eid


_ENC = ("enc_robots", "enc_wr", "enc_wl")
_CLAIMS = ("claim_robots", "claim_t", "claim_ux", "claim_uy", "claim_w", "claim_accel")


@message(
    name=keys.CLOCK,
    publisher="plant, lockstep only",
    periodic=True,
    rules=(Together(_ENC), SameLength(_ENC), Together(_CLAIMS), SameLength(_CLAIMS)),
)
@dataclass(frozen=True, slots=True, kw_only=True)
class Clock:
    """Lockstep tick: the plant advanced to sim time `t`; agents answer with Wheels(tick=...).

    With the plant's encoder emulation (scenario `[plant] encoder_counts_per_rev > 0`) the clock
    carries each robot's emulated encoder reading of this tick (`enc_*`): the firmware's
    `wheel_speeds`, as the in-process simulator hands them over. A real robot reads its own
    encoders (the motor backend); a realtime plant emulates none.
    """

    v: int = field(default=1, metadata=_V)
    t: float = field(metadata=_T)
    seq: int = field(metadata=_SEQ)
    tick: int = field(metadata=f_int("step number of the simulation"))
    tracking: tuple[str, ...] | None = field(
        default=None,
        metadata=f_robot_id_list(
            "robots whose wheels answering the previous tick said mode `tracking` (for the "
            "safety filter's cooperative neighbours)"
        ),
    )
    enc_robots: tuple[str, ...] | None = field(
        default=None,
        metadata=f_robot_id_list("robots whose encoder speeds follow (`enc_wr`, `enc_wl`)"),
    )
    enc_wr: tuple[float, ...] | None = field(
        default=None,
        metadata=f_float_list(
            "right wheel speed each encoder measured, mean over the tick before `t`",
            "rad/s",
            lo=-_WHEEL,
            hi=_WHEEL,
        ),
    )
    enc_wl: tuple[float, ...] | None = field(
        default=None,
        metadata=f_float_list(
            "left wheel speed each encoder measured, mean over the tick before `t`",
            "rad/s",
            lo=-_WHEEL,
            hi=_WHEEL,
        ),
    )
    claim_robots: tuple[str, ...] | None = field(
        default=None,
        metadata=f_robot_id_list(
            "robots whose wheels answering the previous tick carried a motion claim (`claim_*`"
            " follow: that message's `t`, `ux`, `uy`, `w`, `accel`)"
        ),
    )
    claim_t: tuple[float, ...] | None = field(
        default=None, metadata=f_float_list("each claim's `t`", "s", lo=0.0, hi=_TMAX)
    )
    claim_ux: tuple[float, ...] | None = field(
        default=None, metadata=f_float_list("each claim's `ux`", "m/s", lo=-_SPEED, hi=_SPEED)
    )
    claim_uy: tuple[float, ...] | None = field(
        default=None, metadata=f_float_list("each claim's `uy`", "m/s", lo=-_SPEED, hi=_SPEED)
    )
    claim_w: tuple[float, ...] | None = field(
        default=None, metadata=f_float_list("each claim's `w`", "rad/s", lo=-1000.0, hi=1000.0)
    )
    claim_accel: tuple[float, ...] | None = field(
        default=None, metadata=f_float_list("each claim's `accel`", "m/s^2", lo=0.0, hi=100.0)
    )


@message(
    name=keys.DISTURBANCE,
    publisher="operator / tools (the plant subscribes)",
    periodic=False,
    rules=(RequiredWhen("kind", DisturbanceKind.TELEPORT.value, ("x", "y", "theta")),),
)
@dataclass(frozen=True, slots=True, kw_only=True)
class Disturbance:
    """Push a simulated robot: drag it by (dx, dy) over duration_s, or teleport it to (x, y, theta).

    Only the plant acts on it (a real robot cannot be teleported).
    """

    v: int = field(default=1, metadata=_V)
    t: float = field(metadata=_T)
    robot: str = field(metadata=f_robot_id("robot to disturb"))
    kind: str = field(
        metadata=f_enum("drag: move by (dx, dy); teleport: jump to (x, y, theta)", DisturbanceKind)
    )
    dx: float = field(
        metadata=f_float("drag displacement along x, world frame", "m", lo=-_POS, hi=_POS)
    )
    dy: float = field(
        metadata=f_float("drag displacement along y, world frame", "m", lo=-_POS, hi=_POS)
    )
    duration_s: float = field(
        metadata=f_float("time over which the drag is applied (0 = at once)", "s", lo=0.0, hi=_DUR)
    )
    x: float | None = field(
        default=None, metadata=f_float("teleport target x", "m", lo=-_POS, hi=_POS)
    )
    y: float | None = field(
        default=None, metadata=f_float("teleport target y", "m", lo=-_POS, hi=_POS)
    )
    theta: float | None = field(default=None, metadata=f_angle("teleport target heading"))


@message(
    name=keys.HEARTBEAT, publisher="coordinator (each instance, active or standby)", periodic=True
)
@dataclass(frozen=True, slots=True, kw_only=True)
class Heartbeat:
    """Application heartbeat of a coordinator instance, for standby takeover."""

    v: int = field(default=1, metadata=_V)
    t: float = field(metadata=_T)
    seq: int = field(metadata=_SEQ)
    name: str = field(metadata=f_name("coordinator instance name (= the key's name)"))
    active: bool = field(metadata=f_bool("this instance is the one publishing setpoints"))
    epoch: int = field(metadata=f_int("leadership epoch, +1 at every takeover", hi=_EPOCH_MAX))
    leader_t0: float = field(
        metadata=f_float(
            "time origin of the virtual-leader trajectory (same clock as t)",
            "s",
            lo=-_TMAX,
            hi=_TMAX,
        )
    )


Message = (
    Leader
    | Slot
    | Setpoint
    | Assignment
    | Pose
    | Truth
    | Wheels
    | Status
    | Estop
    | Clock
    | Disturbance
    | Heartbeat
    | PoseBatch
    | TruthBatch
    | SetpointBatch
    | Movers
    | WheelsBatch
    | StatusBatch
    | CoordinatorStatus
    | PlantStatus
    | CameraStatus
    | CmdVel
    | Goal
    | Path
    | Shape
    | Obstacle
    | Fault
)
"""Any bus message."""

MESSAGE_TYPES: tuple[type[Message], ...] = (
    Leader,
    Slot,
    Setpoint,
    Assignment,
    Pose,
    Truth,
    Wheels,
    Status,
    Estop,
    Clock,
    Disturbance,
    Heartbeat,
    PoseBatch,
    TruthBatch,
    SetpointBatch,
    Movers,
    WheelsBatch,
    StatusBatch,
    CoordinatorStatus,
    PlantStatus,
    CameraStatus,
    CmdVel,
    Goal,
    Path,
    Shape,
    Obstacle,
    Fault,
)

BATCH_CHUNK = 256
"""Entries per batched message that publishers send (a larger fleet takes several messages):
keeps every payload far below the 64 KiB limit (a 256-robot setpoint batch is ~16 KB)."""

_BY_NAME: dict[str, type[Message]] = {spec_of(cls).name: cls for cls in MESSAGE_TYPES}


def message_type(name: str) -> type[Message] | None:
    """The message type of a key leaf / message name (``"pose"`` -> Pose), or None."""
    return _BY_NAME.get(name)


def message_type_for_key(key: str) -> type[Message] | None:
    """The message type published on a concrete key, or None (liveliness token, unknown key)."""
    info = keys.parse_key(key)
    if info is None:
        return None
    cls = _BY_NAME.get(info.leaf)
    if cls is None:
        return None
    # A robot leaf must be a robot key and vice versa (e.g. formation/f/pose is not a key).
    is_robot_key = info.robot is not None
    return cls if is_robot_key == ("{robot}" in spec_of(cls).key) else None
