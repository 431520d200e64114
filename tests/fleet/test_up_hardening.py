"""Issue 13 from outside, against real ``formation up`` runs: authenticated runs refuse spoofing,
the fault tool signals only what it verified, children die with a SIGKILLed launcher, and a
router or plant death is an event of the run.

Every run is a real subprocess tree on a free loopback port; attackers are plain Zenoh clients
in this process (no certificate, another CA's, or a valid certificate of the wrong identity).
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from support.spawn import Child, Spawner, child_env, free_port

import runtime as rt
from bus_schemas import Disturbance, Estop, Pose, Setpoint, Status, decode, encode, keys
from formation.cli import EXIT_INTERRUPTED
from formation.outputs import runfile

pytestmark = [pytest.mark.slow, pytest.mark.zenoh, pytest.mark.shares_cpu]

UP_READY_S = 90.0  # python start of ~8 processes on a loaded 2-core box


def stop_ups(started: list[Child]) -> None:
    """SIGTERM every launcher still running and give each 20 s to write its results."""
    for up in started:
        if up.proc.poll() is None:
            up.send_signal(signal.SIGTERM)
    for up in started:
        try:
            up.proc.wait(20)
        except subprocess.TimeoutExpired:
            up.send_signal(signal.SIGKILL)
            pytest.fail(f"formation up ignored SIGTERM for 20 s: {up.describe()}")


@pytest.fixture
def ups(spawn: Spawner) -> Iterator[list[Child]]:
    """Launchers started by a test: SIGTERMed at teardown with time to write their results
    (torn down before ``spawn``, whose 2 s SIGTERM patience is for nodes)."""
    started: list[Child] = []
    yield started
    stop_ups(started)


def launch_up(
    spawn: Spawner,
    out: Path,
    *extra: str,
    robots: int = 3,
    duration: float = 120.0,
    ups: list[Child] | None = None,
) -> tuple[Child, int]:
    """Start ``formation up`` (realtime) on a free port; :func:`wait_ready` waits for it."""
    port = free_port()
    child = spawn(
        "up", "--robots", str(robots), "--duration", repr(duration),
        "--endpoint", f"tcp/127.0.0.1:{port}", "--out", str(out), "--no-figures",
        "--ready-timeout", "80", *extra,
    )  # fmt: skip
    if ups is not None:
        ups.append(child)
    return child, port


def wait_ready(child: Child, robots: int = 3, hosts: int | None = None) -> None:
    """Wait until every node of ``child``'s run is ready (its agents' or agent hosts' line)."""
    n = robots if hosts is None else hosts
    child.wait_for_line(f"  {n} agent" + (" hosts" if hosts else "s"), timeout_s=UP_READY_S)


def start_up(
    spawn: Spawner,
    out: Path,
    *extra: str,
    robots: int = 3,
    duration: float = 120.0,
    ups: list[Child] | None = None,
) -> tuple[Child, int]:
    """``formation up`` (realtime) on a free port, returned once every node is ready."""
    child, port = launch_up(spawn, out, *extra, robots=robots, duration=duration, ups=ups)
    hosts = [a for i, a in enumerate(extra) if i > 0 and extra[i - 1] == "--hosts"]
    wait_ready(child, robots, int(hosts[0]) if hosts else None)
    return child, port


def run_info(port: int) -> runfile.RunInfo:
    info = runfile.lookup(port)
    assert info is not None, f"no run file for port {port}"
    return info


def fault_command(*args: str) -> list[str]:
    return [sys.executable, "-m", "formation", "fault", *args]


def fault(*args: str, timeout_s: float = 30.0) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        fault_command(*args), capture_output=True, text=True, timeout=timeout_s, env=child_env()
    )


def faults_at_once(
    *calls: tuple[str, ...], timeout_s: float = 30.0
) -> list[subprocess.CompletedProcess[str]]:
    """``formation fault`` with each of ``calls``' arguments, all running at the same time (calls
    that change nothing, so their order does not matter); their results in ``calls``' order."""
    procs = [
        subprocess.Popen(
            fault_command(*args),
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            env=child_env(),
        )
        for args in calls
    ]
    results = []
    for proc in procs:
        out, err = proc.communicate(timeout=timeout_s)
        results.append(subprocess.CompletedProcess(proc.args, proc.returncode, out, err))
    return results


