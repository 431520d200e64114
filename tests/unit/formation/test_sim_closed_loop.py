"""The in-process closed loop (``formation.sim.simulate``) on the built-in scenarios, its
determinism,
scenario validation, and the agreement of the components' small-fleet (plain Python) paths with
their vectorised numpy paths, which the fast simulator relies on.

Closed loop: paper-sim converges into the triangle; paper-exp1 holds it with r1 leading;
paper-exp2 hands the lead from r1 to r2 after the drag, once, without a collision; chevron7
converges. Each scenario runs once per module (full durations; a few seconds in all).
"""

from __future__ import annotations

import copy
import math
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import scenario as scenario_mod
import sim_plant.core.plant as plant_mod
import sim_plant.core.sensors as sensors_mod
from coordinator.core.assignment import RoleAssigner, assign_optimal
from coordinator.core.coordinator import CoordinatorCore, CoordinatorOutput
from coordinator.core.formation import FormationSpec, slot_arrays, slot_rows, slot_states
from coordinator.core.matching import _cost_rows_py, _costs, _greedy_np
from coordinator.core.matching import greedy_py as _greedy_py
from coordinator.core.trajectory import LeaderState
from formation.outputs import metrics
from formation.outputs.runlog import RunLog
from formation.sim import simulate
from robot_agent.core.params import RobotGeometry
from sim_plant.core.accounting import SeparationMonitor
from sim_plant.core.kinematics import PoseRows, wrap_angle, wrap_angles
from sim_plant.core.plant import Plant
from sim_plant.core.sensors import Camera, CommandLink

GEOM = RobotGeometry()
BODY_RADIUS_M = GEOM.body_radius_m  # 0.075 m


def _run(name: str, seed: int | None = None) -> tuple[simulate.SimResult, dict[str, Any]]:
    scn = scenario_mod.load(name)
    res = simulate.run(scn, seed=seed)
    return res, metrics.compute(res.log, scn.settle_s, scn.settle_tol_m)


def _comparable(m: dict[str, Any]) -> dict[str, Any]:
    """Metrics without the wall-clock fields (the only ones that differ between two runs)."""
    out = copy.deepcopy(m)
    out["meta"].pop("wall_s", None)
    out["meta"].pop("realtime_factor", None)
    return out


@pytest.fixture(scope="module")
def paper_sim() -> tuple[simulate.SimResult, dict[str, Any]]:
    return _run("paper-sim")


@pytest.fixture(scope="module")
def paper_exp1() -> tuple[simulate.SimResult, dict[str, Any]]:
    return _run("paper-exp1")


@pytest.fixture(scope="module")
def paper_exp2() -> tuple[simulate.SimResult, dict[str, Any]]:
    return _run("paper-exp2")


@pytest.fixture(scope="module")
def chevron7() -> tuple[simulate.SimResult, dict[str, Any]]:
    return _run("chevron7")


def _assert_converged(m: dict[str, Any], rms_max_m: float) -> None:
    for rid, r in m["robots"].items():
        assert r["settling_time_s"] is not None, f"{rid} never settled"
        assert r["formation_error_rms_m"] is not None
        assert r["formation_error_rms_m"] < rms_max_m, f"{rid}: RMS {r['formation_error_rms_m']}"
        assert r["final_slot"] is not None
    assert m["run"]["collisions"] == 0
    assert m["run"]["min_separation_m"] > 2 * BODY_RADIUS_M


# ---------------------------------------------------------------- closed loop


def test_paper_sim_converges_into_the_triangle(paper_sim: Any) -> None:
    res, m = paper_sim
    _assert_converged(m, rms_max_m=0.02)
    # Each robot's reference point ends on its own slot of the triangle (side b = 0.4 m).
    log = res.log
    assert sorted(r["final_slot"] for r in m["robots"].values()) == [0, 1, 2]
    ref = log.ref[-1]
    for a in range(3):
        for b in range(a + 1, 3):
            assert math.dist(ref[a], ref[b]) == pytest.approx(0.4, abs=0.02)


