"""Fault injection with real processes and real signals (issue 4, docs/faults.md).

One ``formation up --standby --respawn`` fleet (3 robots, realtime) is shared by the tests of
this module, in file order: e-stop and release (fleet, one robot), kill the leader at a random
time, pause (SIGSTOP) an agent and resume it, kill the active coordinator. Faults go through the
``formation fault`` CLI, which prints the ``time.monotonic()`` of its action; an observer Zenoh
session in this process stamps every message with the same clock on receipt, so latencies are
measured from the signal to the receipt of the reaction. A second test starts the nodes one by
one and restarts the plant and the router under them.

Assertions are about behaviour; the bounds are the issue's (reassignment 50 ms, e-stop 100 ms,
hang 1 s, takeover 500 ms) plus, where a Python process on a loaded 2-core box must be woken,
nothing else. Separation is measured from the plant's truth.
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import math
import os
import random
import re
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import msgpack
import pytest
from conftest import Spawner, free_port

import runtime as rt
from bus_schemas import Assignment, Heartbeat, Leader, Slot, Status, Truth, Wheels, decode, keys

pytestmark = [pytest.mark.slow, pytest.mark.zenoh]

BODY_RADIUS_M = 0.075
COLLISION_M = 2 * BODY_RADIUS_M
SCENARIO = """\
name = "faults"
description = "Three robots on a slow line, for fault injection."
duration_s = 120.0
dt_s = 0.02
seed = 5
settle_s = 10.0

[robots]
ids = ["r1", "r2", "r3"]
initial = [[0.35, 0.0, 0.0], [0.15, 0.35, 0.0], [0.15, -0.35, 0.0]]

[trajectory]
kind = "line"
x0 = 0.4
y0 = 0.0
heading = 0.0
speed_mps = 0.03

[formation]
kind = "triangle"
b_m = 0.4

[assignment]
method = "greedy"
hysteresis_m = 0.05
tie_tol_m = 0.01
"""


# ---------------------------------------------------------------------------------------------
# Observer: every message of interest, stamped with time.monotonic() on receipt
# ---------------------------------------------------------------------------------------------


class Observer:
    """A client session recording (rx_s, robot or name, decoded message) per kind."""

    def __init__(self, endpoint: str, fleet: str) -> None:
        self.fleet = fleet
        self.lock = threading.Lock()
        self.log: dict[str, list[tuple[float, str, Any]]] = {
            k: []
            for k in ("assignment", "status", "truth", "wheels", "slot0", "leader", "hb", "cst")
        }
        self.session = rt.open_session(rt.ZenohSettings(connect=(endpoint,)))
        f = fleet
        self._sub(keys.assignment_key(f), "assignment", Assignment)
        self._sub(keys.all_status_pattern(f), "status", Status)
        self._sub(keys.all_truth_pattern(f), "truth", Truth)
        self._sub(keys.all_wheels_pattern(f), "wheels", Wheels)
        self._sub(keys.slot_key(f, 0), "slot0", Slot)
        self._sub(keys.leader_key(f), "leader", Leader)
        self._sub(keys.all_heartbeats_pattern(f), "hb", Heartbeat)
        self._sub(f"{keys.ROOT}/{f}/coordinator/*/status", "cst", None)

    def _sub(self, key: str, kind: str, cls: Any) -> None:
        store = self.log[kind]

        def on(sample: Any) -> None:  # Zenoh thread: decode is cheap and pure
            rx = time.monotonic()
            payload = sample.payload.to_bytes()
            k = str(sample.key_expr)
            msg = msgpack.unpackb(payload) if cls is None else decode(payload, cls)
            parsed = keys.parse_robot_key(k)
            who = parsed[1] if parsed is not None else k.split("/")[-2]
            with self.lock:
                store.append((rx, who, msg))

        self.session.declare_subscriber(key, on)

    def get(self, kind: str, since: float = -math.inf) -> list[tuple[float, str, Any]]:
        with self.lock:
            return [e for e in self.log[kind] if e[0] >= since]

    def latest_status(self, within_s: float = 0.5) -> dict[str, Status]:
        now = time.monotonic()
        out: dict[str, Status] = {}
        for _rx, who, msg in self.get("status", now - within_s):
            out[who] = msg
        return out

    def latest_assignment(self) -> Assignment | None:
        a = self.get("assignment")
        return a[-1][2] if a else None

    def min_separation(self, since: float, until: float = math.inf) -> float:
        """Minimum pairwise distance of the truth poses (m), frame by frame (same t)."""
        frames: dict[float, dict[str, tuple[float, float]]] = {}
        for rx, who, msg in self.get("truth", since):
            if rx <= until:
                frames.setdefault(msg.t, {})[who] = (msg.x, msg.y)
        best = math.inf
        for poses in frames.values():
            for a, b in itertools.combinations(poses.values(), 2):
                best = min(best, math.dist(a, b))
        return best

    def close(self) -> None:
        self.session.close()


async def until(pred: Callable[[], Any], timeout_s: float, what: str) -> Any:
    deadline = time.monotonic() + timeout_s
    while True:
        value = pred()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"not within {timeout_s} s: {what}")
        await asyncio.sleep(0.02)


def tracking_err(st: Status) -> float:
    return math.hypot(st.ex or 0.0, st.ey or 0.0)


def formed(obs: Observer, robots: set[str], tol_m: float = 0.06) -> bool:
    """Every robot of ``robots`` assigned, tracking and within ``tol_m`` of its slot."""
    a = obs.latest_assignment()
    st = obs.latest_status()
    return (
        a is not None
        and robots <= set(a.robots)
        and all(
            r in st
            and st[r].mode == "tracking"
            and st[r].slot == a.robots[r]
            and tracking_err(st[r]) < tol_m
            for r in robots
        )
    )


def fault(endpoint: str, fleet: str, *args: str) -> tuple[str, float]:
    """Run ``formation fault`` and return its line and the action's time.monotonic()."""
    import subprocess

    from conftest import child_env

    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "formation",
            "fault",
            "--fleet",
            fleet,
            "--endpoint",
            endpoint,
            *args,
        ],
        capture_output=True,
        text=True,
        timeout=60,  # a bound on a Python start + one action, not a property: loaded machines
        env=child_env(),
    )
    assert proc.returncode == 0, proc.stderr
    line = proc.stdout.strip()
    m = re.search(r"t=([0-9.]+)", line)
    return line, float(m.group(1)) if m else time.monotonic()