def state(pid: int) -> str | None:
    """/proc state letter of the first of ``pid``'s threads still running (None: gone, or every
    thread a zombie). A killed process's main thread shows ``Z`` while its other threads may
    still be exiting, and the last of them to exit is the one that closes its sockets: a
    process is gone only when all of its threads are."""
    try:
        tasks = os.listdir(f"/proc/{pid}/task")
    except OSError:
        return None
    for task in tasks:
        try:
            raw = Path(f"/proc/{pid}/task/{task}/stat").read_text()
        except OSError:
            continue
        letter = raw[raw.rfind(")") + 2 :].split()[0]
        if letter not in ("Z", "X"):
            return letter
    return None


def port_is_free(port: int) -> bool:
    """A new router could listen on ``port`` (SO_REUSEADDR, as servers do: connections of the
    dead run left in TIME_WAIT do not count; a listening socket does)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind(("127.0.0.1", port))
            s.listen()
        except OSError:
            return False
    return True


def holders(port: int) -> str:
    """The lines of /proc/net/tcp whose local port is ``port`` (state in hex: 0A listening,
    06 TIME_WAIT), for a failure's message."""
    rows = Path("/proc/net/tcp").read_text().splitlines()[1:]
    mine = [r for r in rows if int(r.split()[1].split(":")[1], 16) == port]
    return "\n".join(mine) or "(no socket on it in /proc/net/tcp)"


def children_of(pid: int) -> set[int]:
    out = set()
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                raw = Path(f"/proc/{entry}/stat").read_text()
            except OSError:
                continue
            if int(raw[raw.rfind(")") + 2 :].split()[1]) == pid:
                out.add(int(entry))
    return out


class Publisher:
    """Publish ``payload`` on ``key`` every 50 ms from a thread until stopped."""

    def __init__(self, session: Any, key: str, payload: bytes) -> None:
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, args=(session, key, payload), daemon=True)
        self._thread.start()

    def _run(self, session: Any, key: str, payload: bytes) -> None:
        while not self._stop.is_set():
            session.put(key, payload)
            self._stop.wait(0.05)

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(2.0)


# ---------------------------------------------------------------------------------------------
# Children never outlive the launcher (deliver 5)
# ---------------------------------------------------------------------------------------------


@pytest.mark.alone
def test_sigkill_of_the_launcher_leaves_no_process_and_frees_the_port(
    spawn: Spawner, ups: list[Child], tmp_path: Path
) -> None:
    up, port = start_up(spawn, tmp_path / "run", "--secure", robots=3, ups=ups)
    kids = children_of(up.pid)
    assert len(kids) >= 5, kids  # router, plant, coordinator, 3 agents
    paused = next(p for p in kids if "agent" in Path(f"/proc/{p}/cmdline").read_text())
    os.kill(paused, signal.SIGSTOP)  # a hung child must go too
    up.send_signal(signal.SIGKILL)
    up.proc.wait(5)
    deadline = time.monotonic() + 2.0  # every child gone within 2 s: polled, not slept out
    while (alive := {p: s for p in kids if (s := state(p)) is not None}) and (
        time.monotonic() < deadline
    ):
        time.sleep(0.05)
    assert not alive, f"children still running 2 s after the launcher's SIGKILL: {alive}"
    while not (free := port_is_free(port)) and time.monotonic() < deadline:
        time.sleep(0.05)  # a socket is closed by the kernel as its last thread exits
    assert free, f"port {port} still held 2 s after the launcher's SIGKILL:\n{holders(port)}"
    assert runfile.lookup(port) is None  # the stale run file is ignored (and removed)


# ---------------------------------------------------------------------------------------------
# Router and plant deaths are events (deliver 9)
# ---------------------------------------------------------------------------------------------


def wait_for_line_after(child: Child, marker: str, prefix: str, timeout_s: float) -> str:
    """Wait for a stdout line of ``child`` starting with ``prefix`` after its line ``marker``."""
    deadline = time.monotonic() + timeout_s
    while True:
        lines = child.stdout().splitlines()
        at = next((i for i, line in enumerate(lines) if line.startswith(marker)), None)
        found = [] if at is None else [x for x in lines[at + 1 :] if x.startswith(prefix)]
        if found:
            return found[0]
        assert child.proc.poll() is None, f"exited before {prefix!r}: {child.describe()}"
        assert time.monotonic() < deadline, f"no {prefix!r} after {marker!r}: {child.describe()}"
        time.sleep(0.05)


