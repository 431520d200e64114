"""The shipped deployment on separate hosts (issue 17 item 2): network namespaces joined by veth.

Topology (pid-tagged names, deleted at teardown)::

    ns hub: the coordinator host                       ns 1, 2, 3: one robot host each
      formation router   (router-mtls.json5)  <-veth->   formation agent --config rN.toml
      coordinator main   (coordinator-main-mtls)          (robot-mtls.json5, motor backend
      coordinator standby (coordinator-standby-mtls)       roboclaw on the emulator's pty)
      formation camera   (localization-mtls.json5,
                          the shipped unit's command line)
      world: motor emulators + kinematics, the truth
             on its own loopback session (the light)
      operator tools: top, fault, record (operator-mtls.json5)
    root ns: this test's observer (observer-mtls.json5) over one more veth to the hub

Every Zenoh config is the file shipped in deploy/zenoh/ with only the certificate directory and
the router address substituted; the robot configs are deploy/config/r1.example.toml with only
the id, paths and address substituted; the certificates come from ``formation certs``; the
coordinators read a fleet file (``--fleet-file``, deploy/config/fleet.example.toml with a
faster line). The camera is the real tracker on rendered frames: the ExecStart of
deploy/systemd/formation-camera.service with only its paths substituted and ``CAMERA_SOURCE``
(the unit's environment file) set to ``rendered`` with the render options (systemd splits
``${CAMERA_SOURCE}`` into words the same way): 640x360 frames of a straight-down camera over the
robots' path, at most 15 fps, 10 cm tags, the truth read from the world's loopback session
(``--truth-endpoint``). The camera used ~12 % of one core over a run, its start included (the
test prints it; bench/bench_render_size.py has the per-frame figures), light enough next to ten
processes on 2 cores. The world compares every pose the camera published with the truth instant
it was rendered from.

The test forms the fleet, kills the active coordinator with ``formation fault kill-coordinator``
run with the operator certificate (the standby continues the trajectory: no jump back of the
virtual leader, no robot moves backwards), cuts robot host 3's link (the fleet re-forms with r1
and r2), checks the formation is kept with neighbour positions arriving at every agent, runs
``formation top`` and ``formation record`` with the operator certificate, and stops everything
with SIGTERM (exit 0 within 2 s).

Skipped unless root with ``ip`` and permission to create network namespaces. The namespaces
and the installation (shipped files with paths substituted) are made by
tests/support/deploy_hosts.py;
the world by tests/support/deploy_world.py.
"""

from __future__ import annotations

import contextlib
import math
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from support.deploy_hosts import (
    CAMERA_SIZE,
    DEPLOY,
    READY_S,
    ROBOTS,
    TRUTH_ENDPOINT,
    Net,
    camera_files,
    camera_unit_command,
    cpu_seconds,
    fleet_file,
    formation_in_ns,
    hub_and_hosts,
    in_ns,
    robot_config,
    shipped_zenoh,
)
from support.netns import ip
from support.spawn import REPO_ROOT, Spawner

import runtime as rt
from bus_schemas import (
    Assignment,
    DecodeError,
    Heartbeat,
    Leader,
    PoseBatch,
    Status,
    decode,
    keys,
)

pytestmark = [pytest.mark.slow, pytest.mark.zenoh]

FLEET = "demo"  # the fleet the shipped router ACL is generated for
# start poses near a triangle behind the line's origin (x0 = -0.6)
INITIAL = {"r1": (-0.55, 0.0, 0.0), "r2": (-0.95, 0.22, 0.0), "r3": (-0.95, -0.22, 0.0)}
FORM_BOUND_S = 30.0
TAKEOVER_BOUND_S = 4.0
DROP_BOUND_S = 4.0
EXIT_BOUND_S = 2.0
BACKWARDS_TOL_M = 0.03
POSE_MEDIAN_MM = 2.0  # the camera's poses against the truth they were rendered from
POSE_MAX_MM = 10.0


