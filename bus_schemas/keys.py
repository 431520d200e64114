"""Zenoh key expressions of the bus contract (docs/bus.md): builders, wildcard patterns, parsing.

Every key lives under ``formation/<fleet>/``. Robot ids match ``[a-z0-9_-]{1,64}``; fleet and
coordinator names match ``[A-Za-z0-9_-]{1,64}`` (no ``/``, ``*``, ``$``, ``?``, ``#``, so a name can
never change the shape of a key or act as a wildcard). Builders raise ValueError for an invalid id
or name; parsers return None for a key that is not one of ours.
"""

from __future__ import annotations

import re
from typing import NamedTuple

ROOT = "formation"
DEFAULT_FLEET = "demo"

ID_MAX_LEN = 64
ROBOT_ID_PATTERN = r"[a-z0-9_-]{1,64}"
NAME_PATTERN = r"[A-Za-z0-9_-]{1,64}"
MAX_SLOT = 65535

_ROBOT_ID_MATCH = re.compile(ROBOT_ID_PATTERN).fullmatch
_NAME_MATCH = re.compile(NAME_PATTERN).fullmatch
_SLOT_MATCH = re.compile(r"0|[1-9][0-9]{0,4}").fullmatch  # canonical decimal, no sign/zeros

# Leaf names: the last segment of a key, also the message names of bus_schemas.messages.
LEADER = "leader"
SLOT = "slot"
SETPOINT = "setpoint"
ASSIGNMENT = "assignment"
POSE = "pose"
TRUTH = "truth"
WHEELS = "wheels"
STATUS = "status"
ESTOP = "estop"
CLOCK = "clock"
DISTURBANCE = "disturbance"
HEARTBEAT = "heartbeat"
POSES = "poses"
SETPOINTS = "setpoints"
TRUTHS = "truths"
HOST_WHEELS = "host_wheels"
HOST_STATUS = "host_status"
ALIVE_ROBOT = "alive_robot"
ALIVE_COORDINATOR = "alive_coordinator"
ALIVE_PLANT = "alive_plant"
COORDINATOR_STATUS = "coordinator_status"
PLANT_STATUS = "plant_status"
CAMERA_STATUS = "camera_status"
ESTOP_HELD = "estop_held"
# the operator's commands to the virtual leader (issue 28; bus_schemas.messages_operator)
CMD_VEL = "cmd_vel"
GOAL = "goal"
PATH = "path"
SHAPE = "shape"
OBSTACLE = "obstacle"
FAULT = "fault"
MOVERS = "movers"

# Key templates (for documentation and str.format); the builders below are the API.
KEY_TEMPLATES: dict[str, str] = {
    LEADER: "formation/{fleet}/leader",
    SLOT: "formation/{fleet}/slot/{slot}",
    SETPOINT: "formation/{fleet}/robot/{robot}/setpoint",
    ASSIGNMENT: "formation/{fleet}/assignment",
    POSE: "formation/{fleet}/robot/{robot}/pose",
    TRUTH: "formation/{fleet}/robot/{robot}/truth",
    WHEELS: "formation/{fleet}/robot/{robot}/wheels",
    STATUS: "formation/{fleet}/robot/{robot}/status",
    ESTOP: "formation/{fleet}/estop",
    CLOCK: "formation/{fleet}/clock",
    DISTURBANCE: "formation/{fleet}/disturbance",
    FAULT: "formation/{fleet}/fault",
    HEARTBEAT: "formation/{fleet}/coordinator/{name}/heartbeat",
    POSES: "formation/{fleet}/poses",
    SETPOINTS: "formation/{fleet}/setpoints",
    TRUTHS: "formation/{fleet}/truths",
    MOVERS: "formation/{fleet}/movers",
    HOST_WHEELS: "formation/{fleet}/host/{name}/wheels",
    HOST_STATUS: "formation/{fleet}/host/{name}/status",
    ALIVE_ROBOT: "formation/{fleet}/alive/robot/{robot}",
    ALIVE_COORDINATOR: "formation/{fleet}/alive/coordinator/{name}",
    ALIVE_PLANT: "formation/{fleet}/alive/plant",
    # the status of the fleet's processes (bus_schemas.messages_status)
    COORDINATOR_STATUS: "formation/{fleet}/coordinator/{name}/status",
    PLANT_STATUS: "formation/{fleet}/plant/status",
    CAMERA_STATUS: "formation/{fleet}/camera/{name}/status",
    # queried, never published: the e-stop engagements an agent (robot id) or agent host (name)
    # holds, answered only while it holds one (robot_agent.core.estop, docs/faults.md)
    ESTOP_HELD: "formation/{fleet}/estop/held/{name}",
    # the operator drives the virtual leader: a teleop twist, a goal, a path (coordinators read)
    CMD_VEL: "formation/{fleet}/operator/cmd_vel",
    GOAL: "formation/{fleet}/operator/goal",
    PATH: "formation/{fleet}/operator/path",
    SHAPE: "formation/{fleet}/operator/shape",
    # a planning obstacle added, moved or removed at run time (issue 27: the coordinator replans)
    OBSTACLE: "formation/{fleet}/operator/obstacle",
}

