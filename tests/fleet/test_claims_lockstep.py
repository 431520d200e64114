"""Motion claims over the bus (issue 30, "Realtime precision"): with a motion bound
(``safety_filter.accel_bound_mps2``) every robot's firmware bounds its command's change and each
``wheels`` message carries its claim; in lockstep the plant relays the claims of the answers to
tick k-1 in clock k, so the agents' safety filters see exactly what the in-process simulator
hands over, and ``formation up --lockstep`` equals ``formation sim`` to the last bit."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
from support.spawn import Spawner, free_port

from formation.sim import command as sim_cli

REPO = Path(__file__).resolve().parents[2]
pytestmark = [pytest.mark.zenoh, pytest.mark.shares_cpu]


def _task(tmp: Path, accel: float = 0.25) -> Path:
    """The Robotarium task with the realtime shells' configuration (no shared-frame plane: the
    claims carry every pair), camera latency and noise, and a motion bound; 4 s."""
    text = (REPO / "scenario" / "builtin" / "anchor-triangle.toml").read_text()
    text = text.replace("duration_s = 60.0", "duration_s = 4.0").replace(
        "settle_s = 40.0", "settle_s = 1.0"
    )
    text = text.replace("latency_s = 0.0\n[link]", "latency_s = 0.06\n[link]")
    text = text.replace("pos_std_m = 0.0", "pos_std_m = 0.003")
    text = text.replace("shared_frame = true", f"shared_frame = false\naccel_bound_mps2 = {accel}")
    assert "accel_bound_mps2" in text and "latency_s = 0.06" in text
    path = tmp / "anchor-claims.toml"
    path.write_text(text)
    return path


@pytest.mark.parametrize("accel", [0.25, 0.0])
def test_lockstep_with_motion_claims_equals_the_in_process_run(
    spawn: Spawner, tmp_path: Path, accel: float
) -> None:
    toml = _task(tmp_path, accel)
    out = tmp_path / "up"
    up = spawn(
        "up", "--lockstep", "--scenario", str(toml), "--endpoint",
        f"tcp/127.0.0.1:{free_port()}", "--out", str(out), "--no-figures", "--quiet",
        "--hosts", "0",
    )  # fmt: skip
    assert up.proc.wait(timeout=180) == 0, up.describe()
    live: dict[str, Any] = json.loads((out / "metrics.json").read_text())
    import scenario as scenario_mod

    sim = sim_cli.run_and_write(scenario_mod.load(str(toml)), tmp_path / "sim", figures=False)
    assert live["robots"] == sim["robots"]
    assert live["run"] == sim["run"]
