"""Issue 27's Done-when over Zenoh: the built-in ``door`` (a wall with a gap only a column fits
through) run as real processes in lockstep reaches its goal with no collision, and its metrics
equal the in-process simulator's, so every in-process figure of docs/planning.md holds for the
distributed fleet too (tests/unit/formation/test_planning_scenarios.py checks warehouse, door
and maze in-process).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
from support.spawn import Spawner, free_port

import scenario as scenario_mod
from formation.sim import command as sim_cli

pytestmark = [pytest.mark.zenoh, pytest.mark.slow, pytest.mark.shares_cpu]


def test_the_door_is_passed_over_zenoh_as_in_process(spawn: Spawner, tmp_path: Path) -> None:
    out = tmp_path / "up"
    up = spawn(
        "up", "--lockstep", "--scenario", "door", "--endpoint",
        f"tcp/127.0.0.1:{free_port()}", "--out", str(out), "--no-figures", "--quiet",
        "--hosts", "1",
    )  # fmt: skip
    assert up.proc.wait(timeout=300) == 0, up.describe()
    live: dict[str, Any] = json.loads((out / "metrics.json").read_text())
    sim = sim_cli.run_and_write(scenario_mod.load("door"), tmp_path / "sim", figures=False)
    assert live["robots"] == sim["robots"]
    assert live["run"] == sim["run"]
    plan = live["plan"]
    assert plan is not None and plan["time_to_goal_s"] is not None, plan
    assert plan["min_clearance_m"] >= plan["slot_radius_m"], plan
    assert live["run"]["collisions"] == 0, live["run"]
