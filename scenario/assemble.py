"""A scenario turned into the cores of one run: the one assembly both runtimes use.

``formation/sim/simulate.py`` (in-process) and the process shells
(``coordinator/node/coordinator.py``,
``sim_plant/node/plant.py``) build their cores here, so the two runtimes run the same experiment by
construction: the same trajectory, formation and assigner, the same plant, camera and command
link drawing from one seeded generator in the same order, and the same rule for a scheduled
disturbance. Imports the numeric cores, so it is not re-exported by ``scenario/__init__`` (an
agent loads scenarios without numpy).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from coordinator.core.coordinator import CoordinatorCore
from coordinator.core.leader import LeaderConfig
from coordinator.core.path_check import PathConflict, slot_path_conflicts
from coordinator.core.planning.limits import SlotLimits
from coordinator.core.planning.replan import PlanSetup
from coordinator.core.planning.trajectory import DEFAULT_CLEARANCE_M, min_separation_m
from robot_agent.core.params import CircleObstacle
from scenario.load import Disturbance, Scenario
from sim_plant.core.accounting import SeparationMonitor
from sim_plant.core.plant import Plant
from sim_plant.core.sensors import Camera, CommandLink

__all__ = ["apply_scheduled", "coordinator_core", "path_conflicts", "plan_setup", "plant_models"]


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


PATH_CHECK_HORIZON_S = 3600.0
"""The slot-path conflict check samples the first hour of a run at most (36,000 instants): the
scenario of a real fleet's file runs "for ever" (``scenario.fleet.RUN_FOREVER_S``) and a check
of all of it would take hours before the coordinator started."""


def path_conflicts(scenario: Scenario, duration_s: float | None = None) -> list[PathConflict]:
    """The slots whose paths cross an obstacle of ``scenario.agent.world`` or leave its arena
    over ``duration_s`` (default: the scenario's; at most :data:`PATH_CHECK_HORIZON_S`); what
    the coordinator warns about."""
    geom = scenario.agent.geometry
    duration = scenario.duration_s if duration_s is None else duration_s
    return slot_path_conflicts(
        scenario.trajectory,
        scenario.formation,
        scenario.agent.world,
        min(duration, PATH_CHECK_HORIZON_S),
        body_radius_m=geom.body_radius_m,
        ref_offset_m=geom.ref_offset_m,
    )


def plant_models(
    scenario: Scenario, rng: np.random.Generator, t0_s: float = 0.0
) -> tuple[Plant, Camera, CommandLink[Any], SeparationMonitor]:
    """Plant, camera, command link and separation monitor of ``scenario`` starting at ``t0_s``.

    The camera and then the link draw from ``rng``: build them in this one place so a seed gives
    the same noise in every runtime.
    """
    geom = scenario.agent.geometry
    plant = Plant(
        np.array(scenario.initial, dtype=float),
        geom,
        motor_tau_s=scenario.plant.motor_tau_s,
        t0_s=t0_s,
    )
    cam = scenario.camera
    camera = Camera(
        len(scenario.robot_ids),
        rate_hz=cam.rate_hz,
        pos_std_m=cam.pos_std_m,
        theta_std_rad=cam.theta_std_rad,
        latency_s=cam.latency_s,
        rng=rng,
        t0_s=t0_s,
    )
    lk = scenario.link
    link: CommandLink[Any] = CommandLink(
        latency_s=lk.latency_s, jitter_s=lk.jitter_s, loss_prob=lk.loss_prob, rng=rng
    )
    return plant, camera, link, SeparationMonitor(geom.body_radius_m)


def apply_scheduled(
    plant: Plant, i: int, d: Disturbance, camera: Camera | None = None, t0_s: float = 0.0
) -> None:
    """Start scheduled disturbance ``d`` on robot ``i``: a drag, a camera loss (robot ``i``
    out of ``camera``'s view for ``duration_s``; scenario times are relative to ``t0_s``), or a
    teleport to ``(x, y)`` (each defaulting to the current truth plus ``dx``/``dy``) and
    ``theta``."""
    if d.kind == "drag":
        plant.drag(i, d.dx, d.dy, d.duration_s)
    elif d.kind == "camera_loss":
        if camera is not None:
            camera.occlude(i, t0_s + d.t_s, t0_s + d.t_s + d.duration_s)
    else:
        x_i, y_i, _ = plant.truth_rows()[i]
        plant.teleport(
            i,
            d.x if d.x is not None else x_i + d.dx,
            d.y if d.y is not None else y_i + d.dy,
            d.theta,
        )
