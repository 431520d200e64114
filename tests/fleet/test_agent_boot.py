"""The agent's boot order with real processes (docs/deploy.md, formation-agent@.service):

motor backend open and held at zero first (the RoboClaw's own serial timeout armed), then READY
to systemd, then Zenoh in the background with a log line saying where; SIGTERM/SIGINT honoured
within 1 s also while the router is unreachable; WATCHDOG only from the loop that commands the
wheels; a missing serial port is an error naming it.

The motor is the packet-serial emulator (robot_agent/motors/emulator.py) on a pty; systemd is a
datagram socket of the test passed as $NOTIFY_SOCKET.
"""

from __future__ import annotations

import json
import os
import signal
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from support.notify_socket import FakeSystemd
from support.routers import ROUTER_READY
from support.spawn import Spawner, free_port

from robot_agent.motors.emulator import RoboClawEmulator

pytestmark = [pytest.mark.slow, pytest.mark.zenoh]

EXIT_BOUND_S = 1.5  # requirement: exit within 1 s of the signal; margin for a loaded machine


@pytest.fixture
def systemd(tmp_path: Path) -> Iterator[FakeSystemd]:
    fake = FakeSystemd(tmp_path / "notify.sock")
    try:
        yield fake
    finally:
        fake.close()


@pytest.fixture
def emulator() -> Iterator[RoboClawEmulator]:
    with RoboClawEmulator() as emu:
        yield emu


def write_config(tmp_path: Path, port: str, zenoh_port: int) -> Path:
    """A robot config like the shipped one: a Zenoh config file that retries forever
    (``timeout_ms: -1``, as deploy/zenoh/robot-mtls.json5, without TLS) and a RoboClaw."""
    zconf = tmp_path / "robot.json5"
    conf = {
        "mode": "client",
        "connect": {
            "endpoints": [f"tcp/127.0.0.1:{zenoh_port}"],
            "timeout_ms": -1,
            "exit_on_failure": False,
            "retry": {"period_init_ms": 100, "period_max_ms": 500, "period_increase_factor": 2},
        },
        "scouting": {"multicast": {"enabled": False}},
        "transport": {"link": {"tx": {"lease": 700, "keep_alive": 4}}},
    }
    zconf.write_text(json.dumps(conf))
    path = tmp_path / "r1.toml"
    path.write_text(
        'robot_id = "r1"\n'
        f'[zenoh]\nconfig_file = "{zconf}"\n'
        f'[motor]\nbackend = "roboclaw"\nport = "{port}"\nmode = "duty"\n'
        "serial_timeout_s = 0.5\n"
    )
    return path


def wait_stderr(child: object, fragment: str, timeout_s: float = 15.0) -> str:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        for line in child.stderr().splitlines():  # type: ignore[attr-defined]
            if fragment in line:
                return str(line)
        if child.proc.poll() is not None:  # type: ignore[attr-defined]
            break
        time.sleep(0.01)
    raise AssertionError(f"no {fragment!r} on stderr: {child.describe()}")  # type: ignore[attr-defined]


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_router_unreachable_motors_held_ready_sent_and_stop_honoured(
    spawn: Spawner,
    tmp_path: Path,
    systemd: FakeSystemd,
    emulator: RoboClawEmulator,
    sig: int,
) -> None:
    zport = free_port()  # nobody listens there
    agent = spawn("agent", "--config", str(write_config(tmp_path, emulator.port, zport)),
                  env=systemd.env())  # fmt: skip
    line = wait_stderr(agent, "connecting to Zenoh at")
    assert f"tcp/127.0.0.1:{zport}" in line, line
    ready_t = systemd.wait("READY=1")
    # The motors were opened and commanded zero before READY: serial timeout armed (5 tenths)
    # and every drive command received is zero.
    assert emulator.serial_timeout_tenths == 5
    assert emulator.drives, "no drive command before READY"
    assert emulator.drives[0].t <= ready_t
    assert all(d.m1 == 0 and d.m2 == 0 for d in emulator.drives)
    time.sleep(1.0)
    # The hold-zero loop keeps commanding the wheels and pets the watchdog (period 0.2 s).
    pings = [t for t in systemd.times("WATCHDOG=1") if t >= ready_t]
    assert len(pings) >= 3, systemd.messages
    assert emulator.timeout_stops == 0  # the controller never had to time out
    assert agent.proc.poll() is None
    elapsed = agent.stop(sig, timeout_s=3.0)
    assert elapsed < EXIT_BOUND_S, (elapsed, agent.describe())
    assert agent.proc.returncode == 0, agent.describe()
    assert "agent r1 ready" not in agent.stdout()