@pytest.fixture
def net() -> Iterator[Net]:
    with hub_and_hosts(ROBOTS) as network:
        yield network


# ---------------------------------------------------------------------------------------------
# The observer (root namespace, observer certificate)
# ---------------------------------------------------------------------------------------------


class Observer:
    """Everything of the fleet this observer receives: (rx_s, name, message)."""

    def __init__(self, zenoh_file: Path) -> None:
        self.session = rt.open_session(
            rt.ZenohSettings(connect=(), mode=None, config_file=str(zenoh_file)), timeout_s=15.0
        )
        self.lock = threading.Lock()
        self.poses: list[tuple[float, PoseBatch]] = []
        self.status: list[tuple[float, Status]] = []
        self.assignments: list[tuple[float, Assignment]] = []
        self.leader: list[tuple[float, Leader]] = []
        self.heartbeats: list[tuple[float, Heartbeat]] = []
        prefix = f"{keys.ROOT}/{FLEET}/"
        decoders: dict[str, tuple[type, list[Any]]] = {
            "poses": (PoseBatch, self.poses),
            "assignment": (Assignment, self.assignments),
            "leader": (Leader, self.leader),
        }

        def on(sample: Any) -> None:
            key = str(sample.key_expr)[len(prefix) :]
            if key in decoders:
                cls, out = decoders[key]
            elif key.startswith("robot/") and key.endswith("/status"):
                cls, out = Status, self.status
            elif key.startswith("coordinator/") and key.endswith("/heartbeat"):
                cls, out = Heartbeat, self.heartbeats
            else:
                return
            msg = decode(sample.payload.to_bytes(), cls)
            if not isinstance(msg, DecodeError):
                with self.lock:
                    out.append((time.monotonic(), msg))

        self.sub = self.session.declare_subscriber(keys.fleet_pattern(FLEET), on)

    def close(self) -> None:
        self.session.close()

    def since(self, items: list[tuple[float, Any]], t0: float) -> list[tuple[float, Any]]:
        with self.lock:
            return [(t, m) for t, m in items if t >= t0]

    def latest_status(self, robot: str, t0: float) -> Status | None:
        st = [m for _, m in self.since(self.status, t0) if m.robot == robot]
        return st[-1] if st else None

    def latest_assignment(self, t0: float = 0.0) -> Assignment | None:
        a = self.since(self.assignments, t0)
        return a[-1][1] if a else None

    def positions(self, t0: float, t1: float = math.inf) -> dict[str, list[tuple[float, float]]]:
        out: dict[str, list[tuple[float, float]]] = {}
        for rx, batch in self.since(self.poses, t0):
            if rx > t1:
                break
            for rid, x in zip(batch.robots, batch.x, strict=True):
                out.setdefault(rid, []).append((rx, x))
        return out


def until(pred: Callable[[], object], timeout_s: float, what: str) -> float:
    start = time.monotonic()
    while time.monotonic() - start < timeout_s:
        if pred():
            return time.monotonic() - start
        time.sleep(0.05)
    raise AssertionError(f"not within {timeout_s} s: {what}")


def tracking(obs: Observer, robots: set[str], t0: float) -> bool:
    a = obs.latest_assignment(t0)
    if a is None or set(a.robots) != robots:
        return False
    for r in robots:
        st = obs.latest_status(r, t0)
        if st is None or st.mode != "tracking" or st.slot != a.robots[r]:
            return False
    return True


def max_error(obs: Observer, robots: set[str], t0: float) -> float:
    errs = [
        math.hypot(m.ex or 0.0, m.ey or 0.0)
        for _, m in obs.since(obs.status, t0)
        if m.robot in robots and m.mode == "tracking"
    ]
    assert errs, f"no tracking status of {robots} since {t0}"
    return max(errs)


# ---------------------------------------------------------------------------------------------
# The test
# ---------------------------------------------------------------------------------------------


