"""Whole ``formation up`` runs from a test: :func:`up` starts one with the ``spawn`` fixture on a
free port and its own fleet, :func:`finish` waits for it and reads its metrics;
:func:`up_process` and :func:`finish_process` do the same for paper-exp1 with a plain
``Popen`` whose output goes to pipes, and
:func:`lockstep_result` is what a lockstep run decides (no wall-clock field)."""

from __future__ import annotations

import json
import subprocess
import sys
import uuid
from pathlib import Path
from typing import Any

from support.spawn import Child, Spawner, child_env, free_port

RUN_TIMEOUT_S = 150.0


def up(spawn: Spawner, out: Path, *args: str) -> Child:
    """Start ``formation up`` on a free port with its own fleet, writing into ``out``."""
    return spawn(
        "up", "--endpoint", f"tcp/127.0.0.1:{free_port()}", "--fleet",
        f"t{uuid.uuid4().hex[:8]}", "--out", str(out), "--no-figures", *args,
    )  # fmt: skip


def finish(child: Child, out: Path) -> dict[str, Any]:
    child.proc.wait(timeout=RUN_TIMEOUT_S)
    assert child.proc.returncode == 0, child.describe()
    m: dict[str, Any] = json.loads((out / "metrics.json").read_text())
    return m


def up_process(out: Path, *args: str, endpoint: str | None = None) -> subprocess.Popen[str]:
    """Start ``formation up`` of paper-exp1 (fleet: ``out``'s name; a free port unless
    ``endpoint``), its output in pipes."""
    return subprocess.Popen(
        [
            sys.executable, "-m", "formation", "up", "--scenario", "paper-exp1",
            "--endpoint", endpoint or f"tcp/127.0.0.1:{free_port()}", "--fleet", out.name,
            "--out", str(out), "--no-figures", "--quiet", "--ready-timeout", "60", *args,
        ],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=child_env(),
    )  # fmt: skip


def finish_process(proc: subprocess.Popen[str], out: Path) -> dict[str, Any]:
    """The run's metrics; the launcher must exit 0: every child stopped within its bound (2 s
    after SIGTERM) under the hog too (runtime.lifecycle.exit_fast)."""
    _, stderr = proc.communicate(timeout=200)
    assert proc.returncode == 0, stderr[-2000:]
    assert (out / "metrics.json").exists(), stderr[-2000:]
    metrics: dict[str, Any] = json.loads((out / "metrics.json").read_text())
    return metrics


def lockstep_result(m: dict[str, Any]) -> dict[str, Any]:
    """What a lockstep run decides (no wall-clock field)."""
    run = {k: v for k, v in m["run"].items() if k != "duration_s"}
    return {"run": run, "robots": m["robots"]}