# Leaves that sit under formation/<fleet>/ directly (no id in the key).
_FLEET_LEAVES = frozenset(
    {LEADER, ASSIGNMENT, ESTOP, CLOCK, DISTURBANCE, FAULT, POSES, SETPOINTS, TRUTHS, MOVERS}
)
# formation/<fleet>/host/<name>/<leaf> -> message name
_HOST_LEAVES = {WHEELS: HOST_WHEELS, STATUS: HOST_STATUS}
# formation/<fleet>/coordinator/<name>/<leaf> -> message name
_COORDINATOR_LEAVES = {HEARTBEAT: HEARTBEAT, STATUS: COORDINATOR_STATUS}
# formation/<fleet>/operator/<leaf>
_OPERATOR_LEAVES = frozenset({CMD_VEL, GOAL, PATH, SHAPE, OBSTACLE})


class KeyInfo(NamedTuple):
    """A parsed key: its fleet, its leaf (message or token name) and the id it carries, if any."""

    fleet: str
    leaf: str
    robot: str | None = None
    slot: int | None = None
    name: str | None = None


# --- validation ----------------------------------------------------------------------------


def is_robot_id(robot: object) -> bool:
    """True if `robot` is a str matching ``[a-z0-9_-]{1,64}``."""
    return type(robot) is str and _ROBOT_ID_MATCH(robot) is not None


def is_name(name: object) -> bool:
    """True if `name` is a valid fleet or coordinator name (``[A-Za-z0-9_-]{1,64}``)."""
    return type(name) is str and _NAME_MATCH(name) is not None


def check_robot_id(robot: str) -> str:
    """Return `robot` unchanged, or raise ValueError if it is not a valid robot id."""
    if not is_robot_id(robot):
        raise ValueError(f"invalid robot id {robot!r}: must match {ROBOT_ID_PATTERN}")
    return robot


def check_fleet(fleet: str) -> str:
    """Return `fleet` unchanged, or raise ValueError if it is not a valid fleet name."""
    if not is_name(fleet):
        raise ValueError(f"invalid fleet name {fleet!r}: must match {NAME_PATTERN}")
    return fleet


def check_name(name: str) -> str:
    """Return a coordinator `name` unchanged, or raise ValueError if it is invalid."""
    if not is_name(name):
        raise ValueError(f"invalid coordinator name {name!r}: must match {NAME_PATTERN}")
    return name


def check_slot(slot: int) -> int:
    """Return `slot` unchanged, or raise ValueError unless it is an int in [0, MAX_SLOT]."""
    if type(slot) is not int or not 0 <= slot <= MAX_SLOT:
        raise ValueError(f"invalid slot {slot!r}: must be an int in [0, {MAX_SLOT}]")
    return slot


def _fleet_prefix(fleet: str) -> str:
    return f"{ROOT}/{check_fleet(fleet)}"


def _robot_key(fleet: str, robot: str, leaf: str) -> str:
    return f"{_fleet_prefix(fleet)}/robot/{check_robot_id(robot)}/{leaf}"


# --- message keys ---------------------------------------------------------------------------


def leader_key(fleet: str) -> str:
    """``formation/<fleet>/leader``: virtual-leader state (coordinator)."""
    return f"{_fleet_prefix(fleet)}/{LEADER}"


def slot_key(fleet: str, k: int) -> str:
    """``formation/<fleet>/slot/<k>``: state of formation slot k (coordinator); 0 = leader."""
    return f"{_fleet_prefix(fleet)}/{SLOT}/{check_slot(k)}"


def setpoint_key(fleet: str, robot: str) -> str:
    """``formation/<fleet>/robot/<id>/setpoint``: the robot's assigned slot (coordinator)."""
    return _robot_key(fleet, robot, SETPOINT)


def assignment_key(fleet: str) -> str:
    """``formation/<fleet>/assignment``: robot -> slot map (coordinator)."""
    return f"{_fleet_prefix(fleet)}/{ASSIGNMENT}"


def pose_key(fleet: str, robot: str) -> str:
    """``formation/<fleet>/robot/<id>/pose``: measured pose (localization)."""
    return _robot_key(fleet, robot, POSE)


