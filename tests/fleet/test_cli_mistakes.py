"""Every CLI mistake is one line naming the option or field, exit status 2, no traceback.

A table of mistakes walked through every subcommand of the real ``formation`` command (a
subprocess of ``python -m formation``, as a user types it), plus: a busy port for ``up`` and
``router``, Ctrl-C on a long ``formation sim`` (exit 130, one line), ``--version``, an example
and the defaults in every ``--help``, and progress with an ETA.
"""

from __future__ import annotations

import argparse
import io
import os
import pty
import select
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import pytest
from support.spawn import REPO_ROOT, child_env

from formation import cli
from formation.cli import EXAMPLES, SUBCOMMANDS

# The table runs ~60 fresh Pythons; on a loaded shared machine that takes minutes.
pytestmark = [pytest.mark.timeout(900), pytest.mark.shares_cpu]

BASE = REPO_ROOT / "scenario" / "builtin" / "paper-exp2.toml"


def formation(
    *args: str, cwd: Path, timeout: float = 60.0, env: dict[str, str] | None = None
) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "formation", *args],
        cwd=cwd,
        env=child_env(env),
        capture_output=True,
        text=True,
        timeout=timeout,
    )


def _scenario_variant(tmp: Path, name: str, old: str, new: str) -> str:
    text = BASE.read_text()
    assert old in text, old
    path = tmp / f"{name}.toml"
    path.write_text(text.replace(old, new, 1))
    return str(path)


@pytest.fixture(scope="module")
def files(tmp_path_factory: pytest.TempPathFactory) -> dict[str, str]:
    tmp = tmp_path_factory.mktemp("mistakes")
    (tmp / "broken.toml").write_text("not toml [\n")
    (tmp / "afile").write_text("x")
    return {
        "dir": str(tmp),
        "badkind": _scenario_variant(tmp, "badkind", 'kind = "line"', 'kind = "zigzag"'),
        "badkey": _scenario_variant(tmp, "badkey", "speed_mps = 0.02", "sped_mps = 0.02"),
        "badphi": _scenario_variant(tmp, "badphi", "b_m = 0.4", "b_m = 0.4\nphi = [1.0]"),
        "badtop": _scenario_variant(tmp, "badtop", "dt_s = 0.02", "dt_s = 0.02\ndt = 0.1"),
        "baddur": _scenario_variant(tmp, "baddur", "duration_s = 110.0", "duration_s = -1.0"),
        "broken": str(tmp / "broken.toml"),
        "afile": str(tmp / "afile"),
    }


