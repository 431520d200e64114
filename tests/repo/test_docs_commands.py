"""Every command shown in README.md and docs/*.md runs on this machine, or says why it cannot.

Commands are taken from the documents' shell code blocks (lines starting with ``formation``,
``make``, ``python``, ``sudo``, ``systemctl``; ``\\`` continuations joined, ``# comments`` and
optional ``[...]`` parts dropped, ``;`` splitting a line) and from the command column of README's
table. Each one is either run (as a subprocess of ``python -m formation``, with a short
``--duration``, a free port and a temporary folder: exit status 0 asserted) or skipped by the
first rule of :data:`SKIP_RULES` that matches, which names the reason. The by-hand blocks of
docs/runtime.md (router, plant, coordinator, agents, realtime and lockstep) are run together, as
written, by :func:`test_the_by_hand_runbook_runs`. Also: every scenario key the loader and the
cores accept is named in docs/scenarios.md, and every subcommand is in README's table.
"""

from __future__ import annotations

import dataclasses
import re
import shlex
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from support.spawn import REPO_ROOT, child_env, free_port

pytestmark = pytest.mark.timeout(900)

DOCS = [REPO_ROOT / "README.md", *sorted((REPO_ROOT / "docs").glob("*.md"))]
SHELL_LANGS = {"", "sh", "bash", "console", "shell"}
STARTS = ("formation", "make", "python", "sudo", "systemctl", ".venv/bin/")

# (regex on the command, reason): the first match skips the command.
SKIP_RULES: list[tuple[str, str]] = [
    (r"^(sudo|systemctl)\b", "needs root / systemd on a robot (docs/deploy.md; unit files: "
     "tests/repo/test_deploy_files.py)"),
    (r"/dev/video", "needs a camera device"),
    (r"^make (test|demo)\b", "the whole suite / the demo take minutes; `make` targets run in CI"),
    (r"^python bench/", "a benchmark: minutes of full load; its figures are in docs/benchmarks.md"),
    (r"\.\.\.|<|\bNAME\b|\bFILE\b|\bHOST\b|\brK\b|\bDIR\b|\bS\b", "a template with placeholders"),
    (r"my-fleet\.toml|test_my_fleet\.py", "the tutorial's own files: "
     "test_the_tutorial_runs_end_to_end runs docs/tutorial.md in order"),
    (r"^formation fault\b", "needs a running fleet (tests/fleet/test_faults.py)"),
    (r"^formation (teleop|goal|path|shape|obstacle)\b", "drives a running fleet "
     "(tests/bus/test_operator.py, tests/fleet/test_operator_fleet.py)"),
    (r"^formation (top|record)\b", "watches a running fleet (tests/bus/test_top.py, "
     "tests/fleet/test_record_live.py)"),
    (r"^formation report\b", "needs a recording (tests/unit/formation/test_record_report.py)"),
    (r"^formation camera calibrate\b", "needs a photo of the floor markers "
     "(tests/unit/localization/test_camera_core.py calibrates on rendered frames)"),
    (r"^formation (router|plant|coordinator|agent|agent-host|camera|ros2)\b",
     "a long-running process: docs/runtime.md's by-hand blocks run them together "
     "(test_the_by_hand_runbook_runs)"),
    (r"--robots (\d{3,}|[2-9]\d)\b", "a large fleet: minutes on 2 cores (bench/, docs/scale.md)"),
]  # fmt: skip
RUNNABLE = re.compile(r"^formation (sim|up|demo|acl|certs|check|--version|--help)\b")
SHORT_DURATION_S = "3"


def _code_blocks(text: str) -> Iterator[str]:
    for m in re.finditer(r"^```([A-Za-z0-9]*)\n(.*?)^```", text, re.S | re.M):
        if m.group(1) in SHELL_LANGS:
            yield m.group(2)


def _clean(line: str) -> list[str]:
    line = line.strip()
    line = re.sub(r"^\$\s+", "", line)
    line = re.sub(r"\s#.*$", "", line)  # a trailing comment
    line = re.sub(r"\s*\[[^\]]*\]", "", line)  # optional parts
    return [c.strip() for c in line.split(";") if c.strip()]