def truth_key(fleet: str, robot: str) -> str:
    """``formation/<fleet>/robot/<id>/truth``: simulated true pose (plant only)."""
    return _robot_key(fleet, robot, TRUTH)


def wheels_key(fleet: str, robot: str) -> str:
    """``formation/<fleet>/robot/<id>/wheels``: wheel command (agent)."""
    return _robot_key(fleet, robot, WHEELS)


def status_key(fleet: str, robot: str) -> str:
    """``formation/<fleet>/robot/<id>/status``: agent status (agent, >= 5 Hz)."""
    return _robot_key(fleet, robot, STATUS)


def estop_key(fleet: str) -> str:
    """``formation/<fleet>/estop``: emergency stop for the fleet or one robot (operator)."""
    return f"{_fleet_prefix(fleet)}/{ESTOP}"


def estop_held_key(fleet: str, name: str) -> str:
    """``formation/<fleet>/estop/held/<name>``: the e-stop engagements agent ``name`` (a robot id
    or an agent host's name) holds; a queryable, answered only while it holds one."""
    return f"{_fleet_prefix(fleet)}/{ESTOP}/held/{check_name(name)}"


def clock_key(fleet: str) -> str:
    """``formation/<fleet>/clock``: lockstep tick (plant, lockstep only)."""
    return f"{_fleet_prefix(fleet)}/{CLOCK}"


def disturbance_key(fleet: str) -> str:
    """``formation/<fleet>/disturbance``: drag/teleport a simulated robot (tools -> plant)."""
    return f"{_fleet_prefix(fleet)}/{DISTURBANCE}"


def fault_key(fleet: str) -> str:
    """Scripted faults: the coordinator's notices, the operator's requests."""
    return f"{_fleet_prefix(fleet)}/{FAULT}"


def heartbeat_key(fleet: str, name: str) -> str:
    """``formation/<fleet>/coordinator/<name>/heartbeat``: coordinator heartbeat."""
    return f"{_fleet_prefix(fleet)}/coordinator/{check_name(name)}/{HEARTBEAT}"


def poses_key(fleet: str) -> str:
    """``formation/<fleet>/poses``: batched poses of many robots in one frame (localization)."""
    return f"{_fleet_prefix(fleet)}/{POSES}"


def setpoints_key(fleet: str) -> str:
    """``formation/<fleet>/setpoints``: batched setpoints of many robots (coordinator)."""
    return f"{_fleet_prefix(fleet)}/{SETPOINTS}"


def movers_key(fleet: str) -> str:
    """``formation/<fleet>/movers``: the moving obstacles the coordinator sees (issue 30)."""
    return f"{_fleet_prefix(fleet)}/{MOVERS}"


def truths_key(fleet: str) -> str:
    """``formation/<fleet>/truths``: batched true poses of many robots (plant only)."""
    return f"{_fleet_prefix(fleet)}/{TRUTHS}"


def host_wheels_key(fleet: str, name: str) -> str:
    """``formation/<fleet>/host/<name>/wheels``: wheel commands of an agent host's robots."""
    return f"{_fleet_prefix(fleet)}/host/{check_name(name)}/{WHEELS}"


def coordinator_status_key(fleet: str, name: str) -> str:
    """``formation/<fleet>/coordinator/<name>/status``: status of coordinator instance ``name``."""
    return f"{_fleet_prefix(fleet)}/coordinator/{check_name(name)}/{STATUS}"


def plant_status_key(fleet: str) -> str:
    """``formation/<fleet>/plant/status``: status of the plant simulator."""
    return f"{_fleet_prefix(fleet)}/plant/{STATUS}"


def camera_status_key(fleet: str, name: str) -> str:
    """``formation/<fleet>/camera/<name>/status``: status of camera tracker ``name``."""
    return f"{_fleet_prefix(fleet)}/camera/{check_name(name)}/{STATUS}"


def host_status_key(fleet: str, name: str) -> str:
    """``formation/<fleet>/host/<name>/status``: status of an agent host's robots."""
    return f"{_fleet_prefix(fleet)}/host/{check_name(name)}/{STATUS}"


def cmd_vel_key(fleet: str) -> str:
    """``formation/<fleet>/operator/cmd_vel``: teleop twist for the virtual leader (operator)."""
    return f"{_fleet_prefix(fleet)}/operator/{CMD_VEL}"


def goal_key(fleet: str) -> str:
    """``formation/<fleet>/operator/goal``: drive the virtual leader to a point (operator)."""
    return f"{_fleet_prefix(fleet)}/operator/{GOAL}"


