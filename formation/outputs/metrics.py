"""Run metrics, computed from a :class:`~formation.outputs.runlog.RunLog` (truth, never
measurements).

Per robot: formation error RMS after settling (distance from the robot's reference point to its
assigned slot, eqs 17-18), settling time (the time after which that error stays within the
tolerance to the end of the run), peak motor power. For the run: minimum pairwise separation of
axle centres, collisions (pairs closer than two body radii, counted once per contact), each
robot's initial assignment, every role change after it with its time (a clean run has none), and
the leader's identity over time.

Safety (issue 14), under the ``safety`` key (not ``run``: a recording and the simulator agree on
``run`` tick for tick, while a distributed run knows the filter counters only as of each agent's
last status):
minimum separation, the time some pair of centres is closer than the safety distance Ds, the
boundary violations (a body overlapping an obstacle or over the arena's edge, from the truth,
counted once per entry like a collision), and from the robots' safety filter counters the
filter-active fraction, the deadlock tie-breaks, the barrier violations and the infeasible ticks
(``filter_source`` says where those came from: ``"firmware"`` in-process; ``"status"`` from the
agents' ``Status.filter`` on the bus (formation.record.collector: each robot's last status, so up to
one status period behind the end of the run); ``null`` when the run did not report them).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from formation.outputs.runlog import RunLog


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


def _tick_weights(t_s: np.ndarray) -> np.ndarray:
    """How long each row stands for (s): the gap to the next row, the last one the median."""
    if t_s.size == 0:
        return np.zeros(0)
    if t_s.size == 1:
        return np.zeros(1)
    gaps = np.diff(t_s)
    return np.append(gaps, float(np.median(gaps)))


def min_pair_distance(truth: np.ndarray, block_ticks: int = 0) -> np.ndarray:
    """(T,) least centre distance over all robot pairs at each tick (inf with < 2 robots;
    NaN positions are ignored)."""
    ticks, n = truth.shape[0], truth.shape[1]
    out = np.full(ticks, np.inf)
    if n < 2 or ticks == 0:
        return out
    iu, ju = np.triu_indices(n, k=1)
    block = block_ticks or max(1, (1 << 20) // len(iu))
    for k0 in range(0, ticks, block):
        xy = truth[k0 : k0 + block, :, :2]
        d = np.hypot(xy[:, iu, 0] - xy[:, ju, 0], xy[:, iu, 1] - xy[:, ju, 1])
        d = np.where(np.isnan(d), np.inf, d)
        out[k0 : k0 + block] = d.min(axis=1)
    return out


def boundary_clearance(log: RunLog) -> list[tuple[str, np.ndarray]]:
    """Per obstacle of ``log.world`` (``"obstacle[k]"``) and the arena (``"arena"``): the (T, n)
    gap between each robot's body (disc of ``log.body_radius_m`` at the axle centre) and it (m,
    < 0: overlap / over the edge)."""
    world = log.world
    if world is None:
        return []
    from robot_agent.core.params import CircleObstacle

    r_b = log.body_radius_m if math.isfinite(log.body_radius_m) else 0.0
    x = log.truth[:, :, 0]
    y = log.truth[:, :, 1]
    out: list[tuple[str, np.ndarray]] = []
    for k, o in enumerate(world.obstacles):
        if isinstance(o, CircleObstacle):
            gap = np.hypot(x - o.x, y - o.y) - o.radius_m - r_b
        else:
            sx, sy = o.x2 - o.x1, o.y2 - o.y1
            len2 = sx * sx + sy * sy
            t = ((x - o.x1) * sx + (y - o.y1) * sy) / len2 if len2 > 0.0 else np.zeros_like(x)
            t = np.clip(t, 0.0, 1.0)
            gap = np.hypot(x - (o.x1 + t * sx), y - (o.y1 + t * sy)) - o.radius_m - r_b
        out.append((f"obstacle[{k}]", gap))
    a = world.arena
    if a is not None:
        gap = np.minimum(np.minimum(x - a.x_min, a.x_max - x), np.minimum(y - a.y_min, a.y_max - y))
        out.append(("arena", gap - r_b))
    return out


def _entries(bad: np.ndarray) -> np.ndarray:
    """(k, 2) (tick, robot) where ``bad`` (T, n) becomes true (counted once per entry)."""
    prev = np.zeros((1, bad.shape[1]), dtype=bool)
    starts = bad & ~np.concatenate([prev, bad[:-1]], axis=0)
    return np.argwhere(starts)


def attach_agent(log: RunLog, agent: Any) -> RunLog:
    """Give ``log`` what the safety metrics need from the run's ``AgentConfig`` (body radius,
    Ds, the world map); returns ``log``. The filter counters stay as they are."""
    log.body_radius_m = agent.geometry.body_radius_m
    log.safety_distance_m = agent.safety_distance_m
    log.world = agent.world
    return log


def safety_metrics(log: RunLog) -> dict[str, Any]:
    """The run's safety figures (see the module docstring), JSON-ready."""
    w = _tick_weights(log.t_s)
    ds = log.safety_distance_m
    dmin = min_pair_distance(log.truth)
    out: dict[str, Any] = {
        "safety_distance_m": _finite_or_none(ds),
        "body_radius_m": _finite_or_none(log.body_radius_m),
        "min_separation_m": _finite_or_none(float(dmin.min())) if dmin.size else None,
        "time_below_ds_s": float(w[dmin < ds].sum()) if math.isfinite(ds) else None,
        "time_touching_s": (
            float(w[dmin < 2.0 * log.body_radius_m].sum())
            if math.isfinite(log.body_radius_m)
            else None
        ),
    }
    events: list[dict[str, Any]] = []
    min_gap = math.inf
    for what, gap in boundary_clearance(log):
        finite = gap[np.isfinite(gap)]
        if finite.size:
            min_gap = min(min_gap, float(finite.min()))
        for k, j in _entries(gap < 0.0).tolist():
            events.append(
                {
                    "t_s": round(float(log.t_s[k]), 6),
                    "robot": log.robot_ids[j],
                    "boundary": what,
                    "clearance_m": float(gap[k, j]),
                }
            )
    events.sort(key=lambda e: (e["t_s"], e["robot"], e["boundary"]))
    out["boundary_violations"] = len(events)
    out["boundary_violation_events"] = events[:100]
    out["min_boundary_clearance_m"] = _finite_or_none(min_gap)
    counts = log.filter_counts
    if counts:
        # an agent host's batched status carries no tick count: no fraction for its robots
        fraction_known = all("ticks" in c for c in counts.values())
        ticks = sum(int(c.get("ticks", 0)) for c in counts.values())
        active = sum(int(c.get("active", 0)) for c in counts.values())
        out["filter_source"] = log.filter_source
        out["filter_active_fraction"] = (
            (active / ticks if ticks else 0.0) if fraction_known else None
        )
        out["tiebreaks"] = sum(int(c.get("tiebreaks", 0)) for c in counts.values())
        out["filter_violations"] = sum(int(c.get("violations", 0)) for c in counts.values())
        out["filter_infeasible"] = sum(int(c.get("infeasible", 0)) for c in counts.values())
        out["filter_per_robot"] = {
            rid: {
                "active_fraction": (
                    int(c.get("active", 0)) / int(c["ticks"]) if c["ticks"] else 0.0
                )
                if "ticks" in c
                else None,
                "tiebreaks": int(c.get("tiebreaks", 0)),
                "violations": int(c.get("violations", 0)),
            }
            for rid, c in sorted(counts.items())
        }
    else:
        out["filter_source"] = None
        for name in ("filter_active_fraction", "tiebreaks", "filter_violations",
                     "filter_infeasible", "filter_per_robot"):  # fmt: skip
            out[name] = None
    return out


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
        "safety": safety_metrics(log),
        "reshapes": reshape_metrics(log),
        "meta": log.meta,
    }


def reshape_metrics(log: RunLog) -> list[dict[str, Any]]:
    """Each runtime reshape of the run (issue 28, ``log.reshapes``): its kind, the number of
    slots it ends with (None: not recorded), start, transition
    time (s, as the leader messages reported it running), the least distance between two
    robots' axle centres (m, the truth) during it, and whether it was complete (a run that
    ended during a reshape reports the part it saw)."""
    out: list[dict[str, Any]] = []
    for r in log.reshapes:
        start, end = float(r["start_s"]), float(r["end_s"])
        inside = (log.t_s >= start) & (log.t_s <= end)
        least = math.inf
        pts = log.truth[inside, :, :2]
        n = pts.shape[1]
        for i in range(n):
            for j in range(i + 1, n):
                d = np.hypot(pts[:, i, 0] - pts[:, j, 0], pts[:, i, 1] - pts[:, j, 1])
                d = d[np.isfinite(d)]
                if d.size:
                    least = min(least, float(d.min()))
        out.append(
            {
                "kind": r["kind"],
                "start_s": start,
                "transition_s": end - start,
                "least_separation_m": _finite_or_none(least),
                "complete": bool(r.get("complete", True)),
                "slots": r.get("slots"),
            }
        )
    return out
