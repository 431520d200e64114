"""The files under deploy/: systemd unit, install script, example config, udev rule, Zenoh."""

from __future__ import annotations

import os
import re
import shutil
import stat
import subprocess
import sys
from pathlib import Path

import pytest

from scenario.robot_config import check_config, load_robot_config

REPO = Path(__file__).resolve().parents[2]
DEPLOY = REPO / "deploy"
UNIT = DEPLOY / "systemd" / "formation-agent@.service"
INSTALL = DEPLOY / "install.sh"
UDEV_RULE = DEPLOY / "udev" / "99-formation-roboclaw.rules"
EXAMPLE = DEPLOY / "config" / "r1.example.toml"
SYSTEMD_ANALYZE = "/usr/bin/systemd-analyze"


def parse_unit(text: str) -> dict[str, dict[str, list[str]]]:
    """A unit file as section -> key -> values (keys may repeat, e.g. DeviceAllow)."""
    sections: dict[str, dict[str, list[str]]] = {}
    current: dict[str, list[str]] | None = None
    for raw in text.splitlines():
        line = raw.strip()
        if not line or line.startswith(("#", ";")):
            continue
        if line.startswith("[") and line.endswith("]"):
            current = sections.setdefault(line[1:-1], {})
            continue
        assert current is not None, f"key outside a section: {line}"
        key, sep, value = line.partition("=")
        assert sep, f"not a key=value line: {line}"
        current.setdefault(key.strip(), []).append(value.strip())
    return sections


# ---------------------------------------------------------------------- systemd unit


def test_unit_settings() -> None:
    unit = parse_unit(UNIT.read_text())
    service = {k: v[-1] for k, v in unit["Service"].items()}
    assert service["Type"] == "notify"
    assert service["ExecStart"] == (
        "/opt/formation/venv/bin/formation agent --config /etc/formation/%i.toml"
    )
    assert service["WatchdogSec"] == "2"
    assert service["Restart"] == "on-failure"
    assert service["KillSignal"] == "SIGTERM"
    assert service["TimeoutStopSec"] == "2"
    assert (service["User"], service["Group"]) == ("formation", "formation")
    assert service["SupplementaryGroups"] == "dialout"
    for hardening in ("NoNewPrivileges", "PrivateTmp", "ProtectHome"):
        assert service[hardening] == "yes", hardening
    assert service["ProtectSystem"] == "strict"
    assert "RestartSec" in service
    assert {"StartLimitIntervalSec", "StartLimitBurst"} <= set(unit["Unit"])
    assert "char-ttyACM rw" in unit["Service"]["DeviceAllow"]
    assert unit["Install"]["WantedBy"] == ["multi-user.target"]


