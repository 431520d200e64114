"""Run metrics, computed from a :class:`~formation.runlog.RunLog` (truth, never measurements).

Per robot: formation error RMS after settling (distance from the robot's reference point to its
assigned slot, eqs 17-18), settling time (the time after which that error stays within the
tolerance to the end of the run), peak motor power. For the run: minimum pairwise separation of
axle centres, collisions (pairs closer than two body radii, counted once per contact), each
robot's initial assignment, every role change after it with its time (a clean run has none), and
the leader's identity over time.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from formation.runlog import RunLog


def formation_error(log: RunLog) -> np.ndarray:
    """(T, n) distance between each robot's reference point and its assigned slot (NaN when
    unassigned)."""
    d: np.ndarray = np.linalg.norm(log.ref - log.target, axis=2)
    return d


def settling_time(t_s: np.ndarray, err: np.ndarray, tol_m: float) -> float | None:
    """First time after which ``err`` stays <= tol_m to the end; None if it never settles."""
    bad = ~(err <= tol_m)  # NaN (unassigned) counts as not settled
    if bad[-1]:
        return None
    idx = np.flatnonzero(bad)
    if idx.size == 0:
        return float(t_s[0])
    return float(t_s[idx[-1] + 1])


def _slot_or_none(s: int) -> int | None:
    return None if s < 0 else int(s)


def initial_assignments(log: RunLog) -> list[dict[str, Any]]:
    """Each robot's first slot and when it got it, in time order: {t_s, robot, slot}. Robots
    that never got a slot are left out."""
    out: list[dict[str, Any]] = []
    s = log.slot_of
    if s.shape[0] == 0:
        return out
    assigned = s >= 0
    for j in np.flatnonzero(assigned.any(axis=0)).tolist():
        k = int(np.argmax(assigned[:, j]))
        out.append(
            {"t_s": round(float(log.t_s[k]), 6), "robot": log.robot_ids[j], "slot": int(s[k, j])}
        )
    out.sort(key=lambda e: (e["t_s"], log.robot_ids.index(e["robot"])))
    return out


def role_changes(log: RunLog) -> list[dict[str, Any]]:
    """Every change of a robot's slot after its initial assignment (see
    :func:`initial_assignments`), in time order: {t_s, robot, from_slot, to_slot}. A clean run
    has none; losing a slot (``to_slot`` None) and getting one back are changes."""
    out: list[dict[str, Any]] = []
    s = log.slot_of
    if s.shape[0] < 2:
        return out
    assigned = s >= 0
    first = np.where(assigned.any(axis=0), np.argmax(assigned, axis=0), s.shape[0])
    changed_t, changed_r = np.nonzero(s[1:] != s[:-1])
    for k, j in zip(changed_t.tolist(), changed_r.tolist(), strict=True):
        if k + 1 <= first[j]:  # before or at the robot's first slot: the initial assignment
            continue
        out.append(
            {
                "t_s": round(float(log.t_s[k + 1]), 6),
                "robot": log.robot_ids[j],
                "from_slot": _slot_or_none(int(s[k, j])),
                "to_slot": _slot_or_none(int(s[k + 1, j])),
            }
        )
    return out


def leader_timeline(log: RunLog) -> list[dict[str, Any]]:
    """Who held slot 0 and from when: [{t_s, leader}] (leader None when nobody)."""
    out: list[dict[str, Any]] = []
    prev: str | int | None = -1
    for k in range(log.slot_of.shape[0]):
        row = log.slot_of[k]
        holders = np.flatnonzero(row == 0)
        cur = log.robot_ids[int(holders[0])] if holders.size else None
        if cur != prev:
            out.append({"t_s": round(float(log.t_s[k]), 6), "leader": cur})
            prev = cur
    return out


def settle_for(settle_s: float, duration_s: float) -> float:
    """The settling time a run of ``duration_s`` is measured with: the scenario's ``settle_s``,
    or half the run when the run is not longer than that. ``formation sim``, ``formation up``
    (``plan_run``) and ``formation report`` all use this rule, so the same run gets the same
    metrics from each of them."""
    return settle_s if settle_s < duration_s else duration_s / 2.0


def _finite_or_none(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


def compute(log: RunLog, settle_s: float, settle_tol_m: float) -> dict[str, Any]:
    """All metrics of a run as a JSON-ready dictionary."""
    err = formation_error(log)
    after = log.t_s >= settle_s
    robots: dict[str, Any] = {}
    for j, rid in enumerate(log.robot_ids):
        e = err[:, j]
        e_after = e[after]
        e_after = e_after[np.isfinite(e_after)]
        rms = float(np.sqrt(np.mean(e_after**2))) if e_after.size else None
        peak = float(np.max(np.abs(log.power[:, j, :]))) if log.power.shape[0] else 0.0
        robots[rid] = {
            "formation_error_rms_m": rms,
            "formation_error_max_after_settle_m": float(np.max(e_after)) if e_after.size else None,
            "settling_time_s": settling_time(log.t_s, e, settle_tol_m),
            "peak_motor_power": peak,
            "peak_motor_power_r": float(np.max(np.abs(log.power[:, j, 0]))),
            "peak_motor_power_l": float(np.max(np.abs(log.power[:, j, 1]))),
            "final_slot": int(log.slot_of[-1, j]) if log.slot_of[-1, j] >= 0 else None,
        }
    changes = role_changes(log)
    return {
        "robots": robots,
        "run": {
            "duration_s": float(log.t_s[-1] - log.t_s[0]) if log.t_s.size else 0.0,
            "ticks": int(log.t_s.size),
            "settle_s": settle_s,
            "settle_tol_m": settle_tol_m,
            "min_separation_m": _finite_or_none(log.min_separation_m),
            "collisions": len(log.collisions),
            "collision_events": log.collisions,
            "initial_assignments": initial_assignments(log),
            "role_changes": changes,
            "role_change_count": len(changes),
            "leader_timeline": leader_timeline(log),
            "final_leader": leader_timeline(log)[-1]["leader"] if log.t_s.size else None,
        },
        "meta": log.meta,
    }
