"""The hosts and the installation of tests/fleet/test_deploy_netns.py: network namespaces joined by
veth (a hub, one namespace a robot), the shipped files with only their paths and addresses
substituted (Zenoh configs, robot configs, the fleet file, the camera's calibration and unit
command line), and commands run in a namespace.

Root with ``ip`` and the permission to create network namespaces, or the test is skipped.
"""

from __future__ import annotations

import contextlib
import os
import secrets
import subprocess
import sys
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import pytest

from support.netns import add_namespace_or_skip, delete_namespaces, ip, skip_unless_root_with_ip
from support.spawn import REPO_ROOT, Child, Spawner

ROBOTS = ("r1", "r2", "r3")
DEPLOY = REPO_ROOT / "deploy"
PORT = 7447
SPEED_MPS = 0.03
TRUTH_ENDPOINT = "tcp/127.0.0.1:7449"  # the world's own session, in the hub namespace
# The rendered camera: 640x360 (the default lens at a quarter of the pixels), straight down over
# the robots' path (x from the followers' start to ~50 s of the line at SPEED_MPS), 15 fps,
# 10 cm tags (~30 px; 6 cm tags would be ~18 px, too small at this resolution)
CAMERA_SIZE = (640, 360)
CAMERA_VIEW = ((-1.1, -0.3), (1.0, 0.3))  # floor box the view must cover (m)
CAMERA_FPS = 15.0
TAG_SIZE_M = 0.10
READY_S = 60.0  # python + numpy imports on a loaded 2-core machine (load ~30 measured)


@dataclass
class Net:
    hub: str
    hosts: dict[str, str] = field(default_factory=dict)  # robot -> namespace
    hub_devs: dict[str, str] = field(default_factory=dict)  # robot -> hub end of its veth
    hub_addrs: dict[str, str] = field(default_factory=dict)  # robot -> hub address on its link
    observer_addr: str = "10.212.0.1"  # the hub's address on the root namespace's link
    root_dev: str = ""


@contextlib.contextmanager
def hub_and_hosts(robots: Sequence[str] = ROBOTS) -> Iterator[Net]:
    """The hub namespace joined by a veth to the root namespace and to one namespace a robot,
    addresses set and links up; on exit every process left in them is killed (and the test
    failed) and they are deleted. Skips the test unless root with ``ip`` and the permission."""
    skip_unless_root_with_ip()
    tag = f"{os.getpid() % 10000}{secrets.token_hex(1)}"
    network = Net(hub=f"fd{tag}h", root_dev=f"fd{tag}o")
    created: list[str] = []
    try:
        add_namespace_or_skip(network.hub)
        created.append(network.hub)
        veth = ip("link", "add", network.root_dev, "type", "veth", "peer", "name",
                  f"fd{tag}p", "netns", network.hub, check=False)  # fmt: skip
        if veth.returncode != 0:
            pytest.skip(f"cannot create a veth pair: {veth.stderr.strip()}")
        ip("addr", "add", "10.212.0.2/30", "dev", network.root_dev)
        ip("link", "set", network.root_dev, "up")
        ip("-n", network.hub, "addr", "add", "10.212.0.1/30", "dev", f"fd{tag}p")
        ip("-n", network.hub, "link", "set", f"fd{tag}p", "up")
        for i, robot in enumerate(robots, start=1):
            ns, hub_dev = f"fd{tag}{i}", f"fd{tag}h{i}"
            ip("netns", "add", ns)
            created.append(ns)
            ip("link", "add", hub_dev, "netns", network.hub, "type", "veth",
               "peer", "name", f"fd{tag}r{i}", "netns", ns)  # fmt: skip
            ip("-n", network.hub, "addr", "add", f"10.212.{i}.1/30", "dev", hub_dev)
            ip("-n", ns, "addr", "add", f"10.212.{i}.2/30", "dev", f"fd{tag}r{i}")
            ip("-n", network.hub, "link", "set", hub_dev, "up")
            ip("-n", ns, "link", "set", f"fd{tag}r{i}", "up")
            network.hosts[robot] = ns
            network.hub_devs[robot] = hub_dev
            network.hub_addrs[robot] = f"10.212.{i}.1"
        for ns in created:
            ip("-n", ns, "link", "set", "lo", "up")
        yield network
    finally:
        problems = delete_namespaces(created)
        ip("link", "del", network.root_dev, check=False)
    if problems:
        pytest.fail("\n".join(problems), pytrace=False)


# ---------------------------------------------------------------------------------------------
# The installation: certificates, shipped configs with paths/addresses substituted
# ---------------------------------------------------------------------------------------------


def shipped_zenoh(name: str, cert_dir: Path, router_addr: str, out: Path) -> Path:
    """deploy/zenoh/<name> with the certificate directory and the router address substituted."""
    text = (DEPLOY / "zenoh" / name).read_text()
    assert "/etc/formation/certs" in text
    text = text.replace("/etc/formation/certs", str(cert_dir))
    text = text.replace("coordinator.local", router_addr)
    path = out / name
    path.write_text(text)
    return path


