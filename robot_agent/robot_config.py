"""Per-robot configuration file (TOML): identity, firmware parameters, Zenoh and motors.

One file per robot, ``/etc/formation/<id>.toml`` on the robot (deploy/config/r1.example.toml
is the annotated template). Layout::

    robot_id = "r1"          # [a-z0-9_-]+, the <id> of every bus key of this robot
    fleet = "demo"           # [a-z0-9_-]+, the <fleet> of every bus key (default "demo")

    [geometry]   # robot_agent.params.RobotGeometry fields (m, rad/s)
    [gains]      # robot_agent.params.TrackingGains fields
    [repulsion]  # robot_agent.params.RepulsionParams fields
    [safety]     # robot_agent.params.SafetyParams fields (s)
    [safety_filter]  # robot_agent.params.SafetyFilterParams fields (barrier-certificate filter)

    [arena]      # optional: the rectangle the robot's body stays inside (m)
    x_min = -2.0
    y_min = -1.5
    x_max = 2.0
    y_max = 1.5

    [[obstacle]] # optional, any number: static obstacles the safety filter keeps clear of
    kind = "circle"                       # x, y, radius_m
    x = 0.5
    y = 0.0
    radius_m = 0.1
    [[obstacle]]
    kind = "segment"                      # x1, y1, x2, y2, radius_m (default 0: a thin wall)
    x1 = -1.0
    y1 = 1.0
    x2 = 1.0
    y2 = 1.0
    [[obstacle]]
    kind = "polygon"                      # points = [[x, y], ...] (>= 3), its closed outline
    points = [[1.0, -1.0], [1.2, -1.0], [1.2, -0.8]]
    [estimator]  # robot_agent.params.EstimatorParams fields (pose estimator, extrapolation)

    [zenoh]
    mode = "client"                       # "client" (default) or "peer"
    endpoints = ["tls/coordinator.local:7447"]
    config_file = "/etc/formation/zenoh/robot-mtls.json5"   # optional zenoh json5 file

    [motor]
    backend = "roboclaw"                  # "bus" (simulation), "roboclaw" or "ros2"
    port = "/dev/roboclaw"                # roboclaw only: RoboClawConfig fields
    ...

Every parameter section is optional and every key in it too: a missing key keeps the
dataclass default. The sections and their keys are read from the dataclasses themselves
(``dataclasses.fields``), so a parameter added to ``robot_agent.params`` is configurable
without touching this module. Values are checked for unknown keys, types and ranges; every
problem is reported (not only the first), each naming the offending field, e.g.
``geometry.wheel_radius_m: expected a number, got 'big' (str)``.

``check_config(path)`` returns those problems as a list (empty = valid), for
``formation agent --check-config FILE``; ``load_robot_config(path)`` returns the parsed
:class:`RobotConfig` or raises :class:`ConfigError` carrying the same list.
"""

from __future__ import annotations

import dataclasses
import math
import re
import tomllib
import typing
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from robot_agent.motors.roboclaw import RoboClawConfig
from robot_agent.motors.ros2 import Ros2MotorConfig
from robot_agent.params import AgentConfig, Arena, CircleObstacle, SegmentObstacle, WorldMap

from .plausible import (
    PLAUSIBLE,
)

__all__ = [
    "ID_PATTERN",
    "ConfigError",
    "MotorConfig",
    "RobotConfig",
    "ZenohConfig",
    "check_config",
    "load_robot_config",
    "robot_config_from_dict",
]

ID_PATTERN = re.compile(r"[a-z0-9_-]+")
"""Robot ids and fleet names (bus contract): lower-case letters, digits, '_' and '-'."""

ZENOH_MODES = ("client", "peer")
MOTOR_BACKENDS = ("bus", "roboclaw", "ros2")
_ENDPOINT = re.compile(r"[a-z][a-z0-9-]*/\S+")


class ConfigError(ValueError):
    """A robot configuration file is invalid; ``problems`` lists every reason."""

    def __init__(self, source: str, problems: list[str]) -> None:
        self.source = source
        self.problems = list(problems)
        super().__init__(f"{source}: invalid robot config:\n  " + "\n  ".join(self.problems))


