"""Issue 14 at the scenario level: obstacles and the arena in scenario files, the coordinator's
path warning, the safety metrics, obstacles in figures and in the Foxglove scene, and whole
in-process runs (``formation.sim.simulate``) of the corridor, with and without camera noise and
latency, and of the Robotarium task (separation >= 0.2625 m, error no worse than 1.97 mm).

The firmware-level closed loops (stationary robot in the path, head-on swap, dragged leader,
e-stopped robot, random starts, the filter's properties) are in
tests/unit/robot_agent/test_safety_filter.py;
the e-stopped robot over Zenoh in tests/fleet/test_safety_zenoh.py.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import scenario as scenario_mod
from coordinator.core.path_check import slot_path_conflicts
from formation.outputs import metrics
from formation.outputs.runlog import RunLog
from formation.sim import simulate
from robot_agent.core.params import Arena, CircleObstacle, SegmentObstacle, WorldMap
from scenario.preflight import path_conflicts

BODY_RADIUS_M = 0.075
TOUCH = 2 * BODY_RADIUS_M

BASE: dict[str, Any] = {
    "duration_s": 10.0,
    "robots": {"ids": ["r1", "r2", "r3"]},
    "trajectory": {"kind": "line", "x0": 0.0, "y0": 0.0, "heading": 0.0, "speed_mps": 0.05},
    "formation": {"kind": "triangle", "b_m": 0.4},
}


def _parse(**extra: Any) -> scenario_mod.Scenario:
    return scenario_mod.parse({**BASE, **extra})


# ------------------------------------------------------------------------- scenario tables


def test_scenario_obstacles_arena_and_filter_reach_the_agent_config() -> None:
    scn = _parse(
        arena={"x_min": -1, "y_min": -1.5, "x_max": 3.0, "y_max": 1.5},
        obstacle=[
            {"kind": "circle", "x": 1.0, "y": 0.2, "radius_m": 0.05},
            {"kind": "segment", "x1": 0, "y1": 0.6, "x2": 2, "y2": 0.6, "radius_m": 0.01},
            {"kind": "polygon", "points": [[2, -1], [2.2, -1], [2.2, -0.8]]},
        ],
        safety_filter={"margin_m": 0.05, "tiebreak_time_s": 2.5},
    )
    world = scn.agent.world
    assert world.arena == Arena(-1.0, -1.5, 3.0, 1.5)
    assert world.obstacles[0] == CircleObstacle(1.0, 0.2, 0.05)
    assert world.obstacles[1] == SegmentObstacle(0.0, 0.6, 2.0, 0.6, 0.01)
    assert len(world.obstacles) == 2 + 3  # a triangle is its three edges
    assert world.obstacles[4] == SegmentObstacle(2.2, -0.8, 2.0, -1.0, 0.0)  # closed outline
    assert scn.agent.safety_filter.margin_m == 0.05
    assert scn.agent.safety_filter.tiebreak_time_s == 2.5
    assert scn.agent.safety_distance_m == pytest.approx(0.2)
    assert _parse().agent.world == WorldMap()  # none given: an empty world


@pytest.mark.parametrize(
    ("extra", "needle"),
    [
        ({"obstacle": [{"kind": "blob", "x": 0}]}, "obstacle[0].kind"),
        ({"obstacle": [{"kind": "circle", "x": 0, "y": 0, "radius_m": -1}]}, "radius_m"),
        ({"obstacle": [{"kind": "circle", "x": 0, "y": 0}]}, "obstacle[0].radius_m: required"),
        ({"obstacle": [{"kind": "circle", "x": "a", "y": 0, "radius_m": 1}]}, "obstacle[0].x"),
        ({"obstacle": [{"kind": "circle", "x": 0, "y": 0, "radius_m": 1, "z": 2}]}, ".z"),
        ({"obstacle": [{"kind": "polygon", "points": [[0, 0], [1, 1]]}]}, "points"),
        ({"obstacle": {"kind": "circle"}}, "array of tables"),
        ({"arena": {"x_min": 1, "y_min": 0, "x_max": 0, "y_max": 1}}, "x_min must be < x_max"),
        ({"arena": {"x_min": 0, "y_min": 0, "x_max": 1}}, "arena.y_max: required"),
        ({"arena": {"x_min": 0, "y_min": 0, "x_max": 1, "y_max": math.nan}}, "arena.y_max"),
        ({"safety_filter": {"margin": 0.1}}, "safety_filter"),
        ({"safety_filter": {"tiebreak_angle_rad": 3.0}}, "tiebreak_angle_rad"),
    ],
)
def test_scenario_rejects_bad_obstacles_arena_and_filter(
    extra: dict[str, Any], needle: str
) -> None:
    with pytest.raises(scenario_mod.ScenarioError, match=None) as exc:
        _parse(**extra)
    assert needle in str(exc.value), str(exc.value)


def test_corridor_scenario_survives_the_toml_round_trip(tmp_path: Path) -> None:
    import tomllib

    src = scenario_mod.resolve("corridor").read_text()
    text = scenario_mod.to_toml(tomllib.loads(src))
    path = tmp_path / "c.toml"
    path.write_text(text)
    assert scenario_mod.load(str(path)).agent == scenario_mod.load("corridor").agent


# ------------------------------------------------------------------------- path check


SCRIPTED_LINE = {"kind": "line", "x0": 0.05, "y0": 0.0, "heading": 0.0, "speed_mps": 0.05}


def scripted_corridor() -> scenario_mod.Scenario:
    """The corridor with a scripted leader (the straight line it had before it planned, issue
    27): the pillar stands in slot 1's path, so the second layer (the robots' safety filter)
    alone keeps the robot clear; what these tests are about."""
    scn = scenario_mod.load("corridor")
    return dataclasses.replace(scn, trajectory=dict(SCRIPTED_LINE), duration_s=70.0)


def test_path_check_finds_the_pillar_in_slot_1s_path_and_nothing_else() -> None:
    scn = scripted_corridor()
    conflicts = path_conflicts(scn)
    assert [(c.slot, c.what) for c in conflicts] == [(1, "obstacle[2]")]
    c = conflicts[0]
    assert 20.0 < c.t_s < 30.0 and c.clearance_m < 0.0
    assert "slot 1" in c.message() and "obstacle[2]" in c.message()
    assert path_conflicts(scn, duration_s=20.0) == []  # not reached in 20 s
    assert (
        path_conflicts(dataclasses.replace(scn, agent=scenario_mod.load("paper-sim").agent)) == []
    )


def test_path_check_sees_the_arena_edge_and_segments() -> None:
    traj = {"kind": "line", "x0": 0.0, "y0": 0.0, "heading": 0.0, "speed_mps": 0.1}
    form = {"kind": "triangle", "b_m": 0.4}
    world = WorldMap(
        obstacles=(SegmentObstacle(0.5, -1.0, 0.5, -0.15),),  # a wall across slot 2's lane
        arena=Arena(-1.0, -1.0, 1.0, 1.0),
    )
    found = slot_path_conflicts(
        traj, form, world, 10.0, body_radius_m=0.075, ref_offset_m=0.05, step_s=0.05
    )
    what = {(c.slot, c.what) for c in found}
    assert (0, "arena") in what  # the leader drives out at x = 1 - 0.125 m
    assert (2, "obstacle[0]") in what
    assert (1, "obstacle[0]") not in what
    leader_exit = next(c for c in found if c.slot == 0)
    assert leader_exit.t_s == pytest.approx((1.0 - 0.125) / 0.1, abs=0.06)


def test_coordinator_node_warns_once_about_the_pillar(capsys: pytest.CaptureFixture[str]) -> None:
    from coordinator.node.coordinator import CoordinatorNode

    node = CoordinatorNode(scripted_corridor(), "c1", "demo", lambda *a, **k: None)
    assert len(node.path_warnings) == 1
    err = capsys.readouterr().err
    assert err.count("warning: slot 1's path crosses obstacle[2]") == 1


# ------------------------------------------------------------------------- metrics


def _log(truth: np.ndarray, dt: float = 0.1) -> RunLog:
    ticks, n = truth.shape[:2]
    log = RunLog.allocate([f"r{i + 1}" for i in range(n)], [0], ticks)
    log.t_s = np.asarray(np.arange(ticks) * dt, dtype=np.float64)
    log.truth = truth
    log.body_radius_m = BODY_RADIUS_M
    log.safety_distance_m = 0.19
    return log


def test_safety_metrics_time_below_ds_and_boundary_entries() -> None:
    ticks = 10
    truth = np.zeros((ticks, 2, 3))
    truth[:, 1, 0] = 0.3
    truth[4:6, 1, 0] = 0.18  # two ticks below Ds, none touching
    truth[8, 1, 0] = 0.14  # one touching
    truth[:, 0, 1] = 0.0
    log = _log(truth)
    log.world = WorldMap(
        obstacles=(CircleObstacle(0.0, 0.3, 0.1),), arena=Arena(-0.2, -1.0, 1.0, 1.0)
    )
    log.truth[1:3, 0, 1] = 0.2  # robot 1 into the disc (gap 0.2 - 0.1 - 0.075 < 0) twice
    log.truth[6, 0, 1] = 0.2
    log.truth[9, 0, 0] = -0.15  # and over the arena edge (x_min + r_b = -0.125)
    log.filter_counts = {
        "r1": {"ticks": 10, "active": 4, "tiebreaks": 1, "violations": 2, "infeasible": 0},
        "r2": {"ticks": 10, "active": 0, "tiebreaks": 0, "violations": 0, "infeasible": 1},
    }
    s = metrics.safety_metrics(log)
    assert s["min_separation_m"] == pytest.approx(0.14)
    assert s["time_below_ds_s"] == pytest.approx(0.3)  # ticks 4, 5, 8
    assert s["time_touching_s"] == pytest.approx(0.1)
    kinds = [(e["robot"], e["boundary"], e["t_s"]) for e in s["boundary_violation_events"]]
    assert kinds == [("r1", "obstacle[0]", 0.1), ("r1", "obstacle[0]", 0.6), ("r1", "arena", 0.9)]
    assert s["boundary_violations"] == 3
    assert s["min_boundary_clearance_m"] == pytest.approx(-0.075 + 0.1 - 0.1)
    assert s["filter_source"] == "firmware"
    assert s["filter_active_fraction"] == pytest.approx(0.2)
    assert (s["tiebreaks"], s["filter_violations"], s["filter_infeasible"]) == (1, 2, 1)
    log.filter_counts = {}
    s = metrics.safety_metrics(log)
    assert s["filter_source"] is None and s["tiebreaks"] is None


# ------------------------------------------------------------------------- whole runs


EXACT = {"camera": {"pos_std_m": 0.0, "theta_std_rad": 0.0, "latency_s": 0.0},
         "link": {"latency_s": 0.0, "jitter_s": 0.0, "loss_prob": 0.0}}  # fmt: skip


def _corridor(exact: bool) -> scenario_mod.Scenario:
    scn = scripted_corridor()
    if exact:
        scn = dataclasses.replace(
            scn,
            camera=scenario_mod.CameraModel(30.0, 0.0, 0.0, 0.0),
            link=scenario_mod.LinkModel(0, 0, 0),
        )
    return scn


@pytest.fixture(scope="module", params=["exact", "noisy"])
def corridor_run(request: pytest.FixtureRequest) -> tuple[simulate.SimResult, dict[str, Any]]:
    scn = _corridor(request.param == "exact")
    res = simulate.run(scn)
    return res, metrics.compute(res.log, scn.settle_s, scn.settle_tol_m)


def test_corridor_robots_pass_the_pillar_without_touching_anything(corridor_run: Any) -> None:
    """The pillar stands in slot 1's path: its robot goes round it (tie-break counted), nobody
    touches anybody, a wall, the pillar, the box or the arena's edge; all back on their slots."""
    res, m = corridor_run
    saf = m["safety"]
    assert m["run"]["collisions"] == 0
    assert m["run"]["min_separation_m"] >= TOUCH
    assert saf["time_touching_s"] == 0.0
    assert saf["boundary_violations"] == 0, saf["boundary_violation_events"]
    assert saf["min_boundary_clearance_m"] >= 0.0
    assert saf["filter_source"] == "firmware" and saf["filter_active_fraction"] > 0.0
    assert saf["tiebreaks"] >= 1  # the pillar blocked slot 1's robot
    on_pillar_slot = m["run"]["initial_assignments"][1]["robot"]
    assert saf["filter_per_robot"][on_pillar_slot]["active_fraction"] > 0.05
    # the robot on slot 1 passed x = 1.2 (the pillar) and everyone ends on its slot
    assert float(res.log.truth[-1, :, 0].min()) > 2.5
    for rid, r in m["robots"].items():
        assert r["formation_error_max_after_settle_m"] is not None
        err_end = float(metrics.formation_error(res.log)[-1, res.log.robot_ids.index(rid)])
        assert err_end < 0.05, (rid, err_end)
    assert any("obstacle[2]" in w for w in m["meta"]["path_warnings"])