# (argv, substrings the one line must contain). "{name}" is replaced from the `files` fixture.
MISTAKES: list[tuple[tuple[str, ...], tuple[str, ...]]] = [
    # the entry point
    (("nosuch",), ("unknown command", "nosuch")),
    (("--bogus",), ("unknown option", "--bogus")),
    # formation check
    (("check", "nosuch"), ("no scenario", "nosuch")),
    (("check", "corridor", "--duration", "-1"), ("--duration",)),
    (("check",), ("scenario",)),
    # formation sim: options
    (("sim", "--duration", "-5"), ("--duration", "> 0")),
    (("sim", "--duration", "nan"), ("--duration", "nan")),
    (("sim", "--duration", "inf"), ("--duration",)),
    (("sim", "--duration", "0"), ("--duration",)),
    (("sim", "--duration", "abc"), ("--duration", "not a number")),
    (("sim", "--duration", "1e9"), ("--duration", "limit")),
    (("sim", "--duration", "1e5"), ("--duration", "--yes")),
    (("sim", "--seed", "-1"), ("--seed", ">= 0")),
    (("sim", "--seed", "1.5"), ("--seed", "integer")),
    (("sim", "--bogus"), ("--bogus", "unrecognized")),
    (("sim", "--scenario"), ("--scenario", "expected one argument")),
    (("sim", "--scenario", "nosuch"), ("nosuch", "not a file")),
    (("sim", "--scenario", "/no/such/file.toml"), ("/no/such/file.toml",)),
    (("sim", "--out", "{afile}", "--duration", "1"), ("--out", "not a folder")),
    # formation sim: scenario fields
    (("sim", "--scenario", "{badkind}"), ("trajectory kind", "zigzag")),
    (("sim", "--scenario", "{badkey}"), ("trajectory", "sped_mps")),
    (("sim", "--scenario", "{badphi}"), ("phi",)),
    (("sim", "--scenario", "{badtop}"), ("unknown key", "dt")),
    (("sim", "--scenario", "{baddur}"), ("duration_s",)),
    (("sim", "--scenario", "{broken}"), ("not valid TOML",)),
    # formation up (all refused before anything starts)
    (("up", "--duration", "-5"), ("--duration",)),
    (("up", "--duration", "nan"), ("--duration",)),
    (("up", "--duration", "1e9"), ("--duration",)),
    (("up", "--seed", "-1"), ("--seed",)),
    (("up", "--fleet", "bad/fleet"), ("fleet", "bad/fleet")),
    (("up", "--endpoint", "bogus"), ("bogus", "endpoint")),
    (("up", "--robots", "0"), ("--robots",)),
    (("up", "--hosts", "999"), ("--hosts",)),
    (("up", "--ready-timeout", "-1"), ("--ready-timeout",)),
    (("up", "--lockstep", "--lockstep-timeout", "0"), ("--lockstep-timeout",)),
    (("up", "--lockstep-timeout", "30"), ("--lockstep-timeout", "--lockstep")),
    (("up", "--scenario", "{badphi}"), ("phi",)),
    (("up", "--scenario", "nosuch"), ("nosuch",)),
    (("up", "--bogus"), ("--bogus",)),
    # the other subcommands
    (("demo", "--bogus"), ("--bogus",)),
    (("sweep", "s.toml", "--bogus"), ("--bogus",)),
    (("sweep", "no-such-study.toml"), ("no-such-study.toml", "cannot read")),
    (("demo", "--duration", "-1"), ("--duration",)),
    (("router", "--listen", "nonsense"), ("nonsense", "endpoint")),
    (("router", "--lease-ms", "-5"), ("lease",)),
    (("router", "--bogus"), ("--bogus",)),
    (("coordinator",), ("--scenario", "required")),
    (("coordinator", "--scenario", "nosuch"), ("nosuch",)),
    (("coordinator", "--scenario", "paper-exp2", "--rate-hz", "0"), ("--rate-hz",)),
    (
        ("coordinator", "--scenario", "paper-exp2", "--estop-state", "/nonexistent/x.msgpack"),
        ("--estop-state", "does not exist"),
    ),
    (("agent",), ("--id",)),
    (("agent", "--id", "bad id"), ("robot id", "bad id")),
    (("agent", "--id", "r1", "--rate-hz", "0"), ("--rate-hz",)),
    (("agent", "--id", "r1", "--scenario", "nosuch"), ("nosuch",)),
    (("agent-host",), ("--ids", "required")),
    (("plant",), ("--scenario", "required")),
    (("plant", "--scenario", "nosuch"), ("nosuch",)),
    (("plant", "--scenario", "paper-exp2", "--bogus"), ("--bogus",)),
    (("fault",), ("COMMAND", "required")),
    (("fault", "nosuch"), ("nosuch", "invalid choice")),
    # the operator's tools (issue 28): refused before anything is sent
    (("teleop", "--v", "nan"), ("--v", "finite")),
    (("teleop", "--v", "1e300"), ("--v", "within")),
    (("teleop", "--omega", "abc"), ("--omega", "number")),
    (("teleop", "--duration", "-1"), ("--duration", "positive")),
    (("teleop", "--fleet", "a/b"), ("fleet", "a/b")),
    (("teleop", "--gamepad", "/nonexistent/js0"), ("--gamepad", "No such file")),
    (("goal",), ("required",)),
    (("goal", "nan", "0"), ("X", "finite")),
    (("goal", "1", "1e300"), ("Y", "within")),
    (("goal", "1", "2", "--heading", "inf"), ("--heading", "finite")),
    (("path",), ("--waypoints", "required")),
    (("path", "--waypoints", "1,2,3"), ("1,2,3", "X,Y")),
    (("path", "--waypoints", "1,1", "1,1"), ("same point",)),
    (("path", "--waypoints", "1,nan"), ("waypoint y", "finite")),
    (("shape",), ("KIND", "required")),
    (("shape", "zigzag"), ("zigzag", "invalid choice")),
    (("shape", "column", "--spacing", "0.01"), ("--spacing", "[0.1, 5]")),
    (("shape", "column", "--spacing", "inf"), ("--spacing", "finite")),
    (("shape", "column", "--slots", "0"), ("--slots", "[1, 1024]")),
    (("shape", "line", "--slots", "two"), ("--slots", "whole number")),
    (("obstacle", "add"), ("ID", "required")),
    (("obstacle", "teleport", "box1"), ("teleport", "invalid choice")),
    (("obstacle", "add", "box1", "--circle", "1", "1", "-0.5"), ("R", "> 0")),
    (("obstacle", "add", "box1", "--polygon", "0,0", "1,1"), ("--polygon", "3 to 64")),
    (("motor-emulator", "--address", "0x99"), ("--address", "0x80..0x87")),
    (("motor-emulator", "--bogus"), ("--bogus",)),
    (("ros2", "--domain-id", "300"), ("--domain-id", "0..232")),
    (("ros2", "--namespace", "a b"), ("a b",)),
    (("ros2", "--max-cmd-hz", "0"), ("--max-cmd-hz",)),
    (("record",), ("--out", "required")),
    (("record", "--out", "x.mcap", "--bogus"), ("--bogus",)),
    (("report",), ("file", "required")),
    (("report", "no-such.mcap"), ("no-such.mcap", "no such file")),
    (("report", "{dir}"), ("not a file",)),
    (("top", "--bogus"), ("--bogus",)),
    (("ls", "--wait", "0"), ("--wait",)),
    (("ls", "--bogus"), ("--bogus",)),
    (("echo", "robot//x"), ("KEY", "robot//x")),
    (("echo", "assignment", "--fleet", "a/b"), ("fleet", "a/b")),
    (("echo", "assignment", "--count", "0"), ("--count",)),
    (("top", "--fleet", "a/b"), ("fleet", "a/b")),
    (("acl",), ("--out", "required")),
    (("certs",), ("--out", "required")),
    (("camera",), ("--source", "required")),
    (("camera", "calibrate", "--bogus"), ("required",)),
]


