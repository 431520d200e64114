"""Run-time plans shown (issue 27, deliverable 8): the coordinator's plans made while running
(an operator's goal around an obstacle, a replan when an obstacle is added) reach the run's
record. In-process: ``formation sim`` fills ``RunLog.replans`` from the coordinator core, with
each plan's path, and metrics.json and ``trajectories.png`` show them. From the bus: the
collector reads the coordinators' status (counts, reasons, plan time; no path on the bus).
"""

from __future__ import annotations

import json
import math
import tomllib
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import numpy as np
import pytest

from bus_schemas import CoordinatorStatus, Truth, encode, keys
from formation.outputs import figures
from formation.outputs.plan_view import add_plan, plan_summary, replans_of
from formation.record.collector import RunCollector, key_patterns
from formation.record.collector_plans import UNSEEN_REASON
from formation.sim import simulate
from formation.sim.command import run_and_write
from scenario.load import parse

YARD = """\
name = "yard-goal"
description = "A scripted goal past a pillar, then a box dropped on the way: two run-time plans."
duration_s = 9.0
dt_s = 0.02
seed = 27

[robots]
ids = ["r1", "r2", "r3"]
initial = [[0.0, 0.0, 0.0], [-0.4, 0.2, 0.0], [-0.4, -0.2, 0.0]]

[trajectory]
kind = "line"
x0 = 0.05
y0 = 0.0
heading = 0.0
speed_mps = 0.0

[formation]
kind = "triangle"
b_m = 0.4

[arena]
x_min = -1.5
y_min = -2.0
x_max = 4.0
y_max = 2.0

[[obstacle]]
kind = "circle"
x = 1.5
y = 0.0
radius_m = 0.2

[[operator]]
t_s = 0.5
command = "goal"
x = 3.2
y = 0.0

[[operator]]
t_s = 4.0
command = "obstacle"
id = "box"
action = "add"
shape = "circle"
x = 2.6
y = 0.6
radius_m = 0.25
"""


@pytest.fixture(scope="module")
def yard_run() -> Any:
    scn = parse(tomllib.loads(YARD))
    return scn, simulate.run(scn)


def test_the_simulator_logs_each_run_time_plan_with_its_path(yard_run: Any) -> None:
    _, result = yard_run
    log = result.log
    assert [e["reason"] for e in log.replans] == ["goal", "obstacle box added"]
    assert log.meta["planner"]["plans"] == 2 and log.meta["planner"]["replans"] == 1
    for e in log.replans:
        path = np.asarray(e["path"])
        assert path.shape[1] == 2 and len(path) >= 2
        assert e["plan_time_s"] > 0.0 and e["length_m"] >= math.dist(path[0], path[-1])
        # on the log's axis: the plan starts where the virtual leader is at its switch tick
        k = int(np.searchsorted(log.t_s, e["t_s"]))
        assert log.t_s[k] == pytest.approx(e["t_s"])
        assert math.dist(log.leader[k, :2], path[0]) < 1e-6
        assert np.allclose(path[-1], (3.2, 0.0))
    # the replan goes round the box: its path differs from the first plan's
    first, second = (np.asarray(e["path"]) for e in log.replans)
    assert not (first.shape == second.shape and np.allclose(first, second))


def test_formation_sim_lists_the_run_time_plans_in_metrics_json(tmp_path: Path) -> None:
    scn = parse(tomllib.loads(YARD))
    m = run_and_write(scn, tmp_path, duration=5.0, figures=False)
    on_disk = json.loads((tmp_path / "metrics.json").read_text())
    p = on_disk["plan"]
    assert p == m["plan"] and p["replans"] == 2
    assert [e["reason"] for e in p["replan_events"]] == ["goal", "obstacle box added"]
    assert p["runtime"]["plans"] == 2 and p["runtime"]["replans"] == 1
    assert p["runtime"]["min_clearance_m"] > 0.0
    assert "replans 1" in (plan_summary(p) or "")