def test_router_and_plant_deaths_are_events_with_respawn(
    spawn: Spawner, ups: list[Child], tmp_path: Path
) -> None:
    out = tmp_path / "run"
    up, port = start_up(spawn, out, "--respawn", "0.3", robots=3, duration=30.0, ups=ups)
    time.sleep(2.0)
    os.kill(run_info(port).children["router"], signal.SIGKILL)
    up.wait_for_line("formation up: router respawned", timeout_s=30)
    time.sleep(2.0)
    os.kill(run_info(port).children["plant"], signal.SIGKILL)
    up.wait_for_line("formation up: plant respawned", timeout_s=30)
    # the run goes on after both restarts: a progress line after the plant's respawn (one every
    # 5 s of the run); then a stop signal instead of the rest of the 30 s (status 130 after a
    # stop, 1 after any failure of the run)
    wait_for_line_after(up, "formation up: plant respawned", "t ", timeout_s=30)
    up.send_signal(signal.SIGTERM)
    assert up.proc.wait(60) == EXIT_INTERRUPTED, up.describe()
    import json

    meta = json.loads((out / "metrics.json").read_text())["meta"]
    events = [e["event"] for e in meta["events"]]
    for what in ("router (pid", "plant (pid"):
        assert any(e.startswith(what) and "SIGKILL" in e for e in events), events
    assert any(e.startswith("router respawned") for e in events), events
    assert any(e.startswith("plant respawned") for e in events), events
    assert meta["failures"] == []
    # the run continued: status of every robot after the restarts (the nodes survived them)
    assert "exited with status" not in up.stderr()


# ---------------------------------------------------------------------------------------------
# Authenticated runs (deliver 1, 10)
# ---------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def secure_run(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[Child, int]]:
    """One authenticated run for the module's two tests: each only tries to get in and is
    refused (the operator's e-stop of the second is released), so the run they see is the
    same as a fresh one's."""
    base = tmp_path_factory.mktemp("secure")
    spawner = Spawner(base / "procs")
    started: list[Child] = []
    try:
        yield start_up(spawner, base / "run", "--secure", robots=3, duration=120.0, ups=started)
    finally:
        stop_ups(started)
        problems = spawner.cleanup()
    if problems:
        pytest.fail("\n\n".join(problems), pytrace=False)


def test_secure_run_refuses_clients_without_the_fleet_certificate(
    secure_run: tuple[Child, int], tmp_path: Path
) -> None:
    _, port = secure_run
    with pytest.raises(rt.TransportError):  # plain TCP: nothing listens there but TLS
        rt.open_session(rt.ZenohSettings(connect=(f"tcp/127.0.0.1:{port}",), open_timeout_s=1))
    from bus_schemas import acl
    from formation.launch import pki

    # a certificate of the right name from another CA
    other = pki.write_run_configs(tmp_path / "other", [acl.robot("r1")], port=port)
    with pytest.raises(rt.TransportError):
        rt.open_session(
            rt.ZenohSettings(
                connect=(),
                mode=None,
                config_file=str(other.clients["robot.r1"]),
                open_timeout_s=1,
            )
        )