def test_robotarium_task_separation_and_error() -> None:
    """Issue 14's anchor: on the Robotarium side-by-side task the minimum centre separation is
    at least Robotarium's 0.2625 m and the RMS formation error no worse than before the filter
    (1.97 mm); with tiebreak_time_s = 3.0 (docs/defaults.md)."""
    scn = scenario_mod.load("anchor-triangle")
    res = simulate.run(scn)
    m = metrics.compute(res.log, metrics.settle_for(scn.settle_s, scn.duration_s), scn.settle_tol_m)
    assert m["run"]["min_separation_m"] >= 0.2625
    rms = [r["formation_error_rms_m"] for r in m["robots"].values()]
    assert max(rms) <= 0.00197, rms
    assert m["run"]["collisions"] == 0
    assert m["safety"]["time_below_ds_s"] == 0.0


# ------------------------------------------------------------------------- drawing


def test_trajectories_figure_draws_the_world(tmp_path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from formation.outputs import figures, figures_style

    world = scenario_mod.load("corridor").agent.world
    fig, ax = plt.subplots()
    assert figures_style.draw_world(ax, world) == len(world.obstacles) + 1
    assert len(ax.patches) == 2  # the pillar and the arena
    assert len(ax.lines) == len(world.obstacles) - 1  # walls and the box's edges
    plt.close(fig)
    assert figures_style.draw_world(ax, None) == 0
    scn = scenario_mod.load("corridor")
    res = simulate.run(scn, duration_s=2.0)
    out = tmp_path / "t.png"
    figures.plot_trajectories(res.log, out)
    assert out.stat().st_size > 1000


def test_foxglove_scene_has_the_world_entity() -> None:
    pytest.importorskip("foxglove")
    from support.foxglove_fleet import pb_fields, scene_entities

    from formation.live.scene import SceneModel

    world = scenario_mod.load("corridor").agent.world
    ents = scene_entities(SceneModel(world=world).scene(1_000_000_000).encode())
    assert "world" in ents
    fields = ents["world"]
    cylinders = [v for n, v in fields if n == 10]  # SceneEntity.cylinders
    lines = [v for n, v in fields if n == 11]  # SceneEntity.lines
    assert len(cylinders) == 1  # the pillar
    assert len(lines) == 2  # the walls (one line list) and the arena outline
    points = [v for n, v in pb_fields(lines[0]) if n == 5]  # LinePrimitive.points
    assert len(points) == 2 * (len(world.obstacles) - 1)
    assert "world" not in scene_entities(SceneModel().scene(0).encode())
