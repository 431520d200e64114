"""Scripted ``[[fault]]`` entries in ``formation sim`` (formation.sim.simulate): the in-process
meaning of each kind, determinism, and the recovery figures of metrics.json."""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np

import scenario
from formation.outputs import metrics
from formation.outputs.recovery import fault_recovery
from formation.sim import simulate
from scenario.faults import parse_faults

REPO = Path(__file__).resolve().parents[3]


def with_faults(raw: list[dict[str, Any]], duration_s: float = 12.0) -> scenario.Scenario:
    s = scenario.load("leader-kill")
    return dataclasses.replace(
        s, duration_s=duration_s, faults=parse_faults(raw, s.robot_ids, duration_s)
    )


def rows(log: Any, t0: float, t1: float) -> np.ndarray:
    t = log.t_s - log.t_s[0]
    return np.flatnonzero((t >= t0 - 1e-9) & (t < t1 - 1e-9))


def test_the_built_in_leader_kill_hands_the_lead_over_and_recovers() -> None:
    s = scenario.load("leader-kill")
    res = simulate.run(s)
    log = res.log
    (sent,) = log.meta["faults"]
    assert sent["kind"] == "kill" and sent["fault"] == 0 and not sent["undo"]
    victim = sent["robot"]
    j = log.robot_ids.index(victim)
    k = sent["tick"]
    assert log.slot_of[k - 1, j] == 0  # it was the leader when it was killed
    assert (log.slot_of[k:, j] == -1).all()  # the coordinator dropped it at once
    assert (log.power[k:, j, :] == 0.0).all()  # its agent is dead: no command
    assert np.ptp(log.truth[k + 20 :, j, :2], axis=0).max() < 0.01  # it stands where it died
    assert (log.slot_of[k:] == 0).sum(axis=1).min() == 1  # somebody leads at every tick
    m = metrics.compute(log, 15.0, s.settle_tol_m)
    (rec,) = fault_recovery(log, s.settle_tol_m)
    assert rec["detection_s"] == 0.0 and rec["reassignment_s"] == 0.0
    assert rec["new_leader"] not in (None, victim)
    assert rec["recovered_s"] is not None and rec["recovered_s"] > 0.0
    assert rec["peak_error_m"] > s.settle_tol_m
    assert rec["min_separation_m"] > 2 * s.agent.geometry.body_radius_m
    assert m["meta"]["faults_pending"] == []


def test_a_run_with_faults_is_repeatable_to_the_bit() -> None:
    s = with_faults(
        [
            {"kind": "kill", "role": "leader", "t_s": 4.0},
            {"kind": "pause", "robot": "r4", "t_s": 6.0, "duration_s": 1.0},
        ]
    )
    a, b = simulate.run(s).log, simulate.run(s).log
    assert np.array_equal(a.truth, b.truth) and np.array_equal(a.slot_of, b.slot_of)
    ma = metrics.compute(a, 6.0, 0.05)
    mb = metrics.compute(b, 6.0, 0.05)
    for m in (ma, mb):
        m["meta"].pop("wall_s")
    assert json.dumps(ma, sort_keys=True) == json.dumps(mb, sort_keys=True)


def test_a_paused_agent_is_dropped_and_taken_back_on_resume() -> None:
    log = simulate.run(
        with_faults([{"kind": "pause", "robot": "r3", "t_s": 5.0, "duration_s": 2.0}])
    ).log
    j = log.robot_ids.index("r3")
    during = rows(log, 5.0, 7.0)
    assert (log.slot_of[during, j] == -1).all() and (log.power[during, j] == 0.0).all()
    assert (log.slot_of[rows(log, 7.5, 12.0), j] >= 0).all()
    kinds = [(f["kind"], f["undo"], f["t_s"]) for f in log.meta["faults"]]
    assert kinds == [("pause", False, 5.0), ("resume", True, 7.0)]


def test_a_fleet_estop_zeroes_every_wheel_until_its_release() -> None:
    log = simulate.run(with_faults([{"kind": "estop", "t_s": 4.0, "duration_s": 2.0}])).log
    assert (log.power[rows(log, 4.0, 6.0)] == 0.0).all()
    assert (log.slot_of[rows(log, 4.0, 6.0)] >= 0).all()  # still assigned, only stopped
    assert np.abs(log.power[rows(log, 7.0, 12.0)]).max() > 0.0


def test_one_robot_estop_stops_that_robot_only() -> None:
    log = simulate.run(with_faults([{"kind": "estop", "robot": "r2", "t_s": 4.0}])).log
    j = log.robot_ids.index("r2")
    after = rows(log, 4.0, 12.0)
    assert (log.power[after, j] == 0.0).all()
    others = [i for i in range(len(log.robot_ids)) if i != j]
    assert np.abs(log.power[after][:, others]).max() > 0.0


def test_a_cut_link_drops_the_robot_and_stops_its_wheels() -> None:
    log = simulate.run(
        with_faults(
            [
                {"kind": "cut_link", "robot": "r4", "t_s": 4.0},
                {"kind": "restore_link", "robot": "r4", "t_s": 6.0},
            ]
        )
    ).log
    j = log.robot_ids.index("r4")
    cut = rows(log, 4.0, 6.0)
    assert (log.slot_of[cut, j] == -1).all()
    # the firmware still steps (HOLD on its stale pose, no setpoint): zero commands
    assert (log.power[cut, j] == 0.0).all()
    assert (log.slot_of[rows(log, 7.0, 12.0), j] >= 0).all()


