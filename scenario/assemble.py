"""A scenario turned into the coordinator's core: the one assembly both runtimes use.

``formation/sim/simulate.py`` (in-process) and the coordinator's process shell
(``coordinator/node/coordinator.py``) build the coordinator's core here, so the two runtimes run
the same experiment by construction: the same trajectory, formation and assigner, and the same
run-time planning setup. The plant's side (plant, camera and command link drawing from one
seeded generator in the same order, the rule for a scheduled disturbance) is
``scenario.assemble_plant``, apart so that a plant process does not import the coordinator's
cores. Imports the numeric cores, so it is not re-exported by ``scenario/__init__`` (an agent
loads scenarios without numpy).
"""

from __future__ import annotations

from typing import Any

from coordinator.core.coordinator import CoordinatorCore
from coordinator.core.leader import LeaderConfig
from coordinator.core.planning.limits import SlotLimits
from coordinator.core.planning.replan import PlanSetup
from coordinator.core.planning.trajectory import DEFAULT_CLEARANCE_M, min_separation_m
from robot_agent.core.params import CircleObstacle
from scenario.load import Scenario

__all__ = ["coordinator_core", "plan_setup"]


def coordinator_core(scenario: Scenario, t0_s: float = 0.0) -> CoordinatorCore:
    """The coordinator core of ``scenario`` (trajectory time origin ``t0_s``)."""
    return CoordinatorCore.from_config(
        scenario.trajectory,
        scenario.formation,
        scenario.assignment.method,
        scenario.assignment.hysteresis_m,
        scenario.assignment.tie_tol_m,
        ref_offset_m=scenario.agent.geometry.ref_offset_m,
        t0_s=t0_s,
        leader=scenario.leader,
        arena=_arena(scenario),
        plan_setup=plan_setup(scenario),
    )


def plan_setup(scenario: Scenario) -> PlanSetup:
    """What the coordinator's run-time plans share (coordinator.core.planning.replan): the
    scenario's obstacles and arena as the planner's tables (a polygon arrives as its edges, as
    the robots see it), the footprint and limits as ``kind = "plan"`` trajectories have them
    (coordinator.core.planning.trajectory), the leader's cruise speed and accelerations."""
    agent = scenario.agent
    g = agent.geometry
    world = agent.world
    tables: list[dict[str, Any]] = []
    for o in world.obstacles:
        if isinstance(o, CircleObstacle):
            tables.append({"kind": "circle", "x": o.x, "y": o.y, "radius_m": o.radius_m})
        else:
            tables.append({"kind": "segment", "x1": o.x1, "y1": o.y1, "x2": o.x2, "y2": o.y2,
                           "radius_m": o.radius_m})  # fmt: skip
    a = world.arena
    arena = None if a is None else {"x_min": a.x_min, "y_min": a.y_min, "x_max": a.x_max,
                                    "y_max": a.y_max}  # fmt: skip
    clearance = DEFAULT_CLEARANCE_M
    speed = None
    if scenario.trajectory.get("kind") == "plan":
        clearance = float(scenario.trajectory.get("clearance_m", clearance))
        speed = scenario.trajectory.get("speed_mps")
    leader = scenario.leader if scenario.leader is not None else LeaderConfig()
    ds = agent.safety_distance_m
    return PlanSetup(
        obstacles=tuple(tables),
        arena=arena,
        slot_radius_m=g.body_radius_m + g.ref_offset_m + agent.safety_filter.margin_m + clearance,
        min_separation_m=min_separation_m(ds, g.ref_offset_m),
        min_pair_m=ds,
        soft_pair_m=ds + 2.0 * g.ref_offset_m,
        limits=SlotLimits.from_agent(agent),
        cruise_mps=min(float(speed), leader.max_speed_mps) if speed else leader.max_speed_mps,
        body_radius_m=g.body_radius_m,
        accel_mps2=leader.max_accel_mps2,
        turn_accel_radps2=leader.max_turn_accel_radps2,
    )


def _arena(scenario: Scenario) -> tuple[float, float, float, float] | None:
    """The scenario's arena as (x_min, y_min, x_max, y_max) (m), or None."""
    a = scenario.agent.world.arena
    return None if a is None else (a.x_min, a.y_min, a.x_max, a.y_max)