def test_connects_when_the_router_comes_up_then_stops_within_a_second(
    spawn: Spawner, tmp_path: Path, systemd: FakeSystemd, emulator: RoboClawEmulator
) -> None:
    zport = free_port()
    agent = spawn("agent", "--config", str(write_config(tmp_path, emulator.port, zport)),
                  env=systemd.env())  # fmt: skip
    systemd.wait("READY=1")
    time.sleep(0.5)
    assert "agent r1 ready" not in agent.stdout()
    spawn("router", "--listen", f"tcp/127.0.0.1:{zport}", ready=ROUTER_READY)
    agent.wait_for_line("agent r1 ready", timeout_s=15.0)
    wait_stderr(agent, "connected to Zenoh at")
    connected_t = time.monotonic()
    time.sleep(0.8)
    assert len([t for t in systemd.times("WATCHDOG=1") if t >= connected_t]) >= 2
    # Without setpoints the firmware holds the wheels at zero.
    assert all(d.m1 == 0 and d.m2 == 0 for d in emulator.drives)
    elapsed = agent.stop(signal.SIGTERM, timeout_s=3.0)
    assert elapsed < EXIT_BOUND_S, (elapsed, agent.describe())
    assert agent.proc.returncode == 0, agent.describe()
    systemd.wait("STOPPING=1", timeout_s=5.0)  # sent before the exit; the reader may lag


def test_missing_serial_port_is_an_error_naming_it(
    spawn: Spawner, tmp_path: Path, systemd: FakeSystemd
) -> None:
    missing = tmp_path / "ttyNOPE"
    agent = spawn("agent", "--config", str(write_config(tmp_path, str(missing), free_port())),
                  env=systemd.env())  # fmt: skip
    agent.proc.wait(timeout=15.0)
    assert agent.proc.returncode == 69, agent.describe()
    assert f"serial port {missing} does not exist" in agent.stderr(), agent.describe()
    assert not systemd.times("READY=1")  # never READY without motors at zero


def test_motor_emulator_command(spawn: Spawner, tmp_path: Path) -> None:
    """``formation motor-emulator --link PATH``: a RoboClaw the backend opens by that path."""
    from robot_agent.motors.roboclaw import RoboClawBackend
    from robot_agent.motors.roboclaw_config import RoboClawConfig

    link = tmp_path / "roboclaw"
    emu = spawn("motor-emulator", "--link", str(link), ready="roboclaw emulator at address 0x80")
    assert link.is_symlink() and os.readlink(link).startswith("/dev/pts/")
    backend = RoboClawBackend(RoboClawConfig(port=str(link), mode="duty"), 10.0)
    try:
        # a loaded machine may delay the emulator's answer past the ack timeout: retry
        deadline = time.monotonic() + 5.0
        while not backend.open() and time.monotonic() < deadline:
            time.sleep(0.1)
        assert backend.open(), backend.status().last_error
        while not backend.apply(5.0, 5.0, time.monotonic()) and time.monotonic() < deadline:
            time.sleep(0.1)
        line = emu.wait_for_line("mode duty m1 ", timeout_s=5.0)
        assert int(line.split()[3]) > 0, line
    finally:
        backend.close()
    elapsed = emu.stop(signal.SIGTERM, timeout_s=3.0)
    assert elapsed < EXIT_BOUND_S and emu.proc.returncode == 0, emu.describe()
    assert not link.exists() and not link.is_symlink()


def test_missing_extra_names_the_extra(spawn: Spawner) -> None:
    """`formation record` in a robot venv (no mcap): the message names the extra to install."""
    from formation.cli import missing_extra_message

    code = (
        "import sys; sys.modules['mcap'] = None; from formation.cli import main; "
        "sys.exit(main(['record', '--out', 'x.mcap']))"
    )
    child = spawn.python(code)
    child.proc.wait(timeout=30.0)
    assert child.proc.returncode == 2, child.describe()
    assert "formation record: needs the sim extra" in child.stderr(), child.describe()
    assert "pip install 'formation-control[sim]'" in child.stderr()
    assert "camera extra" in missing_extra_message(ModuleNotFoundError("x", name="cv2"))
    assert "not available" in missing_extra_message(ModuleNotFoundError("x", name="nothing"))


def test_router_and_coordinator_notify_systemd(spawn: Spawner, tmp_path: Path) -> None:
    """The coordinator host's units are Type=notify with a watchdog: READY when ready,
    WATCHDOG from the event loop, STOPPING at SIGTERM (the router and a coordinator here)."""
    fleet = Path(__file__).resolve().parents[2] / "deploy" / "config" / "fleet.example.toml"
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    fakes = {name: FakeSystemd(tmp_path / f"{name}.sock") for name in ("router", "coord")}
    try:
        router = spawn("router", "--listen", endpoint, env=fakes["router"].env(),
                       ready=ROUTER_READY)  # fmt: skip
        coord = spawn("coordinator", "--fleet-file", str(fleet), "--endpoint", endpoint,
                      env=fakes["coord"].env(), ready="coordinator ready")  # fmt: skip
        for fake in fakes.values():
            ready_t = fake.wait("READY=1")
            time.sleep(0.1)
            fake.wait("WATCHDOG=1")
            time.sleep(0.6)
            assert len([t for t in fake.times("WATCHDOG=1") if t >= ready_t]) >= 2
        for child, fake in ((coord, fakes["coord"]), (router, fakes["router"])):
            assert child.stop(signal.SIGTERM, timeout_s=3.0) < EXIT_BOUND_S, child.describe()
            assert child.proc.returncode == 0, child.describe()
            # the child has exited: its STOPPING=1, if sent, is in the socket's buffer; the
            # reader thread of this (possibly starved) process may not have taken it yet
            fake.wait("STOPPING=1", timeout_s=5.0)
    finally:
        for fake in fakes.values():
            fake.close()
