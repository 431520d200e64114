"""``formation up`` and the run collector.

Fast part (no processes): the collector rebuilds the in-process simulator's RunLog from that run's
quantities encoded as bus messages and fed in a scrambled order, in lockstep and in realtime
rows; it patches and counts what a lossy bus does; the TOML writer and ``--robots`` rewriting.

System part (``zenoh``, ``slow``): ``python -m formation up`` as a real subprocess tree on a free
port: paper-exp2 in lockstep (the leader swap after the drag at t = 30 s), paper-exp1 in realtime,
determinism of lockstep, Ctrl-C, a bad scenario name.
"""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import time
import tomllib
from pathlib import Path

import numpy as np
import pytest
from support.run_traffic import FLEET, bus_messages, scramble
from support.spawn import REPO_ROOT, Spawner, child_env
from support.up_runs import finish, up

import scenario
from bus_schemas import (
    Status,
    StatusBatch,
    Truth,
    encode,
    keys,
)
from formation.launch.launcher import LAUNCHER_NICE
from formation.launch.up import UpConfig, plan_run
from formation.outputs import metrics
from formation.outputs.runlog import RunLog
from formation.record.collector import RunCollector, slot_ids_of
from formation.sim import simulate
from scenario import scenario_with_robots, to_toml

pytestmark = pytest.mark.shares_cpu

# ---------------------------------------------------------------------------------------------
# Collector: the in-process run as bus traffic
# ---------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def reference() -> tuple[scenario.Scenario, RunLog]:
    """paper-exp2 in-process through the leader swap (t = 31.5 s)."""
    scn = scenario.load("paper-exp2")
    return scn, simulate.run(scn, duration_s=32.5).log


ARRAYS = ("truth", "ref", "target", "slot_of", "slot_xy", "leader", "power")


def test_collector_rebuilds_the_simulator_log_lockstep(
    reference: tuple[scenario.Scenario, RunLog],
) -> None:
    scn, ref = reference
    col = RunCollector.for_scenario(scn, fleet=FLEET, lockstep=True)
    assert col.feed_all(scramble(bus_messages(ref, scn.dt_s), seed=1)) > 0
    log = col.build()
    assert col.rejected == 0 and col.ignored == 0
    np.testing.assert_array_equal(log.t_s, ref.t_s)
    for name in ARRAYS:
        np.testing.assert_array_equal(getattr(log, name), getattr(ref, name), err_msg=name)
    assert log.min_separation_m == ref.min_separation_m
    mine = metrics.compute(log, scn.settle_s, scn.settle_tol_m)
    theirs = metrics.compute(ref, scn.settle_s, scn.settle_tol_m)
    assert mine["robots"] == theirs["robots"]
    assert {k: v for k, v in mine["run"].items() if k != "collision_events"} == {
        k: v for k, v in theirs["run"].items() if k != "collision_events"
    }
    assert mine["run"]["final_leader"] == "r2"  # the swap is in the rebuilt log


def test_collector_realtime_rows_are_truth_frames(
    reference: tuple[scenario.Scenario, RunLog],
) -> None:
    scn, ref = reference
    col = RunCollector.for_scenario(scn, fleet=FLEET, lockstep=False)
    col.feed_all(scramble(bus_messages(ref, None, t_offset_s=5000.0), seed=2))
    log = col.build()
    np.testing.assert_allclose(log.t_s, ref.t_s, atol=1e-9)
    for name in ARRAYS:
        np.testing.assert_array_equal(getattr(log, name), getattr(ref, name), err_msg=name)


