"""Scenario files: the loader and the one validator (TOML in, a frozen ``Scenario`` out).

A scenario fixes everything about a run: robots and their start poses, robot parameters, the
virtual leader's trajectory, the formation, the assignment rule, the plant's sensor and link
models and scheduled disturbances. ``formation sim`` and ``formation up`` both read it, so the
in-process and the distributed runs are the same experiment.

Built-in scenarios live in ``scenario/builtin/*.toml`` and are named without the extension.
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from bus_schemas import keys
from robot_agent.core.config_tables import agent_sections, build_section, world_map
from robot_agent.core.kinematics import reference_point
from robot_agent.core.params import (
    AgentConfig,
    WorldMap,
)
from scenario.faults import Fault, FaultSpecError, parse_faults
from scenario.movers import MoverBody, parse_movers
from scenario.operator import OperatorEvent, parse_operator

if TYPE_CHECKING:
    from coordinator.core.leader import LeaderConfig

SCENARIO_DIR = Path(__file__).parent / "builtin"


class ScenarioError(ValueError):
    """A scenario file is malformed; the message names the field and what is wrong."""


@dataclass(frozen=True)
class CameraModel:
    rate_hz: float = 30.0
    pos_std_m: float = 0.003
    theta_std_rad: float = 0.01
    latency_s: float = 0.03


@dataclass(frozen=True)
class LinkModel:
    latency_s: float = 0.01
    jitter_s: float = 0.005
    loss_prob: float = 0.01


@dataclass(frozen=True)
class PlantModel:
    motor_tau_s: float = 0.05
    encoder_counts_per_rev: float = 0.0  # > 0: emulate wheel encoders (feed the estimator)
    encoder_slip_std: float = 0.0


@dataclass(frozen=True)
class AssignmentConfig:
    method: str = "greedy"
    hysteresis_m: float = 0.05
    tie_tol_m: float = 0.01


@dataclass(frozen=True)
class Disturbance:
    t_s: float
    robot: str
    kind: str  # "drag" | "teleport" | "camera_loss" (robot out of the camera's view)
    dx: float = 0.0
    dy: float = 0.0
    duration_s: float = 1.0
    x: float | None = None
    y: float | None = None
    theta: float | None = None


@dataclass(frozen=True)
class Scenario:
    name: str
    description: str
    duration_s: float
    dt_s: float
    seed: int
    settle_s: float
    settle_tol_m: float
    robot_ids: tuple[str, ...]
    initial: tuple[tuple[float, float, float], ...]
    agent: AgentConfig
    trajectory: dict[str, Any]
    formation: dict[str, Any]
    assignment: AssignmentConfig
    plant: PlantModel
    camera: CameraModel
    link: LinkModel
    disturbances: tuple[Disturbance, ...] = field(default_factory=tuple)
    source: str = ""
    leader: LeaderConfig | None = None
    movers: tuple[MoverBody, ...] = ()
    """Bodies moving among the robots (``[[mover]]``, scenario/movers.py; issue 30)."""
    """``[leader]``: the operator's limits, the deadman and whether the leader waits for its team
    (coordinator.core.leader, docs/operate.md); None: the defaults."""
    faults: tuple[Fault, ...] = field(default_factory=tuple)  # [[fault]] (scenario.faults)
    operator: tuple[OperatorEvent, ...] = ()
    """Scripted operator commands (``[[operator]]``, scenario/operator.py; issue 28)."""

    def with_overrides(self, **changes: Any) -> Scenario:
        return dataclasses.replace(self, **changes)


def builtin_names() -> list[str]:
    return sorted(p.stem for p in SCENARIO_DIR.glob("*.toml"))


def resolve(name_or_path: str) -> Path:
    """A built-in scenario name or a path to a TOML file."""
    p = Path(name_or_path)
    if p.suffix == ".toml" and p.exists():
        return p
    builtin = SCENARIO_DIR / f"{name_or_path}.toml"
    if builtin.exists():
        return builtin
    raise ScenarioError(
        f"no scenario {name_or_path!r}: not a file, and not one of {', '.join(builtin_names())}"
    )


def load(name_or_path: str) -> Scenario:
    path = resolve(name_or_path)
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))  # TOML is UTF-8, whatever the locale
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError(f"{path}: not valid TOML: {exc}") from exc
    return parse(data, source=str(path))


# --------------------------------------------------------------------------------------------
# validation helpers


def _num(
    d: dict[str, Any],
    key: str,
    where: str,
    default: float | None = None,
    *,
    lo: float = -math.inf,
    hi: float = math.inf,
    lo_open: bool = False,
) -> float:
    if key not in d:
        if default is None:
            raise ScenarioError(f"{where}.{key}: required")
        return default
    v = d[key]
    if isinstance(v, bool) or not isinstance(v, int | float):
        raise ScenarioError(f"{where}.{key}: expected a number, got {type(v).__name__} {v!r}")
    fv = float(v)
    if not math.isfinite(fv):
        raise ScenarioError(f"{where}.{key}: must be finite, got {v!r}")
    if fv < lo or fv > hi or (lo_open and fv <= lo):
        bound = f"> {lo}" if lo_open else f">= {lo}"
        raise ScenarioError(f"{where}.{key}: {fv} out of range (must be {bound} and <= {hi})")
    return fv


def _table(d: dict[str, Any], key: str, where: str) -> dict[str, Any]:
    v = d.get(key, {})
    if not isinstance(v, dict):
        raise ScenarioError(f"{where}{key}: expected a table, got {type(v).__name__}")
    return v


def _only(d: dict[str, Any], allowed: set[str], where: str) -> None:
    unknown = set(d) - allowed
    if unknown:
        raise ScenarioError(
            f"{where}: unknown key(s) {', '.join(sorted(unknown))}; allowed: "
            f"{', '.join(sorted(allowed))}"
        )


def _robot_section(cls: Any, table: dict[str, Any], where: str) -> Any:
    """A robot parameter table (``[geometry]``, ``[safety_filter]``, ...) by the robot config's
    one validator (``robot_agent.core.config_tables.build_section``): the same keys, types and
    declared ranges as a robot's own file."""
    problems: list[str] = []
    built = build_section(cls, table, where, problems)
    if built is None or problems:
        raise ScenarioError("; ".join(problems) or f"{where}: invalid")
    return built


