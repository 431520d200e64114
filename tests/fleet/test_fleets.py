"""Fleets of any size (issue 18, part 1): ``--robots N`` grows any formation by the staged rule,
``--spares K`` adds idle hot spares, the plan chooses agent hosts by a documented rule and says
so, ``formation top`` reads batched fleets, and interrupted runs still get their figures."""

from __future__ import annotations

import json
import math
import re
import signal
import threading
import time
import tomllib
import uuid
from pathlib import Path
from typing import Any

import pytest
from support.spawn import Child, Spawner, free_port

import scenario
from coordinator.core.coordinator import CoordinatorCore
from coordinator.core.formation import FormationSpec
from formation.launch.plan import (
    PER_ROBOT_PROCESSES_PER_CORE,
    ROBOTS_PER_HOST,
    UpConfig,
    auto_hosts,
    plan_run,
)
from formation.sim import simulate
from formation.sim.command import run_and_write
from scenario import ScenarioError, fleet_shape, load_with_robots, scenario_with_robots

pytestmark = pytest.mark.shares_cpu


def _table(name: str) -> dict[str, Any]:
    return tomllib.loads(scenario.resolve(name).read_text())


def _core(scn: scenario.Scenario) -> CoordinatorCore:
    a = scn.assignment
    return CoordinatorCore.from_config(
        scn.trajectory, scn.formation, a.method, a.hysteresis_m, a.tie_tol_m,
        ref_offset_m=scn.agent.geometry.ref_offset_m,
    )  # fmt: skip


def _min_pair_distance(points: list[tuple[float, float]]) -> float:
    return min(
        math.dist(p, q) for i, p in enumerate(points) for q in points[i + 1 :]
    )  # small N only


# ---------------------------------------------------------------------------------------------
# --robots N, --spares K
# ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", ["paper-exp1", "paper-exp2"])
def test_robots_grow_a_triangle_by_stages_into_the_lattice(name: str) -> None:
    base = scenario.load(name)
    scn = scenario.parse(scenario_with_robots(_table(name), 10))
    spec = FormationSpec.from_dict(scn.formation)
    b = float(base.formation.get("b_m", 0.4))
    assert spec == FormationSpec.triangle(b).grown(10)
    assert [s.slot for s in spec] == list(range(10))
    assert (spec.n_stages, len(scn.robot_ids)) == (4, 10)
    assert scn.initial[:3] == base.initial  # the paper's robots keep their start poses
    # every robot has a slot (no idle robot) and the new ones start on theirs (eqs 10-11)
    out = _core(scn).tick(0.0, dict(zip(scn.robot_ids, scn.initial, strict=True)))
    assert sorted(out.assignment.values()) == list(range(10))
    l_m = scn.agent.geometry.ref_offset_m
    by_slot = out.slots_by_id
    for rid, (x, y, th) in list(zip(scn.robot_ids, scn.initial, strict=True))[3:]:
        s = by_slot[out.assignment[rid]]
        assert math.hypot(s.x - x - l_m * math.cos(th), s.y - y - l_m * math.sin(th)) < 1e-5


def test_spares_are_idle_robots_behind_the_formation() -> None:
    data = _table("paper-exp2")
    scn = scenario.parse(scenario_with_robots(data, 6, spares=3))
    assert scn.robot_ids == tuple(f"r{k}" for k in range(1, 10))
    shape = fleet_shape(scn.formation, len(scn.robot_ids))
    assert (shape.slots, shape.robots, shape.spares, shape.stages) == (6, 9, 3, 3)
    assert shape.describe() == "9 robots: 6 slots in 3 stages, 3 idle spares"
    out = _core(scn).tick(0.0, dict(zip(scn.robot_ids, scn.initial, strict=True)))
    assert set(out.assignment) == {f"r{k}" for k in range(1, 7)}  # the spares hold no slot
    # behind the rearmost slot (the virtual leader heads +x on y = 0), a row centred on its line
    spec_x = [p[0] for p in scn.initial[:6]]
    spare_xy = [(p[0], p[1]) for p in scn.initial[6:]]
    assert all(x < min(spec_x) - 0.3 for x, _ in spare_xy)
    assert sum(y for _, y in spare_xy) / 3 == pytest.approx(0.0, abs=1e-6)
    assert _min_pair_distance([(p[0], p[1]) for p in scn.initial]) > 0.3
    # spares alone: the scenario's robot count stays the slot count
    only = scenario.parse(scenario_with_robots(data, None, spares=2))
    assert len(FormationSpec.from_dict(only.formation)) == 3 and len(only.robot_ids) == 5