@pytest.mark.skipif(
    not os.access(SYSTEMD_ANALYZE, os.X_OK), reason=f"{SYSTEMD_ANALYZE} is not installed"
)
def test_unit_passes_systemd_analyze_verify(tmp_path: Path) -> None:
    # verify needs ExecStart to exist: point it at an executable stand-in for the venv's
    # `formation`, leave every other line as shipped, and verify an instance (r1).
    fake = tmp_path / "formation"
    fake.write_text("#!/bin/sh\nexit 0\n")
    fake.chmod(0o755)
    text = UNIT.read_text()
    assert "ExecStart=/opt/formation/venv/bin/formation " in text
    text = text.replace("ExecStart=/opt/formation/venv/bin/formation ", f"ExecStart={fake} ")
    instance = tmp_path / "formation-agent@r1.service"
    instance.write_text(text)
    (tmp_path / "formation-agent@.service").write_text(text)
    result = subprocess.run(
        [SYSTEMD_ANALYZE, "verify", "--man=no", str(instance)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    output = result.stdout + result.stderr
    assert result.returncode == 0, output
    # unknown or misspelt keys are only warnings ("Unknown key ..., ignoring"): none allowed
    complaints = [line for line in output.splitlines() if "formation-agent@" in line]
    assert complaints == [], output


def test_systemd_analyze_catches_a_bad_unit(tmp_path: Path) -> None:
    """The check above has teeth: a misspelt key is reported."""
    if not os.access(SYSTEMD_ANALYZE, os.X_OK):
        pytest.skip(f"{SYSTEMD_ANALYZE} is not installed")
    bad = tmp_path / "formation-agent@r1.service"
    bad.write_text(
        UNIT.read_text()
        .replace("ExecStart=/opt/formation/venv/bin/formation", "ExecStart=/bin/true")
        .replace("WatchdogSec=2", "WatchdogSecs=2")
    )
    result = subprocess.run(
        [SYSTEMD_ANALYZE, "verify", "--man=no", str(bad)], capture_output=True, text=True
    )
    assert "WatchdogSecs" in result.stdout + result.stderr


# ---------------------------------------------------------------------- install.sh


def run_install(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(["bash", str(INSTALL), *args], capture_output=True, text=True, timeout=60)


def test_install_dry_run_changes_nothing(tmp_path: Path) -> None:
    stage = tmp_path / "stage"
    result = run_install(
        "--dry-run", "--prefix", str(stage), "--robot-id", "r3", "--python", sys.executable
    )
    assert result.returncode == 0, result.stderr
    assert not stage.exists()  # a dry run creates nothing, not even the prefix
    out = result.stdout
    # the wheel is built (with build or pip wheel --no-deps) and installed with [agent] only
    assert ("-m pip wheel --no-deps" in out) or ("-m build --wheel" in out)
    assert f"-m venv {stage}/opt/formation/venv" in out
    assert "\\[agent\\]" in out or "[agent]" in out
    assert "[sim]" not in out and "numpy" not in out
    for final in (
        "/etc/systemd/system/formation-agent@.service",
        "/etc/udev/rules.d/99-formation-roboclaw.rules",
        "/etc/formation/zenoh/robot-mtls.json5",
        "/etc/formation/r1.example.toml",
        "/etc/formation/r3.toml",
    ):
        assert f"{stage}{final}" in out, final
    assert "not creating the user formation" in out  # no root effects in a prefix
    assert "useradd" not in out and "systemctl" not in out.split("Next steps")[0]


def test_install_rejects_bad_arguments(tmp_path: Path) -> None:
    assert run_install("--bogus").returncode == 2
    assert run_install("--dry-run", "--prefix", str(tmp_path), "--robot-id", "R 1").returncode == 2


def test_install_files_into_prefix_is_idempotent(tmp_path: Path) -> None:
    stage = tmp_path / "stage"
    first = run_install("--files-only", "--prefix", str(stage), "--robot-id", "r3")
    assert first.returncode == 0, first.stderr
    unit = stage / "etc/systemd/system/formation-agent@.service"
    assert unit.read_text() == UNIT.read_text()
    assert stat.S_IMODE(unit.stat().st_mode) == 0o644
    gen = stage / "opt/formation/share/gen-certs.sh"
    assert stat.S_IMODE(gen.stat().st_mode) == 0o755
    assert stat.S_IMODE((stage / "etc/formation/certs").stat().st_mode) == 0o750
    robot = stage / "etc/formation/r3.toml"
    cfg = load_robot_config(robot, check_files=False)
    assert cfg.robot_id == "r3"
    # the example's Zenoh file is one the installer puts in place
    assert cfg.zenoh.config_file is not None
    assert (stage / cfg.zenoh.config_file.lstrip("/")).is_file()

    robot.write_text(robot.read_text() + "\n# edited on the robot\n")
    second = run_install("--files-only", "--prefix", str(stage), "--robot-id", "r3")
    assert second.returncode == 0, second.stderr
    assert "keeping the existing /etc/formation/r3.toml" in second.stdout
    assert robot.read_text().endswith("# edited on the robot\n")  # never overwritten


# ---------------------------------------------------------------------- example config


def test_example_config_passes_check_config() -> None:
    assert check_config(EXAMPLE, check_files=False) == []


def test_example_config_passes_check_config_once_installed(tmp_path: Path) -> None:
    """On the robot, with its Zenoh file in place, the full check (files too) passes."""
    text = EXAMPLE.read_text()
    zenoh_file = tmp_path / "zenoh" / "robot-mtls.json5"
    zenoh_file.parent.mkdir()
    shutil.copy(DEPLOY / "zenoh" / "robot-mtls.json5", zenoh_file)
    local = tmp_path / "r1.toml"
    local.write_text(text.replace("/etc/formation/zenoh/robot-mtls.json5", str(zenoh_file)))
    assert check_config(local) == []


# ---------------------------------------------------------------------- udev rule

_UDEV_TOKEN = re.compile(
    r'\s*(?P<key>[A-Z_]+(?:\{[^}"]+\})?)\s*(?P<op>==|!=|\+=|-=|:=|=)\s*"(?P<value>[^"]*)"\s*'
)
_UDEV_MATCH_KEYS = {
    "ACTION",
    "DEVPATH",
    "KERNEL",
    "KERNELS",
    "NAME",
    "SUBSYSTEM",
    "SUBSYSTEMS",
    "DRIVER",
    "DRIVERS",
    "ATTR",
    "ATTRS",
    "ENV",
    "TAG",
    "TAGS",
    "TEST",
    "PROGRAM",
    "RESULT",
    "SYMLINK",
    "CONST",
    "SYSCTL",
}
_UDEV_ASSIGN_KEYS = {
    "NAME",
    "SYMLINK",
    "OWNER",
    "GROUP",
    "MODE",
    "ATTR",
    "ENV",
    "TAG",
    "RUN",
    "LABEL",
    "GOTO",
    "IMPORT",
    "OPTIONS",
    "SECLABEL",
    "SYSCTL",
}


def parse_udev_rule(line: str) -> list[tuple[str, str, str]]:
    """Split one rule line into (key, operator, value) and check the udev grammar."""
    tokens: list[tuple[str, str, str]] = []
    for part in line.split(","):
        m = _UDEV_TOKEN.fullmatch(part)
        assert m, f'not KEY OP "value": {part!r}'
        key, op, value = m["key"], m["op"], m["value"]
        base = key.split("{", 1)[0]
        if op in ("==", "!="):
            assert base in _UDEV_MATCH_KEYS, f"{key} cannot be matched"
        else:
            assert base in _UDEV_ASSIGN_KEYS, f"{key} cannot be assigned"
        tokens.append((key, op, value))
    return tokens


def test_udev_rule_syntax() -> None:
    lines = [
        line
        for line in UDEV_RULE.read_text().splitlines()
        if line.strip() and not line.lstrip().startswith("#")
    ]
    assert len(lines) == 1
    tokens = parse_udev_rule(lines[0])
    assert ("SUBSYSTEM", "==", "tty") in tokens
    assert ("ATTRS{idVendor}", "==", "03eb") in tokens
    assert ("ATTRS{idProduct}", "==", "2404") in tokens
    assert ("SYMLINK", "+=", "roboclaw") in tokens
    assert ("GROUP", "=", "dialout") in tokens
    mode = dict((k, v) for k, _, v in tokens)["MODE"]
    assert re.fullmatch(r"0[0-7]{3}", mode) and int(mode, 8) & 0o007 == 0  # not world-usable
    udevadm = shutil.which("udevadm")
    if (
        udevadm
        and subprocess.run([udevadm, "verify", "--help"], capture_output=True).returncode == 0
    ):
        result = subprocess.run([udevadm, "verify", str(UDEV_RULE)], capture_output=True, text=True)
        assert result.returncode == 0, result.stdout + result.stderr


def test_udev_parser_rejects_broken_rules() -> None:
    with pytest.raises(AssertionError):
        parse_udev_rule('SUBSYSTEM="tty", ATTRS{idVendor}=="03eb"')  # assignment to a match
    with pytest.raises(AssertionError):
        parse_udev_rule('SUBSYSTEM=="tty" ATTRS{idVendor}=="03eb"')  # missing comma
    with pytest.raises(AssertionError):
        parse_udev_rule("SUBSYSTEM==tty")  # unquoted value


# ---------------------------------------------------------------------- zenoh and certs


@pytest.mark.parametrize("name", sorted(p.name for p in (DEPLOY / "zenoh").glob("*.json5")))
def test_zenoh_configs_parse_with_the_installed_zenoh(name: str) -> None:
    zenoh = pytest.importorskip("zenoh")
    conf = zenoh.Config.from_file(str(DEPLOY / "zenoh" / name))  # strict: unknown keys fail
    assert conf.get_json("scouting/multicast/enabled") == "false"
    expected_mode = '"router"' if name.startswith("router") else '"client"'
    assert conf.get_json("mode") == expected_mode


def test_gen_certs_rejects_bad_identity(tmp_path: Path) -> None:
    result = subprocess.run(
        ["bash", str(DEPLOY / "security" / "gen-certs.sh"), "-o", str(tmp_path), "Robot 1"],
        capture_output=True,
        text=True,
    )
    assert result.returncode == 2
    assert "[a-z0-9_-]+" in result.stderr
    assert not (tmp_path / "ca").exists()


# ---------------------------------------------------------------------- coordinator host

COORDINATOR_UNITS = (
    "formation-router.service",
    "formation-coordinator@.service",
    "formation-camera.service",
    "formation-ros2.service",
)
FLEET_EXAMPLE = DEPLOY / "config" / "fleet.example.toml"


@pytest.mark.parametrize("name", COORDINATOR_UNITS)
def test_coordinator_host_units_are_notify_with_a_watchdog(name: str) -> None:
    unit = parse_unit((DEPLOY / "systemd" / name).read_text())
    service = {k: v[-1] for k, v in unit["Service"].items()}
    assert service["Type"] == "notify" and service["NotifyAccess"] == "main"
    assert 0 < int(service["WatchdogSec"]) <= 5
    assert service["KillSignal"] == "SIGTERM" and service["TimeoutStopSec"] == "2"
    assert (service["User"], service["Group"]) == ("formation", "formation")
    assert service["ExecStart"].startswith("/opt/formation/venv/bin/formation ")
    assert "--zenoh-config /etc/formation/zenoh/" in service["ExecStart"]
    if name != "formation-router.service":
        assert "formation-router.service" in unit["Unit"]["After"][-1]
    if name in ("formation-coordinator@.service", "formation-camera.service"):
        assert "--fleet-file /etc/formation/fleet.toml" in service["ExecStart"]
    assert unit["Install"]["WantedBy"] == ["multi-user.target"]


def test_coordinator_unit_files_name_shipped_configs() -> None:
    text = (DEPLOY / "systemd" / "formation-coordinator@.service").read_text()
    assert "/etc/formation/zenoh/coordinator-%i-mtls.json5" in text
    # the latched e-stop survives a restart or a reboot (coordinator/node/estop_store.py), in the
    # one directory ProtectSystem=strict leaves writable
    unit = parse_unit(text)
    assert unit["Service"]["StateDirectory"] == ["formation"]
    assert "--estop-state /var/lib/formation/estop-%i.msgpack" in unit["Service"]["ExecStart"][-1]
    for instance in ("main", "standby"):
        assert (DEPLOY / "zenoh" / f"coordinator-{instance}-mtls.json5").is_file()
    env = (DEPLOY / "config" / "coordinator-standby.env").read_text()
    assert "FORMATION_COORDINATOR_ARGS=--standby" in env


@pytest.mark.skipif(
    not os.access(SYSTEMD_ANALYZE, os.X_OK), reason=f"{SYSTEMD_ANALYZE} is not installed"
)
def test_coordinator_host_units_pass_systemd_analyze_verify(tmp_path: Path) -> None:
    fake = tmp_path / "formation"
    fake.write_text("#!/bin/sh\nexit 0\n")
    fake.chmod(0o755)
    paths = []
    for name in COORDINATOR_UNITS:
        text = (DEPLOY / "systemd" / name).read_text()
        text = text.replace("/opt/formation/venv/bin/formation ", f"{fake} ")
        (tmp_path / name).write_text(text)
        target = name.replace("@.", "@main.")
        if target != name:
            (tmp_path / target).write_text(text)
        paths.append(str(tmp_path / target))
    result = subprocess.run(
        [SYSTEMD_ANALYZE, "verify", "--man=no", *paths], capture_output=True, text=True, timeout=60
    )
    output = result.stdout + result.stderr
    assert result.returncode == 0, output
    assert [line for line in output.splitlines() if "formation-" in line] == [], output


def test_fleet_example_is_valid_and_read_by_the_coordinator() -> None:
    from scenario.fleet import load_fleet

    fleet = load_fleet(FLEET_EXAMPLE)
    assert fleet.robot_ids == ("r1", "r2", "r3")
    assert fleet.tags == {"r1": 1, "r2": 2, "r3": 3}
    result = subprocess.run(
        [sys.executable, "-m", "formation", "coordinator", "--check", "--fleet-file",
         str(FLEET_EXAMPLE)],
        cwd=REPO, capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert result.returncode == 0, result.stderr
    lines = result.stdout.splitlines()
    assert lines[-1].startswith("OK: fleet demo, robots r1, r2, r3")
    # the fleet's arena reaches the coordinator's path check: the example's slow straight line
    # (0.02 m/s from x = -1 m) leaves the 3 m arena after two minutes of a run that lasts for
    # ever, and the check says so before the start (a warning: the run may go ahead)
    assert [ln.split(" at t = ")[0] for ln in lines[:-1]] == [
        f"warning: slot {k}'s path crosses arena" for k in range(3)
    ], result.stdout


def test_install_coordinator_host_into_prefix(tmp_path: Path) -> None:
    stage = tmp_path / "stage"
    first = run_install("--coordinator-host", "--files-only", "--prefix", str(stage))
    assert first.returncode == 0, first.stderr
    for name in COORDINATOR_UNITS:
        installed = stage / "etc/systemd/system" / name
        assert installed.read_text() == (DEPLOY / "systemd" / name).read_text()
    assert not (stage / "etc/systemd/system/formation-agent@.service").exists()
    zenoh = {p.name for p in (stage / "etc/formation/zenoh").iterdir()}
    assert "router-mtls.json5" in zenoh and "coordinator-standby-mtls.json5" in zenoh
    assert "robot-mtls.json5" not in zenoh
    fleet = stage / "etc/formation/fleet.toml"
    assert fleet.read_text() == FLEET_EXAMPLE.read_text()
    fleet.write_text(fleet.read_text() + "# edited\n")
    second = run_install("--coordinator-host", "--files-only", "--prefix", str(stage))
    assert "keeping the existing /etc/formation/fleet.toml" in second.stdout
    assert fleet.read_text().endswith("# edited\n")
    dry = run_install("--coordinator-host", "--dry-run", "--prefix", str(tmp_path / "d"),
                      "--python", sys.executable)  # fmt: skip
    assert dry.returncode == 0, dry.stderr
    assert "[sim,camera]" in dry.stdout.replace("\\", "")
    assert run_install("--coordinator-host", "--robot-id", "r1", "--dry-run").returncode == 2


# ---------------------------------------------------------------------- every unit's command


def _help_of(subcommand: str) -> str:
    result = subprocess.run(
        [sys.executable, "-m", "formation", subcommand, "--help"],
        cwd=REPO, capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert result.returncode == 0, (subcommand, result.stderr)
    return result.stdout


@pytest.mark.parametrize(
    "unit", sorted(p.name for p in (DEPLOY / "systemd").glob("*.service")), ids=str
)
def test_unit_runs_a_real_command_with_real_options_and_shipped_files(unit: str) -> None:
    """Each unit's ExecStart is a ``formation`` subcommand that exists, every ``--option`` in it
    is one that subcommand's ``--help`` lists, and every Zenoh config it names is shipped in
    deploy/zenoh/ (what deploy/install.sh installs under /etc/formation/zenoh/)."""
    from formation.cli import SUBCOMMANDS

    (exec_start,) = parse_unit((DEPLOY / "systemd" / unit).read_text())["Service"]["ExecStart"]
    words = exec_start.split()
    assert words[0] == "/opt/formation/venv/bin/formation", exec_start
    assert words[1] in SUBCOMMANDS, f"{unit}: no subcommand formation {words[1]}"
    help_text = _help_of(words[1])
    options = [w for w in words[2:] if w.startswith("--")]
    assert options, exec_start
    for option in options:
        listed = rf"(^|[\s,\[]){re.escape(option)}(?=[\s,=\]]|$)"
        assert re.search(listed, help_text, re.MULTILINE), (unit, option)
    for config in re.findall(r"/etc/formation/zenoh/(\S+\.json5)", exec_start):
        name = config.replace("%i", "main")
        assert (DEPLOY / "zenoh" / name).is_file(), (unit, name)