TOP_KEYS = {
    "name", "description", "duration_s", "dt_s", "seed", "settle_s", "settle_tol_m", "robots",
    "geometry", "gains", "repulsion", "safety", "trajectory", "formation", "assignment", "plant",
    "camera", "link", "disturbance", "estimator", "safety_filter", "arena", "obstacle",
    "leader", "fault", "mover", "operator",
}  # fmt: skip


def parse_world(data: dict[str, Any]) -> WorldMap:
    """``[arena]`` and ``[[obstacle]]`` of a scenario as the firmware's ``WorldMap``.

    The same tables and rules as a robot's configuration file (``scenario.robot_config``):
    ``kind = "circle"`` (``x``, ``y``, ``radius_m``), ``"segment"`` (``x1``, ``y1``, ``x2``,
    ``y2``, ``radius_m`` default 0) or ``"polygon"`` (``points`` >= 3 ``[x, y]``, its closed
    outline, as segments), and an ``[arena]`` rectangle (``x_min``, ``y_min``, ``x_max``,
    ``y_max``). Raises ScenarioError naming every problem.
    """
    problems: list[str] = []
    world = world_map(data, problems)
    if world is None or problems:
        raise ScenarioError("; ".join(problems) or "obstacle/arena: invalid")
    return world


def plan_table(
    data: dict[str, Any],
    trajectory: dict[str, Any],
    formation: dict[str, Any],
    agent: AgentConfig,
    initial: tuple[tuple[float, float, float], ...],
) -> dict[str, Any]:
    """A ``kind = "plan"`` trajectory table with the ``context`` its plan depends on: the
    obstacles and arena as written, the formation table, the robot geometry and limits, and the
    start pose (the first robot's reference point, eqs 10-11, and heading). Plain data (the plan
    is a deterministic function of it; ``coordinator.core.planning.trajectory``)."""
    if "context" in trajectory:
        raise ScenarioError("trajectory.context: set from the rest of the scenario, not written")
    g = agent.geometry
    x, y, th = initial[0]
    return {
        **trajectory,
        "context": {
            "obstacles": data.get("obstacle", []),
            "arena": data.get("arena"),
            "formation": formation,
            "geometry": {
                "body_radius_m": g.body_radius_m, "ref_offset_m": g.ref_offset_m,
                "wheel_radius_m": g.wheel_radius_m, "half_track_m": g.half_track_m,
                "max_wheel_radps": g.max_wheel_radps,
            },
            "margin_m": agent.safety_filter.margin_m,
            "safety_distance_m": agent.safety_distance_m,
            "max_ref_speed_mps": agent.gains.max_ref_speed_mps,
            "start": [*reference_point(x, y, th, g.ref_offset_m), th],
        },
    }  # fmt: skip