# ---------------------------------------------------------------------------------------------
# The shared fleet
# ---------------------------------------------------------------------------------------------


class Fleet:
    """A realtime ``formation up --respawn 1.0`` of SCENARIO named ``name`` on a free port
    (``extra``: more ``up`` options, e.g. ``--standby``), with an Observer on its bus."""

    def __init__(self, spawner: Spawner, tmp: Path, name: str = "faults", *extra: str) -> None:
        self.endpoint = f"tcp/127.0.0.1:{free_port()}"
        self.fleet = name
        scn = tmp / f"{name}.toml"
        scn.write_text(SCENARIO)
        self.up = spawner(
            "up", "--scenario", str(scn), "--duration", "110", *extra, "--respawn", "1.0",
            "--endpoint", self.endpoint, "--fleet", self.fleet, "--out", str(tmp / "out"),
            "--no-figures", "--ready-timeout", "30",
            ready="  3 agents", timeout_s=60.0,
        )  # fmt: skip
        self.obs = Observer(self.endpoint, self.fleet)

    def fault(self, *args: str) -> tuple[str, float]:
        return fault(self.endpoint, self.fleet, *args)


def fleet_fixture(
    tmp_path_factory: pytest.TempPathFactory, name: str, *extra: str
) -> Iterator[Fleet]:
    """Body of a module-scoped fleet fixture: start, yield, stop and check nothing is left."""
    tmp = tmp_path_factory.mktemp(name)
    spawner = Spawner(tmp / "procs")
    fl: Fleet | None = None
    try:
        fl = Fleet(spawner, tmp, name, *extra)
        yield fl
    finally:
        if fl is not None:
            fl.obs.close()
        problems = spawner.cleanup()
        assert not problems, problems


@pytest.fixture(scope="module")
def fleet(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Fleet]:
    yield from fleet_fixture(tmp_path_factory, "faults", "--standby")


def formation_history(obs: Observer, robots: set[str], since: float, step_s: float = 2.0) -> str:
    """What the observer saw of ``robots`` since ``since``, every ``step_s``: each robot's newest
    status then (age, mode, slot, tracking error) and the assignment (a failure says why)."""
    lines = []
    statuses = obs.get("status", since - 1.0)
    assignments = obs.get("assignment")
    t = since
    now = time.monotonic()
    while t <= now + 1e-9:
        newest: dict[str, tuple[float, Status]] = {}
        for rx, who, st in statuses:
            if rx <= t and who in robots:
                newest[who] = (rx, st)
        a = [m for rx, _, m in assignments if rx <= t]
        parts = [f"+{t - since:5.1f}s assignment {dict(a[-1].robots) if a else None}"]
        for r in sorted(robots):
            if r not in newest:
                parts.append(f"{r}: no status")
                continue
            rx, st = newest[r]
            parts.append(
                f"{r}: {st.mode} slot {st.slot} err {tracking_err(st) * 100:.1f} cm "
                f"({(t - rx) * 1000:.0f} ms old)"
            )
        lines.append("; ".join(parts))
        t += step_s
    return "\n".join(lines)


