"""The fleet file of a real deployment (scenario/fleet.py) and the options that read it."""

from __future__ import annotations

import subprocess
import sys
import tomllib
from pathlib import Path
from typing import Any

import pytest

from scenario.fleet import FleetError, fleet_from_dict, load_fleet

REPO = Path(__file__).resolve().parents[3]
EXAMPLE = REPO / "deploy" / "config" / "fleet.example.toml"


def example() -> dict[str, Any]:
    return tomllib.loads(EXAMPLE.read_text())


def problems(data: dict[str, Any]) -> list[str]:
    with pytest.raises(FleetError) as info:
        fleet_from_dict(data)
    return info.value.problems


def test_example_gives_the_coordinator_a_scenario() -> None:
    fleet = load_fleet(EXAMPLE)
    assert fleet.fleet == "demo" and fleet.robot_ids == ("r1", "r2", "r3")
    assert fleet.tags == {"r1": 1, "r2": 2, "r3": 3}
    assert fleet.world is not None and fleet.world.arena is not None
    sc = fleet.scenario
    assert sc.robot_ids == fleet.robot_ids
    assert sc.trajectory["kind"] == "line" and sc.formation["kind"] == "triangle"
    assert sc.duration_s >= 1e5  # a real fleet runs until stopped
    assert sc.agent.geometry.ref_offset_m == 0.05


def test_every_problem_is_listed_with_its_field() -> None:
    data = example()
    data["robot"][1]["id"] = "r1"  # duplicate id
    data["robot"][2]["tag"] = 1  # duplicate tag
    data["robot"].append({"id": "R 4", "tag": 9999, "colour": "red"})
    data["fleet"] = "bad fleet"
    data["arena"]["x_max"] = "far"
    data["bogus"] = 1
    found = problems(data)
    for fragment in (
        "robot[1].id: robot 'r1' is listed twice",
        "robot[2].tag: tag 1 is already robot 'r1''s",
        "robot[3].id:",
        "robot[3].tag: expected an integer 0..586",
        "robot[3].colour: unknown key",
        "fleet: 'bad fleet'",
        "arena.x_max:",
        "bogus: unknown key",
    ):
        assert any(p.startswith(fragment) for p in found), (fragment, found)


def test_task_sections_are_required_and_validated() -> None:
    data = example()
    del data["formation"]
    assert any(p.startswith("formation: required") for p in problems(data))
    data = example()
    data["trajectory"]["speed_mps"] = 50.0
    assert any("speed_mps" in p for p in problems(data))
    data = example()
    data["trajectory"]["kind"] = "spiral"
    assert problems(data)
    data = example()
    del data["robot"]
    assert any(p.startswith("robot: required") for p in problems(data))