def test_paper_exp1_r1_leads_throughout_and_all_converge(paper_exp1: Any) -> None:
    res, m = paper_exp1
    _assert_converged(m, rms_max_m=0.02)
    timeline = m["run"]["leader_timeline"]
    assert [e["leader"] for e in timeline] == [None, "r1"]  # nobody before the first pose
    assert timeline[1]["t_s"] < 0.1
    assigned = res.log.slot_of[:, 0] >= 0
    assert np.all(res.log.slot_of[assigned, 0] == 0)


def test_paper_exp2_lead_passes_from_r1_to_r2_once(paper_exp2: Any) -> None:
    res, m = paper_exp2
    log = res.log
    run = m["run"]
    assert [e["leader"] for e in run["leader_timeline"]] == [None, "r1", "r2"]
    handover_t = run["leader_timeline"][2]["t_s"]
    assert 30.0 < handover_t < 34.0  # during or just after the drag (t = 30..32 s)
    # Exactly one reassignment event after the initial assignment: r1 and r2 swap at one tick.
    initial = run["initial_assignments"]
    later = run["role_changes"]  # the initial assignment is not a role change
    assert run["role_change_count"] == len(later) == 2
    assert {(c["robot"], c["slot"]) for c in initial} == {("r1", 0), ("r2", 1), ("r3", 2)}
    assert len({c["t_s"] for c in later}) == 1
    assert {(c["robot"], c["from_slot"], c["to_slot"]) for c in later} == {
        ("r1", 0, 1),
        ("r2", 1, 0),
    }
    assert m["robots"]["r1"]["final_slot"] == 1  # r2's old slot
    assert m["robots"]["r2"]["final_slot"] == 0
    r3 = log.robot_ids.index("r3")
    assigned = log.slot_of[:, r3] >= 0
    assert np.all(log.slot_of[assigned, r3] == 2)  # r3 keeps slot 2 throughout
    assert run["collisions"] == 0
    assert run["min_separation_m"] > 2 * BODY_RADIUS_M
    _assert_converged(m, rms_max_m=0.02)


def test_chevron7_converges(chevron7: Any) -> None:
    _, m = chevron7
    assert len(m["robots"]) == 7
    _assert_converged(m, rms_max_m=0.03)
    assert sorted(r["final_slot"] for r in m["robots"].values()) == list(range(7))


def test_runlog_is_consistent(paper_exp2: Any) -> None:
    """The arrays built at the end agree with their definitions tick by tick."""
    res, _ = paper_exp2
    log = res.log
    ticks = log.t_s.size
    assert ticks == round(110.0 / 0.02) + 1
    np.testing.assert_array_equal(log.t_s, [k * 0.02 for k in range(ticks)])
    th = log.truth[:, :, 2]
    np.testing.assert_array_equal(log.ref[:, :, 0], log.truth[:, :, 0] + 0.05 * np.cos(th))
    for k in (0, 1, 2, 1000, ticks - 1):
        for i in range(len(log.robot_ids)):
            s = log.slot_of[k, i]
            if s < 0:
                assert np.all(np.isnan(log.target[k, i]))
            else:
                row = log.slot_ids.index(int(s))
                np.testing.assert_array_equal(log.target[k, i], log.slot_xy[k, row])
    assert np.all(np.abs(log.power) <= 1.0)
    assert set(np.unique(log.mode).tolist()) <= {0, 1, 2, 3}


# ---------------------------------------------------------------- determinism


def test_same_seed_same_metrics_other_seed_differs(paper_exp2: Any) -> None:
    _, m1 = paper_exp2
    _, m2 = _run("paper-exp2")
    assert _comparable(m1) == _comparable(m2)
    _, m3 = _run("paper-exp2", seed=11)
    assert _comparable(m3) != _comparable(m1)
    assert m3["meta"]["seed"] == 11


# ---------------------------------------------------------------- scenario validation