async def wait_formed(fl: Fleet, robots: set[str] | None = None, timeout_s: float = 25.0) -> None:
    robots = robots or {"r1", "r2", "r3"}
    start = time.monotonic()
    try:
        await until(lambda: formed(fl.obs, robots), timeout_s, f"formation of {sorted(robots)}")
    except AssertionError as exc:
        load = os.getloadavg()
        raise AssertionError(
            f"{exc} (load {load[0]:.1f} {load[1]:.1f}); what the observer saw:\n"
            + formation_history(fl.obs, robots, start)
        ) from None


# ---------------------------------------------------------------------------------------------
# Tests on the shared fleet
# ---------------------------------------------------------------------------------------------


async def test_estop_fleet_and_robot_latched_until_release(fleet: Fleet) -> None:
    await wait_formed(fleet, timeout_s=40.0)
    obs = fleet.obs
    try:
        _, t_stop = fleet.fault("estop")

        def all_zero_since(t: float) -> dict[str, float] | None:
            first: dict[str, float] = {}
            for rx, who, w in obs.get("wheels", t):
                if w.omega_r == 0.0 and w.omega_l == 0.0:
                    first.setdefault(who, rx)
            return first if len(first) == 3 else None

        first_zero = await until(lambda: all_zero_since(t_stop), 2.0, "every wheel at zero")
        assert max(first_zero.values()) - t_stop < 0.100, first_zero
        print(f"\nestop: every wheel at zero {(max(first_zero.values()) - t_stop) * 1000:.1f} ms")
        await asyncio.sleep(0.6)  # latched: still stopped, in ESTOP
        late = obs.get("wheels", t_stop + 0.15)
        assert late and all(w.omega_r == 0.0 and w.omega_l == 0.0 for _, _, w in late)
        assert {s.mode for s in obs.latest_status().values()} == {"estop"}

        fleet.fault("release")
        await wait_formed(fleet, timeout_s=10.0)

        # one robot: only r2 stops
        _, t_stop = fleet.fault("estop", "r2")
        await until(
            lambda: (st := obs.latest_status().get("r2")) is not None and st.mode == "estop",
            2.0,
            "r2 in estop",
        )
        await asyncio.sleep(0.5)
        r2 = [w for rx, who, w in obs.get("wheels", t_stop + 0.1) if who == "r2"]
        assert r2 and all(w.omega_r == 0.0 and w.omega_l == 0.0 for w in r2)
        # r1 and r3 go on tracking (their newest status: at 5 Hz, but it can be late next to hogs)
        await until(
            lambda: all(
                (s := obs.latest_status().get(r)) is not None and s.mode == "tracking"
                for r in ("r1", "r3")
            ),
            2.0,
            f"r1 and r3 tracking while r2 is stopped: {obs.latest_status()}",
        )
        fleet.fault("release", "r2")
        await wait_formed(fleet, timeout_s=10.0)
    except BaseException:
        # The fleet is shared: leave it released, so this failure does not fail the next tests
        # too (they would wait for a formation with r2 still in ESTOP).
        with contextlib.suppress(Exception):
            fleet.fault("release")
            fleet.fault("release", "r2")
        raise


