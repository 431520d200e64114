"""The virtual leader as a state (coordinator.core.leader): script, teleop with deadman, goals,
paths, the wait for the team, takeover, hostile input."""

from __future__ import annotations

import itertools
import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from coordinator.core.assignment import RoleAssigner
from coordinator.core.coordinator import CoordinatorCore
from coordinator.core.formation import FormationSpec
from coordinator.core.leader import (
    DEADMAN_S,
    LeaderConfig,
    LeaderCore,
    LeaderMode,
    TeamWait,
    WaitSetting,
    integrate_unicycle,
)
from coordinator.core.trajectory import Circle, LeaderState, StraightLine

DT = 0.02
CFG = LeaderConfig()


def _line() -> StraightLine:
    return StraightLine(x0=0.0, y0=0.0, heading=0.3, speed_mps=0.05)


def _circle() -> Circle:
    return Circle(cx=0.0, cy=0.0, radius_m=1.0, speed_mps=0.08)


def _run(core: LeaderCore, k0: int, k1: int, t0: float = 0.0) -> list[LeaderState]:
    return [core.step(t0 + k * DT) for k in range(k0, k1)]


def _assert_smooth(states: list[LeaderState], cfg: LeaderConfig = CFG) -> None:
    """No jump: consecutive velocities differ by at most the acceleration limits times dt, and
    each position step is the arc of the published (v, omega) (feed-forward consistency)."""
    for a, b in itertools.pairwise(states):
        assert abs(b.v_mps - a.v_mps) <= cfg.max_accel_mps2 * DT + 1e-12
        assert abs(b.omega_radps - a.omega_radps) <= cfg.max_turn_accel_radps2 * DT + 1e-12
        x, y, th = integrate_unicycle(a.x, a.y, a.theta, b.v_mps, b.omega_radps, DT)
        assert math.hypot(b.x - x, b.y - y) < 1e-9
        assert abs(math.remainder(b.theta - th, 2 * math.pi)) < 1e-9


@settings(max_examples=30, deadline=None)
@given(t0=st.floats(-1e5, 1e5), n=st.integers(1, 200))
def test_script_without_commands_is_the_trajectory_bit_for_bit(t0: float, n: int) -> None:
    traj = _circle()
    core = LeaderCore(traj, t0_s=t0)
    for k in range(n):
        now = t0 + k * DT
        assert core.step(now) == traj.sample(now - t0)
    assert core.mode is LeaderMode.SCRIPT and core.rate == 1.0


def test_teleop_takes_over_without_a_jump_and_respects_the_limits() -> None:
    core = LeaderCore(_circle())
    states = _run(core, 0, 100)
    for k in range(100, 400):
        core.command_twist(0.1, -0.3, k * DT)
        states.append(core.step(k * DT))
    assert core.mode is LeaderMode.TELEOP
    # the join from the circle (0.08 m/s, 0.08 rad/s) to the operator's twist
    _assert_smooth(states[99:])
    assert states[-1].v_mps == pytest.approx(0.1)
    assert states[-1].omega_radps == pytest.approx(-0.3)


def test_deadman_stops_the_leader_within_its_bound() -> None:
    core = LeaderCore(_line())
    states = []
    for k in range(300):
        core.command_twist(0.1, 0.2, k * DT)
        states.append(core.step(k * DT))
    last_cmd = 299 * DT
    assert not core.deadman
    bound = CFG.deadman_s + max(
        CFG.max_speed_mps / CFG.max_accel_mps2, CFG.max_turn_radps / CFG.max_turn_accel_radps2
    )
    k = 300
    while states[-1].v_mps != 0.0 or states[-1].omega_radps != 0.0:
        states.append(core.step(k * DT))
        k += 1
        assert (k - 1) * DT - last_cmd <= bound + DT, "not stopped within the deadman bound"
    assert core.deadman
    # obeyed until the deadman, then a braking within the limits
    obeyed = [s for i, s in enumerate(states[300:]) if (300 + i) * DT - last_cmd <= DEADMAN_S]
    assert all(s.v_mps == pytest.approx(0.1) for s in obeyed)
    _assert_smooth(states)
    stopped = states[-1]
    more = _run(core, k, k + 50)
    assert all((s.x, s.y, s.v_mps) == (stopped.x, stopped.y, 0.0) for s in more)


def test_a_new_twist_after_the_deadman_resumes() -> None:
    core = LeaderCore(_line())
    core.command_twist(0.05, 0.0, 0.0)
    _run(core, 0, 200)
    assert core.deadman and core.state is not None and core.state.v_mps == 0.0
    core.command_twist(0.05, 0.0, 200 * DT)
    s = core.step(200 * DT)
    assert not core.deadman and s.v_mps > 0.0


