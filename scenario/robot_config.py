"""Per-robot configuration file (TOML): identity, firmware parameters, Zenoh and motors.

One file per robot, ``/etc/formation/<id>.toml`` on the robot (deploy/config/r1.example.toml
is the annotated template). Layout::

    robot_id = "r1"          # [a-z0-9_-]+, the <id> of every bus key of this robot
    fleet = "demo"           # [a-z0-9_-]+, the <fleet> of every bus key (default "demo")

    [geometry]   # robot_agent.core.params.RobotGeometry fields (m, rad/s)
    [gains]      # robot_agent.core.params.TrackingGains fields
    [repulsion]  # robot_agent.core.params.RepulsionParams fields
    [safety]     # robot_agent.core.params.SafetyParams fields (s)
    [safety_filter]  # robot_agent.core.params.SafetyFilterParams fields (barrier-certificate
    filter)

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
    [estimator]  # robot_agent.core.params.EstimatorParams fields (pose estimator, extrapolation)

    [zenoh]
    mode = "client"                       # "client" (default) or "peer"
    endpoints = ["tls/coordinator.local:7447"]
    config_file = "/etc/formation/zenoh/robot-mtls.json5"   # optional zenoh json5 file

    [motor]
    backend = "roboclaw"                  # "bus" (simulation) or "roboclaw"
    port = "/dev/roboclaw"                # roboclaw only: RoboClawConfig fields
    ...

Every parameter section is optional and every key in it too: a missing key keeps the
dataclass default. The sections and their keys are read from the dataclasses themselves
(``dataclasses.fields``), so a parameter added to ``robot_agent.core.params`` is configurable
without touching this module. Values are checked for unknown keys, types and ranges; every
problem is reported (not only the first), each naming the offending field, e.g.
``geometry.wheel_radius_m: expected a number, got 'big' (str)``.

``check_config(path)`` returns those problems as a list (empty = valid), for
``formation agent --check-config FILE``; ``load_robot_config(path)`` returns the parsed
:class:`RobotConfig` or raises :class:`ConfigError` carrying the same list.
"""

from __future__ import annotations

import re
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from robot_agent.core.config_tables import (
    ID_PATTERN,
    agent_sections,
    build_section,
    identifier,
    read_table,
    world_map,
)
from robot_agent.core.params import AgentConfig
from robot_agent.motors import BACKENDS

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


ZENOH_MODES = ("client", "peer")
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
        backend: a name of ``robot_agent.motors.BACKENDS`` ("bus": simulation, the wheel
            message is the output; "roboclaw": a RoboClaw on a serial port; ...).
        settings: the backend's settings (its ``BackendKind.settings`` dataclass), or None for
            a backend that takes none.
    """

    backend: str = "bus"
    settings: Any = None

    def __post_init__(self) -> None:
        kind = BACKENDS.get(self.backend)
        if kind is None:
            raise ValueError(f"backend must be one of {tuple(BACKENDS)}, got {self.backend!r}")
        if kind.settings is None and self.settings is not None:
            raise ValueError(f"backend {self.backend!r} takes no settings")
        if kind.settings is not None and not isinstance(self.settings, kind.settings):
            raise ValueError(
                f"backend {self.backend!r} needs its settings ({kind.settings.__name__})"
            )


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
    sections = agent_sections()
    allowed = ["robot_id", "fleet", *sections, "arena", "obstacle", "zenoh", "motor"]
    for key in data:
        if key not in allowed:
            problems.append(f"{key}: unknown key (allowed: {', '.join(allowed)})")

    robot_id = identifier(data, "robot_id", None, problems)
    fleet = identifier(data, "fleet", "demo", problems)

    parts: dict[str, Any] = {}
    for section, cls in sections.items():
        table = read_table(data, section, problems)
        if table is not None:
            parts[section] = build_section(cls, table, section, problems)
    world = world_map(data, problems)
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


def _zenoh(
    data: Mapping[str, Any], base_dir: str | Path | None, check_files: bool, problems: list[str]
) -> ZenohConfig | None:
    table = read_table(data, "zenoh", problems)
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
    table = read_table(data, "motor", problems)
    if table is None:
        return None
    backend = table.get("backend", "bus")
    kind = BACKENDS.get(backend) if isinstance(backend, str) else None
    if kind is None:
        problems.append(f"motor.backend: must be one of {', '.join(BACKENDS)}, got {backend!r}")
        return None
    if kind.settings is None:
        # The other keys are another backend's: checked only when it is selected, so a robot
        # config can be switched to the simulated backend by changing one line.
        return MotorConfig(backend=backend)
    settings = build_section(kind.settings, table, "motor", problems, skip=("backend",))
    if settings is None:
        return None
    return MotorConfig(backend=backend, settings=settings)
