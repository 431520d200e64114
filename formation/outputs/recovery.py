"""Recovery from each fault of a run, from its RunLog (``metrics.json`` ``faults``).

Every runner lists the faults it sent in ``log.meta["faults"]`` (dictionaries with at least
``kind``, ``robot`` and ``t_s``, the run's time base: seconds from the log's first row).
:func:`fault_recovery` measures, per fault, from the log alone (so ``formation sim``, ``formation
up`` and ``formation report`` of a recording compute it the same way):

* ``detection_s``: from the fault to the first row at which the coordinator's assignment no
  longer gives the faulted robot a slot (a kill, pause or cut off of an assigned robot; None for
  other kinds, or if it never happens before the next fault);
* ``reassignment_s``: from the fault to the first row, from the detection on, at which another
  robot's slot changed; ``new_leader`` holds slot 0 then (without a reassignment: at the end of
  the window);
* ``recovered_s`` / ``recovered_at_s``: from the fault to the moment after which the formation
  error (eqs. 17-18: reference point to assigned slot, from truth) of every robot still online
  stays within ``tol_m`` until the next fault or the end of the run (the settling rule of
  :func:`formation.outputs.metrics.settling_time`); None if it never comes back;
* ``peak_error_m``: the largest of those errors from the fault to the recovery (or the window's
  end); ``min_separation_m``: the least centre distance between any two robots (a dead robot
  is still an obstacle) over the same span.

Undo actions (the end of a ``duration_s``) are listed with ``undo: true``; they are windows'
ends, not faults of their own, and carry no recovery figures.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from formation.outputs import metrics as metrics_mod
from formation.outputs.runlog import RunLog

__all__ = ["OFFLINE_KINDS", "fault_recovery"]

OFFLINE_KINDS = frozenset({"kill", "pause", "cut_link"})
BACK_KINDS = frozenset({"resume", "restore_link"})


def _rounded(x: float | None) -> float | None:
    return None if x is None or not math.isfinite(x) else round(float(x), 6)


def _row(t_s: np.ndarray, at_s: float) -> int:
    """The first row at or after ``at_s``."""
    return int(np.searchsorted(t_s, at_s - 1e-9, side="left"))


def fault_recovery(
    log: RunLog, tol_m: float, faults: Sequence[dict[str, Any]] | None = None
) -> list[dict[str, Any]]:
    """Each fault of ``faults`` (default ``log.meta["faults"]``) with its recovery figures."""
    sent = list(log.meta.get("faults", []) if faults is None else faults)
    if log.t_s.size == 0 or not sent:
        return [dict(f) for f in sent]
    t = log.t_s - log.t_s[0]
    ids = list(log.robot_ids)
    col = {rid: j for j, rid in enumerate(ids)}
    err = metrics_mod.formation_error(log)
    sep = metrics_mod.min_pair_distance(log.truth)
    starts = [float(f["t_s"]) for f in sent if not f.get("undo")]
    offline: set[str] = set()
    out: list[dict[str, Any]] = []
    for f in sent:
        kind = f.get("kind")
        robot = f.get("robot")
        if kind in OFFLINE_KINDS and robot in col:
            offline.add(robot)
        elif kind in BACK_KINDS and robot in offline:
            offline.discard(robot)
        entry = dict(f)
        if f.get("undo"):
            out.append(entry)
            continue
        t0 = float(f["t_s"])
        later = [s for s in starts if s > t0 + 1e-9]
        t_end = later[0] if later else math.inf
        k0 = _row(t, t0)
        k1 = _row(t, t_end) if math.isfinite(t_end) else t.size
        entry.update(
            detection_s=None,
            reassignment_s=None,
            new_leader=None,
            recovered_s=None,
            recovered_at_s=None,
            peak_error_m=None,
            min_separation_m=None,
        )
        if k0 >= k1:
            out.append(entry)
            continue
        slots = log.slot_of[k0:k1]
        k_detect = k0
        if kind in OFFLINE_KINDS and robot in col:
            gone = np.flatnonzero(slots[:, col[robot]] < 0)
            if gone.size:
                k_detect = k0 + int(gone[0])
                entry["detection_s"] = _rounded(float(t[k_detect]) - t0)
        others = [j for j, rid in enumerate(ids) if rid != robot]
        k_lead = k1 - 1  # who leads: right after the reassignment, else at the window's end
        if others and k_detect > 0:
            base = log.slot_of[k_detect - 1, others]
            changed = np.flatnonzero((log.slot_of[k_detect:k1][:, others] != base).any(axis=1))
            if changed.size:
                k_re = k_detect + int(changed[0])
                entry["reassignment_s"] = _rounded(float(t[k_re]) - t0)
                k_lead = k_re
        holders = np.flatnonzero(log.slot_of[k_lead] == 0)
        entry["new_leader"] = ids[int(holders[0])] if holders.size else None
        live = [col[r] for r in ids if r not in offline]
        entry.update(_window(t, err, sep, live, (k0, k1), t0, tol_m))
        out.append(entry)
    return out


def _window(
    t: np.ndarray,
    err: np.ndarray,
    sep: np.ndarray,
    live: list[int],
    rows: tuple[int, int],
    t0: float,
    tol_m: float,
) -> dict[str, Any]:
    """Recovery time, peak error and least separation over rows ``[k0, k1)`` of a fault at
    ``t0``, for the robots (columns) ``live``."""
    k0, k1 = rows
    got: dict[str, Any] = {}
    k_rec = k1
    if live:
        seg = err[k0:k1][:, live]
        finite = np.isfinite(seg)
        worst = np.where(
            finite.any(axis=1), np.nanmax(np.where(finite, seg, -np.inf), axis=1), np.nan
        )
        settled = metrics_mod.settling_time(t[k0:k1], worst, tol_m)
        if settled is not None:
            got["recovered_at_s"] = _rounded(settled)
            got["recovered_s"] = _rounded(settled - t0)
            k_rec = max(k0 + 1, _row(t, settled) + 1)
        span = worst[: k_rec - k0]
        if np.isfinite(span).any():
            got["peak_error_m"] = float(np.nanmax(span))
    got["min_separation_m"] = _rounded(float(np.min(sep[k0:k_rec])))
    return got
