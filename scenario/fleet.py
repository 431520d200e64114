"""The fleet file of a real deployment: which robots, their tags, the arena, the task.

A simulator scenario describes an experiment (start poses, plant noise, disturbances, a
duration). Real robots need only what the coordinator host's processes read: the fleet name,
the robots and the AprilTag each carries, the arena and its obstacles, the virtual leader's
trajectory and the formation. ``formation coordinator --fleet-file F`` and ``formation camera
--fleet-file F`` read it (``/etc/formation/fleet.toml``; deploy/config/fleet.example.toml is the
annotated template)::

    fleet = "demo"              # <fleet> of every bus key; the robots' configs say the same
    name = "lab-triangle"       # optional, shown in logs
    description = "..."         # optional

    [[robot]]                   # one table per robot, in slot-preference order
    id = "r1"                   # robot id: its certificate is robot.r1, its config r1.toml
    tag = 1                     # the tag36h11 id on its top plate
    [[robot]]
    id = "r2"
    tag = 2

    [arena]                     # optional: x_min, y_min, x_max, y_max (m)
    [[obstacle]]                # optional: circle / segment / polygon, as in a robot config
    [trajectory]                # the virtual leader: as in a scenario (docs/scenarios.md);
                                # kind = "plan" (docs/planning.md) also needs x0, y0, heading:
                                # where the planned leader starts
    [formation]                 # the formation: as in a scenario
    [assignment]                # optional: greedy (default), optimal or sparse
    [geometry]                  # optional: the robots' geometry (ref_offset_m is used by the
                                # coordinator to place reference points; keep it equal to the
                                # robots' own [geometry])

Validation is the scenario's (the same validator, :func:`scenario.load.parse`, for the
trajectory, formation, assignment and geometry) plus the fleet's own rules: ids and fleet name
match the bus contract, tags are unique integers of the family, no unknown key. Every problem
is reported with its dotted field name in :class:`FleetError`.
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final

from bus_schemas import keys
from robot_agent.core.config_tables import world_map as _world
from robot_agent.core.params import WorldMap
from scenario.load import Scenario, ScenarioError, parse

__all__ = ["Fleet", "FleetError", "FleetRobot", "fleet_from_dict", "load_fleet"]

TAG_MAX: Final = 586
"""Largest tag36h11 id (587 codes)."""
RUN_FOREVER_S: Final = 1.0e6
"""The scenario duration given to a real fleet's coordinator (it runs until stopped)."""
_TOP_KEYS: Final = (
    "fleet", "name", "description", "robot", "arena", "obstacle", "trajectory", "formation",
    "assignment", "geometry",
)  # fmt: skip


class FleetError(ScenarioError):
    """A fleet file is invalid; ``problems`` lists every reason (dotted field names)."""

    def __init__(self, source: str, problems: list[str]) -> None:
        self.source = source
        self.problems = list(problems)
        super().__init__(f"{source}: invalid fleet file:\n  " + "\n  ".join(self.problems))


@dataclass(frozen=True)
class FleetRobot:
    """One robot of the fleet: its id and the tag it carries."""

    id: str
    tag: int


@dataclass(frozen=True)
class Fleet:
    """A validated fleet file.

    Attributes:
        fleet: the bus fleet name.
        robots: the robots, in the file's order.
        world: the arena and static obstacles (None: none given).
        scenario: what the coordinator runs (trajectory, formation, assignment, geometry, the
            arena and obstacles), a :class:`scenario.Scenario` lasting :data:`RUN_FOREVER_S`.
        source: the file it was read from.
    """

    fleet: str
    robots: tuple[FleetRobot, ...]
    world: WorldMap | None
    scenario: Scenario
    source: str = "<dict>"

    @property
    def robot_ids(self) -> tuple[str, ...]:
        return tuple(r.id for r in self.robots)

    @property
    def tags(self) -> dict[str, int]:
        """Robot id -> tag id (the camera calibration's ``[tags]``)."""
        return {r.id: r.tag for r in self.robots}


def load_fleet(path: str | Path) -> Fleet:
    """Read and validate a fleet file; raises :class:`FleetError` listing every problem."""
    p = Path(path)
    try:
        data = tomllib.loads(p.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError) as exc:
        raise FleetError(str(p), [f"cannot read the file: {exc}"]) from exc
    except tomllib.TOMLDecodeError as exc:
        raise FleetError(str(p), [f"not valid TOML: {exc}"]) from exc
    return fleet_from_dict(data, source=str(p))