async def test_kill_leader_reassigns_within_50ms_and_reforms(fleet: Fleet) -> None:
    obs = fleet.obs
    await wait_formed(fleet)
    await asyncio.sleep(random.uniform(0.0, 1.0))  # a random moment of the loop
    before = obs.latest_assignment()
    assert before is not None and before.leader is not None
    old = before.leader
    # who is nearest to the leader slot right now (reference points from truth)
    slot0 = obs.get("slot0")[-1][2]
    ref: dict[str, float] = {}
    for _, who, tr in obs.get("truth", time.monotonic() - 0.2):
        ref[who] = math.hypot(
            tr.x + 0.05 * math.cos(tr.theta) - slot0.x, tr.y + 0.05 * math.sin(tr.theta) - slot0.y
        )
    line, t_kill = fleet.fault("kill-leader")
    assert f"killed leader {old}" in line

    def reassigned() -> tuple[float, Assignment] | None:
        for rx, _, a in obs.get("assignment", t_kill):
            if old not in a.robots:
                return rx, a
        return None

    rx, new = await until(reassigned, 2.0, "an assignment without the dead leader")
    latency = rx - t_kill
    assert latency < 0.050, f"reassignment took {latency * 1000:.1f} ms"
    others = sorted(r for r in ("r1", "r2", "r3") if r != old)
    assert set(new.robots) == set(others)
    d = {r: ref[r] for r in others}
    nearest = min(d, key=d.__getitem__)
    if abs(d[others[0]] - d[others[1]]) > 0.05:  # a clear nearest robot takes slot 0
        assert new.leader == nearest, (new, d)

    # the survivors kept tracking (never left TRACKING) while re-forming, and re-formed
    await asyncio.sleep(1.0)
    await wait_formed(fleet, set(others), timeout_s=20.0)
    t_formed = time.monotonic()
    modes = {s.mode for _, who, s in obs.get("status", t_kill) if who in others}
    assert modes == {"tracking"}, modes
    print(
        f"\nkill leader {old}: reassigned in {latency * 1000:.1f} ms, re-formed (6 cm) "
        f"{t_formed - t_kill:.2f} s after the kill"
    )
    # the respawned agent rejoins
    await until(
        lambda: (a := obs.latest_assignment()) is not None and old in a.robots, 15.0, "rejoin"
    )
    sep = obs.min_separation(t_kill)
    assert sep > COLLISION_M, f"min separation {sep:.3f} m"
    await wait_formed(fleet, timeout_s=25.0)


async def test_paused_agent_is_dropped_within_1s_and_does_not_fight_on_resume(
    fleet: Fleet,
) -> None:
    obs = fleet.obs
    await wait_formed(fleet)
    before = obs.latest_assignment()
    assert before is not None
    victim = next(r for r, s in sorted(before.robots.items()) if s != 0)
    line, t_pause = fleet.fault("pause", victim)
    pid = re.search(r"\(pid (\d+)\)", line)
    assert pid is not None, line
    try:

        def dropped() -> tuple[float, Assignment] | None:
            for rx, _, a in obs.get("assignment", t_pause):
                if victim not in a.robots:
                    return rx, a
            return None

        rx, _ = await until(dropped, 3.0, f"{victim} dropped from the assignment")
        assert rx - t_pause < 1.0, f"hang detected after {rx - t_pause:.3f} s"
        print(f"\npause {victim}: dropped after {(rx - t_pause) * 1000:.0f} ms")
        await asyncio.sleep(1.0)
    finally:
        # SIGCONT at once, not through `formation fault resume` (a Python start, 2-3 s on a
        # starved machine: the hang then lasted 4 s instead of detection + 1 s, long enough for
        # the robot given the victim's slot to drive up to the stopped victim and jam with it
        # after the resume; that CLI is tested in test_up_hardening and test_estop_latched).
        os.kill(int(pid.group(1)), signal.SIGCONT)
        t_resume = time.monotonic()
    await asyncio.sleep(1.5)
    # It tracks nothing until the coordinator assigns it again (its backlog of setpoints for the
    # slot another robot took is dropped), so it never drives to a slot held by another robot.
    regiven = [rx for rx, _, a in obs.get("assignment", t_resume) if victim in a.robots]
    tracking = [
        rx for rx, who, s in obs.get("status", t_resume) if who == victim and s.mode == "tracking"
    ]
    if tracking:
        assert regiven and regiven[0] <= tracking[0], (regiven[:1], tracking[:1])
    # while quarantined after the resume it commands no motion toward its old slot
    early = [
        w for rx, who, w in obs.get("wheels", t_resume) if who == victim and rx < t_resume + 0.2
    ]
    assert all(w.omega_r == 0.0 and w.omega_l == 0.0 for w in early), early[:3]
    assert obs.min_separation(t_pause) > COLLISION_M
    await wait_formed(fleet, timeout_s=25.0)