def _is_command(text: str) -> bool:
    """A command line, not a benchmark's output table that happens to start with "formation"."""
    from formation.cli import SUBCOMMANDS

    if not text.startswith(STARTS):
        return False
    words = text.split()
    return words[0] != "formation" or (
        len(words) > 1 and (words[1] in SUBCOMMANDS or words[1].startswith("--"))
    )


def documented_commands() -> list[tuple[str, str]]:
    """(document, command) for every command shown in the documents."""
    found: list[tuple[str, str]] = []
    for path in DOCS:
        text = path.read_text()
        name = str(path.relative_to(REPO_ROOT))
        for block in _code_blocks(text):
            for line in block.replace("\\\n", " ").splitlines():
                if line.strip().lstrip("$ ").startswith(STARTS):
                    found += [(name, c) for c in _clean(line) if _is_command(c)]
        if path.name == "README.md":  # the command table
            for row in re.findall(r"^\| `(formation [^`]*)`", text, re.M):
                found += [(name, c) for c in _clean(row.replace("\\|", "|"))]
    return list(dict.fromkeys(found))  # in order, without repeats


# Placeholders of README's table that have an obvious value here.
FILL: list[tuple[str, str]] = [
    ("NAME|FILE", "paper-exp2"),
    ("--scenario S", "--scenario paper-exp2"),
    ("--robots N", "--robots 3"),
    ("--seed N", "--seed 1"),
    (" -o DIR", " -o out"),
    ("--out DIR", "--out out"),
]


def fill(cmd: str) -> str:
    for old, new in FILL:
        cmd = cmd.replace(old, new)
    return cmd


def classify(cmd: str) -> str | None:
    """The reason ``cmd`` is not run here, or None if it is."""
    cmd = fill(cmd)
    for pattern, reason in SKIP_RULES:
        if re.search(pattern, cmd):
            return reason
    if not RUNNABLE.search(cmd):
        return "not one of the commands this test knows how to run briefly"
    return None


def _shorten(argv: list[str], tmp: Path) -> list[str]:
    """Short duration, a free port, no figures, paths inside ``tmp``."""
    argv = [a.replace("/etc/formation", str(tmp / "etc")) for a in argv]
    cmd = argv[1] if len(argv) > 1 else ""
    if cmd in ("sim", "up", "demo"):
        if "--duration" in argv:
            argv[argv.index("--duration") + 1] = SHORT_DURATION_S
        else:
            argv += ["--duration", SHORT_DURATION_S]
        if "--no-figures" not in argv:
            argv.append("--no-figures")
    if cmd in ("up", "demo") and "--endpoint" not in argv:
        argv += ["--endpoint", f"tcp/127.0.0.1:{free_port()}"]
    if cmd == "up" and "--quiet" not in argv:
        argv.append("--quiet")
    return argv


COMMANDS = documented_commands()


def test_the_documents_show_commands_and_every_skip_has_a_reason() -> None:
    assert len(COMMANDS) > 30, COMMANDS
    runnable = [c for _, c in COMMANDS if classify(c) is None]
    assert len(runnable) >= 5, runnable
    table = "\n".join(f"{doc}: {cmd}  ->  {classify(cmd) or 'RUN'}" for doc, cmd in COMMANDS)
    print(table)  # `pytest -s` shows the whole table


@pytest.mark.parametrize(("doc", "cmd"), COMMANDS, ids=[f"{d}: {c}" for d, c in COMMANDS])
def test_a_documented_command_runs(doc: str, cmd: str, tmp_path: Path) -> None:
    reason = classify(cmd)
    if reason is not None:
        pytest.skip(reason)
    argv = _shorten(shlex.split(fill(cmd)), tmp_path)
    for attempt in range(2):
        r = subprocess.run(
            [sys.executable, "-m", *argv],
            cwd=tmp_path,
            env=child_env(),
            capture_output=True,
            text=True,
            timeout=300,
        )
        # On a 2-core machine shared by several test runs (load 20-30 seen), a child of
        # `formation up` starved of CPU can miss the launcher's shutdown grace ("did not exit
        # 2.0 s after SIGTERM", exit 1) although the command is right: one more try, then fail.
        if r.returncode == 0 or "after SIGTERM" not in r.stderr or attempt == 1:
            break
    assert r.returncode == 0, (doc, argv, r.stdout[-1500:], r.stderr[-1500:])


