"""One row of numbers per run: the metrics a study tabulates and plots (from the truth).

Each metric is one number per case (the worst robot where robots differ), named with its unit;
:data:`METRICS` gives its meaning. They extend :func:`formation.outputs.metrics.compute` (which
they reuse for the formation error, settling, motor power and roles) with what the paper's
simulation claims are about:

* ``overshoot_pct``: the error along its initial direction goes past zero by this much of the
  initial error (eqs 17-18; the ideal loop of eqs 23-24 with the paper's poles -0.2 / -0.01
  overshoots by 3.6 %; docs/paper-errata.md);
* ``omega_rms_radps``: the body's turn rate (RMS after settling): the "oscillation" the paper
  sees at small ``l``, on a straight path ideally 0;
* ``heading_settle_s``: time after which every robot's heading stays within
  :data:`HEADING_TOL_RAD` of the leader's: the "lag" of a large ``l`` (the body follows the
  reference point);
* ``fast_pole_fit`` / ``slow_pole_fit``: the closed loop's poles (1/s) measured by a least-squares
  fit of ``e(t) / e0 = a exp(p1 t) + (1 - a) exp(p2 t)`` (the response of eqs 23-24 to an initial
  error) to each robot's error along its initial direction, median over robots.
"""

from __future__ import annotations

import math
from typing import Any, Final

import numpy as np

from formation.outputs import metrics as run_metrics
from formation.outputs.runlog import RunLog

__all__ = ["HEADING_TOL_RAD", "METRICS", "compute", "fit_poles", "overshoot_fraction"]

HEADING_TOL_RAD: Final = 0.1
MIN_E0_M: Final = 0.02
"""Overshoot and pole fits use robots whose initial error is at least this (m)."""
FIT_POINTS: Final = 2000

METRICS: Final[dict[str, str]] = {
    "err_rms_cm": "formation error RMS after settling, worst robot (cm; eqs 17-18)",
    "settling_time_s": "time after which every robot's error stays within the tolerance (s)",
    "unsettled_robots": "robots whose error is above the tolerance at the end",
    "overshoot_pct": "error past zero along its initial direction, worst robot (% of e0)",
    "peak_power_pct": "peak commanded motor power, worst wheel (% of maximum; paper Fig 7)",
    "omega_rms_radps": "body turn rate RMS after settling, worst robot (rad/s): oscillation",
    "heading_settle_s": f"time after which every heading stays within {HEADING_TOL_RAD} rad of "
    "the leader's (s): lag",
    "fast_pole_fit": "fitted fast closed-loop pole (1/s), median over robots (design -0.2)",
    "slow_pole_fit": "fitted slow closed-loop pole (1/s), median over robots (design -0.01)",
    "min_separation_cm": "least distance between two robots' axle centres (cm)",
    "collisions": "body contacts (pairs closer than two body radii)",
    "role_changes": "role changes after the initial assignment",
    "final_leader": "the robot holding the leader slot at the end (text)",
}
"""Every metric of a case: name -> meaning (with its unit)."""


def _initial_error(log: RunLog, j: int) -> tuple[int, np.ndarray] | None:
    """(first assigned tick, error vector slot - reference point there) of robot ``j``."""
    assigned = np.flatnonzero(log.slot_of[:, j] >= 0)
    if assigned.size == 0:
        return None
    k0 = int(assigned[0])
    return k0, log.target[k0, j] - log.ref[k0, j]


def _along(log: RunLog, j: int) -> tuple[np.ndarray, np.ndarray, float] | None:
    """(t - t0, error along its initial direction / |e0|, |e0|) for robot ``j``; None when its
    initial error is below :data:`MIN_E0_M`."""
    first = _initial_error(log, j)
    if first is None:
        return None
    k0, e0 = first
    norm = float(np.hypot(*e0))
    if not norm >= MIN_E0_M:
        return None
    e = log.target[k0:, j] - log.ref[k0:, j]
    s = (e @ (e0 / norm)) / norm
    t = log.t_s[k0:] - log.t_s[k0]
    ok = np.isfinite(s)
    return t[ok], s[ok], norm


