"""Issue 30 over the bus: an idle spare carried head-on through a triangle's leader at 0.3 m/s
(the robots' top speed), ``formation up --lockstep`` as real processes (plant, coordinator,
agents). The coordinator detects the carried robot, publishes it on
``formation/<fleet>/movers`` and sends the formation aside; the agents take it as a
non-cooperative neighbour with its velocity. The run equals ``formation sim``'s for the same
scenario metric for metric (the in-process simulator applies the same movers one tick late, as
the agents do), the spare never touches a robot and never takes a slot.
"""

from __future__ import annotations

import json
import uuid
from pathlib import Path

import pytest
from conftest import Spawner, free_port

import scenario

SCENARIO = Path(__file__).with_name("carried_spare.toml")
RUN_TIMEOUT_S = 120.0
TOUCH_M = 0.150  # two bodies of 0.075 m radius


@pytest.mark.zenoh
def test_a_carried_spare_over_zenoh_behaves_as_in_process(spawn: Spawner, tmp_path: Path) -> None:
    from formation.sim.command import run_and_write

    out = tmp_path / "up"
    child = spawn(
        "up", "--endpoint", f"tcp/127.0.0.1:{free_port()}", "--fleet",
        f"t{uuid.uuid4().hex[:8]}", "--out", str(out), "--no-figures",
        "--scenario", str(SCENARIO), "--lockstep",
    )  # fmt: skip
    child.proc.wait(timeout=RUN_TIMEOUT_S)
    assert child.proc.returncode == 0, child.describe()
    m = json.loads((out / "metrics.json").read_text())
    sc = scenario.load(str(SCENARIO))
    run_and_write(sc, tmp_path / "sim", figures=False)
    m_sim = json.loads((tmp_path / "sim" / "metrics.json").read_text())
    assert m["robots"] == m_sim["robots"]
    assert m["run"] == m_sim["run"]
    assert m["run"]["collisions"] == 0
    assert m["run"]["min_separation_m"] > TOUCH_M
    assert m["robots"]["r4"]["final_slot"] is None
