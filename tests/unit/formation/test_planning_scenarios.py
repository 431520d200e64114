"""The built-in planned scenarios in closed loop (issue 27), and the checks before a run.

``warehouse`` (aisles narrower than the triangle), ``door`` (a gap only a column fits through),
``maze`` and ``corridor`` plan their virtual leader: in-process each reaches its goal with no
collision, no boundary violation, the robots at least the safety distance apart, and (the
corridor) the formation error back at the few-millimetre level. ``formation sim`` prints every
check's warnings BEFORE the run's table.
"""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from support.spawn import REPO_ROOT, child_env

import scenario as scenario_mod
from formation.outputs import metrics
from formation.sim import simulate
from scenario.preflight import preflight_warnings
from scenario.write import to_toml

PLANNED = ("corridor", "door", "warehouse", "maze")


@pytest.mark.parametrize("name", PLANNED)
def test_the_planned_scenarios_have_nothing_to_warn_about(name: str) -> None:
    scn = scenario_mod.load(name)
    assert scn.trajectory["kind"] == "plan"
    assert preflight_warnings(scn) == []


@pytest.mark.slow
@pytest.mark.parametrize("name", PLANNED)
def test_a_planned_scenario_reaches_its_goal_safely(name: str) -> None:
    scn = scenario_mod.load(name)
    res = simulate.run(scn)
    m = metrics.compute(res.log, scn.settle_s, scn.settle_tol_m)
    assert m["run"]["collisions"] == 0
    assert m["run"]["min_separation_m"] >= scn.agent.safety_distance_m
    assert m["safety"]["boundary_violations"] == 0, m["safety"]["boundary_violation_events"]
    assert m["run"]["role_change_count"] == 0
    goal = scn.trajectory["goal"]
    x, y = (float(v) for v in res.log.leader[-1, :2])
    assert math.hypot(x - goal[0], y - goal[1]) < 1e-6
    rms = [r["formation_error_rms_m"] for r in m["robots"].values()]
    assert max(rms) < (0.01 if name == "corridor" else 0.02), rms


def _issue_user_scenario() -> dict[str, Any]:
    """The issue's new user: 5 robots in a chevron, a waypoint path written to detour round a
    pillar (the followers cross it, the outer slots swing round the corners too fast)."""
    return {
        "name": "detour",
        "duration_s": 60.0,
        "robots": {"count": 5, "initial": [[0.0, 0.0, 0.0], [-0.35, 0.2, 0.0],
                                           [-0.35, -0.2, 0.0], [-0.7, 0.4, 0.0],
                                           [-0.7, -0.4, 0.0]]},
        "trajectory": {"kind": "waypoints", "points": [[0, 0], [1.0, 0.0], [1.5, 0.8],
                                                       [2.5, 0.8], [3.0, 0.0]],
                       "speed_mps": 0.08, "max_turn_radps": 1.0},
        "formation": {"kind": "chevron", "n": 5, "b_m": 0.4},
        "obstacle": [{"kind": "circle", "x": 2.0, "y": 0.6, "radius_m": 0.1}],
    }  # fmt: skip


def test_sim_prints_every_warning_before_the_table(tmp_path: Path) -> None:
    path = tmp_path / "detour.toml"
    path.write_text(to_toml(_issue_user_scenario()))
    r = subprocess.run(
        [sys.executable, "-m", "formation", "sim", "--scenario", str(path), "--duration", "40",
         "--no-figures", "--out", str(tmp_path / "out")],
        capture_output=True, text=True, cwd=REPO_ROOT, env=child_env(), timeout=300,
    )  # fmt: skip
    assert r.returncode == 0, r.stderr
    lines = r.stdout.splitlines()
    table = next(i for i, ln in enumerate(lines) if ln.startswith("robot "))
    warnings = [i for i, ln in enumerate(lines) if ln.startswith("warning: ")]
    assert warnings and max(warnings) < table, r.stdout
    text = "\n".join(lines[i] for i in warnings)
    assert "is infeasible: its speed" in text  # the outer slots at the corners
    assert "crosses obstacle[0]" in text  # a follower's path through the pillar
    # formation check prints the same lines, exit 0 (the run may go ahead), 1 with --strict
    for strict, code in ((False, 0), (True, 1)):
        c = subprocess.run(
            [sys.executable, "-m", "formation", "check", str(path), "--duration", "40",
             *(["--strict"] if strict else [])],
            capture_output=True, text=True, cwd=REPO_ROOT, env=child_env(), timeout=300,
        )  # fmt: skip
        assert c.returncode == code, c.stderr
        assert [ln for ln in c.stdout.splitlines() if ln.startswith("warning: ")] == [
            lines[i] for i in warnings
        ]


def test_an_unreachable_goal_is_one_line_exit_2_for_sim_and_check(tmp_path: Path) -> None:
    data = _issue_user_scenario()
    data["trajectory"] = {"kind": "plan", "goal": [2.0, 0.6]}  # in the pillar
    path = tmp_path / "in-pillar.toml"
    path.write_text(to_toml(data))
    for cmd in (["sim", "--scenario", str(path), "--no-figures"], ["check", str(path)]):
        r = subprocess.run(
            [sys.executable, "-m", "formation", *cmd, "--duration", "3"],
            capture_output=True, text=True, cwd=REPO_ROOT, env=child_env(), timeout=300,
        )  # fmt: skip
        assert r.returncode == 2, (cmd, r.stdout, r.stderr)
        err = r.stderr.strip().splitlines()
        assert len(err) == 1 and "trajectory.goal" in err[0] and "inside an obstacle" in err[0]
        assert "Traceback" not in r.stderr


def test_a_huge_map_is_planned_or_refused_in_a_bound() -> None:
    """10,000 obstacles: planned within the work bound of the planner (a capped grid, an
    STRtree), never a hang (the test's timeout would say so)."""
    from coordinator.core.formation import FormationSpec
    from coordinator.core.planning import Footprint, NoPlan, PlanWorld, SlotLimits, plan
    from coordinator.core.planning.trajectory import min_separation_m

    rng = np.random.default_rng(27)
    xy = rng.uniform(0.5, 29.5, size=(10_000, 2))
    keep = (np.hypot(xy[:, 0] - 1.0, xy[:, 1] - 1.0) > 1.5) & (
        np.hypot(xy[:, 0] - 29.0, xy[:, 1] - 29.0) > 1.5
    )
    obstacles = [{"kind": "circle", "x": float(x), "y": float(y), "radius_m": 0.03}
                 for x, y in xy[keep]]  # fmt: skip
    world = PlanWorld(obstacles, {"x_min": 0.0, "y_min": 0.0, "x_max": 30.0, "y_max": 30.0})
    fp = Footprint(FormationSpec.triangle(0.4).body_offsets_m, 0.185, min_separation_m(0.19, 0.05))
    limits = SlotLimits(0.127, 2.07, 0.1)
    try:
        r = plan(world, fp, (1.0, 1.0, math.pi / 4), (29.0, 29.0), cruise_mps=0.05,
                 limits=limits, min_pair_m=0.19)  # fmt: skip
    except NoPlan as exc:
        assert str(exc)
    else:
        assert r.stats.min_clearance_m >= fp.slot_radius_m