def test_goal_is_reached_with_the_heading_and_a_continuous_join() -> None:
    core = LeaderCore(_line())
    states = _run(core, 0, 50)
    assert core.command_goal(1.0, 1.0, heading=math.pi) is None
    k = 50
    while core.mode is not LeaderMode.STOP:
        states.append(core.step(k * DT))
        k += 1
        assert k < 10_000, "goal never reached"
    _assert_smooth(states[49:])
    end = states[-1]
    assert math.hypot(end.x - 1.0, end.y - 1.0) <= 4 * CFG.goal_tol_m
    assert abs(math.remainder(end.theta - math.pi, 2 * math.pi)) <= CFG.heading_tol_rad
    assert all(abs(s.v_mps) <= CFG.max_speed_mps + 1e-12 for s in states[50:])


def test_path_passes_its_waypoints_and_stops_at_the_last() -> None:
    core = LeaderCore(_line())
    pts = [(0.5, 0.0), (1.0, 0.5), (0.5, 1.0)]
    states = _run(core, 0, 10)
    assert core.command_path(pts) is None
    k = 10
    while core.mode is not LeaderMode.STOP:
        states.append(core.step(k * DT))
        k += 1
        assert k < 20_000
    _assert_smooth(states[9:])
    for px, py in pts[:-1]:
        assert min(math.hypot(s.x - px, s.y - py) for s in states) <= CFG.lookahead_m + 1e-9
    assert math.hypot(states[-1].x - 0.5, states[-1].y - 1.0) <= 4 * CFG.goal_tol_m


@pytest.mark.parametrize(
    ("v", "w", "why"),
    [
        (math.nan, 0.0, "nonfinite"),
        (0.0, math.inf, "nonfinite"),
        (1e300, 0.0, "absurd"),
        (0.0, -1e300, "absurd"),
    ],
)
def test_absurd_twists_are_refused_and_counted(v: float, w: float, why: str) -> None:
    core = LeaderCore(_line())
    ref = LeaderCore(_line())
    for k in range(50):
        assert core.command_twist(v, w, k * DT) == why
        assert core.step(k * DT) == ref.step(k * DT)
    assert core.rejects == {why: 50} and core.mode is LeaderMode.SCRIPT


def test_goals_outside_the_arena_and_bad_paths_are_refused() -> None:
    core = LeaderCore(_line(), arena=(-1.0, -1.0, 1.0, 1.0))
    assert core.command_goal(2.0, 0.0) == "outside_arena"
    assert core.command_goal(math.nan, 0.0) == "nonfinite"
    assert core.command_goal(0.5, 0.0, heading=math.inf) == "nonfinite"
    assert core.command_path([]) == "path_length"
    assert core.command_path([(0.1, 0.1), (0.1, 0.1)]) == "coincident_points"
    assert core.command_path([(0.1, 0.1)] * 300) == "path_length"
    assert sum(core.rejects.values()) == 6
    assert core.step(0.0).v_mps == 0.0 and core.mode is LeaderMode.SCRIPT


def test_too_fast_twists_are_clamped_and_counted() -> None:
    core = LeaderCore(_line())
    for k in range(200):
        core.command_twist(0.5, -1.0, k * DT)
        s = core.step(k * DT)
    assert s.v_mps == CFG.max_speed_mps and s.omega_radps == -CFG.max_turn_radps
    assert core.rejects == {"clamped": 200}


@settings(max_examples=60, deadline=None)
@given(
    cmds=st.lists(
        st.tuples(
            st.integers(0, 3),
            st.floats(allow_nan=True, allow_infinity=True),
            st.floats(allow_nan=True, allow_infinity=True),
        ),
        max_size=40,
    )
)
def test_no_input_ever_makes_the_leader_jump(cmds: list[tuple[int, float, float]]) -> None:
    core = LeaderCore(_circle())
    states = _run(core, 0, 5)
    for k, (burst, v, w) in enumerate(cmds, start=5):
        for _ in range(burst):
            core.command_twist(v, w, k * DT)
        if burst == 3:
            core.command_goal(v, w)
        states.append(core.step(k * DT))
    for a, b in itertools.pairwise(states):
        assert all(math.isfinite(c) for c in (b.x, b.y, b.theta, b.v_mps, b.omega_radps))
        # the circle (0.08 m/s) or the limits: a step never exceeds the fastest of both
        assert math.hypot(b.x - a.x, b.y - a.y) <= CFG.max_speed_mps * DT + 1e-12
        assert abs(b.v_mps - a.v_mps) <= CFG.max_accel_mps2 * DT + 0.08 + 1e-12