def test_coordinator_check_and_bad_file_exit_codes(tmp_path: Path) -> None:
    bad = tmp_path / "fleet.toml"
    bad.write_text(EXAMPLE.read_text().replace("tag = 2", "tag = 1"))
    result = subprocess.run(
        [sys.executable, "-m", "formation", "coordinator", "--check", "--fleet-file", str(bad)],
        cwd=REPO, capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert result.returncode == 2
    assert "robot[1].tag: tag 1 is already robot 'r1''s" in result.stderr


def test_camera_takes_the_tags_from_the_fleet_file(tmp_path: Path) -> None:
    pytest.importorskip("cv2")
    from localization.core.calibration import Calibration, CalibrationError
    from localization.node.main import with_tags

    cal = Calibration(
        homography=((0.001, 0.0, 0.0), (0.0, 0.001, 0.0), (0.0, 0.0, 1.0)), tags={"a": 7}
    )
    fleet = load_fleet(EXAMPLE)
    mapped = with_tags(cal, fleet.tags)
    assert mapped.robots == ["r1", "r2", "r3"] and mapped.robot_of_tag()[2] == "r2"
    patches = Calibration(
        homography=cal.homography, tags={}, family="patches", start={"r1": (0.0, 0.0)}
    )
    with pytest.raises(CalibrationError):
        with_tags(patches, fleet.tags)
    bad = tmp_path / "fleet.toml"
    bad.write_text("fleet = 3\n")
    result = subprocess.run(
        [sys.executable, "-m", "formation", "camera", "--source", "rendered", "--calibration",
         str(tmp_path / "none.toml"), "--fleet-file", str(bad)],
        cwd=REPO, capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert result.returncode == 2 and "invalid fleet file" in result.stderr, result.stderr


def door_fleet() -> dict[str, Any]:
    """The built-in ``door`` scenario as the fleet file of a real fleet: its robots with tags,
    arena, wall, planned trajectory (``kind = "plan"``, issue 27) and formation; the start the
    scenario plans from (its first robot's reference point, eqs 10-11) written as the plan's
    x0, y0, heading."""
    from scenario.load import SCENARIO_DIR

    door = tomllib.loads((SCENARIO_DIR / "door.toml").read_text())
    start = {"x0": 0.05, "y0": 0.0, "heading": 0.0}  # r1 at (0, 0, 0), l = 0.05 m
    return {
        "fleet": "doorway",
        "name": "door-fleet",
        "robot": [{"id": rid, "tag": k + 1} for k, rid in enumerate(door["robots"]["ids"])],
        "arena": door["arena"],
        "obstacle": door["obstacle"],
        "trajectory": {**door["trajectory"], **start},
        "formation": door["formation"],
        "assignment": door["assignment"],
    }


def test_a_fleet_file_with_a_plan_checks_clean_and_plans_the_scenarios_path(
    tmp_path: Path,
) -> None:
    import numpy as np

    import scenario as scenario_mod
    from coordinator.core.planning.feasibility import trajectory_of
    from scenario.write import to_toml

    path = tmp_path / "fleet.toml"
    path.write_text(to_toml(door_fleet()))
    result = subprocess.run(
        [sys.executable, "-m", "formation", "check", str(path)],
        cwd=REPO, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert result.returncode == 0, result.stderr
    assert result.stdout.startswith(f"OK: fleet doorway ({path}), door-fleet, robots 3, ")
    assert "trajectory plan" in result.stdout and "warning" not in result.stdout
    fleet = load_fleet(path)
    mine = trajectory_of(fleet.scenario.trajectory).result  # type: ignore[attr-defined]
    theirs = trajectory_of(scenario_mod.load("door").trajectory).result  # type: ignore[attr-defined]
    for name in ("s_m", "x_m", "y_m", "theta_rad", "q", "v_mps", "t_s"):
        assert np.array_equal(getattr(mine, name), getattr(theirs, name)), name
    assert mine.stats == theirs.stats


def test_a_plan_in_a_fleet_file_says_where_the_leader_starts(tmp_path: Path) -> None:
    data = door_fleet()
    for key in ("x0", "heading"):
        del data["trajectory"][key]
    found = problems(data)
    assert [p.split(":")[0] for p in found] == ["trajectory.x0", "trajectory.heading"], found
    # formation check names them too, exit 2
    path = tmp_path / "fleet.toml"
    from scenario.write import to_toml

    path.write_text(to_toml(data))
    result = subprocess.run(
        [sys.executable, "-m", "formation", "check", str(path)],
        cwd=REPO, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert result.returncode == 2, result.stdout
    assert "trajectory.x0: required" in result.stderr, result.stderr
    data = door_fleet()
    data["trajectory"]["goal"] = [2.0, -1.0]  # inside the wall
    assert any(p.startswith("trajectory.goal: no plan") for p in problems(data)), problems(data)


def test_the_obstacles_of_a_fleet_file_are_the_coordinators_too() -> None:
    """The fleet's arena and obstacles reach the scenario the coordinator runs: its path check
    warns about a slot crossing a pillar (over the first hour of a run that lasts for ever)."""
    from scenario.preflight import PATH_CHECK_HORIZON_S, preflight_warnings

    data = example()
    data["obstacle"] = [{"kind": "circle", "x": 0.0, "y": 0.2, "radius_m": 0.05}]
    scn = fleet_from_dict(data).scenario
    assert scn.agent.world.arena is not None and len(scn.agent.world.obstacles) == 1
    assert scn.duration_s > PATH_CHECK_HORIZON_S
    found = preflight_warnings(scn)  # the first hour, not 1e6 s (that took hours)
    assert any("crosses obstacle[0]" in w for w in found), found