def test_the_trajectories_figure_draws_each_run_time_plan(
    yard_run: Any, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    _, result = yard_run
    log = result.log
    drawn: list[Any] = []
    monkeypatch.setattr(figures, "save_figure", lambda fig, path: drawn.append(fig))
    figures.plot_trajectories(log, tmp_path / "trajectories.png", plan=None)
    (ax,) = drawn[0].axes
    lines = {ln.get_label(): ln for ln in ax.get_lines()}
    for n, e in enumerate(log.replans, start=1):
        line = lines[f"replan {n} path"]
        assert np.allclose(np.column_stack(line.get_data()), np.asarray(e["path"]) * 100.0)
    texts = [t.get_text() for t in ax.texts]
    assert any(t.startswith("replan 2 (") and t.endswith("obstacle box added") for t in texts)


def _status(t: float, seq: int, **plan: Any) -> bytes:
    return encode(
        CoordinatorStatus(
            t=t, seq=seq, name="main", mode="lockstep", role="active", epoch=1, takeovers=0,
            stepdowns=0, ticks=seq, alive=("r1",), assignment={}, leader=None,
            estop_fleet=False, estop_robots=(), rejected=0, rejects={}, internal_errors=0,
            rx={}, pid=8, host="h", **plan,
        )
    )  # fmt: skip


def test_the_collector_reads_the_run_time_plans_from_the_coordinator_status() -> None:
    fleet = keys.DEFAULT_FLEET
    status_key = keys.coordinator_status_key(fleet, "main")
    assert keys.all_coordinator_status_pattern(fleet) in key_patterns(fleet)
    c = RunCollector(["r1"], slot_ids=[0], fleet=fleet, dt_s=0.02, ref_offset_m=0.05,
                     body_radius_m=0.05)  # fmt: skip
    for k in range(200):
        c.feed(keys.truth_key(fleet, "r1"), encode(Truth(t=k * 0.02, seq=k + 1, x=0.0, y=0.0,
                                                         theta=0.0)))  # fmt: skip
    common = {"plan_late": 0, "obstacles": 1, "stuck": ()}
    assert not c.feed(status_key, _status(0.4, 1))  # no planner fields yet: nothing to log
    assert c.rejected == 0
    c.feed(status_key, _status(1.0, 2, plan="following", plan_why="goal", plans=1, replans=0,
                               plan_ms=120.0, plan_clearance_m=0.2, **common))  # fmt: skip
    c.feed(status_key, _status(1.2, 3, plan="following", plan_why="goal", plans=1, replans=0,
                               plan_ms=120.0, plan_clearance_m=0.2, **common))  # fmt: skip
    c.feed(status_key, _status(2.0, 5, plan="no_way", plan_why="no plan: goal blocked",
                               plans=3, replans=2, plan_ms=80.0, plan_clearance_m=0.2,
                               **common))  # fmt: skip
    c.feed(status_key, _status(1.6, 4, plan="following", plan_why="late", plans=2, replans=1,
                               plan_ms=1.0, plan_clearance_m=0.2, **common))  # fmt: skip
    assert not c.feed(status_key, b"\x81\xa1v\x01")  # a bad payload: rejected and counted
    assert c.rejected == 1
    log = c.build()
    assert [(e["t_s"], e["reason"], e["plan_time_s"]) for e in log.replans] == [
        (pytest.approx(1.0), "goal", pytest.approx(0.12)),
        (pytest.approx(2.0), UNSEEN_REASON, None),
        (pytest.approx(2.0), "no way: no plan: goal blocked", pytest.approx(0.08)),
    ]
    assert all("path" not in e and e["length_m"] is None for e in log.replans)
    assert log.meta["planner"]["plans"] == 3 and log.meta["planner"]["replans"] == 2
    assert log.meta["planner"]["plan_ms"] == 80.0
    # metrics.json (formation report, formation up): the plan entry of a scripted trajectory
    m: dict[str, Any] = {}
    assert add_plan(m, {"kind": "line"}, log, 0.05) is None
    assert m["plan"]["replans"] == 3 and m["plan"]["runtime"]["state"] == "no_way"
    assert replans_of(log.replans)[2].reason.startswith("no way")