def test_chevron_and_lattice_keep_their_kind_and_bad_counts_are_refused() -> None:
    scn = scenario.parse(scenario_with_robots(_table("chevron7"), 12, spares=1))
    assert scn.formation["kind"] == "chevron" and len(FormationSpec.from_dict(scn.formation)) == 12
    assert len(scn.robot_ids) == 13
    for n, k, field in ((0, 0, "--robots"), (3, -1, "--spares"), (True, 0, "--robots")):
        with pytest.raises(ScenarioError, match=field):
            scenario_with_robots(_table("paper-exp1"), n, spares=k)  # type: ignore[arg-type]
    with pytest.raises(ScenarioError, match="no scenario"):
        load_with_robots("nope", 3)


# ---------------------------------------------------------------------------------------------
# The plan: automatic agent hosts and the banner
# ---------------------------------------------------------------------------------------------


def test_automatic_agent_hosts_rule() -> None:
    k = PER_ROBOT_PROCESSES_PER_CORE
    assert auto_hosts(3, cores=2)[0] == 0
    assert auto_hosts(2 * k, cores=2)[0] == 0  # at the limit: still one process per robot
    hosts, why = auto_hosts(2 * k + 1, cores=2)
    assert hosts == 1 and "--hosts 0" in why and f"> {2 * k}" in why
    assert auto_hosts(100, cores=2)[0] == 1
    assert auto_hosts(1000, cores=2)[0] == 2  # at most one host per core
    assert auto_hosts(1000, cores=16)[0] == math.ceil(1000 / ROBOTS_PER_HOST)
    assert auto_hosts(1, cores=0)[0] == 0  # a machine that reports no cores counts as one


def test_plan_decides_the_processes_and_the_banner_says_what_the_fleet_is() -> None:
    small = plan_run(UpConfig(scenario="paper-exp1"))
    assert small.hosts == 0 and small.scenario_toml is None
    assert small.banner().startswith("fleet: 3 robots: 3 slots in 2 stages, 0 idle spares; ")
    assert "3 agent processes [automatic: 3 robots <=" in small.banner()
    big = plan_run(UpConfig(robots=100))
    assert big.hosts == auto_hosts(100)[0]
    assert big.scenario_toml is not None and len(big.scenario.robot_ids) == 100
    forced = plan_run(UpConfig(robots=100, hosts=0, spares=2))
    assert forced.hosts == 0 and len(forced.scenario.robot_ids) == 102
    assert forced.banner() == (
        "fleet: 102 robots: 100 slots in 14 stages, 2 idle spares; robots run in 102 agent "
        "processes [--hosts 0]"
    )
    assert plan_run(UpConfig(hosts=7)).hosts == 3  # never more hosts than robots
    assert "1 agent host (batched bus) [--hosts 1]" in plan_run(UpConfig(hosts=1)).banner()
    with pytest.raises(ValueError, match="--hosts"):
        plan_run(UpConfig(hosts=-1))
    with pytest.raises(ScenarioError, match="--spares"):
        plan_run(UpConfig(spares=-2))


# ---------------------------------------------------------------------------------------------
# Interrupted runs
# ---------------------------------------------------------------------------------------------


class _StopAfter(threading.Event):
    """Set as seen by the simulator after ``n`` looks (a deterministic Ctrl-C)."""

    def __init__(self, n: int) -> None:
        super().__init__()
        self.looks, self.n = 0, n

    def is_set(self) -> bool:
        self.looks += 1
        return self.looks > self.n


def test_an_interrupted_simulation_keeps_what_ran_and_gets_figures(tmp_path: Path) -> None:
    scn = scenario.load("paper-exp1")
    result = simulate.run(scn, duration_s=60.0, stop=_StopAfter(100))
    assert result.interrupted and result.log.t_s.size == 101  # tick 0 + the 100 looked at
    full = simulate.run(scn, duration_s=2.0)
    assert not full.interrupted and full.log.t_s.size == 101
    assert (result.log.truth == full.log.truth).all()  # the same ticks, bit for bit
    m = run_and_write(scn, tmp_path, duration=60.0, stop=_StopAfter(150))
    assert m["meta"]["interrupted"] is True and m["run"]["duration_s"] == pytest.approx(3.0)
    assert {p.name for p in tmp_path.glob("*.png")} >= {"trajectories.png", "roles.png"}
    assert "interrupted after 3.0 s" in (tmp_path / "index.md").read_text()


def _up(spawn: Spawner, out: Path, *args: str) -> Child:
    return spawn(
        "up", "--endpoint", f"tcp/127.0.0.1:{free_port()}", "--fleet", f"t{uuid.uuid4().hex[:8]}",
        "--out", str(out), *args,
    )  # fmt: skip