def test_secure_run_refuses_forged_setpoints_poses_and_estop(
    secure_run: tuple[Child, int],
) -> None:
    up, port = secure_run
    info = run_info(port)
    assert info.secure and set(info.configs) == {"operator", "observer"}
    conf_dir = Path(info.configs["observer"]).parent
    fleet = info.fleet

    def open_as(cn: str) -> Any:
        return rt.open_session(
            rt.ZenohSettings(connect=(), mode=None, config_file=str(conf_dir / f"{cn}.json5"))
        )

    observer, attacker = open_as("observer"), open_as("robot.r2")
    seen: dict[str, list[Any]] = {"forged": [], "status": []}
    marker_t = 4242.4242

    def on_any(sample: Any) -> None:
        payload = sample.payload.to_bytes()
        key = str(sample.key_expr)
        if key.endswith("/status") and "/robot/" in key:
            msg = decode(payload, Status)
            if isinstance(msg, Status):
                seen["status"].append((time.monotonic(), key.split("/")[-2], msg.mode))
            return
        kinds: tuple[Any, ...] = (Estop, Setpoint, Pose, Disturbance)
        for kind in kinds:
            msg = decode(payload, kind)
            if isinstance(msg, kind) and abs(msg.t - marker_t) < 1e-6:
                seen["forged"].append((key, msg))

    sub = observer.declare_subscriber(keys.fleet_pattern(fleet), on_any)
    try:
        deadline = time.monotonic() + 10.0
        while not seen["status"] and time.monotonic() < deadline:
            time.sleep(0.05)
        assert seen["status"], "the observer identity receives the fleet's status"
        forged: list[tuple[str, Any]] = [
            (keys.estop_key(fleet), Estop(t=marker_t, engage=True, robot=None)),
            (
                keys.setpoint_key(fleet, "r1"),
                Setpoint(
                    t=marker_t,
                    seq=1,
                    robot="r1",
                    slot=0,
                    role="leader",
                    stage=0,
                    parent=None,
                    x=5.0,
                    y=5.0,
                    theta=0.0,
                    vx=0.5,
                    vy=0.5,
                ),
            ),
            (keys.pose_key(fleet, "r1"), Pose(t=marker_t, seq=1, x=-3.0, y=2.0, theta=1.0)),
            (
                keys.disturbance_key(fleet),
                Disturbance(t=marker_t, robot="r1", kind="drag", dx=1.0, dy=1.0, duration_s=1.0),
            ),
        ]
        t0 = time.monotonic()
        pubs = [Publisher(attacker, k, encode(m)) for k, m in forged]
        time.sleep(3.0)
        for p in pubs:
            p.stop()
        assert seen["forged"] == [], "a robot identity published keys it may not"
        after = [mode for t, _, mode in seen["status"] if t > t0]
        assert after and "estop" not in after, after
        # positive control: the operator (found by the tool from the run file) can e-stop
        res = fault("estop", "--endpoint", f"tcp/127.0.0.1:{port}")
        assert res.returncode == 0, res.stderr
        t1 = time.monotonic()
        deadline = t1 + 5.0
        while time.monotonic() < deadline:
            stopped = {r for t, r, mode in seen["status"] if t > t1 and mode == "estop"}
            if stopped == {"r1", "r2", "r3"}:
                break
            time.sleep(0.1)
        assert stopped == {"r1", "r2", "r3"}, seen["status"][-6:]
        res = fault("release", "--endpoint", f"tcp/127.0.0.1:{port}")
        assert res.returncode == 0, res.stderr
    finally:
        sub.undeclare()
        observer.close()
        attacker.close()
    assert up.proc.poll() is None, up.describe()


# ---------------------------------------------------------------------------------------------
# The fault tool signals only what it verified (deliver 3)
# ---------------------------------------------------------------------------------------------


