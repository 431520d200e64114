"""A Python API for experiments: the in-process closed loop one tick at a time.

:class:`Experiment` runs the loop of :func:`formation.sim.simulate.run` (``formation sim``) over
the same cores (coordinator, firmware, camera, link and plant models, in the same order with the
same random draws), but the caller drives it: ``reset(seed)`` starts a run, ``step()`` advances
one control tick (``dt_s``) and returns what happened, ``step(actions)`` does the same with the
caller's wheel speeds in place of the firmware's output for the robots it names (a controller of
one's own, a learned policy). Stepping a whole run without actions gives exactly the log of
``formation sim`` for the same scenario and seed (``tests/unit/formation/test_experiment.py``)::

    import scenario
    from formation.sim.experiment import Experiment

    exp = Experiment(scenario.load("paper-exp2"))
    obs = exp.reset(seed=3)
    while not exp.done:
        # my controller: the firmware's command for every robot, but r3 stands still
        obs = exp.step({"r3": (0.0, 0.0)})
    log = exp.log()  # a RunLog: formation.outputs.metrics.compute(log, ...) and the figures

Actions are wheel speeds ``(omega_right, omega_left)`` in rad/s. They go through the same lossy,
delayed command link as the firmware's; a speed beyond the robot's ``max_wheel_radps`` is
clamped to it (counted in :attr:`Experiment.clamped_actions`); an unknown robot, a pair that is
not two finite numbers, or a step after the end raise ``ValueError``. The firmware still steps
for a robot with an action (its estimator and safety filter keep their state; its command is
in :attr:`Observation.firmware`), only its output is replaced.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from operator import itemgetter
from typing import Any

import numpy as np

from coordinator.core.coordinator import CoordinatorOutput, pose_stale_s
from formation.outputs.runlog import RunLog
from formation.sim.ticklog import TickLog
from robot_agent.core.firmware import Firmware, Mode, Pose, Setpoint, WheelCommand
from robot_agent.core.lockstep import SETPOINT_DELAY_TICKS, SetpointWindow, tick_time
from robot_agent.core.neighbours import is_current, neighbour
from scenario import Scenario
from scenario.assemble import coordinator_core
from scenario.assemble_plant import apply_scheduled, plant_models
from sim_plant.core.encoders import WheelEncoders

__all__ = ["Experiment", "Observation"]

_tuple_new = tuple.__new__
_xy_of = itemgetter(0, 1)


@dataclass(frozen=True)
class Observation:
    """One tick of an experiment, robots in ``robot_ids`` order.

    ``t_s``: the tick's time (s); ``truth``: each robot's true axle centre ``(x, y, theta)``
    (m, m, rad) at ``t_s``, before the tick's wheel speeds act; ``measured``: each robot's latest
    camera pose ``(x, y, theta, capture_t_s)`` or None (what the firmware saw); ``leader``: the
    virtual leader ``(x, y, theta)``; ``assignment``: robot id -> slot this tick; ``firmware``:
    each firmware's command this tick (``WheelCommand``: omega_r, omega_l rad/s, power_r,
    power_l, mode); ``wheels``: the wheel speeds sent this tick (the actions where given).
    """

    t_s: float
    truth: tuple[tuple[float, float, float], ...]
    measured: tuple[Pose | None, ...]
    leader: tuple[float, float, float]
    assignment: Mapping[str, int]
    firmware: tuple[WheelCommand, ...]
    wheels: tuple[tuple[float, float], ...]


class Experiment:
    """The closed loop of ``formation sim`` stepped by the caller (see the module docstring)."""

    def __init__(self, scn: Scenario, duration_s: float | None = None) -> None:
        self.scenario = scn
        self.duration_s = scn.duration_s if duration_s is None else float(duration_s)
        if not (math.isfinite(self.duration_s) and self.duration_s > 0.0):
            raise ValueError(f"duration_s: expected a finite number > 0, got {duration_s!r}")
        self.robot_ids = list(scn.robot_ids)
        self.dt_s = scn.dt_s
        self.ticks = round(self.duration_s / self.dt_s) + 1
        self.clamped_actions = 0
        self._k = -1  # no run yet: reset() first
        self._max_wheel = scn.agent.geometry.max_wheel_radps

    # -- run control ---------------------------------------------------------------------------

    @property
    def done(self) -> bool:
        """True when the run has no tick left (or was never reset)."""
        return self._k < 0 or self._k >= self.ticks

    @property
    def tick(self) -> int:
        """How many ticks this run has stepped."""
        return max(self._k, 0)

    def reset(self, seed: int | None = None) -> Observation | None:
        """Start a new run (``seed`` overrides the scenario's); the models and firmware are made
        afresh, exactly as ``formation sim`` makes them. Returns None: nothing has happened
        until the first :meth:`step`."""
        scn = self.scenario
        self.seed = scn.seed if seed is None else seed
        rng = np.random.default_rng(self.seed)
        n = len(self.robot_ids)
        self._index = {rid: i for i, rid in enumerate(self.robot_ids)}
        self._coord = coordinator_core(scn)
        self._plant, self._camera, self._link, self._monitor = plant_models(scn, rng)
        self._encoders = (
            WheelEncoders(n, scn.plant.encoder_counts_per_rev, scn.plant.encoder_slip_std, rng)
            if scn.plant.encoder_counts_per_rev > 0.0
            else None
        )
        self._firmwares = [Firmware(scn.agent) for _ in self.robot_ids]
        self._slot_ids = list(self._coord.formation.slot_ids)
        self._slot_row = {s: k for k, s in enumerate(self._slot_ids)}
        self._stale = pose_stale_s(scn.agent, odometry=self._encoders is not None)
        self._poses: list[Pose | None] = [None] * n
        self._xyt: list[tuple[float, float, float] | None] = [None] * n
        self._pose_rx = [-math.inf] * n
        self._pose_cap: list[float | None] = [None] * n
        self._applied: list[tuple[float, float]] = [(0.0, 0.0)] * n
        self._tracking = [False] * n
        self._pending = list(scn.disturbances)
        self._fresh: dict[str, tuple[float, float, float]] = {}
        self._oldest_rx = math.inf
        self._outputs: SetpointWindow[CoordinatorOutput] = SetpointWindow()
        self._ticklog = TickLog(keyed=False)  # the record, as formation sim keeps it
        self._slot_of_changes: list[tuple[int, list[int]]] = []
        self.clamped_actions = 0
        self._k = 0
        return None

    # -- one tick ------------------------------------------------------------------------------

    def _check_actions(self, actions: Mapping[str, Any]) -> dict[int, tuple[float, float]]:
        out: dict[int, tuple[float, float]] = {}
        for rid, pair in actions.items():
            if rid not in self._index:
                raise ValueError(f"actions: unknown robot {rid!r}")
            try:
                wr, wl = (float(v) for v in pair)
            except (TypeError, ValueError):
                raise ValueError(
                    f"actions[{rid!r}]: expected (omega_right, omega_left) in rad/s"
                ) from None
            if not (math.isfinite(wr) and math.isfinite(wl)):
                raise ValueError(f"actions[{rid!r}]: wheel speeds must be finite")
            lim = self._max_wheel
            if abs(wr) > lim or abs(wl) > lim:
                self.clamped_actions += 1
                wr, wl = max(-lim, min(lim, wr)), max(-lim, min(lim, wl))
            out[self._index[rid]] = (wr, wl)
        return out

    def _neighbours(self, t: float) -> list[list[Any]]:
        pts = [
            None
            if p is None or not is_current(t, self._pose_rx[j])
            else neighbour(p[0], p[1], p[2], p[3], t, self._tracking[j])
            for j, p in enumerate(self._poses)
        ]
        n = len(pts)
        if None in pts:
            return [[q for j, q in enumerate(pts) if j != i and q is not None] for i in range(n)]
        return [pts[:i] + pts[i + 1 :] for i in range(n)]

    def _sense(self, t: float) -> tuple[tuple[float, float, float], ...]:
        """Disturbances, truth, encoders and the camera at tick time ``t`` (loop stages 1-2)."""
        while self._pending and self._pending[0].t_s <= t + 1e-9:
            d = self._pending.pop(0)
            apply_scheduled(self._plant, self._index[d.robot], d, self._camera)
        truth: tuple[tuple[float, float, float], ...] = self._plant.truth_rows()
        self._wheel_meas = (
            self._encoders.read(t, self._plant.wheel_angles())
            if self._encoders is not None
            else None
        )
        self._camera.capture(t, truth)
        self._delivered = self._camera.poll(t)
        for i, stamp, x, y, th in self._delivered:
            self._poses[i] = _tuple_new(Pose, (x, y, th, stamp))
            self._pose_cap[i] = stamp
            self._xyt[i] = (x, y, th)
            self._pose_rx[i] = t
        return truth

    def _coordinate(self, t: float) -> CoordinatorOutput:
        """The coordinator on the fresh measured poses (loop stage 3)."""
        if self._delivered or t - self._oldest_rx > self._stale:
            self._fresh = {}
            self._oldest_rx = math.inf
            for i, q in enumerate(self._xyt):
                if q is not None and t - self._pose_rx[i] <= self._stale:
                    self._fresh[self.robot_ids[i]] = q
                    if self._pose_rx[i] < self._oldest_rx:
                        self._oldest_rx = self._pose_rx[i]
        out: CoordinatorOutput = self._coord.tick(t, self._fresh)
        return out

    def _firmware(self, k: int, t: float) -> list[WheelCommand]:
        """Each firmware on the previous tick's setpoints (loop stage 4)."""
        neighbours = self._neighbours(t)
        prev_out = self._outputs.for_clock(k)
        t_prev = tick_time(k - SETPOINT_DELAY_TICKS, self.dt_s)
        cmds: list[WheelCommand] = []
        asg: Mapping[str, int] = prev_out.assignment if prev_out is not None else {}
        for i, rid in enumerate(self.robot_ids):
            sp = None
            slot = asg.get(rid)
            if slot is not None and prev_out is not None:
                row = prev_out.approach.get(rid) or prev_out.rows[self._slot_row[slot]]
                x, y, vx, vy = row
                sp = _tuple_new(Setpoint, (x, y, vx, vy, prev_out.theta, slot, t_prev))
            cmds.append(
                self._firmwares[i].step(
                    t,
                    pose=self._poses[i],
                    pose_rx_s=self._pose_rx[i],
                    setpoint=sp,
                    setpoint_rx_s=t_prev,
                    neighbours=neighbours[i],
                    pose_capture_s=self._pose_cap[i],
                    wheel_speeds=None if self._wheel_meas is None else self._wheel_meas[i],
                )
            )
        return cmds

    def step(self, actions: Mapping[str, Any] | None = None) -> Observation:
        """Advance one control tick; ``actions`` (robot id -> (omega_right, omega_left) rad/s)
        replace the firmware's wheel speeds of those robots. See the module docstring."""
        if self._k < 0:
            raise ValueError("step before reset(): call reset(seed) first")
        if self._k >= self.ticks:
            raise ValueError(f"the run is over ({self.ticks} ticks): call reset(seed)")
        chosen = self._check_actions(actions) if actions else {}
        k = self._k
        t = tick_time(k, self.dt_s)
        truth = self._sense(t)
        out = self._coordinate(t)
        cmds = self._firmware(k, t)
        self._tracking = [c[4] is Mode.TRACKING for c in cmds]
        wheels = list(map(_xy_of, cmds))
        logged: list[Any] = cmds
        if chosen:
            logged = list(cmds)
            for i, (wr, wl) in chosen.items():
                wheels[i] = (wr, wl)
                # the log's power is what the wheels were told (fraction of the maximum)
                logged[i] = (wr, wl, wr / self._max_wheel, wl / self._max_wheel, cmds[i][4])
        # 5. command link
        self._link.send_all(t, wheels)
        for i, w in self._link.poll(t):
            self._applied[i] = w
        leader = out.leader
        self._ticklog.record(
            truth, leader.x, leader.y, leader.theta, out.rows, out.slot_ids, logged
        )
        asg = out.assignment
        if out.changed or k == 0:
            self._slot_of_changes.append((k, [asg.get(rid, -1) for rid in self.robot_ids]))
        self._outputs.add(k, out)
        # 6. plant
        self._plant.step(self.dt_s, self._applied)
        self._k += 1
        return Observation(
            t_s=t,
            truth=truth,
            measured=tuple(self._poses),
            leader=(leader.x, leader.y, leader.theta),
            assignment=dict(asg),
            firmware=tuple(cmds),
            wheels=tuple(wheels),
        )

    # -- the record ----------------------------------------------------------------------------

    def log(self) -> RunLog:
        """The run so far as a :class:`RunLog` (the same arrays as ``formation sim``'s for the
        same ticks), with the separation accounting over its truth."""
        if self._k <= 0:
            raise ValueError("no tick stepped yet")
        scn = self.scenario
        log = self._ticklog.runlog(
            self.robot_ids,
            self._slot_ids,
            self.dt_s,
            self._slot_of_changes,
            scn.agent.geometry.ref_offset_m,
        )
        # a fresh monitor each call: log() may be called mid-run and again at the end
        monitor = type(self._monitor)(scn.agent.geometry.body_radius_m)
        monitor.update_many(log.t_s, log.truth)
        log.min_separation_m = float(monitor.min_separation_m)
        log.collisions = [_event(e, self.robot_ids) for e in monitor.collisions]
        log.body_radius_m = scn.agent.geometry.body_radius_m
        log.safety_distance_m = scn.agent.safety_distance_m
        log.world = scn.agent.world
        log.filter_counts = {
            rid: fw.safety_filter.status().as_dict()
            for rid, fw in zip(self.robot_ids, self._firmwares, strict=True)
        }
        log.meta = {"scenario": scn.name, "seed": self.seed, "dt_s": self.dt_s, "mode": "api"}
        return log


def _event(e: Any, ids: list[str]) -> dict[str, Any]:
    from formation.sim.simulate import _event_dict

    return _event_dict(e, ids)
