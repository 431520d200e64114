"""``--robots N`` / ``--spares K``: a scenario table resized to N formation slots and robots
``r1..r(N+K)``.

The formation is grown (or cut) to exactly N slots by the paper's staged rule (Fig 2b,
:func:`coordinator.core.formation.resized_formation_table`: a triangle grows into the triangular
lattice, chevron and lattice keep their kind with N slots, an explicit formation grows by its
first stage's pattern). New robots start with their reference point on their slot (eqs 10-11),
so a resized fleet starts in formation; the K spares start idle in rows behind it. The
coordinator cores are imported inside the function that needs them, so loading a scenario (what
an agent does) never pulls in numpy.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from robot_agent.core.kinematics import axle_from_reference_point
from scenario.load import Scenario, ScenarioError, parse, resolve

__all__ = ["FleetShape", "fleet_shape", "load_with_robots", "scenario_with_robots"]


def _robot_ids(robots: Mapping[str, Any]) -> list[str]:
    if "ids" in robots:
        return [str(r) for r in robots["ids"]]
    return [f"r{i + 1}" for i in range(int(robots.get("count", 0)))]


def _slot_poses(data: Mapping[str, Any]) -> list[tuple[float, float, float]]:
    """Axle-centre poses that put each robot's reference point on a slot at t = 0, in slot
    definition order (the reference point is ``ref_offset_m`` ahead of the axle, eqs 10-11)."""
    from coordinator.core.formation import FormationSpec, slot_states
    from coordinator.core.trajectory import make_trajectory

    traj = dict(data["trajectory"])
    kind = str(traj.pop("kind"))
    # a plan is made later, from the resized scenario: its start pose is enough here
    leader = _plan_start(data, traj) if kind == "plan" else make_trajectory(kind, traj).sample(0.0)
    spec = FormationSpec.from_dict(dict(data["formation"]))
    l_m = float(data.get("geometry", {}).get("ref_offset_m", 0.05))
    return [
        (*axle_from_reference_point(s.x, s.y, s.theta, l_m), s.theta)
        for s in slot_states(spec, leader)
    ]


def _plan_start(data: Mapping[str, Any], traj: Mapping[str, Any]) -> Any:
    """The virtual leader at rest at a planned trajectory's start: ``x0``, ``y0``, ``heading``
    or the first robot's reference point and heading (what ``scenario.load`` plans from)."""
    from coordinator.core.trajectory import LeaderState

    robots = dict(data.get("robots", {}))
    first = (robots.get("initial") or [[0.0, 0.0, 0.0]])[0]
    l_m = float(data.get("geometry", {}).get("ref_offset_m", 0.05))
    th = float(traj.get("heading", first[2]))
    x = float(traj.get("x0", first[0] + l_m * math.cos(first[2])))
    y = float(traj.get("y0", first[1] + l_m * math.sin(first[2])))
    return LeaderState(0.0, x, y, th, 0.0, 0.0)