def _ids() -> Iterator[str]:
    for argv, _ in MISTAKES:
        yield " ".join(argv)


# Each invocation is a fresh Python that imports zenoh/numpy: run them a few at a time, once for
# the whole module, and let the parametrized tests below look at their own result.
POOL_WORKERS = 4


@pytest.fixture(scope="module")
def results(
    files: dict[str, str], tmp_path_factory: pytest.TempPathFactory
) -> dict[tuple[str, ...], tuple[subprocess.CompletedProcess[str], Path]]:
    jobs: list[tuple[str, ...]] = [tuple(a.format(**files) for a in argv) for argv, _ in MISTAKES]

    def one(argv: tuple[str, ...]) -> tuple[subprocess.CompletedProcess[str], Path]:
        cwd = tmp_path_factory.mktemp("cwd")
        return formation(*argv, cwd=cwd, timeout=120.0), cwd

    with ThreadPoolExecutor(max_workers=POOL_WORKERS) as pool:
        done = list(pool.map(one, jobs))
    return dict(zip(jobs, done, strict=True))


@pytest.mark.parametrize(("argv", "needles"), MISTAKES, ids=list(_ids()))
def test_a_mistake_is_one_line_exit_2_no_traceback(
    argv: tuple[str, ...],
    needles: tuple[str, ...],
    files: dict[str, str],
    results: dict[tuple[str, ...], tuple[subprocess.CompletedProcess[str], Path]],
) -> None:
    r, cwd = results[tuple(a.format(**files) for a in argv)]
    lines = r.stderr.splitlines()
    assert r.returncode == 2, (r.returncode, r.stderr[-2000:])
    assert "Traceback" not in r.stderr
    assert len(lines) == 1, r.stderr
    for needle in needles:
        assert needle.format(**files) in lines[0], (needle, lines[0])
    assert ".rs:" not in r.stderr
    # refused before anything started: no run folder written
    assert not (cwd / "runs").exists(), list(cwd.iterdir())


