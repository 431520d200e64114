"""A run's plan as the tools show it: the leader's planned path, the footprint corridor, the
plan's figures and its replans (issue 27, deliverables 4 and 8).

``formation sim`` (metrics.json, ``trajectories.png``), ``formation report`` (the same, from a
recording) and the live Foxglove scene (``formation.live.scene``) all read a plan through
:func:`plan_view`:

* the **planned leader path** (the virtual leader's ``x, y`` along the plan, m);
* the **footprint corridor**: the union of every slot's disc (``Footprint.slot_radius_m``: body,
  reference offset, filter margin, planning clearance) swept along the slot's planned path,
  squeeze included (shapely: each slot's path buffered by the radius, then the union). It is
  the area the plan keeps clear of every obstacle, the first of the paper's two
  collision-avoidance layers;
* the plan's figures: length against the straight line through the via points, least planned
  clearance (slot point to obstacle or wall), time to the goal as planned, and the time it
  took to plan, wall and CPU (measured here, by planning the same inputs once more: the plan
  is a deterministic function of the scenario, ``coordinator.core.planning.trajectory``);
* the **replans**: ``RunLog.replans``, one ``{t_s, reason, plan_time_s, length_m}`` per replan
  the coordinator made at run time (optionally ``path``: the new plan's leader path as
  ``[[x, y], ...]``, drawn when given): every plan the coordinator switched in at run time
  (the first plan of an operator's goal, every replan) or found to have no way. The in-process
  simulator fills the list from the coordinator core (:func:`replan_events`: with each path);
  a recording from the coordinator's status (``formation.record.collector_plans``: times,
  reasons and plan times; the status carries no path, so a recorded replan is a mark where
  the virtual leader was, and the path it then followed is the leader's logged track).

:func:`plan_metrics` is the ``plan`` entry of metrics.json (``null`` for a run without a plan):
the plan's figures plus what the run did with it (``time_to_goal_s``: from the start of the run
to the first instant after which the virtual leader is on its goal and every assigned robot is
within the settling band of its slot; ``replans`` and their list; ``runtime``: the coordinator's
counts, :func:`planner_counts`). A scripted trajectory with run-time plans (an operator's goal
around an obstacle) gets a ``plan`` entry of those only (:func:`runtime_plan_metrics`).
:func:`draw_plan` draws the corridor (translucent), the planned path, the goal and every replan
on a matplotlib axis.
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Final

import numpy as np
import numpy.typing as npt
import shapely
from shapely.geometry import LineString, MultiPolygon, Point, Polygon
from shapely.geometry.base import BaseGeometry
from shapely.geometry.polygon import orient

from formation.outputs.metrics import formation_error, settling_time

__all__ = [
    "CORRIDOR_STEP_M",
    "MESH_TOL_M",
    "PlanMesh",
    "PlanView",
    "Replan",
    "add_plan",
    "draw_plan",
    "draw_replans",
    "plan_mesh",
    "plan_metrics",
    "plan_summary",
    "plan_view",
    "planner_counts",
    "replan_events",
    "replans_of",
    "runtime_plan_metrics",
    "time_to_goal",
]

F64 = npt.NDArray[np.float64]

CORRIDOR_STEP_M: Final = 0.005
"""Largest step (m) of a slot between two of the positions the corridor is swept through (the
chords of a slot's path then stay within a fraction of a millimetre of it; at 2 cm steps of
the leader they cut 4 mm off a slot's disc on the ``maze`` plan)."""
SIMPLIFY_M: Final = 1e-4
"""Each slot's sampled path is simplified by this much (m) before it is swept: the buffers of
the straight stretches then cost a few segments, not hundreds."""
GOAL_TOL_M: Final = 1e-3
"""The virtual leader is on its goal within this distance (m); a plan ends on it exactly."""
REASON_MAX: Final = 80


@dataclass(frozen=True)
class Replan:
    """One replan of a run: when (s, on the run's time axis), why, how long planning took (s),
    the new plan's length (m) and, when known, its leader path (m)."""

    t_s: float
    reason: str
    plan_time_s: float | None
    length_m: float | None
    path: F64 | None = None

    def as_dict(self) -> dict[str, Any]:
        """The metrics.json form (``path`` left out: the figure draws it)."""
        return {
            "t_s": self.t_s,
            "reason": self.reason,
            "plan_time_s": self.plan_time_s,
            "length_m": self.length_m,
        }


@dataclass(frozen=True)
class PlanView:
    """A plan drawn and measured (module docstring). Lengths in m, times in s."""

    path: F64
    """(N, 2) the virtual leader's planned path."""
    corridor: BaseGeometry
    """The footprint corridor (a shapely (Multi)Polygon)."""
    slot_radius_m: float
    goal: tuple[float, float]
    length_m: float
    straight_m: float
    min_clearance_m: float
    duration_s: float
    t_start_s: float
    squeezes: bool
    plan_time_s: float | None = None
    """Wall time of planning (s); None when not measured."""
    plan_cpu_s: float | None = None
    """CPU time of this process while planning (s): less sensitive than the wall time to the
    other processes of a loaded machine."""
    replans: tuple[Replan, ...] = field(default=())


def _number(v: Any) -> float | None:
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
        return None
    return float(v)


def replans_of(events: Iterable[Mapping[str, Any]]) -> tuple[Replan, ...]:
    """Replan events (``RunLog.replans``: dicts) as :class:`Replan`, in time order. An event
    without a finite ``t_s`` is left out; other missing or bad fields become None, a bad path
    is dropped (the events come from a recording: never trusted)."""
    out: list[Replan] = []
    for e in events:
        t = _number(e.get("t_s"))
        if t is None:
            continue
        reason = e.get("reason")
        path: F64 | None = None
        raw = e.get("path")
        if raw is not None:
            try:
                arr = np.asarray(raw, dtype=float)
            except (TypeError, ValueError):
                arr = np.empty((0, 2))
            if arr.ndim == 2 and arr.shape[1] == 2 and len(arr) >= 2 and np.isfinite(arr).all():
                path = arr
        out.append(
            Replan(
                t_s=t,
                reason=str(reason)[:REASON_MAX] if isinstance(reason, str) else "?",
                plan_time_s=_number(e.get("plan_time_s")),
                length_m=_number(e.get("length_m")),
                path=path,
            )
        )
    out.sort(key=lambda r: r.t_s)
    return tuple(out)


def replan_events(events: Iterable[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """``RunLog.replans`` from the coordinator core's ``ReplanStats.events`` (times on the
    tick clock, which is the log's axis in-process): a plan switched in keeps its path; a plan
    refused (no way) has its reason followed by the planner's one line and no length."""
    out: list[dict[str, Any]] = []
    for e in events:
        ms = _number(e.get("plan_ms"))
        reason = str(e.get("reason", "?"))
        if not e.get("ok", False):
            reason = f"{reason}: {e.get('why') or 'no plan'}"
        rec: dict[str, Any] = {
            "t_s": e.get("t_s"), "reason": reason[:REASON_MAX],
            "plan_time_s": None if ms is None else ms / 1e3, "length_m": e.get("length_m"),
        }  # fmt: skip
        if e.get("path") is not None:
            rec["path"] = [[float(a), float(b)] for a, b in e["path"]]
        out.append(rec)
    return out


def planner_counts(stats: Any) -> dict[str, Any]:
    """The coordinator's run-time planner figures (a ``ReplanStats``, or the status's fields
    as the collector read them): plans made, replans among them, the last plan's compute time
    (ms), the least planned clearance of the plan followed (m), late plans."""
    return {
        "plans": int(stats.plans),
        "replans": int(stats.replans),
        "plan_ms": _number(stats.plan_ms),
        "min_clearance_m": _number(stats.min_clearance_m),
        "late": int(stats.late),
    }


def _slots_at(traj: Any, spec: Any, s_grid: F64) -> F64:
    """(K, n, 2) every slot's planned position with the leader at the arc lengths ``s_grid``
    (m; the coordinator's arithmetic, the squeeze's offsets included)."""
    from coordinator.core.formation import morphed_slot_rows, slot_rows

    r = traj.result
    # the time of each arc length (s(t) is increasing: the leader never stops mid-plan)
    t_grid = traj.t_start_s + np.interp(s_grid, r.s_m, r.t_s)
    out = np.empty((len(s_grid), len(spec), 2))
    for k, t in enumerate(t_grid.tolist()):
        leader = traj.sample(t)
        offs = traj.slot_offsets(t)
        _, rows = slot_rows(spec, leader) if offs is None else morphed_slot_rows(leader, offs)
        out[k] = [(row[0], row[1]) for row in rows]
    return out


def _slot_paths(traj: Any, formation: Mapping[str, Any]) -> F64:
    """(K, n, 2) every slot's planned path, no slot moving more than :data:`CORRIDOR_STEP_M`
    between two rows: the leader every :data:`CORRIDOR_STEP_M` of its path, then finer where
    a slot moves faster than the leader (an outer slot on a tight turn moves up to four times
    as far on the built-in plans)."""
    from coordinator.core.formation import FormationSpec

    spec = FormationSpec.from_dict(dict(formation))
    s_end = float(traj.result.s_m[-1])
    s_grid = np.linspace(0.0, s_end, max(2, math.ceil(s_end / CORRIDOR_STEP_M) + 1))
    coarse = _slots_at(traj, spec, s_grid)
    moved = np.hypot(*np.diff(coarse, axis=0).transpose(2, 0, 1)).max(axis=1)
    parts = np.ceil(moved / CORRIDOR_STEP_M).astype(int)
    if (parts <= 1).all():
        return coarse
    fine = [s_grid[:1]]
    for k in range(len(moved)):
        fine.append(np.linspace(s_grid[k], s_grid[k + 1], max(parts[k], 1) + 1)[1:])
    return _slots_at(traj, spec, np.concatenate(fine))


def corridor_of(slot_paths: F64, radius_m: float) -> BaseGeometry:
    """The union of a disc of ``radius_m`` swept along each slot's path ((K, n, 2), m)."""
    parts = []
    for j in range(slot_paths.shape[1]):
        pts = slot_paths[:, j, :]
        keep = np.r_[True, np.hypot(*np.diff(pts, axis=0).T) > 1e-9]
        pts = pts[keep]
        geom = LineString(pts).simplify(SIMPLIFY_M) if len(pts) >= 2 else Point(pts[0])
        parts.append(geom.buffer(radius_m, quad_segs=8))
    return shapely.union_all(parts)


def plan_view(
    trajectory: Mapping[str, Any], replans: Iterable[Mapping[str, Any]] = (), *, timed: bool = True
) -> PlanView | None:
    """The plan of a scenario's trajectory table (``Scenario.trajectory``, with the
    ``context`` ``scenario.load`` adds), or None when it is not ``kind = "plan"``. ``timed``:
    measure the plan time by planning the same inputs once more (about as long as the plan
    took at start: 0.1-0.3 s for the built-in scenarios). Raises ValueError when the table does
    not plan (the run could not have started with it)."""
    if trajectory.get("kind") != "plan":
        return None
    from coordinator.core.planning.feasibility import trajectory_of
    from coordinator.core.planning.trajectory import PlannedTrajectory, plan_from_context

    traj = trajectory_of(trajectory)
    if not isinstance(traj, PlannedTrajectory):  # pragma: no cover - kind "plan" builds one
        raise ValueError("trajectory: kind = 'plan' did not build a plan")
    r = traj.result
    plan_time: float | None = None
    plan_cpu: float | None = None
    if timed:
        start = traj.context.get("start", (0.0, 0.0, 0.0))
        canon = {
            "goal": [float(v) for v in traj.goal], "via": [list(v) for v in traj.via],
            "goal_heading": traj.goal_heading, "speed_mps": float(traj.speed_mps),
            "clearance_m": float(traj.clearance_m),
            "x0": float(start[0] if traj.x0 is None else traj.x0),
            "y0": float(start[1] if traj.y0 is None else traj.y0),
            "heading": float(start[2] if traj.heading is None else traj.heading),
            "context": traj.context,
        }  # fmt: skip
        t0, c0 = time.perf_counter(), time.process_time()
        plan_from_context(canon)  # the same inputs, planned again (not the cached result)
        plan_time, plan_cpu = time.perf_counter() - t0, time.process_time() - c0
    formation = traj.context["formation"]
    corridor = corridor_of(_slot_paths(traj, formation), r.footprint.slot_radius_m)
    st = r.stats
    return PlanView(
        path=np.column_stack([r.x_m, r.y_m]),
        corridor=corridor,
        slot_radius_m=float(r.footprint.slot_radius_m),
        goal=(float(traj.goal[0]), float(traj.goal[1])),
        length_m=float(st.length_m),
        straight_m=float(st.straight_m),
        min_clearance_m=float(st.min_clearance_m),
        duration_s=float(st.duration_s),
        t_start_s=float(traj.t_start_s),
        squeezes=bool(st.squeezes),
        plan_time_s=plan_time,
        plan_cpu_s=plan_cpu,
        replans=replans_of(replans),
    )


# -- metrics ---------------------------------------------------------------------------------


def time_to_goal(log: Any, goal: tuple[float, float], tol_m: float) -> float | None:
    """Seconds from the first row of ``log`` (a RunLog) to the first instant after which the
    virtual leader stays within :data:`GOAL_TOL_M` of ``goal`` and every robot that holds a slot
    stays within ``tol_m`` of it to the end of the run; None if that never holds at the end."""
    if log.t_s.size == 0:
        return None
    at_goal = np.hypot(log.leader[:, 0] - goal[0], log.leader[:, 1] - goal[1]) <= GOAL_TOL_M
    err = formation_error(log)
    held = log.slot_of >= 0
    worst = np.where(held, np.where(np.isfinite(err), err, np.inf), 0.0).max(axis=1)
    worst = np.where(at_goal & held.any(axis=1), worst, np.inf)
    settled = settling_time(log.t_s, worst, tol_m)
    return None if settled is None else round(settled - float(log.t_s[0]), 6)


def plan_metrics(view: PlanView | None, log: Any, tol_m: float) -> dict[str, Any] | None:
    """The ``plan`` entry of metrics.json (module docstring); None without a plan."""
    if view is None:
        return None
    return {
        "plan_time_s": view.plan_time_s,
        "plan_cpu_s": view.plan_cpu_s,
        "length_m": view.length_m,
        "straight_m": view.straight_m,
        "length_ratio": view.length_m / view.straight_m if view.straight_m > 0 else None,
        "min_clearance_m": view.min_clearance_m,
        "slot_radius_m": view.slot_radius_m,
        "squeezes": view.squeezes,
        "goal": list(view.goal),
        "planned_time_to_goal_s": view.t_start_s + view.duration_s,
        "time_to_goal_s": time_to_goal(log, view.goal, tol_m),
        "corridor_area_m2": float(view.corridor.area),
        "replans": len(view.replans),
        "replan_events": [r.as_dict() for r in view.replans],
    }


def runtime_plan_metrics(log: Any) -> dict[str, Any] | None:
    """The ``plan`` entry of a run whose trajectory is not planned but whose coordinator made
    plans at run time (an operator's goal around an obstacle): the replans and the
    coordinator's counts only; None if it made none."""
    events = replans_of(getattr(log, "replans", ()))
    counts = getattr(log, "meta", {}).get("planner")
    if not events and not counts:
        return None
    return {
        "replans": len(events),
        "replan_events": [r.as_dict() for r in events],
        "runtime": counts,
    }


def add_plan(m: dict[str, Any], trajectory: Mapping[str, Any], log: Any, tol_m: float) -> Any:
    """Set ``m["plan"]`` (metrics.json) from the run's trajectory table and ``log`` (its
    ``replans``); return the :class:`PlanView` for the figures (None without a plan)."""
    view = plan_view(trajectory, getattr(log, "replans", ()))
    m["plan"] = plan_metrics(view, log, tol_m)
    if m["plan"] is None:
        m["plan"] = runtime_plan_metrics(log)
    elif getattr(log, "meta", {}).get("planner"):
        m["plan"]["runtime"] = log.meta["planner"]
    return view


def plan_summary(p: Mapping[str, Any] | None) -> str | None:
    """One line for the run's summary table; None without a plan."""
    if not p:
        return None
    if "length_m" not in p:  # run-time plans only (runtime_plan_metrics)
        rt = p.get("runtime") or {}
        return f"plan: made at run time {rt.get('plans', p['replans'])} time(s), " + (
            f"replans {rt.get('replans', p['replans'])}"
        )
    ratio = p.get("length_ratio")
    took = p.get("plan_time_s")
    cpu = p.get("plan_cpu_s")
    reached = p.get("time_to_goal_s")
    return (
        f"plan: {p['length_m']:.2f} m (straight {p['straight_m']:.2f} m"
        + (f", x{ratio:.2f}" if ratio is not None else "")
        + ")"
        + (f", planned in {took * 1e3:.0f} ms" if took is not None else "")
        + (f" ({cpu * 1e3:.0f} ms CPU)" if cpu is not None else "")
        + f", least clearance {p['min_clearance_m']:.3f} m, time to goal "
        + (f"{reached:.1f} s" if reached is not None else "not reached")
        + f" (planned {p['planned_time_to_goal_s']:.1f} s), replans {p['replans']}"
    )


# -- a mesh for 3D scenes ------------------------------------------------------------------

MESH_TOL_M: Final = 0.002
"""Simplification tolerance (m) of the corridor and path sent to a 3D scene: 2 mm, a third of
the vertices of the exact union (the figure and the metrics use the exact one)."""


@dataclass(frozen=True)
class PlanMesh:
    """A plan for a 3D scene (m): the leader ``path`` (K, 2); the corridor as ``vertices``
    (V, 2) and ``triangles`` (T, 3) indices into them (a constrained Delaunay triangulation of
    the corridor, holes kept open); its ``outlines`` (every ring, closed); the replans' marks
    ``(x, y, label)``."""

    path: F64
    vertices: F64
    triangles: npt.NDArray[np.int64]
    outlines: tuple[F64, ...]
    marks: tuple[tuple[float, float, str], ...] = ()


def plan_mesh(view: PlanView, tol_m: float = MESH_TOL_M) -> PlanMesh:
    """:class:`PlanMesh` of ``view``, simplified by ``tol_m`` (m). Each replan with a known
    path is marked where its path starts."""
    corridor = view.corridor.simplify(tol_m) if tol_m > 0 else view.corridor
    tris = shapely.get_parts(shapely.constrained_delaunay_triangles(corridor))
    index: dict[tuple[float, float], int] = {}
    triangles: list[list[int]] = []
    for tri in tris:
        corners = list(tri.exterior.coords)[:3]
        triangles.append([index.setdefault((float(x), float(y)), len(index)) for x, y in corners])
    vertices = np.array(list(index), dtype=float).reshape(-1, 2)
    outlines = tuple(
        np.asarray(ring.coords)
        for poly in _polygons(corridor)
        for ring in (poly.exterior, *poly.interiors)
    )
    path_line = LineString(view.path).simplify(tol_m) if tol_m > 0 else LineString(view.path)
    marks = tuple(
        (float(r.path[0, 0]), float(r.path[0, 1]), f"{REPLAN_LABEL} {n}: {r.reason}")
        for n, r in enumerate(view.replans, start=1)
        if r.path is not None
    )
    return PlanMesh(
        path=np.asarray(path_line.coords),
        vertices=vertices,
        triangles=np.array(triangles, dtype=np.int64).reshape(-1, 3),
        outlines=outlines,
        marks=marks,
    )


# -- drawing ---------------------------------------------------------------------------------

CORRIDOR_LABEL: Final = "footprint corridor"
PATH_LABEL: Final = "planned leader path"
REPLAN_LABEL: Final = "replan"


def _polygons(geom: BaseGeometry) -> list[Polygon]:
    if isinstance(geom, Polygon):
        return [geom] if not geom.is_empty else []
    if isinstance(geom, MultiPolygon):
        return [g for g in geom.geoms if not g.is_empty]
    return [g for g in getattr(geom, "geoms", ()) if isinstance(g, Polygon) and not g.is_empty]


def corridor_patch(geom: BaseGeometry, scale: float, **kw: Any) -> Any:
    """One matplotlib ``PathPatch`` of a (Multi)Polygon, holes included, in units of
    ``1 / scale`` m."""
    from matplotlib.patches import PathPatch
    from matplotlib.path import Path as MplPath

    verts: list[Sequence[float]] = []
    codes: list[Any] = []
    for poly in _polygons(geom):
        poly = orient(poly, 1.0)  # exterior counter-clockwise, holes clockwise: holes stay open
        for ring in (poly.exterior, *poly.interiors):
            xy = np.asarray(ring.coords) * scale
            verts.extend(xy.tolist())
            codes.extend([MplPath.MOVETO] + [MplPath.LINETO] * (len(xy) - 2) + [MplPath.CLOSEPOLY])
    if not verts:
        verts, codes = [(0.0, 0.0)], [MplPath.MOVETO]
    return PathPatch(MplPath(np.asarray(verts), codes), **kw)


def draw_plan(ax: Any, view: PlanView, scale: float = 100.0, log: Any = None) -> dict[str, Any]:
    """Draw ``view`` on ``ax`` (units of ``1 / scale`` m): the corridor (translucent), the
    planned leader path, the goal and every replan (a marker where the virtual leader was, on
    ``log`` when given, labelled ``replan k: reason``; its new path dashed when known). Returns
    the artists by name (``corridor``, ``path``, ``goal``, ``replans``) for the caller's legend
    and tests."""
    patch = corridor_patch(
        view.corridor, scale, fc=(0.2, 0.6, 0.3, 0.16), ec=(0.1, 0.45, 0.2, 0.5), lw=0.6,
        zorder=1.5, label=CORRIDOR_LABEL,
    )  # fmt: skip
    ax.add_patch(patch)
    (line,) = ax.plot(
        view.path[:, 0] * scale, view.path[:, 1] * scale, "-", color=(0.1, 0.4, 0.15),
        lw=4.0, alpha=0.45, solid_capstyle="round", zorder=2.5, label=PATH_LABEL,
    )  # fmt: skip
    (goal,) = ax.plot(
        view.goal[0] * scale, view.goal[1] * scale, "*", color=(0.1, 0.35, 0.15), ms=12,
        mec="white", zorder=6, label="goal",
    )  # fmt: skip
    marks = draw_replans(ax, view.replans, scale, log)
    return {"corridor": patch, "path": line, "goal": goal, "replans": marks}


def draw_replans(
    ax: Any, replans: Sequence[Replan], scale: float = 100.0, log: Any = None
) -> list[Any]:
    """Draw each replan on ``ax`` (:func:`draw_plan`; also alone, for a run whose plans were
    all made at run time): its new path dashed when known, a marker where the virtual leader
    was (on ``log`` when given) labelled ``replan k (t s): reason``. Returns the markers."""
    marks = []
    for n, rp in enumerate(replans, start=1):
        xy = _leader_at(log, rp.t_s) if log is not None else None
        if rp.path is not None:
            ax.plot(
                rp.path[:, 0] * scale, rp.path[:, 1] * scale, "--", color="tab:red", lw=1.2,
                zorder=2.6, label=f"{REPLAN_LABEL} {n} path",
            )  # fmt: skip
            xy = xy if xy is not None else (float(rp.path[0, 0]), float(rp.path[0, 1]))
        if xy is None:
            continue
        (mark,) = ax.plot(
            xy[0] * scale, xy[1] * scale, "X", color="tab:red", ms=9, mec="white", zorder=6,
            label=REPLAN_LABEL if n == 1 else None,
        )  # fmt: skip
        ax.annotate(
            f"{REPLAN_LABEL} {n} ({rp.t_s:.1f} s): {rp.reason}", (xy[0] * scale, xy[1] * scale),
            xytext=(8, -12), textcoords="offset points", fontsize=8, color="tab:red", zorder=6,
        )  # fmt: skip
        marks.append(mark)
    return marks


def _leader_at(log: Any, t_s: float) -> tuple[float, float] | None:
    """The virtual leader's logged position at the row nearest ``t_s``."""
    if log is None or log.t_s.size == 0:
        return None
    k = int(np.clip(np.searchsorted(log.t_s, t_s), 0, log.t_s.size - 1))
    x, y = float(log.leader[k, 0]), float(log.leader[k, 1])
    return (x, y) if math.isfinite(x) and math.isfinite(y) else None