def parse(data: dict[str, Any], source: str = "<dict>") -> Scenario:  # noqa: PLR0915 (a validator: one check per key)
    """Validate a scenario dictionary (as read from TOML)."""
    _only(data, TOP_KEYS, "scenario")
    name = data.get("name", Path(source).stem)
    if not isinstance(name, str) or not name:
        raise ScenarioError("name: expected a non-empty string")
    duration = _num(data, "duration_s", "scenario", lo=0.0, hi=1e6, lo_open=True)
    dt = _num(data, "dt_s", "scenario", 0.02, lo=0.0, hi=1.0, lo_open=True)
    seed_v = data.get("seed", 0)
    if isinstance(seed_v, bool) or not isinstance(seed_v, int) or seed_v < 0:
        raise ScenarioError(f"seed: expected a non-negative integer, got {seed_v!r}")
    settle = _num(data, "settle_s", "scenario", min(duration / 2, 60.0), lo=0.0, hi=duration)
    settle_tol = _num(data, "settle_tol_m", "scenario", 0.05, lo=0.0, lo_open=True)

    robots = _table(data, "robots", "")
    _only(robots, {"ids", "count", "initial"}, "robots")
    if "ids" in robots:
        ids = robots["ids"]
        if not isinstance(ids, list) or not ids or not all(isinstance(i, str) for i in ids):
            raise ScenarioError("robots.ids: expected a non-empty list of strings")
    elif "count" in robots:
        count = robots["count"]
        if isinstance(count, bool) or not isinstance(count, int) or not 1 <= count <= 10000:
            raise ScenarioError(f"robots.count: expected an integer 1..10000, got {count!r}")
        ids = [f"r{i + 1}" for i in range(count)]
    else:
        raise ScenarioError("robots: give either ids = [...] or count = N")
    for rid in ids:
        if not keys.is_robot_id(rid):
            raise ScenarioError(f"robots.ids: {rid!r} does not match {keys.ROBOT_ID_PATTERN}")
    if len(set(ids)) != len(ids):
        raise ScenarioError("robots.ids: duplicate robot id")
    initial_raw = robots.get("initial")
    if initial_raw is None:
        # default: a row behind the origin, spaced 0.4 m
        initial = tuple((-0.4 * (i // 3), 0.4 * ((i % 3) - 1), 0.0) for i in range(len(ids)))
    else:
        if not isinstance(initial_raw, list) or len(initial_raw) != len(ids):
            raise ScenarioError(
                f"robots.initial: expected {len(ids)} entries [x, y, theta], one per robot"
            )
        rows = []
        for j, row in enumerate(initial_raw):
            if (
                not isinstance(row, list)
                or len(row) != 3
                or not all(isinstance(v, int | float) and not isinstance(v, bool) for v in row)
                or not all(math.isfinite(float(v)) for v in row)
            ):
                raise ScenarioError(f"robots.initial[{j}]: expected [x, y, theta] finite numbers")
            rows.append((float(row[0]), float(row[1]), float(row[2])))
        initial = tuple(rows)

    sections = {
        name: _robot_section(cls, _table(data, name, ""), name)
        for name, cls in agent_sections().items()
    }
    agent = AgentConfig(
        **sections,
        world=parse_world(data),
    )

    trajectory = _table(data, "trajectory", "")
    if "kind" not in trajectory:
        raise ScenarioError("trajectory.kind: required (line, circle, figure8, waypoints, plan)")
    formation = _table(data, "formation", "")
    if "kind" not in formation and "slots" not in formation:
        raise ScenarioError("formation.kind: required (triangle, chevron, lattice) or slots")
    if trajectory["kind"] == "plan":
        trajectory = plan_table(data, trajectory, formation, agent, initial)

    a = _table(data, "assignment", "")
    _only(a, {"method", "hysteresis_m", "tie_tol_m"}, "assignment")
    method = a.get("method", "greedy")
    if method not in ("greedy", "optimal", "sparse"):
        raise ScenarioError(f"assignment.method: {method!r} is not 'greedy', 'optimal' or 'sparse'")
    assignment = AssignmentConfig(
        method=method,
        hysteresis_m=_num(a, "hysteresis_m", "assignment", 0.05, lo=0.0),
        tie_tol_m=_num(a, "tie_tol_m", "assignment", 0.01, lo=0.0),
    )

    leader = None
    leader_table = _table(data, "leader", "")
    if leader_table:
        # imported here: coordinator.core.coordinator's package pulls numpy, and a robot's
        # agent process
        # imports this module without it (tests/repo/test_agent_imports.py); only a scenario
        # with a [leader] table needs the coordinator's validation
        from coordinator.core.leader import LeaderConfig

        try:
            leader = LeaderConfig.from_dict(leader_table)
        except (TypeError, ValueError) as exc:
            raise ScenarioError(str(exc)) from None

    p = _table(data, "plant", "")
    _only(p, {"motor_tau_s", "encoder_counts_per_rev", "encoder_slip_std"}, "plant")
    plant = PlantModel(
        motor_tau_s=_num(p, "motor_tau_s", "plant", 0.05, lo=0.0, hi=10.0),
        encoder_counts_per_rev=_num(p, "encoder_counts_per_rev", "plant", 0.0, lo=0.0, hi=1e7),
        encoder_slip_std=_num(p, "encoder_slip_std", "plant", 0.0, lo=0.0, hi=0.5),
    )
    c = _table(data, "camera", "")
    _only(c, {f.name for f in dataclasses.fields(CameraModel)}, "camera")
    camera = CameraModel(
        rate_hz=_num(c, "rate_hz", "camera", 30.0, lo=0.0, hi=1000.0, lo_open=True),
        pos_std_m=_num(c, "pos_std_m", "camera", 0.003, lo=0.0, hi=1.0),
        theta_std_rad=_num(c, "theta_std_rad", "camera", 0.01, lo=0.0, hi=1.0),
        latency_s=_num(c, "latency_s", "camera", 0.03, lo=0.0, hi=5.0),
    )
    ln = _table(data, "link", "")
    _only(ln, {f.name for f in dataclasses.fields(LinkModel)}, "link")
    link = LinkModel(
        latency_s=_num(ln, "latency_s", "link", 0.01, lo=0.0, hi=5.0),
        jitter_s=_num(ln, "jitter_s", "link", 0.005, lo=0.0, hi=5.0),
        loss_prob=_num(ln, "loss_prob", "link", 0.01, lo=0.0, hi=1.0),
    )

    dist_raw = data.get("disturbance", [])
    if not isinstance(dist_raw, list):
        raise ScenarioError("disturbance: expected an array of tables [[disturbance]]")
    disturbances = []
    for j, d in enumerate(dist_raw):
        where = f"disturbance[{j}]"
        if not isinstance(d, dict):
            raise ScenarioError(f"{where}: expected a table")
        _only(d, {"t_s", "robot", "kind", "dx", "dy", "duration_s", "x", "y", "theta"}, where)
        kind = d.get("kind")
        if kind not in ("drag", "teleport", "camera_loss"):
            raise ScenarioError(
                f"{where}.kind: {kind!r} is not 'drag', 'teleport' or 'camera_loss'"
            )
        robot = d.get("robot")
        if robot not in ids:
            raise ScenarioError(f"{where}.robot: {robot!r} is not one of the scenario's robots")
        disturbances.append(
            Disturbance(
                t_s=_num(d, "t_s", where, lo=0.0, hi=duration),
                robot=str(robot),
                kind=kind,
                dx=_num(d, "dx", where, 0.0),
                dy=_num(d, "dy", where, 0.0),
                duration_s=_num(d, "duration_s", where, 1.0, lo=0.0),
                x=_num(d, "x", where) if "x" in d else None,
                y=_num(d, "y", where) if "y" in d else None,
                theta=_num(d, "theta", where) if "theta" in d else None,
            )
        )
    try:
        faults = parse_faults(data.get("fault"), tuple(ids), duration)
    except FaultSpecError as exc:
        raise ScenarioError(str(exc)) from None
    try:
        movers = parse_movers(data.get("mover"), tuple(ids), duration)
        operator = parse_operator(data.get("operator"), len(ids), duration)
    except ValueError as exc:
        raise ScenarioError(str(exc)) from None
    description = data.get("description", "")
    if not isinstance(description, str):
        raise ScenarioError("description: expected a string")
    return Scenario(
        name=name,
        description=description,
        duration_s=duration,
        dt_s=dt,
        seed=int(seed_v),
        settle_s=settle,
        settle_tol_m=settle_tol,
        robot_ids=tuple(ids),
        initial=initial,
        agent=agent,
        trajectory=dict(trajectory),
        formation=dict(formation),
        assignment=assignment,
        plant=plant,
        camera=camera,
        link=link,
        disturbances=tuple(sorted(disturbances, key=lambda x: x.t_s)),
        source=source,
        leader=leader,
        faults=faults,
        movers=movers,
        operator=operator,
    )
