"""``[[fault]]`` entries: the loader's validation (one line naming the field) and the pure
scheduler (scenario.faults)."""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st

import scenario
from scenario.faults import FaultScheduler, FleetFaults, parse_faults

REPO = Path(__file__).resolve().parents[3]
IDS = ("r1", "r2", "r3")


def base(**extra: Any) -> dict[str, Any]:
    d: dict[str, Any] = {
        "name": "t",
        "duration_s": 20.0,
        "robots": {"ids": list(IDS)},
        "trajectory": {"kind": "line", "speed_mps": 0.02},
        "formation": {"kind": "triangle", "b_m": 0.4},
    }
    d.update(extra)
    return d


def test_a_fault_table_is_parsed_into_the_scenario() -> None:
    s = scenario.parse(
        base(fault=[{"kind": "kill", "role": "leader", "when": "in_formation", "after_s": 2.0}])
    )
    (f,) = s.faults
    assert (f.kind, f.role, f.robot, f.when, f.after_s, f.t_s) == (
        "kill", "leader", None, "in_formation", 2.0, None,
    )  # fmt: skip
    assert f.describe().startswith("kill of the leader when in_formation")


@pytest.mark.parametrize(
    ("fault", "field", "words"),
    [
        ({"kind": "explode", "robot": "r1", "t_s": 1.0}, "fault[0].kind", "explode"),
        ({"kind": "kill", "robot": "r9", "t_s": 1.0}, "fault[0].robot", "r9"),
        ({"kind": "kill", "role": "boss", "t_s": 1.0}, "fault[0].role", "boss"),
        ({"kind": "kill", "robot": "r1", "t_s": 25.0}, "fault[0].t_s", "past the run"),
        ({"kind": "kill", "robot": "r1"}, "fault[0]", "exactly one of t_s or when"),
        ({"kind": "kill", "robot": "r1", "t_s": 1, "when": "in_formation"}, "fault[0]", "one"),
        ({"kind": "kill", "robot": "r1", "when": "never"}, "fault[0].when", "never"),
        ({"kind": "kill", "t_s": 1.0}, "fault[0].robot", "required"),
        ({"kind": "kill", "robot": "r1", "t_s": -1.0}, "fault[0].t_s", ">= 0"),
        ({"kind": "kill", "robot": "r1", "t_s": 1.0, "extra": 1}, "fault[0]", "extra"),
        ({"kind": "kill", "robot": "r1", "t_s": 1.0, "duration_s": 1}, "fault[0].duration_s", ""),
        ({"kind": "resume", "robot": "r1", "t_s": 1.0}, "fault[0].robot", "no earlier pause"),
        ({"kind": "kill_coordinator", "robot": "r1", "t_s": 1.0}, "fault[0]", "no robot"),
        (
            {"kind": "kill", "robot": "r1", "when": "in_formation", "after_s": 30},
            "fault[0].after_s",
            "past",
        ),
    ],
)
def test_a_bad_fault_is_one_line_naming_the_field(
    fault: dict[str, Any], field: str, words: str
) -> None:
    with pytest.raises(scenario.ScenarioError) as err:
        scenario.parse(base(fault=[fault]))
    text = str(err.value)
    assert "\n" not in text
    assert text.startswith(f"{field}:")
    assert words in text


def test_the_kill_of_the_last_robot_is_refused() -> None:
    kills = [{"kind": "kill", "robot": r, "t_s": 1.0 + i} for i, r in enumerate(IDS[:2])]
    scenario.parse(base(fault=kills))  # two of three: fine
    with pytest.raises(scenario.ScenarioError, match=r"fault\[2\]: kills the last robot"):
        scenario.parse(base(fault=[*kills, {"kind": "kill", "role": "leader", "t_s": 5.0}]))
    with pytest.raises(scenario.ScenarioError, match=r"fault\[1\].robot: r1 is already killed"):
        scenario.parse(base(fault=[kills[0], {"kind": "kill", "robot": "r1", "t_s": 3.0}]))


def test_formation_sim_refuses_a_bad_fault_before_running(tmp_path: Path) -> None:
    toml = tmp_path / "bad.toml"
    toml.write_text(
        'name = "bad"\nduration_s = 10.0\n[robots]\nids = ["r1", "r2"]\n'
        '[trajectory]\nkind = "line"\n[formation]\nkind = "triangle"\n'
        '[[fault]]\nkind = "kill"\nrobot = "r7"\nt_s = 2.0\n'
    )
    p = subprocess.run(
        [sys.executable, "-m", "formation", "sim", "--scenario", str(toml), "--out",
         str(tmp_path / "out")],
        cwd=REPO, capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert p.returncode == 2, p.stderr
    lines = p.stderr.strip().splitlines()
    assert len(lines) == 1 and "fault[0].robot" in lines[0] and "r7" in lines[0]
    assert not (tmp_path / "out").exists()


def test_the_scheduler_resolves_roles_and_undoes_durations() -> None:
    faults = parse_faults(
        [
            {"kind": "pause", "role": "leader", "t_s": 1.0, "duration_s": 0.5},
            {"kind": "estop", "t_s": 3.0, "duration_s": 1.0},
            {"kind": "kill", "robot": "r3", "when": "in_formation", "after_s": 2.0, "delay_s": 1},
        ],
        IDS,
        10.0,
    )
    sch = FaultScheduler(faults)
    fired: list[tuple[float, str, str | None, bool]] = []
    state = FleetFaults()
    for k in range(300):
        t = k * 0.02
        for a in sch.due(t, leader=None if t < 1.2 else "r2", in_formation=t >= 2.5):
            state.apply(a)
            fired.append((round(t, 2), a.kind, a.robot, a.undo))
    assert fired == [
        (1.2, "pause", "r2", False),  # nobody led before 1.2 s: it waited for the role
        (1.7, "resume", "r2", True),
        (3.0, "estop", None, False),
        (3.5, "kill", "r3", False),  # in formation from 2.5 s, + 1 s
        (4.0, "release", None, True),
    ]
    assert state.killed == {"r3"} and not state.paused and not state.estop_fleet
    assert sch.pending() == []


def test_a_condition_that_never_comes_is_reported_pending() -> None:
    faults = parse_faults([{"kind": "kill", "robot": "r1", "when": "in_formation"}], IDS, 10.0)
    sch = FaultScheduler(faults)
    for k in range(100):
        assert sch.due(k * 0.1, leader="r1", in_formation=False) == []
    (left,) = sch.pending()
    assert left["fault"] == 0 and "never fired" in left["why"]


@given(
    times=st.lists(st.floats(0.0, 10.0, allow_nan=False), min_size=1, max_size=6),
    steps=st.integers(1, 200),
)
def test_every_timed_fault_fires_once_at_its_first_tick(times: list[float], steps: int) -> None:
    raw = [{"kind": "estop", "t_s": t} for t in times]
    sch = FaultScheduler(parse_faults(raw, IDS, 10.0))
    dt = 10.0 / steps
    seen: dict[int, float] = {}
    for k in range(steps + 1):
        t = k * dt
        for a in sch.due(t, leader="r1", in_formation=True):
            assert a.fault not in seen
            seen[a.fault] = t
    assert sorted(seen) == list(range(len(times)))
    for j, t_fault in enumerate(times):
        assert seen[j] + 1e-9 >= t_fault
        assert seen[j] - dt < t_fault + 1e-6 or math.isclose(seen[j], 0.0)