def _scenario_dict() -> dict[str, Any]:
    return {
        "name": "t",
        "duration_s": 1.0,
        "robots": {"ids": ["r1", "r2"], "initial": [[0.0, 0.0, 0.0], [0.0, 0.5, 0.0]]},
        "trajectory": {"kind": "line", "x0": 0.0, "y0": 0.0, "heading": 0.0, "speed_mps": 0.02},
        "formation": {"kind": "triangle", "b_m": 0.4},
    }


@pytest.mark.parametrize(
    ("path", "value", "field"),
    [
        (("duration_s",), -1.0, "duration_s"),
        (("dt_s",), "fast", "dt_s"),
        (("robots", "initial"), [[0.0, 0.0, 0.0]], "robots.initial"),
        (("robots", "ids"), ["R1", "r2"], "robots.ids"),
        (("assignment",), {"method": "random"}, "assignment.method"),
        (("camera",), {"fps": 30}, "camera"),
        (("link",), {"loss_prob": 1.5}, "link.loss_prob"),
        (("disturbance",), [{"t_s": 0.5, "robot": "r9", "kind": "drag"}], "disturbance[0].robot"),
        (("geometry",), {"wheel_radius_m": "big"}, "geometry.wheel_radius_m"),
    ],
)
def test_bad_scenario_names_the_field(path: tuple[str, ...], value: Any, field: str) -> None:
    data = _scenario_dict()
    node = data
    for key in path[:-1]:
        node = node[key]
    node[path[-1]] = value
    with pytest.raises(scenario_mod.ScenarioError, match=field.replace("[", r"\[")):
        scenario_mod.parse(data)


def test_bad_scenario_file(tmp_path: Any) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text('name = "bad"\nduration_s = [\n')
    with pytest.raises(scenario_mod.ScenarioError, match="not valid TOML"):
        scenario_mod.load(str(bad))
    with pytest.raises(scenario_mod.ScenarioError, match="no scenario"):
        scenario_mod.load("no-such-scenario")


# ---------------------------------------------------------------- small-fleet paths == numpy