def _runbook_blocks() -> list[list[str]]:
    text = (REPO_ROOT / "docs" / "runtime.md").read_text()
    section = text.split("## Running the processes by hand", 1)[1].split("\n## ", 1)[0]
    return [
        [ln.strip() for ln in block.splitlines() if ln.strip()] for block in _code_blocks(section)
    ]


def test_the_runbook_has_a_realtime_and_a_lockstep_block() -> None:
    blocks = _runbook_blocks()
    assert len(blocks) == 2
    realtime, lockstep = blocks
    for block in blocks:
        names = [shlex.split(c)[1] for c in block]
        assert names[:3] == ["router", "plant", "coordinator"], names
        assert names[3:] and set(names[3:]) == {"agent"}
    assert not any("--lockstep" in c for c in realtime)
    assert all("--lockstep" in c for c in lockstep[1:])


@pytest.mark.parametrize("mode", ["realtime", "lockstep"])
def test_the_by_hand_runbook_runs(mode: str, tmp_path: Path) -> None:
    """Start the block's commands in order, as written (on a free port, a short --duration):
    the plant ends the run itself (exit 0), then SIGINT stops the others (exit 0)."""
    block = _runbook_blocks()[0 if mode == "realtime" else 1]
    port = str(free_port())
    procs: list[tuple[str, subprocess.Popen[str]]] = []
    try:
        for cmd in block:
            argv = shlex.split(cmd.replace("7447", port))
            if "--duration" in argv:
                argv[argv.index("--duration") + 1] = SHORT_DURATION_S
            p = subprocess.Popen(
                [sys.executable, "-m", *argv],
                cwd=tmp_path,
                env=child_env(),
                stdout=subprocess.PIPE,
                stderr=subprocess.PIPE,
                text=True,
            )
            procs.append((cmd, p))
            if argv[1] == "router":
                time.sleep(1.0)  # the others retry their connection anyway
        plant_cmd, plant = procs[1]
        out, err = plant.communicate(timeout=240)
        assert plant.returncode == 0, (plant_cmd, out[-1000:], err[-1500:])
        for _, p in procs:
            if p.poll() is None:
                p.send_signal(signal.SIGINT)
        for cmd, p in procs:
            if p is plant:
                continue
            out, err = p.communicate(timeout=30)
            assert p.returncode == 0, (cmd, p.returncode, err[-1500:])
    finally:
        for _, p in procs:
            if p.poll() is None:
                p.kill()
                p.wait()


def test_every_subcommand_is_in_the_readme_table() -> None:
    from formation.cli import SUBCOMMANDS

    table = "\n".join(
        ln for ln in (REPO_ROOT / "README.md").read_text().splitlines() if ln[:1] == "|"
    )
    missing = [n for n in SUBCOMMANDS if not re.search(rf"`formation {re.escape(n)}\b", table)]
    assert not missing, missing