@dataclass(frozen=True, slots=True)
class ZenohConfig:
    """How the agent's Zenoh session connects.

    Attributes:
        mode: "client" (connect to the fleet router only; the deployment default) or "peer".
        endpoints: endpoints to connect to, e.g. ``"tls/coordinator.local:7447"``; when a
            ``config_file`` is given too, these replace its ``connect/endpoints``.
        config_file: a Zenoh json5 configuration (TLS certificates, timeouts), absolute
            (relative paths in the TOML file are resolved against the TOML file's folder).
    """

    mode: str = "client"
    endpoints: tuple[str, ...] = ()
    config_file: str | None = None

    def __post_init__(self) -> None:
        if self.mode not in ZENOH_MODES:
            raise ValueError(f"mode must be one of {ZENOH_MODES}, got {self.mode!r}")
        for endpoint in self.endpoints:
            if not isinstance(endpoint, str) or not _ENDPOINT.fullmatch(endpoint):
                raise ValueError(
                    f"endpoint {endpoint!r} is not of the form <protocol>/<address>, "
                    f"e.g. 'tcp/192.168.1.10:7447'"
                )
        if not self.endpoints and not self.config_file:
            raise ValueError("set endpoints, config_file or both")


@dataclass(frozen=True, slots=True)
class MotorConfig:
    """Which motor backend drives the wheels, and its settings.

    Attributes:
        backend: "bus" (simulation: the wheel message is the output), "roboclaw" or "ros2"
            (a ROS 2 base driven over rmw_zenoh: robot_agent.motors.ros2).
        roboclaw: the RoboClaw settings; required with backend "roboclaw", else None.
        ros2: the ROS 2 base's settings with backend "ros2" (defaults when the section has
            none), else None.
    """

    backend: str = "bus"
    roboclaw: RoboClawConfig | None = None
    ros2: Ros2MotorConfig | None = None

    def __post_init__(self) -> None:
        if self.backend not in MOTOR_BACKENDS:
            raise ValueError(f"backend must be one of {MOTOR_BACKENDS}, got {self.backend!r}")
        if self.backend == "roboclaw" and self.roboclaw is None:
            raise ValueError("backend 'roboclaw' needs its settings (port, ...)")
        if self.backend != "roboclaw" and self.roboclaw is not None:
            raise ValueError(f"backend {self.backend!r} takes no roboclaw settings")
        if self.backend == "ros2" and self.ros2 is None:
            object.__setattr__(self, "ros2", Ros2MotorConfig())
        if self.backend != "ros2" and self.ros2 is not None:
            raise ValueError(f"backend {self.backend!r} takes no ros2 settings")


@dataclass(frozen=True, slots=True)
class RobotConfig:
    """Everything one robot's agent process is configured with.

    Attributes:
        robot_id: this robot's id (``[a-z0-9_-]+``).
        fleet: the fleet name, ``<fleet>`` in every bus key.
        agent: the firmware parameters (geometry, gains, repulsion, safety).
        zenoh: how to connect to the bus.
        motor: which motor backend to use.
        source: the file this was loaded from, or None.
    """

    robot_id: str
    fleet: str
    agent: AgentConfig
    zenoh: ZenohConfig
    motor: MotorConfig
    source: str | None = None


# ---------------------------------------------------------------------- public API


def load_robot_config(path: str | Path, *, check_files: bool = True) -> RobotConfig:
    """Read and validate a robot TOML file; raises :class:`ConfigError` listing every problem.

    ``check_files`` also requires ``zenoh.config_file`` to exist (what a robot needs; a
    template checked elsewhere passes ``False``).
    """
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(str(p), [f"cannot read the file: {exc}"]) from exc
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(str(p), [f"not valid TOML: {exc}"]) from exc
    return robot_config_from_dict(
        data, source=str(p), base_dir=p.resolve().parent, check_files=check_files
    )


def check_config(path: str | Path, *, check_files: bool = True) -> list[str]:
    """Every problem of a robot TOML file, one message each naming its field; [] = valid."""
    try:
        load_robot_config(path, check_files=check_files)
    except ConfigError as exc:
        return exc.problems
    return []