def test_a_killed_coordinator_leaves_the_robots_without_setpoints_until_the_takeover() -> None:
    log = simulate.run(
        with_faults([{"kind": "kill_coordinator", "t_s": 4.0, "takeover_s": 1.0}])
    ).log
    # setpoints of the tick before the kill still arrive on the first tick; then none: HOLD
    assert (log.power[rows(log, 4.04, 5.0)] == 0.0).all()
    assert np.abs(log.power[rows(log, 5.5, 12.0)]).max() > 0.0
    # the trajectory goes on: the standby continues the same virtual leader
    base = simulate.run(with_faults([])).log
    assert np.array_equal(base.leader, log.leader)


def test_a_camera_loss_fault_occludes_the_robot() -> None:
    s = with_faults([{"kind": "camera_loss", "robot": "r2", "t_s": 4.0, "duration_s": 2.0}])
    log = simulate.run(s).log
    j = log.robot_ids.index("r2")
    # no pose for longer than the coordinator's bound: the robot loses its slot, then is back
    assert (log.slot_of[rows(log, 5.0, 6.0), j] == -1).any()
    assert (log.slot_of[rows(log, 7.0, 12.0), j] >= 0).all()


def test_formation_sim_reports_a_condition_that_never_came(tmp_path: Path) -> None:
    toml = tmp_path / "k.toml"
    text = (REPO / "scenario" / "builtin" / "leader-kill.toml").read_text()
    toml.write_text(text.replace("after_s = 5.0", "after_s = 0.0"))
    p = subprocess.run(
        [sys.executable, "-m", "formation", "sim", "--scenario", str(toml), "--duration",
         "3", "--out", str(tmp_path / "out"), "--no-figures"],
        cwd=REPO, capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert p.returncode == 0, p.stderr
    m = json.loads((tmp_path / "out" / "metrics.json").read_text())
    # 3 s is too short for the robots to get into formation: the condition never came
    assert m["faults"] == []
    (left,) = m["meta"]["faults_pending"]
    assert left["fault"] == 0 and "never fired" in left["why"]
    assert "fault[0] never fired: kill of the leader when in_formation" in p.stderr


def test_the_figures_mark_every_fault_and_disturbance() -> None:
    import matplotlib.pyplot as plt
    from matplotlib.figure import Figure

    from formation.outputs import figures
    from formation.outputs.figure_marks import event_marks, mark_time_axes

    s = with_faults(
        [
            {"kind": "estop", "t_s": 3.0, "duration_s": 1.0},
            {"kind": "kill", "role": "leader", "t_s": 6.0},
        ]
    )
    s = dataclasses.replace(
        s, disturbances=(scenario.Disturbance(t_s=5.0, robot="r2", kind="drag", dx=-0.1),)
    )
    log = simulate.run(s).log
    marks = event_marks(log)
    assert [(t, label, ls) for t, label, _, ls in marks] == [
        (3.0, "estop", "-"), (4.0, "release", ":"), (5.0, "drag r2", "--"), (6.0, "kill r1", "-"),
    ]  # fmt: skip
    ax = Figure().add_subplot()
    assert mark_time_axes([ax], log) == 4
    assert sorted(float(line.get_xdata()[0]) for line in ax.get_lines()) == [3.0, 4.0, 5.0, 6.0]
    fig = figures.error_figure(log, settle_s=6.0)
    plt.close(fig)
    drawn = {
        float(line.get_xdata()[0])
        for a in fig.axes
        for line in a.get_lines()
        if line.get_linestyle() in ("-", ":", "--") and len(line.get_xdata()) == 2
    }
    assert {3.0, 4.0, 5.0, 6.0} <= drawn


def test_a_dead_robot_carried_is_a_mover_the_others_keep_the_safety_distance() -> None:
    """paper-exp2's leader killed, then the scenario's hand drags its robot back (0.2 m/s, below
    the robots' top speed) through where the others now stand. A dead robot's pose is still
    tracked: the coordinator takes it as an object (its wheels are stopped), so when it moves it
    is a mover: the others make room and their filters see its velocity. Before, it was nobody's
    input but the filters', as a still obstacle: 0.173 m (kill at 20 s) and 0.188 m (28 s), below
    the safety distance; the filter alone lags a body it thinks still by its speed over gamma."""
    base = scenario.load("paper-exp2")
    ds_m = 2 * base.agent.geometry.body_radius_m + base.agent.safety_filter.margin_m
    drag = tuple(dataclasses.replace(d, duration_s=3.0) for d in base.disturbances)
    assert [(d.t_s, d.robot, d.dx) for d in drag] == [(30.0, "r1", -0.6)]
    for kill_s in (20.0, 28.0):
        faults = parse_faults([{"kind": "kill", "robot": "r1", "t_s": kill_s}], base.robot_ids, 34)
        s = dataclasses.replace(base, duration_s=34.0, disturbances=drag, faults=faults)
        log = simulate.run(s).log
        k = rows(log, 30.0, 34.0)
        j = log.robot_ids.index("r1")
        assert np.ptp(log.truth[k, j, 0]) > 0.5  # it was dragged
        sep = metrics.min_pair_distance(log.truth)
        assert float(sep.min()) >= ds_m, f"kill at {kill_s} s: {float(sep.min()):.4f} m"
