"""The closed loop in one process, over the same cores as the distributed runtime (no Zenoh).

Per control tick (``dt_s``), in this order:
1. scheduled disturbances start (drag / teleport the truth);
2. the camera captures truth at its own rate and delivers noisy poses after its latency;
3. the coordinator core runs on the latest measured poses (virtual leader, slots, assignment);
4. each robot's firmware steps on its latest pose, its neighbours' poses and the setpoint the
   coordinator computed on the PREVIOUS tick (as over the bus in lockstep, where a setpoint
   computed on clock tick k reaches the agents before tick k+1; see docs/runtime.md);
5. wheel commands go through the lossy, delayed command link;
6. the plant integrates the wheel speeds that arrived (truth).

Everything random comes from one seeded generator, so a seed gives the same run.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from coordinator.core import CoordinatorCore
from formation.runlog import MODE_CODES, RunLog
from formation.scenario import Scenario
from robot_agent.firmware import Firmware, Pose, Setpoint
from sim_plant.accounting import SeparationMonitor
from sim_plant.plant import Plant
from sim_plant.sensors import Camera, CommandLink


@dataclass
class SimResult:
    log: RunLog
    wall_s: float
    firmware_status: dict[str, Any]

    @property
    def realtime_factor(self) -> float:
        sim_s = float(self.log.t_s[-1] - self.log.t_s[0]) if self.log.t_s.size > 1 else 0.0
        return sim_s / self.wall_s if self.wall_s > 0 else math.inf


def run(scenario: Scenario, seed: int | None = None, duration_s: float | None = None) -> SimResult:
    seed = scenario.seed if seed is None else seed
    duration = scenario.duration_s if duration_s is None else duration_s
    rng = np.random.default_rng(seed)
    ids = list(scenario.robot_ids)
    n = len(ids)
    index = {rid: i for i, rid in enumerate(ids)}
    geom = scenario.agent.geometry
    l_m = geom.ref_offset_m

    coord = CoordinatorCore.from_config(
        scenario.trajectory,
        scenario.formation,
        scenario.assignment.method,
        scenario.assignment.hysteresis_m,
        scenario.assignment.tie_tol_m,
        ref_offset_m=l_m,
    )
    plant = Plant(np.array(scenario.initial, dtype=float), geom, motor_tau_s=scenario.plant.motor_tau_s)
    cam = scenario.camera
    camera = Camera(
        n,
        rate_hz=cam.rate_hz,
        pos_std_m=cam.pos_std_m,
        theta_std_rad=cam.theta_std_rad,
        latency_s=cam.latency_s,
        rng=rng,
    )
    lk = scenario.link
    link = CommandLink(latency_s=lk.latency_s, jitter_s=lk.jitter_s, loss_prob=lk.loss_prob, rng=rng)
    monitor = SeparationMonitor(geom.body_radius_m)
    firmwares = [Firmware(scenario.agent) for _ in ids]

    dt = scenario.dt_s
    ticks = int(round(duration / dt)) + 1
    slot_ids = [s.slot for s in coord.formation.slots]
    slot_row = {s: k for k, s in enumerate(slot_ids)}
    log = RunLog.allocate(ids, slot_ids, ticks)

    poses: list[Pose | None] = [None] * n
    pose_rx = [-math.inf] * n
    applied = np.zeros((n, 2))
    pending = list(scenario.disturbances)
    prev_out = None  # the coordinator output of the previous tick

    wall0 = time.perf_counter()
    for k in range(ticks):
        t = k * dt
        # 1. disturbances
        while pending and pending[0].t_s <= t + 1e-9:
            d = pending.pop(0)
            i = index[d.robot]
            if d.kind == "drag":
                plant.drag(i, d.dx, d.dy, d.duration_s)
            else:
                truth_i = plant.truth[i]
                plant.teleport(
                    i,
                    d.x if d.x is not None else float(truth_i[0]) + d.dx,
                    d.y if d.y is not None else float(truth_i[1]) + d.dy,
                    d.theta,
                )
        truth = plant.truth
        # 2. camera
        camera.capture(t, truth)
        for i, stamp, x, y, th in camera.poll(t):
            poses[i] = Pose(float(x), float(y), float(th), float(stamp))
            pose_rx[i] = t
        # 3. coordinator on the measured poses that are fresh
        stale = scenario.agent.safety.stale_pose_s
        fresh = {
            ids[i]: (p.x, p.y, p.theta)
            for i, p in enumerate(poses)
            if p is not None and t - pose_rx[i] <= stale
        }
        out = coord.tick(t, fresh)
        by_slot = out.slots_by_id
        prev_by_slot = prev_out.slots_by_id if prev_out is not None else {}
        # 4. firmware, on the setpoints of the previous tick
        for i, rid in enumerate(ids):
            sp = None
            if prev_out is not None and rid in prev_out.assignment:
                ps = prev_by_slot[prev_out.assignment[rid]]
                sp = Setpoint(ps.x, ps.y, ps.vx, ps.vy, ps.theta, ps.slot, t - dt)
            slot = out.assignment.get(rid)
            neighbours = [(p.x, p.y) for j, p in enumerate(poses) if j != i and p is not None]
            cmd = firmwares[i].step(
                t,
                pose=poses[i],
                pose_rx_s=pose_rx[i],
                setpoint=sp,
                setpoint_rx_s=t - dt,
                neighbours=neighbours,
            )
            # 5. command link
            link.send(t, i, (cmd.omega_r, cmd.omega_l))
            log.power[k, i, 0] = cmd.power_r
            log.power[k, i, 1] = cmd.power_l
            log.mode[k, i] = MODE_CODES.get(str(cmd.mode), 0)
            log.slot_of[k, i] = -1 if slot is None else slot
            if slot is not None:
                s = by_slot[slot]
                log.target[k, i] = (s.x, s.y)
        for i, wheels in link.poll(t):
            applied[i] = wheels
        # record truth at t (before integrating to t + dt)
        log.t_s[k] = t
        log.truth[k] = truth
        log.ref[k, :, 0] = truth[:, 0] + l_m * np.cos(truth[:, 2])
        log.ref[k, :, 1] = truth[:, 1] + l_m * np.sin(truth[:, 2])
        log.leader[k] = (out.leader.x, out.leader.y, out.leader.theta)
        for s in out.slots:
            log.slot_xy[k, slot_row[s.slot]] = (s.x, s.y)
        monitor.update(t, truth)
        prev_out = out
        # 6. plant
        plant.step(dt, applied)
    wall = time.perf_counter() - wall0

    log.min_separation_m = float(monitor.min_separation_m)
    log.collisions = [_event_dict(e, ids) for e in monitor.collisions]
    log.meta = {
        "scenario": scenario.name,
        "seed": seed,
        "dt_s": dt,
        "mode": "in-process",
        "wall_s": wall,
        "link": {"sent": link.sent, "dropped": link.dropped},
    }
    status = {rid: _status_dict(fw) for rid, fw in zip(ids, firmwares, strict=True)}
    return SimResult(log=log, wall_s=wall, firmware_status=status)


def _event_dict(e: Any, ids: list[str]) -> dict[str, Any]:
    if isinstance(e, dict):
        d = dict(e)
    elif hasattr(e, "_asdict"):
        d = dict(e._asdict())
    elif hasattr(e, "__dataclass_fields__"):
        d = {f: getattr(e, f) for f in e.__dataclass_fields__}
    else:
        d = {"event": repr(e)}
    for key in ("i", "j"):
        if key in d and isinstance(d[key], int | np.integer):
            d[key] = ids[int(d[key])]
    return {k: (float(v) if isinstance(v, np.floating) else v) for k, v in d.items()}


def _status_dict(fw: Firmware) -> dict[str, Any]:
    st = fw.status()
    if hasattr(st, "__dataclass_fields__"):
        return {f: _jsonable(getattr(st, f)) for f in st.__dataclass_fields__}
    return {"status": repr(st)}


def _jsonable(v: Any) -> Any:
    if isinstance(v, float | int | str | bool) or v is None:
        return v if not (isinstance(v, float) and not math.isfinite(v)) else None
    return str(v)