def robot_config_from_dict(
    data: Mapping[str, Any],
    *,
    source: str = "<dict>",
    base_dir: str | Path | None = None,
    check_files: bool = False,
) -> RobotConfig:
    """Validate already-parsed TOML data (the same rules as :func:`load_robot_config`)."""
    problems: list[str] = []
    agent_sections = _agent_sections()
    allowed = ["robot_id", "fleet", *agent_sections, "arena", "obstacle", "zenoh", "motor"]
    for key in data:
        if key not in allowed:
            problems.append(f"{key}: unknown key (allowed: {', '.join(allowed)})")

    robot_id = _identifier(data, "robot_id", None, problems)
    fleet = _identifier(data, "fleet", "demo", problems)

    parts: dict[str, Any] = {}
    for section, cls in agent_sections.items():
        table = _table(data, section, problems)
        if table is not None:
            parts[section] = _build(cls, table, section, problems)
    world = _world(data, problems)
    if world is None:
        parts["world"] = None
    elif world.obstacles or world.arena is not None:
        parts["world"] = world
    agent: AgentConfig | None = None
    if all(v is not None for v in parts.values()):
        try:
            agent = AgentConfig(**parts)
        except (ValueError, TypeError) as exc:
            problems.append(f"agent parameters: {exc}")

    zenoh = _zenoh(data, base_dir, check_files, problems)
    motor = _motor(data, problems)

    if problems or robot_id is None or fleet is None or agent is None:
        raise ConfigError(source, problems or ["invalid configuration"])
    assert zenoh is not None and motor is not None
    return RobotConfig(
        robot_id=robot_id, fleet=fleet, agent=agent, zenoh=zenoh, motor=motor, source=source
    )


# ---------------------------------------------------------------------- sections


def _agent_sections() -> dict[str, type]:
    """AgentConfig's parameter fields: section name -> dataclass (e.g. geometry); the world map
    is read from ``[arena]`` and ``[[obstacle]]`` instead (``_world``)."""
    hints = typing.get_type_hints(AgentConfig)
    return {f.name: hints[f.name] for f in dataclasses.fields(AgentConfig) if f.name != "world"}


_OBSTACLE_KEYS = {
    "circle": ("x", "y", "radius_m"),
    "segment": ("x1", "y1", "x2", "y2", "radius_m"),
    "polygon": ("points", "radius_m"),
}


def _finite_number(value: Any) -> float | None:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    f = float(value)
    return f if math.isfinite(f) else None


def _world(data: Mapping[str, Any], problems: list[str]) -> WorldMap | None:
    """``[arena]`` and ``[[obstacle]]`` as a WorldMap, or None with problems appended."""
    start = len(problems)
    arena: Arena | None = None
    if "arena" in data:
        table = _table(data, "arena", problems)
        if table is not None:
            keys = ("x_min", "y_min", "x_max", "y_max")
            vals: dict[str, float] = {}
            for key in table:
                if key not in keys:
                    problems.append(f"arena.{key}: unknown key (allowed: {', '.join(keys)})")
            for key in keys:
                if key not in table:
                    problems.append(f"arena.{key}: required")
                    continue
                f = _finite_number(table[key])
                if f is None:
                    problems.append(f"arena.{key}: expected a finite number, got {table[key]!r}")
                else:
                    vals[key] = f
            if len(vals) == 4 and len(problems) == start:
                try:
                    arena = Arena(**vals)
                except ValueError as exc:
                    problems.append(f"arena: {exc}")
    obstacles: list[CircleObstacle | SegmentObstacle] = []
    raw = data.get("obstacle", [])
    if not isinstance(raw, list):
        problems.append("obstacle: expected an array of tables [[obstacle]]")
        raw = []
    for j, item in enumerate(raw):
        where = f"obstacle[{j}]"
        if not isinstance(item, Mapping):
            problems.append(f"{where}: expected a table")
            continue
        kind = item.get("kind")
        if kind not in _OBSTACLE_KEYS:
            problems.append(
                f"{where}.kind: must be one of {', '.join(_OBSTACLE_KEYS)}, got {kind!r}"
            )
            continue
        allowed = ("kind", *_OBSTACLE_KEYS[kind])
        bad = False
        for key in item:
            if key not in allowed:
                problems.append(f"{where}.{key}: unknown key (allowed: {', '.join(allowed)})")
                bad = True
        nums: dict[str, float] = {}
        for key in _OBSTACLE_KEYS[kind]:
            if key == "points" or (key == "radius_m" and kind != "circle" and key not in item):
                continue
            if key not in item:
                problems.append(f"{where}.{key}: required")
                bad = True
                continue
            f = _finite_number(item[key])
            if f is None or (key == "radius_m" and f < 0.0):
                problems.append(f"{where}.{key}: expected a finite number (>= 0 for a radius), "
                                f"got {item[key]!r}")  # fmt: skip
                bad = True
            else:
                nums[key] = f
        if bad:
            continue
        if kind == "circle":
            obstacles.append(CircleObstacle(nums["x"], nums["y"], nums["radius_m"]))
        elif kind == "segment":
            obstacles.append(SegmentObstacle(**nums))
        else:
            pts = item.get("points")
            coords: list[tuple[float, float]] = []
            if isinstance(pts, list) and len(pts) >= 3:
                for p in pts:
                    if isinstance(p, list) and len(p) == 2:
                        x, y = _finite_number(p[0]), _finite_number(p[1])
                        if x is not None and y is not None:
                            coords.append((x, y))
            if len(coords) < 3 or len(coords) != len(pts):  # type: ignore[arg-type]
                problems.append(f"{where}.points: expected >= 3 points [x, y] of finite numbers")
                continue
            r = nums.get("radius_m", 0.0)
            for (x1, y1), (x2, y2) in zip(coords, coords[1:] + coords[:1], strict=True):
                obstacles.append(SegmentObstacle(x1, y1, x2, y2, r))
    if len(problems) > start:
        return None
    return WorldMap(obstacles=tuple(obstacles), arena=arena)