def test_every_scenario_key_is_in_docs_scenarios() -> None:
    """The keys scenario/load.py and the cores accept are all named in docs/scenarios.md."""
    from coordinator.core.formation import FORMATION_KINDS
    from coordinator.core.trajectory import (
        _KINDS,
        TRAJECTORY_KINDS,
    )
    from coordinator.core.trajectory import (
        trajectory_class as make_trajectory_class,
    )
    from robot_agent.core.params import (
        Arena,
        CircleObstacle,
        EstimatorParams,
        RepulsionParams,
        RobotGeometry,
        SafetyFilterParams,
        SafetyParams,
        SegmentObstacle,
        TrackingGains,
    )
    from scenario.load import TOP_KEYS, CameraModel, Disturbance, LinkModel, PlantModel

    doc = (REPO_ROOT / "docs" / "scenarios.md").read_text()
    names: set[str] = set(TOP_KEYS) | set(FORMATION_KINDS) | set(TRAJECTORY_KINDS)
    for cls in (RobotGeometry, TrackingGains, RepulsionParams, SafetyParams, EstimatorParams,
                SafetyFilterParams, CircleObstacle, SegmentObstacle, Arena,
                PlantModel, CameraModel, LinkModel, Disturbance,
                *(make_trajectory_class(k) for k in _KINDS)):  # fmt: skip
        names |= {f.name for f in dataclasses.fields(cls) if f.init}
    names |= {"ids", "count", "initial", "method", "greedy", "optimal", "sparse", "n", "slots"}
    names |= {"drag", "teleport", "camera_loss", "phi", "b_m", "parent", "phi_rad"}
    names |= {"arena", "obstacle", "safety_filter", "circle", "segment", "polygon", "points"}
    from scenario.faults import CONDITIONS, FAULT_KINDS, KEYS, ROLES

    names |= set(FAULT_KINDS) | set(ROLES) | set(CONDITIONS) | set(KEYS)
    missing = sorted(n for n in names if not re.search(rf"\b{re.escape(n)}\b", doc))
    assert not missing, missing
    assert "[agent.safety]" not in (REPO_ROOT / "docs" / "faults.md").read_text()


def _tutorial() -> tuple[dict[str, str], list[str]]:
    """docs/tutorial.md: its files (a toml or python block whose first line is ``# NAME...``)
    and the commands of its shell blocks that use them, in order."""
    text = (REPO_ROOT / "docs" / "tutorial.md").read_text()
    files: dict[str, str] = {}
    for m in re.finditer(r"^```(toml|python)\n(.*?)^```", text, re.S | re.M):
        first = m.group(2).splitlines()[0]
        name = re.match(r"# ([\w.-]+)", first)
        assert name is not None, f"a tutorial file block must open with `# NAME`: {first!r}"
        files[name.group(1)] = m.group(2)
    commands = [
        c
        for block in _code_blocks(text)
        for line in block.splitlines()
        for c in _clean(line)
        if re.search(r"my-fleet|test_my_fleet", c)
    ]
    return files, commands


@pytest.mark.slow
@pytest.mark.zenoh
def test_the_tutorial_runs_end_to_end(tmp_path: Path) -> None:
    """The tutorial's scenario (an obstacle, a scripted leader kill) in one process and as
    processes in lockstep (equal metrics, the kill at the same tick), then its pytest fault
    test file, each command as written, in a fresh folder."""
    import json

    files, commands = _tutorial()
    assert set(files) == {"my-fleet.toml", "test_my_fleet.py"}
    for name, body in files.items():
        (tmp_path / name).write_text(body)
    assert [c.split()[:2] for c in commands] == [
        ["formation", "sim"], ["formation", "up"], ["python", "-m"],
    ]  # fmt: skip
    for cmd in commands:
        argv = shlex.split(cmd)
        if argv[0] == "formation":
            argv = [sys.executable, "-m", "formation", *argv[1:]]
            if argv[3] == "up":
                argv += ["--endpoint", f"tcp/127.0.0.1:{free_port()}", "--quiet"]
        else:
            argv = [sys.executable, *argv[1:], "-p", "no:cacheprovider"]
        p = subprocess.run(
            argv, cwd=tmp_path, env=child_env(), capture_output=True, text=True, timeout=600
        )
        if p.returncode != 0:  # whole, in the report's captured output (an assertion's text is
            print(cmd, p.stdout[-6000:], p.stderr[-6000:], sep="\n")  # truncated by pytest)
        assert p.returncode == 0, (cmd, p.stdout[-2000:], p.stderr[-2000:])
    sim = json.loads((tmp_path / "runs" / "my-fleet" / "metrics.json").read_text())
    up = json.loads((tmp_path / "runs" / "my-fleet-up" / "metrics.json").read_text())
    assert sim["robots"] == up["robots"] and sim["run"] == up["run"]
    assert sim["faults"] == up["faults"] and sim["faults"][0]["kind"] == "kill"