def path_key(fleet: str) -> str:
    """``formation/<fleet>/operator/path``: drive the virtual leader along waypoints (operator)."""
    return f"{_fleet_prefix(fleet)}/operator/{PATH}"


def shape_key(fleet: str) -> str:
    """``formation/<fleet>/operator/shape``: reshape the running formation (operator)."""
    return f"{_fleet_prefix(fleet)}/operator/{SHAPE}"


def obstacle_key(fleet: str) -> str:
    """``formation/<fleet>/operator/obstacle``: a planning obstacle added, moved or removed at
    run time (operator; the coordinator replans, issue 27)."""
    return f"{_fleet_prefix(fleet)}/operator/{OBSTACLE}"


def operator_pattern(fleet: str) -> str:
    """``formation/<fleet>/operator/*``: every operator command (coordinators subscribe)."""
    return f"{_fleet_prefix(fleet)}/operator/*"


# --- liveliness tokens ----------------------------------------------------------------------


def alive_robot_key(fleet: str, robot: str) -> str:
    """``formation/<fleet>/alive/robot/<id>``: liveliness token of a robot's agent."""
    return f"{_fleet_prefix(fleet)}/alive/robot/{check_robot_id(robot)}"


def alive_coordinator_key(fleet: str, name: str) -> str:
    """``formation/<fleet>/alive/coordinator/<name>``: liveliness token of a coordinator."""
    return f"{_fleet_prefix(fleet)}/alive/coordinator/{check_name(name)}"


def alive_plant_key(fleet: str) -> str:
    """``formation/<fleet>/alive/plant``: liveliness token of the plant simulator."""
    return f"{_fleet_prefix(fleet)}/alive/plant"


# --- wildcard patterns (for subscribers) ----------------------------------------------------


def estop_held_pattern(fleet: str) -> str:
    """``formation/<fleet>/estop/held/*``: the e-stop engagements every agent holds (a query)."""
    return f"{_fleet_prefix(fleet)}/{ESTOP}/held/*"


def fleet_pattern(fleet: str) -> str:
    """``formation/<fleet>/**``: every key of a fleet (recorders)."""
    return f"{_fleet_prefix(fleet)}/**"


def robot_pattern(fleet: str, robot: str) -> str:
    """``formation/<fleet>/robot/<id>/*``: every message key of one robot."""
    return f"{_fleet_prefix(fleet)}/robot/{check_robot_id(robot)}/*"


def all_slots_pattern(fleet: str) -> str:
    """``formation/<fleet>/slot/*``."""
    return f"{_fleet_prefix(fleet)}/{SLOT}/*"


def _all_robots(fleet: str, leaf: str) -> str:
    return f"{_fleet_prefix(fleet)}/robot/*/{leaf}"


def all_setpoints_pattern(fleet: str) -> str:
    """``formation/<fleet>/robot/*/setpoint``."""
    return _all_robots(fleet, SETPOINT)


def all_poses_pattern(fleet: str) -> str:
    """``formation/<fleet>/robot/*/pose``."""
    return _all_robots(fleet, POSE)


def all_truth_pattern(fleet: str) -> str:
    """``formation/<fleet>/robot/*/truth``."""
    return _all_robots(fleet, TRUTH)


def all_wheels_pattern(fleet: str) -> str:
    """``formation/<fleet>/robot/*/wheels``."""
    return _all_robots(fleet, WHEELS)


def all_status_pattern(fleet: str) -> str:
    """``formation/<fleet>/robot/*/status``."""
    return _all_robots(fleet, STATUS)


def all_host_wheels_pattern(fleet: str) -> str:
    """``formation/<fleet>/host/*/wheels``: batched wheel commands of every agent host."""
    return f"{_fleet_prefix(fleet)}/host/*/{WHEELS}"


def all_host_status_pattern(fleet: str) -> str:
    """``formation/<fleet>/host/*/status``: batched status of every agent host."""
    return f"{_fleet_prefix(fleet)}/host/*/{STATUS}"


def all_coordinator_status_pattern(fleet: str) -> str:
    """``formation/<fleet>/coordinator/*/status``: the status of every coordinator instance."""
    return f"{_fleet_prefix(fleet)}/coordinator/*/{STATUS}"


def all_camera_status_pattern(fleet: str) -> str:
    """``formation/<fleet>/camera/*/status``: the status of every camera tracker."""
    return f"{_fleet_prefix(fleet)}/camera/*/{STATUS}"


def all_heartbeats_pattern(fleet: str) -> str:
    """``formation/<fleet>/coordinator/*/heartbeat``."""
    return f"{_fleet_prefix(fleet)}/coordinator/*/{HEARTBEAT}"