def _identifier(
    data: Mapping[str, Any], key: str, default: str | None, problems: list[str]
) -> str | None:
    if key not in data:
        if default is None:
            problems.append(f'{key}: required (e.g. {key} = "r1")')
        return default
    value = data[key]
    if not isinstance(value, str):
        problems.append(f"{key}: expected a string, got {value!r} ({type(value).__name__})")
        return None
    if not ID_PATTERN.fullmatch(value):
        problems.append(f"{key}: {value!r} must match [a-z0-9_-]+ (lower case, no spaces)")
        return None
    return value


def _table(data: Mapping[str, Any], key: str, problems: list[str]) -> Mapping[str, Any] | None:
    value = data.get(key, {})
    if not isinstance(value, Mapping):
        problems.append(f"{key}: expected a table [{key}], got {type(value).__name__}")
        return None
    return value


_BAD = object()

"""Plausible range (inclusive) of every numeric parameter, by dotted field name: a value
outside is refused by ``--check-config`` and the agent (a typo such as ``stale_pose_s = 1e6``
or ``kp = 1e9`` must never reach the wheels). tests/test_robot_config.py checks that every
numeric field of every section has an entry here."""


def _coerce(value: Any, annotation: Any) -> Any:
    """``value`` converted to the field's type, or ``_BAD``. bool is never a number."""
    if annotation is float:
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            f = float(value)
            return f if math.isfinite(f) else _BAD
        return _BAD
    if annotation is int:
        return value if isinstance(value, int) and not isinstance(value, bool) else _BAD
    if annotation is bool:
        return value if isinstance(value, bool) else _BAD
    if annotation is str:
        return value if isinstance(value, str) else _BAD
    return value  # a type this loader does not know: the dataclass validates it


def _type_name(annotation: Any) -> str:
    return {float: "a number", int: "an integer", bool: "true or false", str: "a string"}.get(
        annotation, getattr(annotation, "__name__", str(annotation))
    )


def _build(
    cls: type,
    table: Mapping[str, Any],
    section: str,
    problems: list[str],
    skip: tuple[str, ...] = (),
) -> Any:
    """An instance of dataclass ``cls`` from ``table``, or None with problems appended."""
    hints = typing.get_type_hints(cls)
    fields = [f for f in dataclasses.fields(cls) if f.name not in skip]
    names = [f.name for f in fields]
    start = len(problems)
    kwargs: dict[str, Any] = {}
    for key, value in table.items():
        if key in skip:
            continue
        if key not in names:
            problems.append(f"{section}.{key}: unknown key (allowed: {', '.join([*skip, *names])})")
            continue
        coerced = _coerce(value, hints[key])
        if coerced is _BAD:
            problems.append(
                f"{section}.{key}: expected {_type_name(hints[key])}, "
                f"got {value!r} ({type(value).__name__})"
            )
            continue
        rng = PLAUSIBLE.get(f"{section}.{key}")
        if rng is not None and isinstance(coerced, (int, float)) and not isinstance(coerced, bool):
            lo, hi = rng
            if not lo <= coerced <= hi:
                problems.append(
                    f"{section}.{key}: {value!r} is outside the plausible range [{lo:g}, {hi:g}]"
                )
                continue
        kwargs[key] = coerced
    for f in fields:
        no_default = f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING
        if no_default and f.name not in kwargs and f.name not in table:
            problems.append(f"{section}.{f.name}: required")
    if len(problems) > start:
        return None
    try:
        return cls(**kwargs)
    except (ValueError, TypeError) as exc:
        problems.append(_dotted(section, str(exc), names))
        return None


