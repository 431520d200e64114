"""A run's plan measured and drawn (issue 27, deliverables 4 and 8): formation.outputs.plan_view.

The footprint corridor is the swept slot discs and stays clear of every obstacle; the plan's
metrics (length against the straight line, least planned clearance, time to goal, replans) of
a run whose leader follows the plan; the figure's artists carry the plan's data; ``formation
sim`` and ``formation report`` put the plan in metrics.json and the trajectories figure; the 3D
scene's plan entity (the Foxglove WebSocket path is in tests/fleet/test_live_foxglove.py).
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import pytest
import shapely
from hypothesis import given, settings
from hypothesis import strategies as st
from matplotlib.patches import PathPatch
from mcap.reader import make_reader
from shapely.geometry import LineString, Point, box

import scenario as scenario_mod
from coordinator.core.formation import FormationSpec, morphed_slot_rows, slot_rows
from coordinator.core.planning.feasibility import trajectory_of
from formation.live.scene import PLAN_ENTITY
from formation.outputs import figures
from formation.outputs.plan_view import (
    CORRIDOR_LABEL,
    PATH_LABEL,
    draw_plan,
    plan_mesh,
    plan_metrics,
    plan_summary,
    plan_view,
    replans_of,
)
from formation.outputs.runlog import RunLog
from formation.record import report as report_mod
from formation.record.replay import read_recording
from robot_agent.core.params import CircleObstacle
from scenario.write import to_toml

PLANNED = ("corridor", "door", "warehouse", "maze")


def slot_positions(traj: Any, formation: dict[str, Any], t_s: np.ndarray) -> np.ndarray:
    """(T, n, 2) every slot's position on ``traj`` at ``t_s`` (the coordinator's arithmetic)."""
    spec = FormationSpec.from_dict(dict(formation))
    out = np.empty((len(t_s), len(spec), 2))
    for k, t in enumerate(t_s.tolist()):
        leader = traj.sample(t)
        offs = traj.slot_offsets(t)
        _, rows = slot_rows(spec, leader) if offs is None else morphed_slot_rows(leader, offs)
        out[k] = [(r[0], r[1]) for r in rows]
    return out


@pytest.mark.parametrize("name", PLANNED)
def test_the_corridor_is_the_swept_slot_discs_clear_of_every_obstacle(name: str) -> None:
    scn = scenario_mod.load(name)
    view = plan_view(scn.trajectory, timed=False)
    assert view is not None and view.plan_time_s is None and view.replans == ()
    traj = trajectory_of(scn.trajectory)
    r = traj.result  # type: ignore[attr-defined]
    # every slot's disc at instants the corridor was not swept at (0.37 s apart) is inside it
    t = np.linspace(0.0, traj.duration_s, 241)  # type: ignore[attr-defined]
    pts = slot_positions(traj, scn.formation, t).reshape(-1, 2)
    inner = shapely.buffer(shapely.points(pts), view.slot_radius_m - 0.002)
    assert shapely.within(inner, view.corridor).all()
    # and nothing of the corridor is farther than the disc from some slot's path
    assert view.corridor.area < shapely.union_all(shapely.buffer(shapely.points(pts), 0.6)).area
    # clear of every obstacle and inside the arena (to the chord error of the sweep)
    shrunk = view.corridor.buffer(-0.002)
    for k, o in enumerate(scn.agent.world.obstacles):
        if isinstance(o, CircleObstacle):
            geom = Point(o.x, o.y).buffer(o.radius_m)
        else:  # a segment (a polygon's edges are segments)
            geom = LineString([(o.x1, o.y1), (o.x2, o.y2)]).buffer(max(o.radius_m, 1e-9))
        assert not shrunk.intersects(geom), (name, k)
    a = scn.trajectory["context"]["arena"]
    assert shrunk.within(box(a["x_min"], a["y_min"], a["x_max"], a["y_max"]))
    # the planned path runs from the start to the goal; its figures are the planner's
    assert np.allclose(view.path[0], r.x_m[0:1].tolist() + r.y_m[0:1].tolist())
    assert math.dist(view.path[-1], scn.trajectory["goal"]) < 1e-9
    assert view.length_m == r.stats.length_m >= view.straight_m
    assert view.min_clearance_m >= view.slot_radius_m


def leader_run(name: str, *, stop_s: float | None = None, off_m: float = 0.0) -> tuple[Any, RunLog]:
    """A RunLog whose virtual leader follows ``name``'s plan and whose robots sit on their slots
    (robot 0 ``off_m`` away from its slot at the end), every 0.1 s to ``stop_s`` (default: 5 s
    after the goal)."""
    scn = scenario_mod.load(name)
    traj = trajectory_of(scn.trajectory)
    end = traj.duration_s + 5.0 if stop_s is None else stop_s  # type: ignore[attr-defined]
    t = np.arange(0.0, end, 0.1)
    spec = FormationSpec.from_dict(dict(scn.formation))
    slots = slot_positions(traj, scn.formation, t)
    log = RunLog.allocate(list(scn.robot_ids), list(spec.slot_ids), len(t))
    log.t_s[:] = t
    for k, tk in enumerate(t.tolist()):
        ld = traj.sample(tk)
        log.leader[k] = (ld.x, ld.y, ld.theta)
    log.slot_xy[:] = slots
    log.target[:] = slots
    log.ref[:] = slots
    log.ref[-1, 0, 0] += off_m
    log.slot_of[:] = np.arange(len(spec))
    return scn, log


def test_plan_metrics_of_a_run_that_reaches_its_goal() -> None:
    scn, log = leader_run("door")
    log.replans = [
        {"t_s": 40.0, "reason": "obstacle[2] moved", "plan_time_s": 0.12, "length_m": 2.5},
        {"t_s": float("nan"), "reason": "dropped: no time"},
        {"t_s": 20.0, "reason": "robot r2 stuck", "plan_time_s": "slow", "path": [[0, 0]]},
    ]
    view = plan_view(scn.trajectory, log.replans)
    m = plan_metrics(view, log, scn.settle_tol_m)
    assert m is not None
    r = trajectory_of(scn.trajectory).result  # type: ignore[attr-defined]
    assert m["length_m"] == r.stats.length_m and m["straight_m"] == r.stats.straight_m
    assert m["length_ratio"] == pytest.approx(r.stats.length_m / r.stats.straight_m)
    assert m["min_clearance_m"] == r.stats.min_clearance_m
    assert m["plan_time_s"] is not None and m["plan_time_s"] > 0.0 and m["plan_cpu_s"] > 0.0
    assert m["planned_time_to_goal_s"] == r.stats.duration_s
    # the leader within 1 mm of its goal, every robot on its slot: the last 0.1 s row before
    # the plan's end (decelerating at 0.04 m/s^2 it is 1 mm short 0.22 s before)
    assert r.stats.duration_s - 0.4 < m["time_to_goal_s"] <= r.stats.duration_s
    # the replans in time order, the one without a time left out, bad fields None
    assert m["replans"] == 2
    assert m["replan_events"] == [
        {"t_s": 20.0, "reason": "robot r2 stuck", "plan_time_s": None, "length_m": None},
        {"t_s": 40.0, "reason": "obstacle[2] moved", "plan_time_s": 0.12, "length_m": 2.5},
    ]
    line = plan_summary(m)
    assert line is not None and "replans 2" in line and f"{r.stats.length_m:.2f} m" in line
    json.dumps(m, allow_nan=False)  # metrics.json material


def test_time_to_goal_is_none_when_the_run_ends_early_or_a_robot_is_off_its_slot() -> None:
    scn, log = leader_run("door", stop_s=30.0)
    m = plan_metrics(plan_view(scn.trajectory, timed=False), log, scn.settle_tol_m)
    assert m is not None and m["time_to_goal_s"] is None and m["plan_time_s"] is None
    assert m["plan_cpu_s"] is None
    scn, log = leader_run("door", off_m=2.0 * scn.settle_tol_m)
    m = plan_metrics(plan_view(scn.trajectory, timed=False), log, scn.settle_tol_m)
    assert m is not None and m["time_to_goal_s"] is None
    assert plan_view({"kind": "line", "speed_mps": 0.02}) is None
    assert plan_metrics(None, log, 0.05) is None and plan_summary(None) is None


@settings(max_examples=60, deadline=None)
@given(
    st.lists(
        st.fixed_dictionaries(
            {},
            optional={
                "t_s": st.one_of(st.floats(allow_nan=True), st.text(max_size=3), st.none()),
                "reason": st.one_of(st.text(max_size=200), st.integers()),
                "plan_time_s": st.one_of(st.floats(allow_nan=True), st.booleans()),
                "length_m": st.floats(allow_nan=True, allow_infinity=True),
                "path": st.one_of(
                    st.lists(st.lists(st.floats(), max_size=3), max_size=4), st.text(max_size=4)
                ),
            },
        ),
        max_size=6,
    )
)
def test_replan_events_from_a_recording_are_never_trusted(events: list[dict[str, Any]]) -> None:
    out = replans_of(events)
    assert [r.t_s for r in out] == sorted(r.t_s for r in out)
    for r in out:
        assert math.isfinite(r.t_s) and len(r.reason) <= 80
        json.dumps(r.as_dict(), allow_nan=False)
        assert r.path is None or (r.path.shape[1] == 2 and np.isfinite(r.path).all())


def test_draw_plan_puts_the_corridor_the_path_and_each_replan_on_the_axes() -> None:
    scn, log = leader_run("door", stop_s=60.0)
    xy = [[1.0, 0.2], [2.0, 0.4], [3.0, 0.1]]
    log.replans = [{"t_s": 30.0, "reason": "obstacle moved", "plan_time_s": 0.1, "path": xy}]
    view = plan_view(scn.trajectory, log.replans, timed=False)
    assert view is not None
    fig, ax = plt.subplots()
    try:
        art = draw_plan(ax, view, scale=100.0, log=log)
        patch = art["corridor"]
        assert isinstance(patch, PathPatch) and patch.get_label() == CORRIDOR_LABEL
        assert 0.0 < patch.get_facecolor()[3] < 0.5  # translucent
        verts = patch.get_path().vertices / 100.0
        ring = np.asarray(view.corridor.exterior.coords)
        assert len(verts) == len(ring) + sum(len(h.coords) for h in view.corridor.interiors)
        assert {tuple(np.round(p, 9)) for p in ring} <= {tuple(np.round(p, 9)) for p in verts}
        x, y = art["path"].get_data()
        assert art["path"].get_label() == PATH_LABEL
        assert np.allclose(np.c_[x, y] / 100.0, view.path)
        assert art["goal"].get_data() == ([400.0], [0.0])
        (mark,) = art["replans"]  # where the virtual leader was at 30 s, on the log
        k = int(np.searchsorted(log.t_s, 30.0))
        assert np.allclose(np.ravel(mark.get_data()), log.leader[k, :2] * 100.0)
        texts = [t.get_text() for t in ax.texts]
        assert texts == ["replan 1 (30.0 s): obstacle moved"]
        replan_path = next(ln for ln in ax.lines if ln.get_label() == "replan 1 path")
        got = np.c_[replan_path.get_xdata(), replan_path.get_ydata()]
        assert np.allclose(got, np.array(xy) * 100.0)
    finally:
        plt.close(fig)


def test_the_trajectories_figure_draws_the_plan_under_the_robots(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    scn, log = leader_run("door", stop_s=20.0)
    view = plan_view(scn.trajectory, timed=False)
    drawn: list[Any] = []
    monkeypatch.setattr(figures, "save_figure", lambda fig, path: drawn.append(fig))
    figures.plot_trajectories(log, tmp_path / "t.png", "door", view)
    figures.plot_trajectories(log, tmp_path / "t.png", "door")
    with_plan, without = (f.axes[0] for f in drawn)
    labels = [a.get_label() for a in with_plan.patches + with_plan.lines]
    assert CORRIDOR_LABEL in labels and PATH_LABEL in labels
    plain = [a.get_label() for a in without.patches + without.lines]
    assert CORRIDOR_LABEL not in plain and PATH_LABEL not in plain
    robot_line = next(ln for ln in with_plan.lines if ln.get_label() == "r1")
    path_line = next(ln for ln in with_plan.lines if ln.get_label() == PATH_LABEL)
    assert path_line.get_zorder() < robot_line.get_zorder()
    for f in drawn:
        plt.close(f)


# -- formation sim / formation report ---------------------------------------------------------


def test_formation_sim_writes_the_plan_into_metrics_and_the_summary(tmp_path: Path) -> None:
    from formation.sim.command import run_and_write, summary

    scn = scenario_mod.load("door")
    m = run_and_write(scn, tmp_path, duration=2.0, figures=False)
    on_disk = json.loads((tmp_path / "metrics.json").read_text())
    assert on_disk["plan"] == m["plan"]
    p = m["plan"]
    assert p["replans"] == 0 and p["replan_events"] == [] and p["plan_time_s"] > 0.0
    assert p["time_to_goal_s"] is None  # 2 s of a 90 s plan
    assert p["goal"] == [4.0, 0.0] and p["length_ratio"] > 1.0
    assert any(ln.startswith("plan: ") for ln in summary(m).splitlines())
    m2 = run_and_write(scenario_mod.load("paper-exp1"), tmp_path / "line", duration=1.0,
                       figures=False)  # fmt: skip
    assert m2["plan"] is None


def two_robot_plan() -> dict[str, Any]:
    """Two robots in a chevron, planned round a pillar: the robots of the synthetic stream of
    tests/unit/formation/test_record_report.py (r1 at x = 0.1, r2 0.3 m behind and 0.2 m left)."""
    return {
        "name": "pillar2",
        "duration_s": 2.0,
        "robots": {"ids": ["r1", "r2"], "initial": [[0.1, 0.0, 0.0], [-0.2, 0.2, 0.0]]},
        "trajectory": {"kind": "plan", "goal": [2.0, 0.0]},
        "formation": {"kind": "chevron", "n": 2, "b_m": 0.36},
        "arena": {"x_min": -0.8, "y_min": -1.2, "x_max": 2.6, "y_max": 1.2},
        "obstacle": [{"kind": "circle", "x": 1.0, "y": 0.0, "radius_m": 0.1}],
    }


def test_formation_report_measures_and_draws_the_plan_of_a_recording(tmp_path: Path) -> None:
    from support.record_stream import FLEET, record_items, synthetic_stream

    text = to_toml(two_robot_plan())
    path = tmp_path / "run.mcap"
    record_items(path, synthetic_stream(), run={"scenario_toml": text})
    # the recorder drew the plan in the 3D scene
    with open(path, "rb") as f:
        scenes = [m.data for _, ch, m in make_reader(f).iter_messages(topics=["/scene"])]
    assert scenes and any(PLAN_ENTITY.encode() in data for data in scenes)
    rec = read_recording(path)
    assert rec.fleet == FLEET
    report = report_mod.analyze(rec)
    p = report.metrics["plan"]
    scn = scenario_mod.parse(two_robot_plan())
    r = trajectory_of(scn.trajectory).result  # type: ignore[attr-defined]
    assert p["length_m"] == r.stats.length_m > p["straight_m"]  # round the pillar
    assert p["time_to_goal_s"] is None and p["replans"] == 0
    assert report.plan is not None and report.plan.corridor.area == p["corridor_area_m2"]
    written = report_mod.write(report, tmp_path / "out")
    assert json.loads((tmp_path / "out" / "metrics.json").read_text())["plan"] == p
    assert tmp_path / "out" / "trajectories.png" in written
    assert any("plan: " in ln for ln in report_mod.summary(report.metrics).splitlines())
    # without a scenario there is no plan to speak of
    bare = tmp_path / "bare.mcap"
    record_items(bare, synthetic_stream())
    assert report_mod.analyze(read_recording(bare)).metrics["plan"] is None


# -- the 3D scene's mesh (the scene itself: tests/fleet/test_live_foxglove.py) ---------------


def test_a_planned_corridor_mesh_has_no_triangle_outside_the_corridor() -> None:
    scn = scenario_mod.load("maze")
    view = plan_view(scn.trajectory, timed=False)
    assert view is not None
    mesh = plan_mesh(view)
    # the mesh covers the corridor: its triangles' area is the (2 mm simplified) corridor's
    tri = mesh.vertices[mesh.triangles]
    cross = (tri[:, 1, 0] - tri[:, 0, 0]) * (tri[:, 2, 1] - tri[:, 0, 1]) - (
        tri[:, 2, 0] - tri[:, 0, 0]
    ) * (tri[:, 1, 1] - tri[:, 0, 1])
    assert 0.5 * np.abs(cross).sum() == pytest.approx(view.corridor.area, rel=0.01)
    centroids = tri.mean(axis=1)
    grown = view.corridor.buffer(0.003)
    assert all(grown.contains(Point(c)) for c in centroids.tolist())


def test_a_report_whose_scenario_does_not_plan_is_a_clean_error(tmp_path: Path) -> None:
    from support.record_stream import record_items, synthetic_stream

    from formation.record.replay import ReportError

    data = two_robot_plan()
    data["trajectory"]["goal"] = [1.0, 0.0]  # in the pillar
    scn_path = tmp_path / "in-pillar.toml"
    scn_path.write_text(to_toml(data))
    path = tmp_path / "run.mcap"
    record_items(path, synthetic_stream())
    with pytest.raises(ReportError, match=r"trajectory\.goal"):
        report_mod.analyze(read_recording(path), scenario=str(scn_path))