def scenario_with_robots(data: Mapping[str, Any], n: int | None, spares: int = 0) -> dict[str, Any]:
    """A copy of the scenario table ``data`` with ``n`` formation slots and robots ``r1..r(n+K)``
    (``K = spares``).

    The formation is grown (or cut) to exactly ``n`` slots by the staged rule (module
    docstring); ``n`` None keeps the scenario's robot count as the slot count. Robots that
    existed keep their start pose; new ones start on their slot (robot ``rK`` on the K-th slot
    of the formation, in definition order) or, beyond the last slot (the spares), in rows 0.5 m
    behind the formation, 0.4 m apart, five to a row, centred on the leader's line. A
    disturbance of a robot that no longer exists is dropped. Raises :class:`ScenarioError` for
    ``n < 1``, ``spares < 0`` or a formation that cannot be grown.
    """
    if n is None:
        n = len(_robot_ids(dict(data.get("robots", {}))))
    if isinstance(n, bool) or not isinstance(n, int) or n < 1:
        raise ScenarioError(f"--robots: need at least 1 robot, got {n}")
    if isinstance(spares, bool) or not isinstance(spares, int) or spares < 0:
        raise ScenarioError(f"--spares: expected an integer >= 0, got {spares}")
    from coordinator.core.formation import resized_formation_table

    out = copy.deepcopy(dict(data))
    robots = dict(out.get("robots", {}))
    old_ids = _robot_ids(robots)
    old_initial = robots.get("initial")
    ids = [f"r{i + 1}" for i in range(n + spares)]
    try:
        out["formation"] = resized_formation_table(dict(out.get("formation", {})), n)
    except (KeyError, TypeError, ValueError) as exc:
        raise ScenarioError(f"--robots: cannot grow the formation to {n} slots: {exc}") from exc
    try:
        slot_poses = _slot_poses(out)
    except (KeyError, TypeError, ValueError) as exc:
        raise ScenarioError(f"--robots: cannot place new robots: {exc}") from exc
    # rows behind the formation, in the leader's frame
    leader_x, leader_y, heading = slot_poses[0] if slot_poses else (0.0, 0.0, 0.0)
    c, s = math.cos(heading), math.sin(heading)
    rear = min(((x - leader_x) * c + (y - leader_y) * s for x, y, _ in slot_poses), default=0.0)
    initial: list[list[float]] = []
    for i, rid in enumerate(ids):
        if isinstance(old_initial, list) and i < len(old_initial) and old_ids[i : i + 1] == [rid]:
            initial.append([float(v) for v in old_initial[i]])
        elif i < len(slot_poses):
            initial.append([round(v, 6) for v in slot_poses[i]])
        else:
            extra = i - len(slot_poses)
            row, col = divmod(extra, 5)
            in_row = min(5, len(ids) - len(slot_poses) - 5 * row)  # a short last row is centred
            back = rear - 0.5 * (row + 1)
            side = 0.4 * (col - (in_row - 1) / 2)
            initial.append(
                [
                    round(leader_x + back * c - side * s, 6),
                    round(leader_y + back * s + side * c, 6),
                    round(heading, 6),
                ]
            )
    out["robots"] = {"ids": ids, "initial": initial}
    if "disturbance" in out:
        kept = [d for d in out["disturbance"] if d.get("robot") in ids]
        if kept:
            out["disturbance"] = kept
        else:
            del out["disturbance"]
    if "fault" in out:  # a fault of a robot that no longer exists is dropped, like a disturbance
        kept_f = [f for f in out["fault"] if f.get("robot") is None or f.get("robot") in ids]
        if kept_f:
            out["fault"] = kept_f
        else:
            del out["fault"]
    return out


@dataclass(frozen=True)
class FleetShape:
    """What a fleet is: formation slots, robots, idle spares (robots beyond the slots) and
    formation stages (the leader's stage 0 included)."""

    slots: int
    robots: int
    stages: int

    @property
    def spares(self) -> int:
        return max(0, self.robots - self.slots)

    def describe(self) -> str:
        """``100 robots: 100 slots in 14 stages, 0 spares`` (for banners)."""
        return (
            f"{self.robots} robots: {self.slots} slots in {self.stages} stages, "
            f"{self.spares} idle spare{'' if self.spares == 1 else 's'}"
        )


def fleet_shape(formation: Mapping[str, Any], n_robots: int) -> FleetShape:
    """The :class:`FleetShape` of a scenario's ``[formation]`` table and robot count."""
    from coordinator.core.formation import FormationSpec

    spec = FormationSpec.from_dict(dict(formation))
    return FleetShape(slots=len(spec), robots=n_robots, stages=spec.n_stages)


def load_with_robots(name_or_path: str, n: int | None, spares: int = 0) -> Scenario:
    """Load a built-in scenario or a TOML file resized by :func:`scenario_with_robots` (what
    ``formation sim --robots N --spares K`` runs); raises :class:`ScenarioError`."""
    import tomllib

    path = resolve(name_or_path)
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))  # TOML is UTF-8, whatever the locale
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError(f"{path}: not valid TOML: {exc}") from exc
    return parse(scenario_with_robots(data, n, spares), source=str(path))
