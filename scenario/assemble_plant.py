"""The plant's side of a scenario's assembly (``scenario.assemble`` holds the coordinator's): the
plant, camera, command link and separation monitor drawn from one seeded generator in one order,
and the rule for a scheduled disturbance. Both runtimes build them here
(``formation/sim/simulate.py``, ``sim_plant/node/plant.py``), so a seed gives the same noise in
both. A module of its own so that a plant process does not import the coordinator's cores
(scipy's optimizer and the planner: about half a second of a plant's start)."""

from __future__ import annotations

from typing import Any

import numpy as np

from scenario.load import Disturbance, Scenario
from sim_plant.core.accounting import SeparationMonitor
from sim_plant.core.plant import Plant
from sim_plant.core.sensors import Camera, CommandLink

__all__ = ["apply_scheduled", "plant_models"]


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