def robot_config(robot: str, zenoh_file: Path, router_addr: str, port: str, out: Path) -> Path:
    """deploy/config/r1.example.toml with only the id, the paths and the address substituted."""
    text = (DEPLOY / "config" / "r1.example.toml").read_text()
    for old, new in (
        ('robot_id = "r1"', f'robot_id = "{robot}"'),
        ("/etc/formation/zenoh/robot-mtls.json5", str(zenoh_file)),
        ("tls/coordinator.local:7447", f"tls/{router_addr}:{PORT}"),
        ('port = "/dev/roboclaw"', f'port = "{port}"'),
    ):
        assert old in text, old
        text = text.replace(old, new)
    path = out / f"{robot}.toml"
    path.write_text(text)
    return path


def fleet_file(out: Path) -> Path:
    text = (DEPLOY / "config" / "fleet.example.toml").read_text()
    for old, new in (("x0 = -1.0", "x0 = -0.6"), ("speed_mps = 0.02", f"speed_mps = {SPEED_MPS}")):
        assert old in text, old
        text = text.replace(old, new)
    path = out / "fleet.toml"
    path.write_text(text)
    return path


def camera_files(conf: Path) -> tuple[Path, list[str]]:
    """The camera's calibration (the rendered camera's true homography, the fleet's tags) and the
    ``CAMERA_SOURCE`` words of its environment file (rendered, with the render options)."""
    from localization.core.calibration import write
    from localization.core.rendered import (
        RenderSettings,
        camera_args,
        camera_covering,
        rendered_calibration,
    )
    from sim_plant.core.render import CameraPose

    base = CameraPose().with_resolution(*CAMERA_SIZE)
    camera = camera_covering(CAMERA_VIEW, margin_m=0.0, base=base)
    tags = {r: i for i, r in enumerate(ROBOTS, start=1)}  # the fleet file's
    calibration = conf / "camera.toml"
    write(rendered_calibration(RenderSettings(camera), tags, TAG_SIZE_M), calibration)
    words = [*camera_args(camera, max_fps=CAMERA_FPS), "--truth-endpoint", TRUTH_ENDPOINT]
    assert words[:2] == ["--source", "rendered"]
    env = conf / "camera.env"
    env.write_text(f"CAMERA_SOURCE={' '.join(words[1:])}\n")
    return calibration, words[1:]


def camera_unit_command(
    source: list[str], substitutions: dict[str, str]
) -> tuple[list[str], dict[str, str]]:
    """deploy/systemd/formation-camera.service's ExecStart and Environment= with only the paths
    substituted: ``${CAMERA_SOURCE}`` expands to ``source`` (systemd splits ``${VAR}`` at
    whitespace), the installed ``formation`` is this interpreter's ``-m formation``."""
    unit = (DEPLOY / "systemd" / "formation-camera.service").read_text()
    lines = unit.splitlines()
    exec_start = [ln.removeprefix("ExecStart=") for ln in lines if ln.startswith("ExecStart=")]
    assert len(exec_start) == 1, exec_start
    env = dict(
        ln.removeprefix("Environment=").split("=", 1)
        for ln in lines
        if ln.startswith("Environment=")
    )
    words = exec_start[0].split()
    assert words[0] == "/opt/formation/venv/bin/formation", words
    argv: list[str] = []
    for word in words[1:]:
        if word == "${CAMERA_SOURCE}":
            argv += source
        else:
            argv.append(substitutions.pop(word, word))
    assert not substitutions, f"not in the unit's command line: {substitutions}"
    assert not any("/etc/formation" in w for w in argv), argv
    return argv, env


def cpu_seconds(pid: int) -> float:
    """User + system CPU time of ``pid`` so far (s), from /proc (``ip netns exec`` execs the
    command, so a child's pid is the process itself)."""
    raw = Path(f"/proc/{pid}/stat").read_text()
    fields = raw[raw.rfind(")") + 2 :].split()  # fields from the 3rd (state) on
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def in_ns(
    spawn: Spawner, ns: str, *argv: str, ready: str | None = None, env: dict[str, str] | None = None
) -> Child:
    return spawn.command(
        ["ip", "netns", "exec", ns, sys.executable, *argv], ready=ready, env=env, timeout_s=READY_S
    )


def formation_in_ns(
    ns: str, *args: str, timeout_s: float = 30.0
) -> subprocess.CompletedProcess[str]:
    from support.spawn import child_env

    return subprocess.run(
        ["ip", "netns", "exec", ns, sys.executable, "-m", "formation", *args],
        cwd=REPO_ROOT, env=child_env(), capture_output=True, text=True, timeout=timeout_s,
    )  # fmt: skip