async def test_kill_active_coordinator_standby_takes_over_without_jump(fleet: Fleet) -> None:
    obs = fleet.obs
    await wait_formed(fleet)
    before = dict(obs.latest_assignment().robots)  # type: ignore[union-attr]
    line, t_kill = fleet.fault("kill-coordinator")
    killed = re.search(r"killed coordinator (\S+)", line)
    assert killed is not None
    old = killed.group(1)

    def takeover() -> tuple[float, Heartbeat] | None:
        for rx, _, hb in obs.get("hb", t_kill):
            if hb.active and hb.name != old:
                return rx, hb
        return None

    rx, hb = await until(takeover, 2.0, "a standby taking over")
    assert rx - t_kill < 0.5, f"takeover after {rx - t_kill:.3f} s"
    print(f"\nkill coordinator {old}: {hb.name} active after {(rx - t_kill) * 1000:.1f} ms")
    await asyncio.sleep(2.0)
    # no jump of the virtual leader: consecutive leader messages move at the trajectory speed
    leaders = [m for _, _, m in obs.get("leader", t_kill - 1.0)]
    for a, b in itertools.pairwise(leaders):
        dt = max(b.t - a.t, 0.0)
        assert math.hypot(b.x - a.x, b.y - a.y) <= 0.03 * dt + 0.005, (a, b)
    # no role chatter: the same robots in the same slots
    assignments = [a.robots for _, _, a in obs.get("assignment", t_kill)]
    assert assignments and all(dict(a) == before for a in assignments), assignments[:3]
    # never two actives: after the takeover only the new one says active
    actives = {h.name for r, _, h in obs.get("hb", rx + 0.05) if h.active}
    assert actives == {hb.name}, actives
    # the killed one is respawned as a standby and stays one
    await until(
        lambda: any(h.name == old and not h.active for _, _, h in obs.get("hb", t_kill)),
        15.0,
        "the respawned coordinator's heartbeat",
    )
    await asyncio.sleep(0.5)
    assert not any(h.name == old and h.active for _, _, h in obs.get("hb", t_kill + 0.1))


# ---------------------------------------------------------------------------------------------
# Plant and router restarts (nodes started one by one)
# ---------------------------------------------------------------------------------------------


async def test_plant_and_router_restart_agents_survive_and_loop_resumes(
    spawn: Spawner, tmp_path: Path
) -> None:
    port = free_port()
    ep = f"tcp/127.0.0.1:{port}"
    fl = "restart"
    scn = tmp_path / "s.toml"
    scn.write_text(SCENARIO)
    common = ["--endpoint", ep, "--fleet", fl, "--lease-ms", "700"]

    def router() -> Any:
        return spawn("router", "--listen", ep, ready="router listening on ")

    def plant() -> Any:
        return spawn("plant", "--scenario", str(scn), *common, ready="plant ready")

    rt = router()
    pl = plant()
    spawn("coordinator", "--scenario", str(scn), *common, ready="coordinator ready")
    agents = [
        spawn("agent", "--id", r, "--scenario", str(scn), *common, ready=f"agent {r} ready")
        for r in ("r1", "r2", "r3")
    ]
    obs = Observer(ep, fl)
    try:

        def moving(since: float) -> bool:
            st = obs.latest_status()
            ws = {who for rx, who, w in obs.get("wheels", since) if w.omega_r or w.omega_l}
            return len(st) == 3 and {s.mode for s in st.values()} == {"tracking"} and len(ws) == 3

        await until(lambda: moving(time.monotonic() - 0.3), 25.0, "the loop running")

        # plant: SIGKILL -> agents hold (no pose), survive; restart -> tracking again
        pl.stop(signal.SIGKILL)
        t_dead = time.monotonic()
        await until(
            lambda: (st := obs.latest_status(0.3)) and {s.mode for s in st.values()} == {"hold"},
            2.0,
            "HOLD without poses",
        )
        await asyncio.sleep(max(0.0, t_dead + 0.8 - time.monotonic()))
        hold = obs.latest_status()
        assert len(hold) == 3 and all(s.mode == "hold" for s in hold.values()), hold
        late = [w for rx, _, w in obs.get("wheels", t_dead + 0.5)]
        assert late and all(w.omega_r == 0.0 and w.omega_l == 0.0 for w in late)
        pl = plant()
        t_back = time.monotonic()
        await until(lambda: moving(t_back), 20.0, "the loop back after the plant restart")
        # no integrator kick: the first commands after the hold are within the normal range
        assert all(a.proc.poll() is None for a in agents)

        # router: SIGKILL and restart on the same port; clients reconnect by themselves
        rt.stop(signal.SIGKILL)
        await asyncio.sleep(1.0)
        assert all(a.proc.poll() is None for a in agents)
        rt = router()
        t_back = time.monotonic()
        await until(lambda: moving(t_back), 15.0, "the loop back after the router restart")
        assert all(a.proc.poll() is None for a in agents) and pl.proc.poll() is None
    finally:
        with contextlib.suppress(Exception):
            obs.close()
