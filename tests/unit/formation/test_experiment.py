"""The experiment API (``formation.sim.experiment.Experiment``): stepping it without actions is
``formation sim`` tick for tick (every array of the run log equal, not close), with scheduled
disturbances and with wheel encoders; actions replace the firmware's output, through the link;
bad actions are refused."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

import scenario as scenario_mod
from formation.outputs import metrics
from formation.sim import simulate
from formation.sim.experiment import Experiment
from scenario.load import PlantModel

ARRAYS = ("t_s", "truth", "ref", "target", "slot_of", "slot_xy", "leader", "power", "mode")


def _assert_same_log(a: object, b: object) -> None:
    for name in ARRAYS:
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    assert a.min_separation_m == b.min_separation_m  # type: ignore[attr-defined]
    assert a.collisions == b.collisions  # type: ignore[attr-defined]
    assert a.filter_counts == b.filter_counts  # type: ignore[attr-defined]


def _step_through(exp: Experiment, seed: int) -> None:
    assert exp.reset(seed) is None
    while not exp.done:
        exp.step()


@pytest.mark.parametrize(
    ("name", "seed", "duration_s"),
    [("paper-exp2", 3, 40.0), ("chevron7", 4, 8.0)],
)
def test_stepping_equals_formation_sim(name: str, seed: int, duration_s: float) -> None:
    """paper-exp2 for 40 s includes the drag at 30 s (a scheduled disturbance)."""
    scn = scenario_mod.load(name)
    ref = simulate.run(scn, seed=seed, duration_s=duration_s)
    exp = Experiment(scn, duration_s=duration_s)
    _step_through(exp, seed)
    assert exp.tick == ref.log.t_s.size
    _assert_same_log(exp.log(), ref.log)
    settle = metrics.settle_for(scn.settle_s, duration_s)
    got = metrics.compute(exp.log(), settle, scn.settle_tol_m)
    want = metrics.compute(ref.log, settle, scn.settle_tol_m)
    assert got["robots"] == want["robots"]
    assert got["run"] == want["run"]


def test_stepping_equals_formation_sim_with_encoders() -> None:
    scn = scenario_mod.load("paper-exp1")
    scn = dataclasses.replace(
        scn, plant=PlantModel(encoder_counts_per_rev=1440.0, encoder_slip_std=0.01)
    )
    ref = simulate.run(scn, seed=5, duration_s=6.0)
    exp = Experiment(scn, duration_s=6.0)
    _step_through(exp, 5)
    _assert_same_log(exp.log(), ref.log)


def test_reset_starts_the_same_run_again_and_a_seed_changes_it() -> None:
    exp = Experiment(scenario_mod.load("paper-exp1"), duration_s=3.0)
    _step_through(exp, 1)
    first = exp.log()
    _step_through(exp, 1)
    _assert_same_log(exp.log(), first)
    _step_through(exp, 2)
    assert not np.array_equal(exp.log().truth, first.truth)


def test_actions_replace_the_firmware_output_through_the_link() -> None:
    """r3 told to stand still stays where it started (up to the link's last command before the
    first action, none here); the others still converge; the firmware's own command is still
    reported; the logged power is the action's."""
    scn = scenario_mod.load("paper-exp1")
    exp = Experiment(scn, duration_s=10.0)
    exp.reset(2)
    start = None
    moved_by_fw = 0.0
    while not exp.done:
        obs = exp.step({"r3": (0.0, 0.0)})
        if start is None:
            start = obs.truth[2]
        assert obs.wheels[2] == (0.0, 0.0)
        moved_by_fw = max(moved_by_fw, abs(obs.firmware[2][0]))
    assert start is not None
    end = exp.log().truth[-1, 2]
    assert math.dist(end[:2], start[:2]) < 1e-12
    assert moved_by_fw > 0.0  # the firmware did want to move it
    assert np.all(exp.log().power[:, 2, :] == 0.0)
    r1 = exp.log().truth[:, 0, :2]
    assert math.dist(r1[0], r1[-1]) > 0.1  # r1 followed its slot


def test_an_action_spins_the_robot_as_the_kinematics_say() -> None:
    """Equal and opposite wheel speeds turn a robot in place (eqs 7-9): after the motor lag
    its heading changes at R (wr - wl) / 2L and its centre stays put."""
    scn = scenario_mod.load("paper-exp1")
    g = scn.agent.geometry
    exp = Experiment(scn, duration_s=4.0)
    exp.reset(2)
    w = 2.0
    for _ in range(exp.ticks):
        obs = exp.step({rid: (w, -w) for rid in scn.robot_ids})
    log = exp.log()
    rate = g.wheel_radius_m * (2 * w) / (2 * g.half_track_m)
    th = np.unwrap(log.truth[:, 0, 2])
    late = log.t_s > 2.0
    measured = np.polyfit(log.t_s[late], th[late], 1)[0]
    assert measured == pytest.approx(rate, rel=0.05)
    assert math.dist(log.truth[0, 0, :2], log.truth[-1, 0, :2]) < 1e-9
    assert obs.t_s == pytest.approx(4.0)


def test_bad_actions_and_misuse_are_refused_and_clamps_counted() -> None:
    scn = scenario_mod.load("paper-exp1")
    exp = Experiment(scn, duration_s=0.1)
    with pytest.raises(ValueError, match="reset"):
        exp.step()
    exp.reset()
    for bad, what in [
        ({"r9": (0.0, 0.0)}, "unknown robot"),
        ({"r1": (math.nan, 0.0)}, "finite"),
        ({"r1": (1.0,)}, "omega_right"),
        ({"r1": "fast"}, "omega_right"),
    ]:
        with pytest.raises(ValueError, match=what):
            exp.step(bad)
    big = scn.agent.geometry.max_wheel_radps * 3
    obs = exp.step({"r1": (big, -big)})
    assert exp.clamped_actions == 1
    assert obs.wheels[0] == (
        scn.agent.geometry.max_wheel_radps,
        -scn.agent.geometry.max_wheel_radps,
    )
    while not exp.done:
        exp.step()
    with pytest.raises(ValueError, match="over"):
        exp.step()
    with pytest.raises(ValueError, match="duration_s"):
        Experiment(scn, duration_s=math.inf)
