"""A freshly booted machine (issue 30, "fresh machines"): the core and the process shells run
when ``time.monotonic()`` reads a few seconds, at any time zone and locale.

A test once subtracted 3600 s from ``time.monotonic()`` and failed on a machine booted less than
an hour ago, while CI passed only because its machine had been up long enough. These tests run
real parts in a Linux time namespace whose monotonic and boot clocks start near 2 s
(``unshare --time``; ``.ci/run`` runs the whole suite that way where the kernel allows it), in
the time zone farthest from UTC and the C locale. Where the kernel or the user may not create a
time namespace they are skipped with the reason (the suite then runs on the machine's clock).
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import time
import uuid
from pathlib import Path

import pytest
from support.spawn import REPO_ROOT, Spawner, child_env, free_port

pytestmark = pytest.mark.shares_cpu

FRESH_CLOCK_S = 2
"""Where the namespace's monotonic and boot clocks start (s)."""
FAR_ZONE = {"TZ": "Pacific/Kiritimati", "LC_ALL": "C"}
"""UTC+14 and the locale with nothing set."""


def _offset(clock: int, name: str) -> int:
    """The namespace offset of ``clock`` (``name`` in /proc/self/timens_offsets) that brings it
    to :data:`FRESH_CLOCK_S`. Offsets are relative to the machine's clock, not to this
    process's (which may itself run in a time namespace: ``.ci/run``), so this one's is added
    back."""
    own = 0
    try:
        for line in Path("/proc/self/timens_offsets").read_text().splitlines():
            parts = line.split()
            if len(parts) == 3 and parts[0] == name:
                own = int(parts[1])
    except OSError:  # a kernel without time namespaces: then unshare is refused below
        pass
    return FRESH_CLOCK_S - (int(time.clock_gettime(clock)) - own)


def fresh_clock_prefix() -> list[str]:
    """``unshare`` arguments that run a command with monotonic and boot clocks near
    :data:`FRESH_CLOCK_S` (the child dies with ``unshare``); skips the test where the kernel
    refuses (no time namespaces, no privilege and no user namespaces)."""
    exe = shutil.which("unshare")
    if exe is None:
        pytest.skip("no unshare(1) on this machine: cannot start a process on a fresh clock")
    clocks = [
        "--time", "--kill-child",
        "--monotonic", str(_offset(time.CLOCK_MONOTONIC, "monotonic")),
        "--boottime", str(_offset(time.CLOCK_BOOTTIME, "boottime")),
    ]  # fmt: skip
    why = ""
    for user in ([], ["--user", "--map-root-user"]):
        argv = [exe, *user, *clocks]
        probe = subprocess.run(
            [*argv, sys.executable, "-c", "import time; print(time.monotonic())"],
            capture_output=True,
            text=True,
            timeout=30,
        )
        if probe.returncode == 0:
            assert float(probe.stdout) < FRESH_CLOCK_S + 30.0, probe.stdout
            return argv
        why = probe.stderr.strip().splitlines()[-1] if probe.stderr.strip() else "refused"
    pytest.skip(f"the kernel refuses a time namespace here ({why}): run on the machine's clock")


def test_the_namespace_clock_starts_near_zero() -> None:
    """The probe itself: inside, ``time.monotonic()`` reads seconds, not this machine's uptime,
    and it keeps advancing (a process's deadlines work)."""
    code = "import time; a = time.monotonic(); time.sleep(0.05); print(a, time.monotonic())"
    out = subprocess.run(
        [*fresh_clock_prefix(), sys.executable, "-c", code],
        capture_output=True, text=True, timeout=30, check=True,
    ).stdout.split()  # fmt: skip
    a, b = float(out[0]), float(out[1])
    assert 0.0 < a < FRESH_CLOCK_S + 30.0
    assert b - a >= 0.05


