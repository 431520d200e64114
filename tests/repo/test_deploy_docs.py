"""docs/deploy.md is a walkthrough that works: every command block is run against a staged install.

The staged install is a temporary prefix: ``deploy/install.sh`` runs with ``--prefix STAGE
--files-only`` (no virtualenv, no user), ``/etc/formation`` in a command means
``STAGE/etc/formation`` (and the paths inside the installed files are relocated the same way
after every command), ``/opt/formation/venv/bin/formation`` and ``formation`` are this
checkout's ``python -m formation``, ``~`` is a home directory inside the stage, and ``sudo`` runs
the command as is. Commands in the order of the document, each must exit 0.

Commands that need the hardware, root, a running systemd, the network or a running fleet are
listed in :data:`SKIPPED` with the reason; the test fails if one of those entries is no longer
used (the list stays true to the document).
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
DOC = REPO / "docs" / "deploy.md"
RUNNING_FLEET = (
    "needs the running fleet and its router; tests/fleet/test_deploy_netns.py runs top, fault and "
    "record with the operator certificate against the deployment"
)
SKIPPED: dict[str, str] = {
    r"sudo apt install ": "installs system packages (root and the network)",
    r"git clone ": "needs the network; the test runs from this checkout",
    r"git pull": "needs the network",
    r"ffmpeg -f v4l2 ": "needs the camera",
    r"formation camera calibrate ": "needs a frame of the mounted camera showing the floor "
    "markers (tests/fleet/test_camera_node.py fits a calibration from rendered markers)",
    r"formation motor-emulator ": "runs until Ctrl-C (tests/fleet/test_agent_boot.py runs it)",
    r"sudo chown -R root:formation ": "needs the user formation, made by a system install "
    "(a --prefix install makes none)",
    r"(sudo )?systemctl ": "needs systemd as PID 1 (tests/repo/test_deploy_files.py verifies "
    "the units with systemd-analyze)",
    r"journalctl ": "needs systemd's journal",
    r"sudo kill -STOP ": "needs the agent running under systemd",
    r"\S*formation top ": RUNNING_FLEET,
    r"\S*formation fault ": RUNNING_FLEET,
    r"sudo rm -rf /opt/formation ": "uninstall: removes a system install (root)",
}
MIN_RUN = 8


def commands(text: str) -> list[tuple[int, str]]:
    """(line number, command) of every ``sh`` block, continuation lines joined, comments out."""
    out: list[tuple[int, str]] = []
    in_block = False
    pending = ""
    start = 0
    for n, line in enumerate(text.splitlines(), start=1):
        if line.startswith("```"):
            in_block = line.strip() == "```sh" if not in_block else False
            continue
        if not in_block:
            continue
        stripped = line.strip()
        if not pending and (not stripped or stripped.startswith("#")):
            continue
        if not pending:
            start = n
        if stripped.endswith("\\"):
            pending += stripped[:-1].rstrip() + " "
            continue
        out.append((start, pending + stripped))
        pending = ""
    return out


def skip_reason(command: str) -> tuple[str, str] | None:
    for pattern, reason in SKIPPED.items():
        if re.match(pattern, command):
            return pattern, reason
    return None


def relocate(stage: Path) -> None:
    """Point the absolute /etc/formation paths inside the staged files into the stage."""
    etc = stage / "etc" / "formation"
    prefix = str(stage)
    pattern = re.compile(r"(?<!" + re.escape(prefix) + r")/etc/formation")
    for path in etc.rglob("*"):
        if path.is_file() and path.suffix in (".toml", ".json5", ".env", ".example"):
            text = path.read_text()
            new = pattern.sub(prefix + "/etc/formation", text)
            if new != text:
                path.write_text(new)


def test_every_command_of_the_walkthrough_runs_on_a_staged_install(tmp_path: Path) -> None:
    stage = tmp_path / "stage"
    home = stage / "home"
    home.mkdir(parents=True)
    shim = tmp_path / "bin"
    shim.mkdir()
    formation = shim / "formation"
    formation.write_text(f'#!/bin/sh\nexec "{sys.executable}" -m formation "$@"\n')
    formation.chmod(0o755)
    sudo = shim / "sudo"  # the test is the administrator of its stage
    sudo.write_text('#!/bin/sh\nexec "$@"\n')
    sudo.chmod(0o755)
    env = dict(os.environ)
    env.pop("ZENOH_CONFIG", None)
    env.update(
        HOME=str(home),
        PATH=f"{shim}{os.pathsep}{env.get('PATH', '')}",
        PYTHONPATH=str(REPO),
    )
    ran: list[str] = []
    used: set[str] = set()
    for line, command in commands(DOC.read_text()):
        hit = skip_reason(command)
        if hit is not None:
            used.add(hit[0])
            continue
        cmd = command
        if cmd.startswith("sudo deploy/install.sh"):
            cmd = cmd + f" --prefix {stage} --files-only"
        cmd = cmd.replace("/opt/formation/venv/bin/formation", str(formation))
        cmd = re.sub(r"(?<![\w.-])/etc/formation", f"{stage}/etc/formation", cmd)
        result = subprocess.run(
            ["bash", "-c", cmd], cwd=REPO, env=env, capture_output=True, text=True, timeout=120
        )
        assert result.returncode == 0, (
            f"docs/deploy.md line {line}: {command}\n(run as: {cmd})\n"
            f"--- stdout ---\n{result.stdout}--- stderr ---\n{result.stderr}"
        )
        relocate(stage)
        ran.append(command)
    stale = set(SKIPPED) - used
    assert not stale, f"SKIPPED entries no command of docs/deploy.md uses: {sorted(stale)}"
    assert len(ran) >= MIN_RUN, ran
    # what the walkthrough promises exists in the stage
    etc = stage / "etc" / "formation"
    for rel in (
        "fleet.toml",
        "r1.toml",
        "camera.env",
        "zenoh/router-mtls.json5",
        "zenoh/robot-mtls.json5",
        "certs/router/cert.pem",
        "certs/coordinator.standby/key.pem",
        "certs/cert.pem",  # the robot's own identity, directly in certs/
    ):
        assert (etc / rel).is_file(), rel
    print(f"\nran {len(ran)} commands, skipped {len(used)} kinds (reasons in SKIPPED)")


def test_the_parser_sees_continuations_and_skips_comments() -> None:
    text = "x\n```sh\n# c\na \\\n  b\nc\n```\n```toml\nd\n```\n"
    assert commands(text) == [(4, "a b"), (6, "c")]


@pytest.mark.parametrize(
    "command",
    ["sudo systemctl enable --now formation-agent@r1", "/opt/formation/venv/bin/formation top x"],
)
def test_skip_list_matches(command: str) -> None:
    assert skip_reason(command) is not None