@pytest.mark.zenoh
@pytest.mark.slow
def test_ctrl_c_of_formation_up_writes_figures_of_the_partial_run(
    spawn: Spawner, tmp_path: Path
) -> None:
    out = tmp_path / "cut"
    child = _up(spawn, out, "--scenario", "paper-exp1", "--duration", "120")
    banner = child.wait_for_line("  fleet:", timeout_s=30.0)
    assert "3 robots: 3 slots in 2 stages, 0 idle spares" in banner
    assert "3 agent processes" in banner
    child.wait_for_line("  3 agents", timeout_s=60.0)
    time.sleep(2.0)  # truth flowing
    child.send_signal(signal.SIGINT)
    child.proc.wait(timeout=60.0)
    assert child.proc.returncode == 130, child.describe()
    lines = [ln for ln in child.stderr().splitlines() if "interrupted:" in ln]
    assert len(lines) == 1 and "metrics and figures of the" in lines[0], child.describe()
    assert json.loads((out / "metrics.json").read_text())["meta"]["interrupted"] is True
    assert (out / "trajectories.png").stat().st_size > 0 and (out / "index.md").exists()


# ---------------------------------------------------------------------------------------------
# formation top on a batched fleet
# ---------------------------------------------------------------------------------------------


@pytest.mark.alone  # rates (pose, wheels, status) and nothing rejected: a realtime bound
@pytest.mark.zenoh
@pytest.mark.slow
def test_top_shows_every_robot_of_a_real_agent_host_fleet(spawn: Spawner, tmp_path: Path) -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    fleet = f"t{uuid.uuid4().hex[:8]}"
    run = spawn(
        "up", "--endpoint", endpoint, "--fleet", fleet, "--out", str(tmp_path / "up"),
        "--robots", "12", "--hosts", "1", "--duration", "60", "--no-figures",
    )  # fmt: skip
    banner = run.wait_for_line("  fleet:", timeout_s=30.0)
    assert "12 slots" in banner and "1 agent host (batched bus) [--hosts 1]" in banner
    run.wait_for_line("  1 agent hosts", timeout_s=90.0)
    time.sleep(3.0)  # every robot assigned and tracking
    top = spawn("top", "--once", "--wait", "2.5", "--fleet", fleet, "--endpoint", endpoint)
    assert top.proc.wait(timeout=30) == 0, top.describe()
    run.send_signal(signal.SIGINT)
    text = top.stdout()
    assert re.search(r"host$", text.splitlines()[1]), text  # the host column
    row = re.compile(r"^(r\d+)\s+(\S+)\s+(\S+) (\S+)\s+(\S+)\s+(.+)$", re.M)
    rows = {m[0]: m for m in row.findall(text)}
    assert sorted(rows, key=lambda r: int(r[1:])) == [f"r{k}" for k in range(1, 13)], text
    slots = set()
    for rid, (_, alive, slot, role, mode, rest) in rows.items():
        cols = rest.split()  # err, pose, setp, whl, stat, truth, rej, age, host
        assert (alive, mode, cols[-1]) == ("yes", "tracking", "h1"), (rid, text)
        assert role in ("leader", "subleader", "follower"), (rid, text)
        slots.add(int(slot))
        pose_hz, wheels_hz, status_hz = float(cols[1]), float(cols[3]), float(cols[4])
        assert pose_hz > 10.0 and wheels_hz > 10.0 and status_hz > 2.0, (rid, text)  # 30/50/5
        assert float(cols[-2]) < 1.0, (rid, text)  # age of the robot's last message
        assert cols[6] == "0", (rid, text)  # nothing rejected
    assert slots == set(range(12)), text
    run.proc.wait(timeout=30)


def test_formation_sim_takes_robots_and_spares(tmp_path: Path) -> None:
    from formation.sim.command import main as sim_main

    out = tmp_path / "sim"
    argv = ["--robots", "5", "--spares", "1", "--duration", "1", "--out", str(out)]
    assert sim_main([*argv, "--no-figures", "--quiet"]) == 0
    m = json.loads((out / "metrics.json").read_text())
    assert len(m["robots"]) == 6 and m["robots"]["r6"]["final_slot"] is None  # the spare
    assert sorted(r["final_slot"] for r in list(m["robots"].values())[:5]) == list(range(5))
    with pytest.raises(SystemExit) as refused:  # argparse: one line, exit 2
        sim_main(["--spares", "-1", "--out", str(out)])
    assert refused.value.code == 2