def test_fault_tool_never_touches_another_fleet_and_refuses_forged_status(
    spawn: Spawner, ups: list[Child], tmp_path: Path
) -> None:
    (up_a, port_a), (up_b, port_b) = (
        launch_up(spawn, tmp_path / name, robots=3, ups=ups) for name in ("a", "b")
    )  # both fleets start at once
    wait_ready(up_a)
    wait_ready(up_b)
    ep_a = f"tcp/127.0.0.1:{port_a}"
    a, b = run_info(port_a), run_info(port_b)
    b_pids = dict(b.children)
    assert a.children["agent-r2"] != b_pids["agent-r2"]

    def b_untouched() -> None:
        for name, pid in b_pids.items():
            assert state(pid) not in (None, "T", "t"), f"fleet B's {name} (pid {pid}) was hit"

    # an unknown robot: one line, status 1; `drag` of it too
    unknown = (("kill", "r9"), ("pause", "r9"), ("drag", "r9", "0.1", "0"))
    *results, res = faults_at_once(
        *((*args, "--endpoint", ep_a, "--timeout", "1.5") for args in unknown),
        ("resume", "r9", "--endpoint", ep_a),
    )
    for args, one in zip(unknown, results, strict=True):
        assert one.returncode == 1, (args, one)
        assert len(one.stderr.strip().splitlines()) == 1 and "r9" in one.stderr, one.stderr
    assert res.returncode == 1 and "no paused agent r9" in res.stderr, res.stderr

    # pause A's r2 (verified: its status and its command line), options after the command
    a2 = a.children["agent-r2"]
    res = fault("pause", "r2", "--endpoint", ep_a)
    assert res.returncode == 0, res.stderr
    assert f"paused r2 (pid {a2})" in res.stdout
    time.sleep(0.2)
    assert state(a2) in ("T", "t")
    b_untouched()

    # A's r2 is silent: a forged status of r2 on A naming B's r2 (a genuine `formation agent
    # --id r2` of the same fleet name, on another router), then an unrelated process: refused
    bystander = subprocess.Popen(["sleep", "60"])
    forger = rt.open_session(rt.ZenohSettings(connect=(ep_a,)))
    try:
        for victim in (b_pids["agent-r2"], bystander.pid):
            st = Status(
                t=time.monotonic(), seq=1, mode="tracking", slot=None, pid=victim,
                host=socket.gethostname(), rejected=0,
            )  # fmt: skip
            pub = Publisher(forger, keys.status_key(a.fleet, "r2"), encode(st))
            try:
                # kill and pause refused; resume too: a robot that publishes status is not paused
                *refused, res = faults_at_once(
                    *((cmd, "r2", "--endpoint", ep_a) for cmd in ("kill", "pause", "resume"))
                )
                for one in refused:
                    assert one.returncode == 1, one
                    assert "refused" in one.stderr and str(victim) in one.stderr, one.stderr
                assert res.returncode == 1 and "publishing status" in res.stderr, res.stderr
            finally:
                pub.stop()
            b_untouched()
            assert bystander.poll() is None
            assert state(a2) in ("T", "t")
    finally:
        forger.close()
        bystander.kill()
        bystander.wait()

    # resume r2 of A (options before the command): only A's r2 was stopped, only it resumes
    res = fault("--endpoint", ep_a, "resume", "r2")
    assert res.returncode == 0, res.stderr
    assert f"resumed r2 (pid {a2})" in res.stdout
    time.sleep(0.2)
    assert state(a2) not in (None, "T", "t")
    b_untouched()

    # kill r3 of A: A's r3 dies, B's r3 lives
    a3 = a.children["agent-r3"]
    res = fault("kill", "r3", "--fleet", a.fleet, "--endpoint", ep_a)
    assert res.returncode == 0, res.stderr
    assert f"killed r3 (pid {a3})" in res.stdout
    time.sleep(0.3)
    assert state(a3) is None
    b_untouched()
    assert up_a.proc.poll() is None and up_b.proc.poll() is None


def test_fault_tool_on_an_agent_host_fleet(
    spawn: Spawner, ups: list[Child], tmp_path: Path
) -> None:
    up, port = start_up(spawn, tmp_path / "h", "--hosts", "1", robots=3, ups=ups)
    ep = f"tcp/127.0.0.1:{port}"
    host_pid = run_info(port).children["agent-host-h1"]
    res = fault("kill", "r2", "--endpoint", ep)
    assert res.returncode == 1
    assert "agent host h1" in res.stderr and "kill-host h1" in res.stderr, res.stderr
    res = fault("kill-leader", "--endpoint", ep)
    assert res.returncode == 1 and "agent host h1" in res.stderr, res.stderr
    assert state(host_pid) is not None
    res = fault("pause-host", "h1", "--endpoint", ep)
    assert res.returncode == 0 and f"(pid {host_pid})" in res.stdout, res.stderr
    time.sleep(0.2)
    assert state(host_pid) in ("T", "t")
    res = fault("resume-host", "h1", "--endpoint", ep)
    assert res.returncode == 0, res.stderr
    res = fault("kill-host", "h1", "--endpoint", ep)
    assert res.returncode == 0 and f"(pid {host_pid})" in res.stdout, res.stderr
    time.sleep(0.3)
    assert state(host_pid) is None
    assert up.proc.poll() is None  # the run goes on (an agent host's death is an event)