def overshoot_fraction(s: np.ndarray) -> float:
    """How far a normalised error ``s`` (1 at the start) goes below 0: ``max(0, -min s)``."""
    return max(0.0, -float(np.min(s))) if s.size else math.nan


def fit_poles(t_s: np.ndarray, s: np.ndarray) -> tuple[float, float]:
    """(fast, slow) poles (1/s) of ``s(t) = a exp(p1 t) + (1 - a) exp(p2 t)`` fitted by least
    squares (scipy), NaN when the fit fails; ``p1 <= p2 < 0`` for a stable response."""
    from scipy.optimize import curve_fit

    if t_s.size < 10:
        return math.nan, math.nan
    stride = max(1, t_s.size // FIT_POINTS)
    t, y = t_s[::stride], s[::stride]

    def model(tt: np.ndarray, a: float, p1: float, p2: float) -> np.ndarray:
        out: np.ndarray = a * np.exp(p1 * tt) + (1.0 - a) * np.exp(p2 * tt)
        return out

    try:
        (_, p1, p2), _ = curve_fit(
            model,
            t,
            y,
            p0=(1.05, -0.2, -0.01),
            bounds=((-10.0, -20.0, -20.0), (10.0, 0.5, 0.5)),
            maxfev=5000,
        )
    except (RuntimeError, ValueError):
        return math.nan, math.nan
    fast, slow = sorted((float(p1), float(p2)))
    return fast, slow


def _unwrapped_rate(log: RunLog, j: int) -> np.ndarray:
    th = np.unwrap(log.truth[:, j, 2])
    rate: np.ndarray = np.gradient(th, log.t_s) if log.t_s.size > 1 else np.zeros(1)
    return rate


def _heading_settle(log: RunLog) -> float:
    d = log.truth[:, :, 2] - log.leader[:, None, 2]
    d = np.abs((d + np.pi) % (2 * np.pi) - np.pi)
    worst = 0.0
    for j in range(d.shape[1]):
        t = run_metrics.settling_time(log.t_s, d[:, j], HEADING_TOL_RAD)
        if t is None:
            return math.nan
        worst = max(worst, t)
    return worst


def _num(v: Any) -> float:
    return math.nan if v is None else float(v)


def compute(log: RunLog, settle_s: float, settle_tol_m: float) -> dict[str, Any]:
    """The metrics of :data:`METRICS` for one run (NaN where a metric does not apply)."""
    m = run_metrics.compute(log, settle_s, settle_tol_m)
    robots = m["robots"].values()
    rms = [r["formation_error_rms_m"] for r in robots if r["formation_error_rms_m"] is not None]
    settle = [r["settling_time_s"] for r in robots]
    after = log.t_s >= settle_s
    overshoot: list[float] = []
    fast: list[float] = []
    slow: list[float] = []
    omega_rms: list[float] = []
    for j in range(len(log.robot_ids)):
        if after.sum() > 1:
            w = _unwrapped_rate(log, j)[after]
            omega_rms.append(float(np.sqrt(np.mean(w**2))))
        resp = _along(log, j)
        if resp is None:
            continue
        t, s, _ = resp
        overshoot.append(overshoot_fraction(s))
        p_fast, p_slow = fit_poles(t, s)
        if math.isfinite(p_fast):
            fast.append(p_fast)
            slow.append(p_slow)
    run = m["run"]
    return {
        "err_rms_cm": max(rms) * 100.0 if rms else math.nan,
        "settling_time_s": math.nan if None in settle or not settle else max(settle),
        "unsettled_robots": sum(1 for v in settle if v is None),
        "overshoot_pct": max(overshoot) * 100.0 if overshoot else math.nan,
        "peak_power_pct": max((r["peak_motor_power"] for r in robots), default=0.0) * 100.0,
        "omega_rms_radps": max(omega_rms) if omega_rms else math.nan,
        "heading_settle_s": _heading_settle(log),
        "fast_pole_fit": float(np.median(fast)) if fast else math.nan,
        "slow_pole_fit": float(np.median(slow)) if slow else math.nan,
        "min_separation_cm": _num(run["min_separation_m"]) * 100.0,
        "collisions": run["collisions"],
        "role_changes": run["role_change_count"],
        "final_leader": run["final_leader"] or "",
    }