def alive_robots_pattern(fleet: str) -> str:
    """``formation/<fleet>/alive/robot/*``: liveliness of every agent."""
    return f"{_fleet_prefix(fleet)}/alive/robot/*"


def alive_coordinators_pattern(fleet: str) -> str:
    """``formation/<fleet>/alive/coordinator/*``: liveliness of every coordinator."""
    return f"{_fleet_prefix(fleet)}/alive/coordinator/*"


def alive_pattern(fleet: str) -> str:
    """``formation/<fleet>/alive/**``: every liveliness token of a fleet."""
    return f"{_fleet_prefix(fleet)}/alive/**"


# --- parsing --------------------------------------------------------------------------------


def parse_key(key: str) -> KeyInfo | None:
    """Parse any concrete key of the contract; None if it is not one (or has an invalid id).

    Robot keys with a leaf this version does not know (``formation/<f>/robot/<id>/<leaf>``, leaf
    matching the robot-id alphabet) still parse, so tools can list robots of a newer fleet.
    """
    if type(key) is not str:
        return None
    parts = key.split("/")
    n = len(parts)
    if n < 3 or parts[0] != ROOT or _NAME_MATCH(parts[1]) is None:
        return None
    fleet = parts[1]
    if n == 3:
        return KeyInfo(fleet, parts[2]) if parts[2] in _FLEET_LEAVES else None
    kind = parts[2]
    if kind == "robot" and n == 5:
        robot, leaf = parts[3], parts[4]
        if _ROBOT_ID_MATCH(robot) is None or _ROBOT_ID_MATCH(leaf) is None:
            return None
        return KeyInfo(fleet, leaf, robot=robot)
    if kind == SLOT and n == 4:
        if _SLOT_MATCH(parts[3]) is None:
            return None
        slot = int(parts[3])
        return KeyInfo(fleet, SLOT, slot=slot) if slot <= MAX_SLOT else None
    if kind == "host" and n == 5 and parts[4] in _HOST_LEAVES:
        if _NAME_MATCH(parts[3]) is None:
            return None
        return KeyInfo(fleet, _HOST_LEAVES[parts[4]], name=parts[3])
    if kind == "coordinator" and n == 5 and parts[4] in _COORDINATOR_LEAVES:
        leaf = _COORDINATOR_LEAVES[parts[4]]
        return KeyInfo(fleet, leaf, name=parts[3]) if _NAME_MATCH(parts[3]) else None
    if kind == ESTOP and n == 5 and parts[3] == "held":
        return KeyInfo(fleet, ESTOP_HELD, name=parts[4]) if _NAME_MATCH(parts[4]) else None
    if kind == "operator" and n == 4 and parts[3] in _OPERATOR_LEAVES:
        return KeyInfo(fleet, parts[3])
    if kind == "plant" and n == 4 and parts[3] == STATUS:
        return KeyInfo(fleet, PLANT_STATUS)
    if kind == "camera" and n == 5 and parts[4] == STATUS:
        return KeyInfo(fleet, CAMERA_STATUS, name=parts[3]) if _NAME_MATCH(parts[3]) else None
    if kind == "alive":
        if n == 4 and parts[3] == "plant":
            return KeyInfo(fleet, ALIVE_PLANT)
        if n == 5 and parts[3] == "robot" and _ROBOT_ID_MATCH(parts[4]) is not None:
            return KeyInfo(fleet, ALIVE_ROBOT, robot=parts[4])
        if n == 5 and parts[3] == "coordinator" and _NAME_MATCH(parts[4]) is not None:
            return KeyInfo(fleet, ALIVE_COORDINATOR, name=parts[4])
    return None


def parse_robot_key(key: str) -> tuple[str, str, str] | None:
    """``formation/<fleet>/robot/<id>/<leaf>`` -> ``(fleet, robot, leaf)``; None otherwise."""
    info = parse_key(key)
    if info is None or info.robot is None or info.leaf == ALIVE_ROBOT:
        return None
    return info.fleet, info.robot, info.leaf


def parse_alive_key(key: str) -> tuple[str, str, str | None] | None:
    """A liveliness key -> ``(fleet, kind, id)``, kind in robot/coordinator/plant; None otherwise.

    ``id`` is the robot id, the coordinator name, or None for the plant.
    """
    info = parse_key(key)
    if info is None:
        return None
    if info.leaf == ALIVE_ROBOT:
        return info.fleet, "robot", info.robot
    if info.leaf == ALIVE_COORDINATOR:
        return info.fleet, "coordinator", info.name
    if info.leaf == ALIVE_PLANT:
        return info.fleet, "plant", None
    return None