def _plant_run(tau: float, cmds: np.ndarray, x0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    p = Plant(x0, GEOM, motor_tau_s=tau)
    for k, c in enumerate(cmds):
        p.step(0.02, c if k % 2 else c.tolist())  # arrays and lists both take the fast path
    return p.truth, p.wheel_speeds


@pytest.mark.parametrize("tau", [0.0, 0.05])
def test_plant_small_path_is_bit_identical(tau: float, monkeypatch: pytest.MonkeyPatch) -> None:
    rng = np.random.default_rng(7)
    x0 = rng.uniform(-2.0, 2.0, (4, 3))
    cmds = rng.uniform(-9.5, 9.5, (400, 4, 2))
    cmds[::7, 2] = [3.0, 3.0]  # straight lines (omega == 0)
    cmds[::11, 3] = [12.0, -15.0]  # over the limit: the general path clamps and counts
    cmds[::13, 0] = [math.nan, 1.0]  # non-finite: the general path zeroes and counts
    fast = _plant_run(tau, cmds, x0)
    monkeypatch.setattr(plant_mod, "SMALL_N", -1)
    slow = _plant_run(tau, cmds, x0)
    np.testing.assert_array_equal(fast[0], slow[0])
    np.testing.assert_array_equal(fast[1], slow[1])


def test_plant_small_path_with_drag_teleport_and_counters(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    a = Plant(np.zeros((3, 3)), GEOM, motor_tau_s=0.05)
    b = Plant(np.zeros((3, 3)), GEOM, motor_tau_s=0.05)
    cmd = np.array([[5.0, 4.0], [20.0, 3.0], [-2.0, 2.0]])  # robot 1 over the limit
    for p, small in ((a, plant_mod.SMALL_N), (b, -1)):
        monkeypatch.setattr(plant_mod, "SMALL_N", small)
        for k in range(200):
            if k == 20:
                p.drag(0, -0.3, 0.1, 0.5)
            if k == 90:
                p.teleport(2, 1.0, 1.0, 4.0)
            p.step(0.02, cmd if k % 3 else cmd[[0, 0, 2]])
            assert p.truth_rows() == tuple(map(tuple, p.truth.tolist()))
    np.testing.assert_array_equal(a.truth, b.truth)
    np.testing.assert_array_equal(a.wheel_speeds, b.wheel_speeds)
    np.testing.assert_array_equal(a.clamp_counts, b.clamp_counts)
    np.testing.assert_array_equal(a.saturated, b.saturated)
    assert a.t_s == b.t_s


@settings(max_examples=200, deadline=None)
@given(st.floats(-1e6, 1e6, allow_nan=False, allow_infinity=False))
def test_scalar_wrap_equals_array_wrap(a: float) -> None:
    assert wrap_angle(a) == float(wrap_angles(np.array([a]))[0])


def _camera_run(truths: list[Any], miss: float) -> tuple[list[Any], list[Any]]:
    cam = Camera(3, rng=np.random.default_rng(3), miss_prob=miss, frame_drop_prob=0.1)
    polled, frames = [], []
    for k, truth in enumerate(truths):
        cam.capture(k * 0.01, truth)
        polled.extend(cam.poll(k * 0.01))
    frames = [(f.stamp_t, f.ids.tolist(), f.poses.tolist()) for f in cam.poll_frames(1e9)]
    return polled, frames


@pytest.mark.parametrize("miss", [0.0, 0.2])
def test_camera_small_path_is_bit_identical(miss: float, monkeypatch: pytest.MonkeyPatch) -> None:
    rng = np.random.default_rng(1)
    arrays = [rng.uniform(-3.0, 3.0, (3, 3)) for _ in range(300)]
    plant = Plant(arrays[0], GEOM)
    as_rows = [tuple(map(tuple, a.tolist())) for a in arrays]
    assert type(plant.truth_rows()) is PoseRows
    fast_arrays = _camera_run(arrays, miss)
    fast_rows = _camera_run(as_rows, miss)
    fast_plant_rows = _camera_run([PoseRows(r) for r in as_rows], miss)
    monkeypatch.setattr(sensors_mod, "SMALL_N", -1)
    slow = _camera_run(arrays, miss)
    assert fast_arrays == slow
    assert fast_rows == slow
    assert fast_plant_rows == slow


def test_camera_small_path_validates_shape() -> None:
    cam = Camera(3, pos_std_m=0.0, theta_std_rad=0.0)
    for bad in ([(0.0, 0.0, 0.0)] * 2, [(0.0, 0.0)] * 3, [("a", 0.0, 0.0)] * 3, np.zeros((3, 2))):
        with pytest.raises(ValueError, match="truth must have shape"):
            cam.capture(0.0, bad)
    assert cam.frames_taken == 0


@pytest.mark.parametrize(
    ("loss", "jitter", "fifo"),
    [(0.2, 0.01, True), (0.0, 0.01, False), (0.3, 0.0, True), (0.0, 0.0, True)],
)
def test_link_send_all_equals_sends(loss: float, jitter: float, fifo: bool) -> None:
    a: CommandLink[tuple[int, int]] = CommandLink(
        0.01, jitter, loss, np.random.default_rng(4), fifo=fifo
    )
    b: CommandLink[tuple[int, int]] = CommandLink(
        0.01, jitter, loss, np.random.default_rng(4), fifo=fifo
    )
    got_a, got_b = [], []
    for k in range(500):
        cmds = [(k, i) for i in range(4)]
        a.send_all(k * 0.002, cmds)
        for i, c in enumerate(cmds):
            b.send(k * 0.002, i, c)
        got_a.extend(a.poll(k * 0.002))
        got_b.extend(b.poll(k * 0.002))
    assert got_a == got_b
    assert (a.sent, a.dropped, a.delivered) == (b.sent, b.dropped, b.delivered)


def test_separation_rows_and_batch_equal_array_path() -> None:
    rng = np.random.default_rng(9)
    n, ticks = 5, 400
    walk = np.cumsum(rng.normal(0.0, 0.03, (ticks, n, 3)), axis=0)
    walk[:, :, :2] += rng.uniform(-0.4, 0.4, (1, n, 2))
    t = np.arange(ticks) * 0.02
    arrays, rows, batch = (SeparationMonitor(BODY_RADIUS_M) for _ in range(3))
    batch.update_many(t[:150], walk[:150])  # in two calls: the contact state carries over
    batch.update_many(t[150:], walk[150:])
    for k in range(ticks):
        arrays.update(float(t[k]), walk[k])
        rows.update(float(t[k]), tuple(map(tuple, walk[k].tolist())))
    assert arrays.collision_count > 0
    for mon in (rows, batch):
        assert mon.collisions == arrays.collisions
        assert mon.min_separation_m == arrays.min_separation_m
        assert mon.min_separation_t_s == arrays.min_separation_t_s
        assert mon.in_contact == arrays.in_contact
        assert mon.updates == arrays.updates
        assert mon.last_min_separation_m == arrays.last_min_separation_m
    with pytest.raises(ValueError, match="finite"):
        rows.update(0.0, [(0.0, 0.0), (math.nan, 1.0)])


@settings(max_examples=200, deadline=None)
@given(
    n_robots=st.integers(0, 9),
    n_slots=st.integers(1, 9),
    seed=st.integers(0, 2**32 - 1),
    hyst=st.sampled_from([0.0, 0.05]),
    tol=st.sampled_from([0.0, 0.01, 0.3]),
)
def test_greedy_python_equals_numpy(
    n_robots: int, n_slots: int, seed: int, hyst: float, tol: float
) -> None:
    rng = np.random.default_rng(seed)
    ids = [f"r{i}" for i in range(n_robots)]
    rxy = [(float(x), float(y)) for x, y in rng.uniform(-1.0, 1.0, (n_robots, 2))]
    sids = list(range(n_slots))
    sxy = [(float(x), float(y)) for x, y in rng.uniform(-1.0, 1.0, (n_slots, 2))]
    if n_robots > 1:  # an exact tie and a near tie
        rxy[1] = (2 * sxy[0][0] - rxy[0][0], 2 * sxy[0][1] - rxy[0][1])
    inc = {rid: int(s) for rid, s in zip(ids, rng.permutation(n_slots), strict=False)}
    k = min(n_robots, n_slots)
    if k == 0:
        return
    py = _greedy_py(ids, rxy, sids, sxy, k, inc, hyst, tol)
    assert py == _greedy_np(ids, rxy, sids, sxy, k, inc, hyst, tol)
    assert list(py) == [r for r in ids if r in py]
    # The optimal rule's cost matrix: plain Python == cdist with the hysteresis applied.
    _, cost = _costs(ids, np.array(rxy), sids[:k], np.array(sxy[:k]), inc, hyst)
    np.testing.assert_array_equal(_cost_rows_py(ids, rxy, sids, sxy, k, inc, hyst), cost)


def test_role_assigner_ordered_update_equals_update() -> None:
    spec = FormationSpec.chevron(7)
    rng = np.random.default_rng(2)
    for method in ("greedy", "optimal"):
        a, b = RoleAssigner(method), RoleAssigner(method)
        for k in range(60):
            leader = LeaderState(0.0, 0.01 * k, 0.0, 0.1 * k, 0.05, 0.01)
            _, rows = slot_rows(spec, leader)
            slots = slot_states(spec, leader)
            robots = {f"r{i}": (float(x), float(y)) for i, (x, y) in
                      enumerate(rng.normal(0.0, 0.6, (6 + k % 3, 2)))}  # fmt: skip
            order = list(robots)[::-1]  # not in natural order: sorted inside
            got = a.update_ordered(
                order,
                [robots[r] for r in order],
                spec.priority_slots,
                [rows[r] for r in spec.priority_rows],
            )
            assert got == b.update(robots, slots)
    with pytest.raises(ValueError, match="non-finite position for robot"):
        a.update_ordered(["r1"], [(math.nan, 0.0)], [0], [(0.0, 0.0)])
    with pytest.raises(ValueError, match="slot 0: non-finite"):
        a.update_ordered(["r1"], [(0.0, 0.0)], [0, 1], [(math.inf, 0.0), (1.0, 0.0)])
    with pytest.raises(ValueError, match="slot 1: non-finite"):
        a.update_ordered(["r1"], [(0.0, 0.0)], [0, 1], [(0.0, 0.0), (math.nan, 0.0)])


@pytest.mark.parametrize("kind", ["triangle", "chevron", "lattice"])
def test_slot_rows_match_slot_states_and_arrays(kind: str) -> None:
    spec = FormationSpec.triangle() if kind == "triangle" else getattr(FormationSpec, kind)(12)
    for leader in (LeaderState(0.0, 1.0, -2.0, 2.9, 0.07, 0.3), LeaderState(1.0, 0, 0, -7.0, 0, 0)):
        theta, rows = slot_rows(spec, leader)
        states = slot_states(spec, leader)
        assert [(s.x, s.y, s.vx, s.vy) for s in states] == rows
        assert all(s.theta == theta for s in states)
        xy, vxy = slot_arrays(spec, leader)
        np.testing.assert_allclose(np.array(rows)[:, :2], xy, rtol=0, atol=1e-12)
        np.testing.assert_allclose(np.array(rows)[:, 2:], vxy, rtol=0, atol=1e-12)


def test_coordinator_output_lazy_slots_equal_eager() -> None:
    scn = scenario_mod.load("chevron7")
    core = CoordinatorCore.from_config(
        scn.trajectory, scn.formation, "optimal", 0.05, 0.01, ref_offset_m=0.05
    )
    poses = {rid: (x, y, th) for rid, (x, y, th) in zip(scn.robot_ids, scn.initial, strict=True)}
    out = core.tick(1.0, poses)
    eager = CoordinatorOutput(out.leader, slot_states(core.formation, out.leader),
                              dict(out.assignment), out.changed)  # fmt: skip
    assert out == eager
    assert out.slots_by_id == eager.slots_by_id
    assert out.rows == eager.rows and out.theta == eager.theta
    assert out.slot_ids == tuple(s.slot for s in out.slots)
    for rid in scn.robot_ids:
        assert out.setpoint_for(rid) == eager.setpoint_for(rid)
    assert out.leader_robot == eager.leader_robot
    # The core's first tick assigns as the public function does from scratch.
    assert out.assignment == assign_optimal(core.reference_points(poses), eager.slots)


def test_runlog_from_ticks_small_example() -> None:
    truth = [((0.0, 0.0, 0.0), (1.0, 0.0, math.pi / 2))] * 3
    leader = [(0.0, 0.0, 0.0)] * 3
    slots = [[(0.5, 0.5, 0.0, 0.0), (2.0, 2.0, 0.0, 0.0)]] * 3
    cmd = (0.1, 0.2, 0.01, 0.02, "tracking", 0.0, False)
    log = RunLog.from_ticks(
        ["a", "b"], [0, 7], 0.5, truth, leader, slots, [(0, [-1, -1]), (1, [7, 0])],
        [[cmd, cmd]] * 3, 0.05,
    )  # fmt: skip
    np.testing.assert_array_equal(log.t_s, [0.0, 0.5, 1.0])
    np.testing.assert_array_equal(log.slot_of, [[-1, -1], [7, 0], [7, 0]])
    assert np.all(np.isnan(log.target[0]))
    np.testing.assert_array_equal(log.target[1], [[2.0, 2.0], [0.5, 0.5]])
    np.testing.assert_allclose(log.ref[0], [[0.05, 0.0], [1.0, 0.05]], atol=1e-15)
    np.testing.assert_array_equal(log.mode, np.ones((3, 2)))
    np.testing.assert_array_equal(log.power[2], [[0.01, 0.02], [0.01, 0.02]])