def test_same_inputs_same_bits() -> None:
    def run() -> list[LeaderState]:
        core = LeaderCore(_circle())
        out = []
        for k in range(400):
            if 50 <= k < 150:
                core.command_twist(0.07, 0.1 * math.sin(k), k * DT)
            if k == 200:
                core.command_path([(1.0, 1.0), (0.0, 1.5)])
            out.append(core.step(k * DT, 1.0 if k < 300 else 0.3))
        return out

    assert run() == run()


def test_a_burst_is_one_command_per_tick() -> None:
    core = LeaderCore(_line())
    for i in range(100):
        core.command_twist(0.001 * i, 0.0, 0.0)
    assert core.superseded == 99
    core.step(0.0)
    assert core._twist is not None and core._twist.v_mps == pytest.approx(0.099)


@pytest.mark.parametrize("mode", ["teleop", "script", "path"])
def test_a_takeover_continues_from_the_same_state(mode: str) -> None:
    cfg = LeaderConfig(wait=WaitSetting.ON)
    active = LeaderCore(_circle(), cfg)
    standby = LeaderCore(_circle(), cfg)
    for k in range(300):
        now = k * DT
        if mode == "teleop":
            active.command_twist(0.08, 0.2, now)
            standby.command_twist(0.08, 0.2, now)
            standby.remember()
        if mode == "path" and k == 10:
            active.command_path([(1.0, 0.0), (1.0, 1.0)])
            standby.command_path([(1.0, 0.0), (1.0, 1.0)])
            standby.remember()
        last = active.step(now, 0.5 if k > 100 else 1.0)
    assert active.mode.value == mode
    standby.adopt(299 * DT, last, active.mode, active.progress_s, active.rate, active.target_index)
    for k in range(300, 500):
        now = k * DT
        if mode == "teleop":
            active.command_twist(0.08, 0.2, now)
            standby.command_twist(0.08, 0.2, now)
        assert standby.step(now, 0.5) == active.step(now, 0.5)


def test_adopt_refuses_garbage() -> None:
    core = LeaderCore(_line())
    bad = LeaderState(0.0, math.nan, 0.0, 0.0, 0.0, 0.0)
    with pytest.raises(ValueError):
        core.adopt(0.0, bad, LeaderMode.SCRIPT, 0.0, 1.0, 0)
    with pytest.raises(ValueError):
        core.adopt(0.0, LeaderState(0.0, 0, 0, 0, 0, 0), LeaderMode.SCRIPT, 0.0, 2.0, 0)


# -- waiting for the team ------------------------------------------------------------------


def test_team_wait_rate_falls_with_the_error_and_is_zero_when_held() -> None:
    w = TeamWait(CFG)
    assert w.target_rate(0.0, {"a": 0.01, "b": 0.05}) == 1.0
    mid = 0.5 * (CFG.wait_err_full_m + CFG.wait_err_stop_m)
    assert w.target_rate(0.1, {"a": 0.01, "b": mid}) == pytest.approx(0.5)
    assert w.worst_robot == "b"
    assert w.target_rate(0.2, {"a": 0.01, "b": 1.0}) == 0.0
    assert w.target_rate(0.3, {"a": 0.01, "b": 0.0}, held={"a"}) == 0.0
    assert w.target_rate(0.4, {"a": math.nan}) == 0.0  # garbage is no reason to run
    assert w.target_rate(0.5, {}) == 1.0


def test_a_robot_held_too_long_is_dropped_and_waited_for_again_once_caught_up() -> None:
    cfg = LeaderConfig(wait_drop_s=5.0)
    w = TeamWait(cfg)
    t = 0.0
    while t <= 5.0:
        assert w.target_rate(t, {"a": 0.0, "b": 0.0}, held={"b"}) == 0.0
        t += 0.5
    assert w.target_rate(t, {"a": 0.0, "b": 0.0}, held={"b"}) == 1.0
    assert w.dropped == {"b"}
    assert w.target_rate(t + 1, {"a": 0.0, "b": 0.5}) == 1.0  # still behind: not waited for
    assert w.target_rate(t + 2, {"a": 0.0, "b": 0.01}) == 1.0
    assert w.dropped == set()
    assert w.target_rate(t + 3, {"a": 0.0, "b": 0.5}) == 0.0  # waited for again


