"""Operator tools on an agent-host fleet (issue 32, item 4): the e-stop acknowledgements are read
from the hosts' batched status, a signal that would hit a whole host is refused with the exact
fix, ``formation ls`` lists the fleet, ``formation echo`` prints decoded messages, and the
tools find the fleet from FORMATION_ENDPOINT / FORMATION_FLEET."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from support.spawn import Spawner, free_port

REPO = Path(__file__).resolve().parents[2]
pytestmark = [pytest.mark.slow, pytest.mark.zenoh, pytest.mark.shares_cpu]


def tool(env: dict[str, str], *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "formation", *args], cwd=REPO, env=env, capture_output=True,
        text=True, timeout=60,
    )  # fmt: skip


def test_tools_on_an_agent_host_fleet(spawn: Spawner, tmp_path: Path) -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    up = spawn(
        "up", "--scenario", "paper-exp2", "--duration", "60", "--hosts", "1", "--endpoint",
        endpoint, "--fleet", "hosts1", "--out", str(tmp_path / "out"), "--no-figures",
        ready="  1 agent host", timeout_s=60.0,
    )  # fmt: skip
    env = {**os.environ, "FORMATION_ENDPOINT": endpoint, "FORMATION_FLEET": "hosts1"}

    ls = tool(env, "ls")
    assert ls.returncode == 0, ls.stderr
    assert "hosts1: 3 robot(s) [r1, r2, r3]; 1 coordinator(s) [main]; 1 plant(s)" in ls.stdout

    echo = tool(env, "echo", "assignment", "--count", "1", "--wait", "10")
    assert echo.returncode == 0, echo.stderr
    line = json.loads(echo.stdout.splitlines()[0])
    assert line["key"] == "formation/hosts1/assignment" and set(line["msg"]["robots"]) == {
        "r1", "r2", "r3",
    }  # fmt: skip

    stop = tool(env, "fault", "estop", "r2")
    assert stop.returncode == 0, stop.stderr
    assert "acknowledged by r2" in stop.stdout
    release = tool(env, "fault", "release", "r2")
    assert release.returncode == 0, release.stderr

    kill = tool(env, "fault", "kill", "r2")
    assert kill.returncode == 1
    assert "formation up --hosts 0" in kill.stderr and "kill-host h1" in kill.stderr

    nothing = tool({**env, "FORMATION_FLEET": "nosuch"}, "echo", "assignment", "--wait", "1")
    assert nothing.returncode == 1 and "nothing on formation/nosuch/assignment" in nothing.stderr
    up.proc.terminate()
    up.proc.wait(timeout=60)