def test_collector_patches_and_counts_a_lossy_bus(
    reference: tuple[scenario.Scenario, RunLog],
) -> None:
    scn, ref = reference
    msgs = bus_messages(ref, scn.dt_s)
    r2_truth = keys.truth_key(FLEET, "r2")
    # drop r2's truth at tick 100 and r1's at tick 0 (a leading incomplete row)
    r2_at_100 = [i for i, (k, _) in enumerate(msgs) if k == r2_truth][100]
    r1_at_0 = next(i for i, (k, _) in enumerate(msgs) if k == keys.truth_key(FLEET, "r1"))
    msgs = [m for i, m in enumerate(msgs) if i not in (r2_at_100, r1_at_0)]
    last_t = float(ref.t_s[-1]) + scn.dt_s  # a final truth nobody answered
    msgs += [(keys.truth_key(FLEET, r), encode(Truth(t=last_t, seq=9999, x=0.0, y=9.0, theta=0.0)))
             for r in ref.robot_ids]  # fmt: skip
    msgs += [
        (keys.leader_key(FLEET), b"\x93\x01\x02"),  # not a map: rejected
        (keys.truth_key(FLEET, "r1"), encode(Truth(t=1.0, seq=1, x=0.0, y=0.0, theta=1.0))[:-3]),
        (keys.truth_key("other", "r1"), msgs[0][1]),  # another fleet: ignored
        (keys.truth_key(FLEET, "r9"), msgs[0][1]),  # not a robot of this run: ignored
        (keys.pose_key(FLEET, "r1"), msgs[0][1]),  # not needed: ignored
    ]
    col = RunCollector.for_scenario(scn, fleet=FLEET, lockstep=True)
    col.feed_all(msgs)
    log = col.build()
    stats = log.meta["collector"]
    assert col.rejected == 2 and col.ignored == 3
    assert stats["leading_incomplete"] == 1 and stats["trailing_unanswered"] == 1
    assert stats["truth_gaps"] == 1
    np.testing.assert_array_equal(log.t_s, ref.t_s[1:])
    np.testing.assert_array_equal(log.truth[98], ref.truth[99])
    np.testing.assert_array_equal(log.truth[99, 1], ref.truth[99, 1])  # held across the gap
    np.testing.assert_array_equal(log.truth[99, [0, 2]], ref.truth[100, [0, 2]])


def test_live_view_reports_error_and_leader(reference: tuple[scenario.Scenario, RunLog]) -> None:
    scn, ref = reference
    col = RunCollector.for_scenario(scn, fleet=FLEET, lockstep=True)
    col.feed_all(bus_messages(ref, scn.dt_s))
    col.feed_alive(keys.alive_robot_key(FLEET, "r1"), True)
    view = col.live()
    assert view.leader == "r2"
    assert view.t_s == pytest.approx(float(ref.t_s[-1]))
    err = metrics.formation_error(ref)[-1]
    for j, robot in enumerate(view.robots):
        assert robot.error_m == pytest.approx(float(err[j]), abs=1e-12)
    assert [r.alive for r in view.robots] == [True, None, None]
    assert view.min_distance_m is not None and view.min_distance_m > 0.15


def test_collector_reports_the_agents_safety_filter_counters(
    reference: tuple[scenario.Scenario, RunLog],
) -> None:
    """The filter counters of a distributed run come from each robot's newest status (an older
    status arriving late does not roll them back; a host's batch has no tick count)."""
    scn, ref = reference
    col = RunCollector.for_scenario(scn, fleet=FLEET, lockstep=True)
    msgs = bus_messages(ref, scn.dt_s)
    col.feed_all(msgs)
    assert col.build().filter_counts == {}
    assert metrics.safety_metrics(col.build())["filter_source"] is None

    def status(rid: str, t: float, active: int, clearance: float | None) -> tuple[str, bytes]:
        counts = {"ticks": 100, "active": active, "violations": 1, "infeasible": 0,
                  "tiebreaks": 2, "tiebreak_active": 0, "rescaled": 0, "rejected": 0,
                  "constraints": 1}  # fmt: skip
        msg = Status(t=t, seq=1, mode="tracking", slot=0, pid=1, host="h", rejected=0,
                     filter=counts, min_clearance_m=clearance)  # fmt: skip
        return keys.status_key(FLEET, rid), encode(msg)

    col.feed(*status("r1", 2.0, 25, 0.05))
    col.feed(*status("r1", 1.0, 10, 0.5))  # older, late: ignored
    col.feed(*status("r2", 1.0, 0, None))
    batch = StatusBatch(t=1.0, seq=1, pid=2, host="h", robots=("r3", "r9"),
                        mode=("tracking", "idle"), slot=(2, -1), rejected=(0, 0), ex=(0.0, 0.0),
                        ey=(0.0, 0.0), filter_active=(4, 0), filter_violations=(0, 0),
                        filter_infeasible=(1, 0), filter_tiebreaks=(0, 0))  # fmt: skip
    col.feed(keys.host_status_key(FLEET, "h"), encode(batch))
    log = col.build()
    assert log.filter_source == "status"
    assert log.filter_counts["r1"]["active"] == 25 and log.filter_counts["r1"]["ticks"] == 100
    assert log.filter_counts["r1"]["min_clearance_m"] == 0.05
    assert log.filter_counts["r2"]["min_clearance_m"] is None
    assert log.filter_counts["r3"] == {"active": 4, "violations": 0, "infeasible": 1,
                                       "tiebreaks": 0}  # fmt: skip
    s = metrics.safety_metrics(log)
    assert s["filter_source"] == "status"
    assert (s["tiebreaks"], s["filter_violations"], s["filter_infeasible"]) == (4, 2, 1)
    assert s["filter_active_fraction"] is None  # r3's batch has no tick count
    assert s["filter_per_robot"]["r1"]["active_fraction"] == 0.25
    assert s["filter_per_robot"]["r3"]["active_fraction"] is None
    del log.filter_counts["r3"]
    assert metrics.safety_metrics(log)["filter_active_fraction"] == 25 / 200


