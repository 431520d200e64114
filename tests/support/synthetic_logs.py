"""A synthetic run log for the figures and metrics tests (:func:`synthetic_log`)."""

from __future__ import annotations

import numpy as np

from coordinator.core.formation import FormationSpec
from formation.outputs.runlog import RunLog


def synthetic_log(
    n: int, *, ticks: int = 400, dt_s: float = 0.05, events: bool = True, seed: int = 0
) -> RunLog:
    """A run of ``n`` robots on a lattice of ``n`` slots moving along +x: unassigned at tick 0,
    everyone on its slot from tick 1, errors decaying from a few cm. With ``events``: robots 0
    and 1 swap slots at mid-run (a leader change with an error spike), the last robot loses its
    slot at 3/4 of the run and gets it back at 7/8."""
    rng = np.random.default_rng(seed)
    spec = FormationSpec.lattice(n)
    log = RunLog.allocate([f"r{j + 1}" for j in range(n)], list(spec.slot_ids), ticks)
    t = np.arange(ticks) * dt_s
    log.t_s[:] = t
    lead = np.stack([0.02 * t, np.zeros(ticks), np.zeros(ticks)], axis=1)
    log.leader[:] = lead
    log.slot_xy[:] = lead[:, None, :2] + spec.body_offsets_m[None, :, :]
    slot_of = np.tile(np.arange(n), (ticks, 1))
    slot_of[0] = -1
    mid, late, back = ticks // 2, 3 * ticks // 4, 7 * ticks // 8
    if events and n >= 3:
        slot_of[mid:, [0, 1]] = [1, 0]
        slot_of[late:back, n - 1] = -1
    log.slot_of[:] = slot_of
    err = 0.05 * np.exp(-t / 3.0)[:, None, None] * rng.normal(size=(1, n, 2))
    err = err + 0.001 * rng.normal(size=(ticks, n, 2))
    if events and n >= 3:
        err[mid:, :2] += 0.3 * np.exp(-(t[mid:] - t[mid]) / 2.0)[:, None, None]
    target = np.full((ticks, n, 2), np.nan)
    rows = slot_of >= 0
    kk, jj = np.nonzero(rows)
    target[kk, jj] = log.slot_xy[kk, slot_of[kk, jj]]
    log.target[:] = target
    log.ref[:] = np.where(np.isnan(target), log.slot_xy[:, :n] + err, target + err)
    log.truth[:, :, :2] = log.ref
    log.truth[:, :, 2] = 0.0
    log.power[:] = 0.1 + 0.02 * rng.normal(size=(ticks, n, 2))
    log.power[mid : mid + 20, 0, 0] = -0.6  # a reverse-power spike
    return log