@pytest.mark.slow
def test_formation_sim_on_a_fresh_clock(tmp_path: Path) -> None:
    """The whole in-process core (coordinator, agents' firmware, plant, metrics, figures) on a
    fresh clock, far from UTC, in the C locale: the same metrics as on this machine's clock."""
    runs = {}
    for name, prefix in (("fresh", fresh_clock_prefix()), ("here", [])):
        out = tmp_path / name
        argv = [sys.executable, "-m", "formation", "sim", "--scenario", "paper-exp1"]
        proc = subprocess.run(
            [*prefix, *argv, "--duration", "5", "--out", str(out), "--quiet"],
            cwd=REPO_ROOT, env=child_env(FAR_ZONE if prefix else None),
            capture_output=True, text=True, timeout=300,
        )  # fmt: skip
        assert proc.returncode == 0, proc.stderr
        runs[name] = json.loads((out / "metrics.json").read_text())
        assert (out / "trajectories.png").stat().st_size > 0
    assert runs["fresh"]["run"] == runs["here"]["run"]
    assert runs["fresh"]["robots"] == runs["here"]["robots"]


@pytest.mark.slow
@pytest.mark.zenoh
def test_a_realtime_fleet_on_a_fresh_clock(spawn: Spawner, tmp_path: Path) -> None:
    """``formation up`` in realtime (router, plant, coordinator, agents: every process shell,
    their leases, e-stop refreshes, clock offsets and watchdogs on ``time.monotonic()``) started
    when that clock reads ~2 s, far from UTC, in the C locale: it runs its duration, exits 0,
    nobody collides and the formation converges."""
    out = tmp_path / "up"
    child = spawn.command(
        [
            *fresh_clock_prefix(), sys.executable, "-m", "formation", "up",
            "--scenario", "paper-exp1", "--duration", "8", "--no-figures", "--quiet",
            "--endpoint", f"tcp/127.0.0.1:{free_port()}", "--fleet", f"t{uuid.uuid4().hex[:8]}",
            "--out", str(out),
        ],
        env=child_env(FAR_ZONE),
    )  # fmt: skip
    child.proc.wait(timeout=150)
    assert child.proc.returncode == 0, child.describe()
    m = json.loads((out / "metrics.json").read_text())
    assert m["meta"]["mode"] == "realtime"
    assert m["run"]["collisions"] == 0
    assert m["run"]["duration_s"] > 6.0
    started = [c["ready_s"] for c in m["meta"]["children"].values()]
    assert all(s is not None and s > 0 for s in started)
    for rid, r in m["robots"].items():  # every robot held a slot and tracked it
        assert r["final_slot"] is not None, (rid, r)
        assert r["formation_error_rms_m"] is not None and r["formation_error_rms_m"] < 0.1, (rid, r)


def test_a_scenario_with_non_ascii_text_loads_in_a_plain_c_locale(tmp_path: Path) -> None:
    """TOML is UTF-8 whatever the locale: a scenario file with a non-ASCII comment loads where
    Python's locale encoding is ASCII (LC_ALL=C without Python's UTF-8 coercion). Before, its
    ``read_text()`` decoded with the locale's encoding and the run died with a traceback."""
    import scenario

    path = tmp_path / "exp1.toml"
    text = scenario.resolve("paper-exp1").read_text(encoding="utf-8")
    path.write_text("# spacing ±5 mm, heading 30° — a comment\n" + text, encoding="utf-8")
    env = child_env({"LC_ALL": "C", "PYTHONCOERCECLOCALE": "0", "PYTHONUTF8": "0"})
    argv = [sys.executable, "-m", "formation", "sim", "--scenario", str(path), "--duration", "1"]
    proc = subprocess.run(
        [*argv, "--no-figures", "--quiet", "--out", str(tmp_path / "out")],
        cwd=REPO_ROOT, env=env, capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    assert json.loads((tmp_path / "out" / "metrics.json").read_text())["run"]["ticks"] > 0