def test_script_slows_along_the_same_path_and_resumes() -> None:
    traj = _line()
    core = LeaderCore(traj, LeaderConfig(wait=WaitSetting.ON))
    states = [core.step(k * DT, 1.0 if k < 100 or k > 300 else 0.0) for k in range(600)]
    # the rate slews: the velocity never steps (after the line's own start at t = 0+)
    for a, b in itertools.pairwise(states[1:]):
        assert abs(b.v_mps - a.v_mps) <= CFG.wait_rate_slew_per_s * DT * traj.speed_mps + 1e-12
        # every state is on the line, at the published progress
    assert min(s.v_mps for s in states) == 0.0
    assert states[-1].v_mps == traj.speed_mps
    assert core.progress_s < 599 * DT
    s = traj.sample(core.progress_s)
    assert (states[-1].x, states[-1].y) == (s.x, s.y)


def test_wait_off_by_default_for_scripts_and_on_for_the_operator() -> None:
    core = LeaderCore(_line())
    assert not core.waits()
    core.command_twist(0.05, 0.0, 0.0)
    core.step(0.0)
    assert core.waits()
    assert LeaderCore(_line(), trajectory_kind="plan").waits()
    assert not LeaderCore(
        _line(), LeaderConfig(wait=WaitSetting.OFF), trajectory_kind="plan"
    ).waits()


@pytest.mark.parametrize(
    "bad",
    [
        {"max_speed_mps": -0.1},
        {"max_accel_mps2": math.nan},
        {"deadman_s": 0},
        {"wait": "sometimes"},
        {"wait_err_full_m": 0.5, "wait_err_stop_m": 0.2},
        {"max_speed": 0.1},
        {"max_turn_radps": True},
    ],
)
def test_bad_leader_config_is_refused(bad: dict[str, object]) -> None:
    with pytest.raises(ValueError, match="leader"):
        LeaderConfig.from_dict(bad)


def test_coordinator_leader_waits_for_a_robot_that_falls_behind() -> None:
    spec = FormationSpec.from_dict({"kind": "triangle", "b_m": 0.4})
    core = CoordinatorCore(
        _line(),
        spec,
        RoleAssigner(),
        ref_offset_m=0.05,
        leader=LeaderCore(_line(), LeaderConfig(wait=WaitSetting.ON)),
    )
    # every robot sits on its slot, except r3, which stays where it started
    out = core.tick(0.0, {})
    start = {sid: row for sid, row in zip(out.slot_ids, out.rows, strict=True)}

    def poses(out_rows: dict[int, tuple[float, float, float, float]]) -> dict[str, tuple]:
        th = 0.3
        p = {}
        for rid, sid in (("r1", 0), ("r2", 1), ("r3", 2)):
            x, y = (out_rows if rid != "r3" else start)[sid][:2]
            p[rid] = (x - 0.05 * math.cos(th), y - 0.05 * math.sin(th), th)
        return p

    rows = start
    for k in range(1, 700):  # 14 s: under wait_drop_s
        out = core.tick(k * DT, poses(rows))
        rows = {sid: row for sid, row in zip(out.slot_ids, out.rows, strict=True)}
    # r3 never moved: the leader crept toward the error at which it stops, and no farther
    assert core.leader.rate < 0.1
    assert out.leader.v_mps < 0.1 * _line().speed_mps
    assert core.leader.wait.worst_robot == "r3"
    lead = out.leader
    assert math.hypot(lead.x, lead.y) <= CFG.wait_err_stop_m + 0.05
    for k in range(700, 1300):  # past wait_drop_s: r3 is dropped, the leader goes on
        out = core.tick(k * DT, poses(rows))
        rows = {sid: row for sid, row in zip(out.slot_ids, out.rows, strict=True)}
    assert core.leader.wait.dropped == {"r3"} and core.leader.rate == 1.0


def test_the_scenario_leader_table_is_validated_and_reaches_the_core() -> None:
    import tomllib
    from pathlib import Path

    from scenario.assemble import coordinator_core
    from scenario.load import ScenarioError, load, parse

    base = tomllib.loads(Path(load("paper-exp2").source).read_text())
    assert load("paper-exp2").leader is None  # no table: the defaults
    core = coordinator_core(parse({**base, "leader": {"wait": "on", "deadman_s": 0.3}}))
    assert core.leader.config.deadman_s == 0.3 and core.leader.waits()
    for bad in ({"wait": "maybe"}, {"deadman_s": -1}, {"max_speed": 1.0}, {"deadman_s": "x"}):
        with pytest.raises(ScenarioError, match="leader"):
            parse({**base, "leader": bad})