def fleet_from_dict(data: Mapping[str, Any], *, source: str = "<dict>") -> Fleet:  # noqa: PLR0915 (a validator: one check per key)
    """Validate already-parsed fleet data (the rules of :func:`load_fleet`)."""
    problems: list[str] = []
    for key in data:
        if key not in _TOP_KEYS:
            problems.append(f"{key}: unknown key (allowed: {', '.join(_TOP_KEYS)})")
    fleet = data.get("fleet", keys.DEFAULT_FLEET)
    if not isinstance(fleet, str) or not keys.is_name(fleet):
        problems.append(f"fleet: {fleet!r} must match {keys.NAME_PATTERN}")
    name = data.get("name", Path(source).stem if source != "<dict>" else "fleet")
    if not isinstance(name, str) or not name:
        problems.append(f"name: expected a non-empty string, got {name!r}")
    description = data.get("description", "")
    if not isinstance(description, str):
        problems.append(f"description: expected a string, got {description!r}")

    robots: list[FleetRobot] = []
    raw = data.get("robot")
    if not isinstance(raw, list) or not raw:
        problems.append('robot: required, one [[robot]] table per robot (id = "r1", tag = 1)')
        raw = []
    seen_ids: set[str] = set()
    seen_tags: dict[int, str] = {}
    for j, item in enumerate(raw):
        where = f"robot[{j}]"
        if not isinstance(item, Mapping):
            problems.append(f"{where}: expected a table")
            continue
        for key in item:
            if key not in ("id", "tag"):
                problems.append(f"{where}.{key}: unknown key (allowed: id, tag)")
        rid, tag = item.get("id"), item.get("tag")
        ok = True
        if not isinstance(rid, str) or not keys.is_robot_id(rid):
            problems.append(f"{where}.id: {rid!r} must match {keys.ROBOT_ID_PATTERN}")
            ok = False
        elif rid in seen_ids:
            problems.append(f"{where}.id: robot {rid!r} is listed twice")
            ok = False
        if isinstance(tag, bool) or not isinstance(tag, int) or not 0 <= tag <= TAG_MAX:
            problems.append(f"{where}.tag: expected an integer 0..{TAG_MAX}, got {tag!r}")
            ok = False
        elif tag in seen_tags:
            problems.append(f"{where}.tag: tag {tag} is already robot {seen_tags[tag]!r}'s")
            ok = False
        if ok:
            assert isinstance(rid, str) and isinstance(tag, int)
            seen_ids.add(rid)
            seen_tags[tag] = rid
            robots.append(FleetRobot(rid, tag))

    world = _world(data, problems)
    if world is not None and not world.obstacles and world.arena is None:
        world = None

    scenario_data: dict[str, Any] = {
        "name": name if isinstance(name, str) and name else "fleet",
        "description": description if isinstance(description, str) else "",
        "duration_s": RUN_FOREVER_S,
        "robots": {"ids": [r.id for r in robots] or ["r1"]},
    }
    # the arena and obstacles too: the coordinator's checks and a planned trajectory's plan
    # (issue 27: its context, scenario.load.plan_table) keep the formation clear of them
    for key in ("trajectory", "formation", "assignment", "geometry", "arena", "obstacle"):
        if key in data:
            scenario_data[key] = data[key]
    for key in ("trajectory", "formation"):
        if key not in data:
            problems.append(f"{key}: required (as in a scenario, docs/scenarios.md)")
    problems += _plan_start_problems(data.get("trajectory"))
    scenario: Scenario | None = None
    if "trajectory" in data and "formation" in data:
        try:
            scenario = parse(scenario_data, source)
            _check_task(scenario)
        except (ScenarioError, ValueError, KeyError, TypeError) as exc:
            problems.append(str(exc))
    if problems or scenario is None or not isinstance(fleet, str):
        raise FleetError(source, problems or ["invalid fleet file"])
    return Fleet(fleet=fleet, robots=tuple(robots), world=world, scenario=scenario, source=source)


PLAN_START_KEYS: Final = ("x0", "y0", "heading")


def _plan_start_problems(trajectory: object) -> list[str]:
    """A planned trajectory (``kind = "plan"``, issue 27) in a fleet file must say where the
    virtual leader starts: a scenario plans from its first robot's start pose, and a fleet
    file has no start poses (the robots are where they are; they join their slots)."""
    if not isinstance(trajectory, Mapping) or trajectory.get("kind") != "plan":
        return []
    return [
        f'trajectory.{key}: required for kind = "plan" in a fleet file (the virtual leader\'s '
        "start pose x0, y0 in m and heading in rad: there are no start poses to plan from)"
        for key in PLAN_START_KEYS
        if key not in trajectory
    ]


def _check_task(scenario: Scenario) -> None:
    """Build the coordinator core once, so a bad trajectory or formation fails at load."""
    from scenario.assemble import coordinator_core

    core = coordinator_core(scenario)
    del core
    speed = scenario.trajectory.get("speed_mps")
    if isinstance(speed, int | float) and not (math.isfinite(speed) and abs(speed) <= 1.0):
        raise ScenarioError(f"trajectory.speed_mps: {speed!r} is not a plausible speed (<= 1 m/s)")