# ---------------------------------------------------------------------------------------------
# Scenario rewriting
# ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", scenario.builtin_names())
def test_builtin_scenarios_survive_toml_round_trip(name: str) -> None:
    data = tomllib.loads(scenario.resolve(name).read_text())
    assert tomllib.loads(to_toml(data)) == data


def test_toml_writer_quotes_and_nests() -> None:
    data = {
        "name": 'a "quoted"\\ name \u00e9\u2603 \x01',
        "x": 1e-05,
        "flag": True,
        "formation": {"kind": "explicit", "slots": [{"slot": 0}, {"slot": 1, "parent": 0}]},
        "table": {"inner": {"deep": [1, 2]}, "odd key": -3},
        "disturbance": [{"t_s": 1.0, "robot": "r1"}, {"t_s": 2.0, "robot": "r2"}],
    }
    assert tomllib.loads(to_toml(data)) == data
    with pytest.raises(TypeError):
        to_toml({"when": object()})


def _min_pair_distance(initial: tuple[tuple[float, float, float], ...]) -> float:
    xy = np.array([p[:2] for p in initial])
    d = np.hypot(*(xy[:, None, :] - xy[None, :, :]).transpose(2, 0, 1))
    d[np.diag_indices_from(d)] = np.inf
    return float(d.min())


def test_robots_override_keeps_old_robots_and_places_new_ones() -> None:
    base = scenario.load("paper-exp2")
    data = tomllib.loads(scenario.resolve("paper-exp2").read_text())
    scn = scenario.parse(tomllib.loads(to_toml(scenario_with_robots(data, 6))))
    assert scn.robot_ids == ("r1", "r2", "r3", "r4", "r5", "r6")
    assert scn.initial[:3] == base.initial
    assert _min_pair_distance(scn.initial) > 2 * base.agent.geometry.body_radius_m
    assert [d.robot for d in scn.disturbances] == ["r1"]
    two = scenario.parse(scenario_with_robots(data, 2))
    assert two.robot_ids == ("r1", "r2") and two.initial == base.initial[:2]


def test_robots_override_resizes_a_chevron_and_starts_robots_on_their_slots() -> None:
    data = tomllib.loads(scenario.resolve("chevron7").read_text())
    scn = scenario.parse(scenario_with_robots(data, 12))
    assert scn.formation["n"] == 12 and len(slot_ids_of(scn)) == 12
    from coordinator.core.coordinator import CoordinatorCore

    a = scn.assignment
    core = CoordinatorCore.from_config(
        scn.trajectory, scn.formation, a.method, a.hysteresis_m, a.tie_tol_m,
        ref_offset_m=scn.agent.geometry.ref_offset_m,
    )  # fmt: skip
    out = core.tick(0.0, {rid: p for rid, p in zip(scn.robot_ids, scn.initial, strict=True)})
    by_slot = out.slots_by_id
    for rid, (x, y, th) in list(zip(scn.robot_ids, scn.initial, strict=True))[7:]:
        s = by_slot[out.assignment[rid]]
        l_m = scn.agent.geometry.ref_offset_m
        assert math.hypot(s.x - x - l_m * math.cos(th), s.y - y - l_m * math.sin(th)) < 1e-5