def test_shipped_deployment_across_hosts(net: Net, spawn: Spawner, tmp_path: Path) -> None:
    pytest.importorskip("cv2", reason="the camera tracker needs the camera extra (OpenCV)")
    t_start = time.monotonic()
    certs = tmp_path / "certs"
    hosts = ["127.0.0.1", net.observer_addr, *net.hub_addrs.values()]
    made = formation_in_ns(net.hub, "certs", "-o", str(certs), "--robots", ",".join(ROBOTS),
                           *[a for h in hosts for a in ("--router-host", h)])  # fmt: skip
    assert made.returncode == 0, made.stderr
    conf = tmp_path / "etc"
    conf.mkdir()
    local = "127.0.0.1"

    def hub_conf(name: str) -> Path:
        return shipped_zenoh(name, certs, local, conf)

    router_conf = hub_conf("router-mtls.json5")
    router = in_ns(spawn, net.hub, "-m", "formation", "router", "--zenoh-config",
                   str(router_conf), ready="router listening on ")  # fmt: skip

    world = in_ns(
        spawn, net.hub, str(REPO_ROOT / "tests" / "support" / "deploy_world.py"),
        TRUTH_ENDPOINT, str(DEPLOY / "config" / "r1.example.toml"),
        *[f"{r}:{','.join(str(v) for v in INITIAL[r])}" for r in ROBOTS],
        "--observer", str(hub_conf("observer-mtls.json5")),
        ready="world ready",
    )  # fmt: skip
    ports = dict(p.split("=", 1) for p in world.wait_for_line("world ports ").split()[2:])

    fleet = fleet_file(conf)
    # the camera tracker as its unit runs it, on frames rendered from the world's truth
    calibration, source = camera_files(conf)
    camera_argv, camera_env = camera_unit_command(source, {
        "/etc/formation/camera.toml": str(calibration),
        "/etc/formation/fleet.toml": str(fleet),
        "/etc/formation/zenoh/localization-mtls.json5": str(hub_conf("localization-mtls.json5")),
    })  # fmt: skip
    camera = in_ns(spawn, net.hub, "-m", "formation", *camera_argv, env=camera_env)
    camera_started = time.monotonic()
    main = in_ns(spawn, net.hub, "-m", "formation", "coordinator", "--fleet-file", str(fleet),
                 "--name", "main", "--zenoh-config",
                 str(hub_conf("coordinator-main-mtls.json5")))  # fmt: skip
    # the robots' configs, each checked as docs/deploy.md says (in parallel with the starts)
    configs: dict[str, Path] = {}
    checks: dict[str, subprocess.Popen[str]] = {}
    for robot in ROBOTS:
        rdir = tmp_path / robot
        rdir.mkdir()
        addr = net.hub_addrs[robot]
        zfile = shipped_zenoh("robot-mtls.json5", certs / f"robot.{robot}", addr, rdir)
        configs[robot] = robot_config(robot, zfile, addr, ports[robot], rdir)
        checks[robot] = subprocess.Popen(
            [sys.executable, "-m", "formation", "agent", "--check-config", str(configs[robot])],
            cwd=REPO_ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        )  # fmt: skip
    for robot, proc in checks.items():
        out, problems = proc.communicate(timeout=60)
        assert out.strip() == "OK", (robot, out, problems)
    main.wait_for_line("coordinator ready", timeout_s=READY_S)
    standby = in_ns(spawn, net.hub, "-m", "formation", "coordinator", "--fleet-file", str(fleet),
                    "--name", "standby", "--standby", "--zenoh-config",
                    str(hub_conf("coordinator-standby-mtls.json5")))  # fmt: skip
    agents = {
        robot: in_ns(spawn, net.hosts[robot], "-m", "formation", "agent", "--config", str(cfg))
        for robot, cfg in configs.items()
    }
    standby.wait_for_line("coordinator ready", timeout_s=READY_S)
    for robot, child in agents.items():
        child.wait_for_line(f"agent {robot} ready", timeout_s=READY_S)
    ready = camera.wait_for_line("camera ready", timeout_s=READY_S)
    assert f"rendered {CAMERA_SIZE[0]}x{CAMERA_SIZE[1]}" in ready, ready
    assert "pupil-apriltags" in ready or "opencv-aruco" in ready, ready
    ready_s = time.monotonic() - t_start

    obs = Observer(shipped_zenoh("observer-mtls.json5", certs, net.observer_addr, conf))
    try:
        # ---- 1. the fleet forms: every robot TRACKING its assigned slot
        t0 = time.monotonic()
        formed_s = until(lambda: tracking(obs, set(ROBOTS), t0), FORM_BOUND_S, "fleet formed")
        until(lambda: max_error(obs, set(ROBOTS), time.monotonic() - 1.0) < 0.1, 20.0,
              "tracking errors below 0.1 m")  # fmt: skip
        # neighbour positions (the camera's `poses` batches) reach every agent: its `poses`
        # count grows, nothing rejected
        first = {r: obs.latest_status(r, t0) for r in ROBOTS}
        for r in ROBOTS:
            a = first[r]
            assert a is not None and a.rx, (r, a)

            def grew(r: str = r, n0: int = a.rx["poses"]) -> bool:
                b = obs.latest_status(r, t0)
                return b is not None and b.rx is not None and b.rx["poses"] > n0 + 10

            until(grew, 10.0, f"{r} received 10 more neighbour position batches")
            b = obs.latest_status(r, t0)
            assert b is not None and b.rejected == 0, (r, b)

        # ---- 2. the operator kills the active coordinator; the standby continues
        def only_main_active() -> bool:
            recent = [h for _, h in obs.since(obs.heartbeats, time.monotonic() - 1.0)]
            return {h.name for h in recent} == {"main", "standby"} and all(
                h.active == (h.name == "main") for h in recent
            )

        # main is the active one (a standby starved on a loaded machine may have taken over
        # for a moment, then yielded: wait for one second of a settled election)
        until(only_main_active, 15.0, "main the only active coordinator for 1 s")
        leaders = obs.since(obs.leader, time.monotonic() - 1.0)
        assert leaders, "no leader messages"
        x_before = leaders[-1][1].x
        pos_before = {r: xs[-1][1] for r, xs in obs.positions(time.monotonic() - 0.5).items()}
        operator = str(hub_conf("operator-mtls.json5"))
        t_kill = time.monotonic()
        killed = formation_in_ns(net.hub, "fault", "--fleet", FLEET, "--zenoh-config", operator,
                                 "kill-coordinator", "main")  # fmt: skip
        assert killed.returncode == 0, killed.stdout + killed.stderr
        assert "killed coordinator main" in killed.stdout, killed.stdout
        main.proc.wait(timeout=5.0)
        takeover_s = until(
            lambda: any(h.name == "standby" and h.active
                        for _, h in obs.since(obs.heartbeats, t_kill)),
            TAKEOVER_BOUND_S, "standby active",
        )  # fmt: skip
        time.sleep(3.0)
        after = obs.since(obs.leader, t_kill)
        assert after, "no leader messages after the takeover"
        jump = min(m.x for _, m in after) - x_before
        assert jump > -0.01, f"the virtual leader went back {jump:.3f} m at the takeover"
        assert after[-1][1].x > x_before, "the trajectory did not continue"
        for r, xs in obs.positions(t_kill).items():
            lowest = min(x for _, x in xs)
            assert lowest > pos_before[r] - BACKWARDS_TOL_M, (r, pos_before[r], lowest)
        until(lambda: tracking(obs, set(ROBOTS), time.monotonic() - 1.0), 5.0,
              "every robot tracking after the takeover")  # fmt: skip

        # ---- 3. robot host 3 loses its link: the fleet re-forms with r1 and r2
        t_cut = time.monotonic()
        ip("-n", net.hub, "link", "set", net.hub_devs["r3"], "down")
        drop_s = until(
            lambda: (a := obs.latest_assignment(t_cut)) is not None and "r3" not in a.robots,
            DROP_BOUND_S, "r3 dropped from the assignment",
        )  # fmt: skip
        until(lambda: tracking(obs, {"r1", "r2"}, time.monotonic() - 0.5), 10.0, "re-formed")
        assert agents["r3"].proc.poll() is None  # the cut robot's agent keeps running (HOLD)

        # ---- 4. operator tools with the operator certificate: top and record
        mcap = tmp_path / "run.mcap"
        recorded = formation_in_ns(net.hub, "record", "--fleet", FLEET, "--out", str(mcap),
                                   "--duration", "3", "--zenoh-config", operator)  # fmt: skip
        assert recorded.returncode == 0, recorded.stderr
        assert mcap.stat().st_size > 1000
        top = formation_in_ns(net.hub, "top", "--fleet", FLEET, "--once", "--wait", "2",
                              "--zenoh-config", operator)  # fmt: skip
        assert top.returncode == 0, top.stderr
        for r in ("r1", "r2"):
            assert r in top.stdout, top.stdout

        # ---- 5. formation kept after the re-forming, neighbours still seen: both robots
        # tracking their slots of the r1+r2 assignment with errors below 0.1 m for 2 s. A
        # condition, not a snapshot: at load ~20 on the 2 cores a robot's 700 ms lease was seen
        # to lapse once (the coordinator then re-forms without it and with it again, as
        # designed); the formation must be back within the bound.
        pair = {"r1", "r2"}

        def kept() -> bool:
            t = time.monotonic() - 2.0
            with contextlib.suppress(AssertionError):  # no tracking status yet
                return tracking(obs, pair, t) and max_error(obs, pair, t) < 0.1
            return False

        kept_s = until(kept, 20.0, "r1 and r2 in formation (errors < 0.1 m) for 2 s")
        t_end = time.monotonic() - 2.0
        err = max_error(obs, pair, t_end)
        for r in ("r1", "r2"):
            st = obs.latest_status(r, t_end)
            assert st is not None and st.rx and st.rx["poses"] > 0 and st.rejected == 0
        print(
            f"\nevery process ready {ready_s:.1f} s after the start, formed in {formed_s:.1f} s, "
            f"standby active {takeover_s:.2f} s after the kill, "
            f"r3 dropped {drop_s:.2f} s after the cut, final max error {err * 1000:.0f} mm "
            f"({kept_s:.1f} s to confirm), "
            f"total {time.monotonic() - t_start:.0f} s"
        )
    finally:
        obs.close()

    cpu_s, alive_s = cpu_seconds(camera.pid), time.monotonic() - camera_started
    print(
        f"camera: {cpu_s:.1f} s of CPU in {alive_s:.0f} s ({100 * cpu_s / alive_s:.0f} % of a core)"
    )

    # ---- 6. every process stops on SIGTERM within the bound, status 0 (all signalled at once;
    # the cut robot's agent too: it leaves without closing its session, see robot_agent.node.main)
    children = [*agents.values(), standby, camera, world]
    sent = time.monotonic()
    for child in children:
        child.send_signal(signal.SIGTERM)
    for child in children:
        child.proc.wait(timeout=10.0)
        elapsed = time.monotonic() - sent
        assert elapsed < EXIT_BOUND_S, (elapsed, child.describe())
        assert child.proc.returncode == 0, child.describe()
    assert router.stop(signal.SIGTERM, timeout_s=5.0) < EXIT_BOUND_S
    assert router.proc.returncode == 0, router.describe()

    # ---- 7. the poses the fleet ran on were the camera's, tracked on the rendered frames: every
    # `poses` batch the world saw is a truth instant it published, within the bounds of truth
    line = world.wait_for_line("world camera ")
    stats = dict(kv.split("=", 1) for kv in line.split()[2:])
    print(line)
    assert int(stats["matched"]) > 100 and int(stats["unmatched"]) == 0, line
    assert int(stats["misses"]) <= int(stats["matched"]) // 100, line  # seen in >= 99 % of frames
    assert float(stats["median_mm"]) < POSE_MEDIAN_MM, line
    assert float(stats["max_mm"]) < POSE_MAX_MM, line
