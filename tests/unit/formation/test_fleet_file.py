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