def test_plan_rejects_bad_input() -> None:
    with pytest.raises(scenario.ScenarioError, match="no scenario 'nope'"):
        plan_run(UpConfig(scenario="nope"))
    with pytest.raises(ValueError, match="fleet"):
        plan_run(UpConfig(fleet="a/b"))
    with pytest.raises(ValueError, match="endpoint"):
        plan_run(UpConfig(endpoint="localhost"))
    with pytest.raises(scenario.ScenarioError, match="at least 1"):
        plan_run(UpConfig(robots=0))
    plan = plan_run(UpConfig(robots=4, duration_s=10.0, out=Path("/tmp/x")))
    assert plan.settle_s == 5.0 and plan.scenario_arg == "/tmp/x/scenario.toml"
    assert plan.scenario_toml is not None and len(plan.scenario.robot_ids) == 4


def test_bad_scenario_name_exits_2_with_a_clear_error() -> None:
    proc = subprocess.run(
        [sys.executable, "-m", "formation", "up", "--scenario", "no-such-scenario"],
        cwd=REPO_ROOT,
        env=child_env(),
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode == 2
    assert "no scenario 'no-such-scenario'" in proc.stderr
    assert "paper-exp2" in proc.stderr  # says what exists


# ---------------------------------------------------------------------------------------------
# The whole system as subprocesses
# ---------------------------------------------------------------------------------------------


@pytest.mark.zenoh
@pytest.mark.slow
def test_paper_exp2_lockstep_swaps_the_leader(spawn: Spawner, tmp_path: Path) -> None:
    """60 s of paper-exp2 over the bus in lockstep: the drag at 30 s makes r2 the leader; every
    metric of the run equals ``formation sim``'s for the same scenario, seed and duration (the
    plant publishes truth at every tick), the leader swap's role changes and times included."""
    from formation.sim.command import run_and_write

    out = tmp_path / "exp2"
    m = finish(up(spawn, out, "--scenario", "paper-exp2", "--lockstep", "--duration", "60"), out)
    run_and_write(scenario.load("paper-exp2"), tmp_path / "sim", duration=60.0, figures=False)
    m_sim = json.loads((tmp_path / "sim" / "metrics.json").read_text())
    assert m["robots"] == m_sim["robots"]
    assert m["run"] == m_sim["run"]
    assert m["run"]["ticks"] == round(60.0 / 0.02) + 1
    run = m["run"]
    assert run["final_leader"] == "r2"
    assert m["robots"]["r1"]["final_slot"] == 1
    assert m["robots"]["r3"]["final_slot"] == 2
    assert run["collisions"] == 0
    assert run["min_separation_m"] > 0.15
    swaps = [c for c in run["role_changes"] if c["from_slot"] is not None]
    assert swaps and all(30.0 < c["t_s"] < 40.0 for c in swaps), swaps
    assert run["duration_s"] == pytest.approx(60.0, abs=0.05)
    collector = m["meta"]["collector"]
    assert collector["first_tick"] == 0 and collector["rejected"] == 0
    for rid in ("r1", "r2", "r3"):  # converged again after the swap
        assert m["robots"][rid]["settling_time_s"] is not None


@pytest.mark.zenoh
@pytest.mark.slow
@pytest.mark.alone
def test_paper_exp1_realtime_converges(spawn: Spawner, tmp_path: Path) -> None:
    """11 s, not 15: the late error is ~0.009 m then (in process and in four realtime runs at
    load 10), the bound 0.03 m (docs/testing.md, "Keeping tier 2 short")."""
    out = tmp_path / "exp1"
    duration_s = 11.0
    m = finish(up(spawn, out, "--scenario", "paper-exp1", "--duration", f"{duration_s:g}"), out)
    assert m["meta"]["mode"] == "realtime"
    assert m["run"]["collisions"] == 0
    assert m["run"]["final_leader"] == "r1"
    assert m["run"]["duration_s"] > duration_s - 2.0
    z = np.load(out / "run.npz")
    arrays = ("t_s", "truth", "ref", "target", "slot_of", "slot_xy", "leader", "power", "mode")
    log = RunLog(
        robot_ids=[str(r) for r in z["robot_ids"]],
        slot_ids=[int(s) for s in z["slot_ids"]],
        **{k: z[k] for k in arrays},
    )
    err = metrics.formation_error(log)
    t = log.t_s
    early = np.nanmean(err[(t >= 1.0) & (t <= 3.0)], axis=0)
    late = np.nanmean(err[t >= t[-1] - 2.0], axis=0)
    assert np.all(late < 0.5 * early), (early, late)
    assert np.all(late < 0.03), late


@pytest.mark.zenoh
@pytest.mark.slow
def test_lockstep_is_deterministic(spawn: Spawner, tmp_path: Path) -> None:
    """Lockstep over the bus is the in-process simulator's run, bit for bit, for the seed it is
    given: truth, powers, slots and leader equal ``simulate.run``'s for that seed (a pure
    function of the scenario and the seed), and another seed gives another run (camera noise,
    link). One run over Zenoh instead of three (two with the same seed, one with another): the
    two same-seed runs proved no more than their equality with this deterministic reference."""
    out = tmp_path / "up"
    args = ("--scenario", "paper-exp2", "--lockstep", "--duration", "20", "--seed", "5")
    m = finish(up(spawn, out, *args, "--quiet"), out)
    z = np.load(out / "run.npz")
    scn = scenario.load("paper-exp2")
    same, other = (simulate.run(scn, seed=s, duration_s=20.0).log for s in (5, 3))
    for name in ("t_s", "truth", "power", "slot_of", "slot_xy", "leader"):
        np.testing.assert_array_equal(z[name], getattr(same, name), err_msg=name)
    assert m["meta"]["collector"]["rejected"] == 0
    assert z["truth"].shape == other.truth.shape
    assert not np.array_equal(z["truth"], other.truth)


def _descendants(root: int) -> dict[int, int]:
    """pid -> process group of every live descendant of ``root`` (from /proc)."""
    parent: dict[int, tuple[int, int]] = {}
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                raw = Path(f"/proc/{entry}/stat").read_text(errors="replace")
            except OSError:
                continue
            f = raw[raw.rfind(")") + 2 :].split()
            if f[0] not in ("Z", "X"):
                parent[int(entry)] = (int(f[1]), int(f[2]))
    out: dict[int, int] = {}
    frontier = [root]
    while frontier:
        p = frontier.pop()
        for pid, (ppid, pgrp) in parent.items():
            if ppid == p and pid not in out:
                out[pid] = pgrp
                frontier.append(pid)
    return out


def _nice(pid: int) -> int:
    """The nice value of process ``pid``'s main thread (``/proc/<pid>/stat``, field 19)."""
    return int(Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[16])


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (OSError, IndexError):
        return False
    return state not in ("Z", "X")


@pytest.mark.zenoh
@pytest.mark.slow
@pytest.mark.alone
def test_ctrl_c_stops_everything_quickly(spawn: Spawner, tmp_path: Path) -> None:
    out = tmp_path / "ctrl-c"
    child = up(spawn, out, "--scenario", "paper-exp1", "--duration", "120")
    child.wait_for_line("  3 agents", timeout_s=60.0)
    time.sleep(1.5)  # running: truth flowing, table lines printing
    tree = _descendants(child.pid)
    assert len(tree) == 6, tree  # router, plant, coordinator, 3 agents
    groups = set(tree.values()) | {child.pid}
    # realtime: the launcher (collector, display) runs niced, the children that close the
    # control loop at the priority they were started with
    base = os.getpriority(os.PRIO_PROCESS, 0)
    assert _nice(child.pid) == min(19, base + LAUNCHER_NICE)
    assert all(_nice(p) == base for p in tree), {p: _nice(p) for p in tree}
    start = time.monotonic()
    child.send_signal(signal.SIGINT)
    child.proc.wait(timeout=10.0)
    elapsed = time.monotonic() - start
    assert elapsed < 3.0, (elapsed, child.describe())
    assert child.proc.returncode == 130, child.describe()
    assert not [p for p in tree if _alive(p)], "children left running"
    from support.procguard import _live_processes

    assert not _live_processes(pgrps=groups), "processes left in the run's groups"
    assert "SIGINT: stopping the run" in child.stderr()
    assert json.loads((out / "metrics.json").read_text())["meta"]["interrupted"] is True