def test_every_subcommand_is_in_the_table() -> None:
    tried = {argv[0] for argv, _ in MISTAKES}
    assert set(SUBCOMMANDS) <= tried, set(SUBCOMMANDS) - tried


def _listening_socket() -> socket.socket:
    s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    s.bind(("127.0.0.1", 0))
    s.listen()
    return s


@pytest.mark.parametrize("cmd", ["up", "router"])
def test_a_busy_port_is_one_line_without_rust_paths(cmd: str, tmp_path: Path) -> None:
    with _listening_socket() as busy:
        ep = f"tcp/127.0.0.1:{busy.getsockname()[1]}"
        args = ["up", "--endpoint", ep, "--duration", "1"] if cmd == "up" else ["router"]
        if cmd == "router":
            args += ["--listen", ep]
        r = formation(*args, cwd=tmp_path)
    assert r.returncode == 2, r.stderr
    lines = r.stderr.splitlines()
    assert len(lines) == 1, r.stderr
    assert ep in lines[0] and ("busy" in lines[0] or "already in use" in lines[0]), lines[0]
    assert ".rs" not in r.stderr and "Traceback" not in r.stderr


def test_version_comes_from_the_installed_metadata(tmp_path: Path) -> None:
    from importlib.metadata import version

    r = formation("--version", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == f"formation {version('formation-control')}"


def _in_process(argv: list[str], monkeypatch: pytest.MonkeyPatch) -> int:
    """``formation.cli.main(argv)`` in this process; argparse restored afterwards."""
    monkeypatch.setattr(argparse.ArgumentParser, "error", argparse.ArgumentParser.error)
    monkeypatch.setattr(argparse.ArgumentParser, "format_help", argparse.ArgumentParser.format_help)
    try:
        return cli.main(argv)
    except SystemExit as exc:
        return int(exc.code or 0)


@pytest.mark.parametrize("cmd", sorted(SUBCOMMANDS))
def test_every_help_has_an_example_and_shows_defaults(
    cmd: str, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    assert _in_process([cmd, "--help"], monkeypatch) == 0
    out = capsys.readouterr().out
    assert "examples:" in out, out[-500:]
    for example in EXAMPLES[f"formation {cmd}"]:
        assert example in out
    assert "default" in out, out  # every subcommand has at least one option with a default


@pytest.mark.parametrize(
    "example", [e for examples in EXAMPLES.values() for e in examples if "--help" not in e]
)
def test_help_examples_parse(
    example: str, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """The examples in --help are real command lines: each parses (checked with --help added)."""
    assert _in_process([*example.split()[1:], "--help"], monkeypatch) == 0, capsys.readouterr()


def _read_until(fd: int, needle: bytes, timeout_s: float) -> bytes:
    got = b""
    end = time.monotonic() + timeout_s
    while needle not in got and time.monotonic() < end:
        ready, _, _ = select.select([fd], [], [], 0.2)
        if ready:
            try:
                chunk = os.read(fd, 4096)
            except OSError:  # EIO: the child closed the terminal
                break
            if not chunk:
                break
            got += chunk
    return got


def test_ctrl_c_on_a_long_sim_exits_130_with_one_line_after_progress_on_a_tty(
    tmp_path: Path,
) -> None:
    """On a terminal the progress line (with an ETA) is redrawn in place; Ctrl-C is one line."""
    main_fd, child_fd = pty.openpty()
    proc = subprocess.Popen(
        [sys.executable, "-m", "formation", "sim", "--duration", "3000", "--no-figures"],
        cwd=tmp_path,
        env=child_env(),
        stdout=subprocess.PIPE,
        stderr=child_fd,
        text=True,
    )
    os.close(child_fd)
    try:
        seen = _read_until(main_fd, b"ETA", timeout_s=60.0)
        assert b"ETA" in seen, seen
        assert proc.poll() is None
        assert b"\r" in seen and b"formation sim: t " in seen and b"% of 3000 s" in seen, seen
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=10.0)
        rest = _read_until(main_fd, b"interrupted\r\n", timeout_s=5.0)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        os.close(main_fd)
    assert proc.returncode == 130
    text = (seen + rest).decode()
    assert "Traceback" not in text
    # the last progress line is cleared, then the one line
    last = text.rstrip().rsplit("\r", 1)[-1].replace("\x1b[K", "")
    assert last.startswith("formation sim: interrupted"), text[-300:]
    assert text.count("interrupted") == 1


def test_progress_lines_when_not_a_terminal() -> None:
    """Not a terminal: a plain line per period, with percentage and ETA; disabled: nothing."""
    from formation.outputs.progress import LINE_PERIOD_S, Progress, eta_text

    stream = io.StringIO()
    bar = Progress("formation sim", stream=stream)
    assert bar.period == LINE_PERIOD_S
    bar.update(0.0, 100.0)  # within the first period: nothing
    assert stream.getvalue() == ""
    bar.start -= 10.0  # pretend 10 s of wall time went by
    bar.last -= LINE_PERIOD_S
    bar.update(25.0, 100.0)
    line = stream.getvalue()
    assert line.startswith("formation sim: t 25.0 s,  25% of 100 s, ETA 30 s"), line
    assert line.endswith("\n") and "\r" not in line
    quiet = io.StringIO()
    off = Progress("x", enabled=False, stream=quiet)
    off.last -= 100.0
    off.update(1.0, 2.0)
    assert quiet.getvalue() == ""
    assert eta_text(50.0, 100.0, 2.0) == " 50% of 100 s, ETA 25 s"
    assert eta_text(0.0, 7200.0, 1.0) == "  0% of 7200 s, ETA 2 h 00 min"


def test_short_sim_output_is_unchanged_by_progress(tmp_path: Path) -> None:
    r = formation("sim", "--duration", "2", "--no-figures", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert r.stderr == ""
    assert "metrics and figures in" in r.stdout


def test_a_failed_metrics_comparison_names_the_metric_and_by_how_much() -> None:
    """`make demo`'s comparison: short lines (metric, both values, difference), not two lists."""
    from formation.record.report import differences_text
    from formation.sim.demo import metrics_differences

    a: dict[str, Any] = {
        "meta": {"wall_s": 1.0},
        "robots": {"r1": {"formation_error_rms_m": 0.0123, "final_slot": 0}},
        "run": {"min_separation_m": 0.36, "role_changes": [[0.0, "r1", 0]] * 400},
    }
    b: dict[str, Any] = {
        "meta": {"wall_s": 2.0},
        "robots": {"r1": {"formation_error_rms_m": 0.0125, "final_slot": 0}},
        "run": {"min_separation_m": 0.36, "role_changes": [[0.0, "r1", 0]] * 401},
    }
    diffs = metrics_differences(a, b)
    assert diffs == [
        "robots.r1.formation_error_rms_m: 0.0123 != 0.0125 (diff +0.0002)",
        "run.role_changes: 400 items != 401 items",
    ]
    b["run"]["role_changes"] = [[0.0, "r1", 0]] * 399 + [[0.5, "r2", 1]]
    assert metrics_differences(a, b)[1:] == [
        "run.role_changes[399][0]: 0 != 0.5 (diff +0.5)",
        "run.role_changes[399][1]: 'r1' != 'r2'",
        "run.role_changes[399][2]: 0 != 1 (diff +1)",
    ]
    text = differences_text([f"m{i}: 1 != 2 (diff +1)" for i in range(20)], limit=8)
    assert text.splitlines()[-1] == "  ... and 12 more" and len(text.splitlines()) == 9
    assert max(len(line) for line in text.splitlines()) < 100