def _dotted(section: str, message: str, names: list[str]) -> str:
    """``section.field: message`` when the dataclass's message starts with one of its field
    names (they do: ``kp must be > 0``), else ``section: message``."""
    first = re.split(r"[\s:=,(]", message.strip(), maxsplit=1)[0]
    if first in names:
        return f"{section}.{first}: {message}"
    return f"{section}: {message}"


def _zenoh(
    data: Mapping[str, Any], base_dir: str | Path | None, check_files: bool, problems: list[str]
) -> ZenohConfig | None:
    table = _table(data, "zenoh", problems)
    if table is None:
        return None
    if "zenoh" not in data:
        problems.append('zenoh: required (endpoints = ["tcp/<router host>:7447"] or config_file)')
        return None
    start = len(problems)
    allowed = ("mode", "endpoints", "config_file")
    for key in table:
        if key not in allowed:
            problems.append(f"zenoh.{key}: unknown key (allowed: {', '.join(allowed)})")
    mode = table.get("mode", "client")
    if not isinstance(mode, str):
        problems.append(f"zenoh.mode: expected a string, got {mode!r}")
    elif mode not in ZENOH_MODES:
        problems.append(f"zenoh.mode: must be one of {', '.join(ZENOH_MODES)}, got {mode!r}")
    endpoints_raw = table.get("endpoints", [])
    endpoints: list[str] = []
    if not isinstance(endpoints_raw, list):
        problems.append(f"zenoh.endpoints: expected a list of strings, got {endpoints_raw!r}")
    else:
        for i, endpoint in enumerate(endpoints_raw):
            if not isinstance(endpoint, str) or not _ENDPOINT.fullmatch(endpoint):
                problems.append(
                    f"zenoh.endpoints[{i}]: {endpoint!r} is not <protocol>/<address> "
                    f"(e.g. 'tls/192.168.1.10:7447')"
                )
            else:
                endpoints.append(endpoint)
    config_file: str | None = None
    if "config_file" in table:
        raw = table["config_file"]
        if not isinstance(raw, str) or not raw.strip():
            problems.append(f"zenoh.config_file: expected a file path, got {raw!r}")
        else:
            p = Path(raw)
            if not p.is_absolute() and base_dir is not None:
                p = Path(base_dir) / p
            config_file = str(p)
            if check_files and not p.is_file():
                problems.append(f"zenoh.config_file: {config_file} does not exist")
    if len(problems) > start:
        return None
    if not endpoints and config_file is None:
        problems.append("zenoh: set endpoints, config_file or both")
        return None
    return ZenohConfig(mode=str(mode), endpoints=tuple(endpoints), config_file=config_file)


def _motor(data: Mapping[str, Any], problems: list[str]) -> MotorConfig | None:
    table = _table(data, "motor", problems)
    if table is None:
        return None
    backend = table.get("backend", "bus")
    if not isinstance(backend, str) or backend not in MOTOR_BACKENDS:
        problems.append(
            f"motor.backend: must be one of {', '.join(MOTOR_BACKENDS)}, got {backend!r}"
        )
        return None
    if backend == "bus":
        # The other keys are the roboclaw backend's: checked only when it is selected, so a
        # robot config can be switched to the simulated backend by changing one line.
        return MotorConfig(backend="bus")
    if backend == "ros2":
        ros2 = _build(Ros2MotorConfig, table, "motor", problems, skip=("backend",))
        return None if ros2 is None else MotorConfig(backend="ros2", ros2=ros2)
    roboclaw = _build(RoboClawConfig, table, "motor", problems, skip=("backend",))
    if roboclaw is None:
        return None
    return MotorConfig(backend="roboclaw", roboclaw=roboclaw)
