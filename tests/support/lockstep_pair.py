"""One scenario run twice: ``formation up --lockstep`` as real processes and ``formation sim``
in-process, for tests that compare the two bit for bit."""

from __future__ import annotations

import json
import uuid
from pathlib import Path
from typing import Any

import numpy as np

import scenario
from support.spawn import Spawner, free_port


def lockstep_and_sim(
    spawn: Spawner, scenario_path: Path, tmp_path: Path, hosts: str, timeout_s: float
) -> tuple[dict[str, Any], dict[str, Any], Any, Any]:
    """(lockstep metrics, in-process metrics, lockstep run.npz, in-process run.npz)."""
    from formation.sim.command import run_and_write

    out = tmp_path / "up"
    child = spawn(
        "up", "--endpoint", f"tcp/127.0.0.1:{free_port()}", "--fleet",
        f"t{uuid.uuid4().hex[:8]}", "--out", str(out), "--no-figures",
        "--scenario", str(scenario_path), "--lockstep", "--hosts", hosts,
    )  # fmt: skip
    child.proc.wait(timeout=timeout_s)
    assert child.proc.returncode == 0, child.describe()
    m = json.loads((out / "metrics.json").read_text())
    run_and_write(scenario.load(str(scenario_path)), tmp_path / "sim", figures=False)
    m_sim = json.loads((tmp_path / "sim" / "metrics.json").read_text())
    return m, m_sim, np.load(out / "run.npz"), np.load(tmp_path / "sim" / "run.npz")
