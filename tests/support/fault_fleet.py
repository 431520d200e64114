"""The realtime fleet that tests/fleet/test_faults.py injects faults into, and what observes it.

``SCENARIO``: three robots on a slow line (realtime, triangle formation), starting on their
slots. The tests inject faults into the formed formation; from the former start 0.18 m off the
slots every fleet spent ~5.5 s before ``formed`` held, and then only just: the followers' errors
were still at the 6 cm tolerance, closing at ~1 cm/s, so a fault right after the first
formation hit a formation still converging (test_operator_fleet.py's e-stop test: r2 at 6.0 cm
when r3 was e-stopped, then 4.9, 3.9, 3.0 cm a second apart, one realtime run; r1 and r2 once
not within 6 cm in 10 s next to a CPU hog, once after 4.2 s in 17 runs next to 2-4 hogs). From
the slots every error stays within ~4 mm (in process). :class:`Fleet` runs it
as ``formation up --respawn 1.0`` on a free port with an :class:`Observer` on its bus (a client
session stamping every message of interest with ``time.monotonic()`` on receipt, the clock
``formation fault`` prints its actions on); :func:`fleet_fixture` is the body of a module-scoped
fixture (one fleet per test module: starting one is slow). Also the waits the fault tests share
(:func:`until`, :func:`formed`, :func:`wait_formed`) and :func:`fault`, what the
``formation fault`` CLI does, in this process. Used by test_faults.py, test_estop_latched.py,
test_multihost.py, test_outsider_fuzz.py and test_safety_zenoh.py; ``bench/bench_soak.py``
reads ``SCENARIO``.
"""

from __future__ import annotations

import asyncio
import itertools
import math
import os
import re
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import msgpack
import pytest

import runtime as rt
from bus_schemas import Assignment, Heartbeat, Leader, Slot, Status, Truth, Wheels, decode, keys
from support.spawn import Spawner, free_port

SCENARIO = """\
name = "faults"
description = "Three robots on a slow line, for fault injection."
duration_s = 120.0
dt_s = 0.02
seed = 5
settle_s = 10.0

[robots]
ids = ["r1", "r2", "r3"]
# on their slots: each robot's reference point (ref_offset_m = 0.05 m ahead of its axle) starts
# on its slot of the triangle (leader at x0, followers 0.4 m back at 30 degrees: x 0.0536, y 0.2)
initial = [[0.35, 0.0, 0.0], [0.0036, 0.2, 0.0], [0.0036, -0.2, 0.0]]

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


def fault(endpoint: str, fleet: str, *args: str, session: Any = None) -> tuple[str, float]:
    """Do what ``formation fault ARGS`` does, with its code
    (:func:`formation.operate.fault.apply`) in this process, over ``session`` (else a session of
    its own), and return its line and the action's time.monotonic(). A ``formation fault``
    process costs 1-2 s to start; these tests need the fault delivered, and the CLI itself is
    tested on its own (test_fault_tools_hosts.py, test_estop_durable.py, test_up_hardening.py,
    test_scripted_faults.py)."""
    from concurrent.futures import ThreadPoolExecutor

    from formation.operate import fault as fault_tool

    ns = fault_tool.build_parser().parse_args(["--fleet", fleet, "--endpoint", endpoint, *args])
    where = fault_tool.Where.of(fleet, rt.ZenohSettings(connect=(endpoint,)))

    async def deliver() -> str:
        own = session is None
        s = await rt.open_session_async(rt.ZenohSettings(connect=(endpoint,))) if own else session
        try:
            return await fault_tool.apply(s, ns, where)
        finally:
            if own:
                s.close()

    # its own event loop on a thread: callers are sync, some inside a test's running loop
    with ThreadPoolExecutor(1) as pool:
        line = pool.submit(lambda: asyncio.run(deliver())).result(timeout=60)
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
        return fault(self.endpoint, self.fleet, *args, session=self.obs.session)


def fleet_fixture(
    tmp_path_factory: pytest.TempPathFactory,
    name: str,
    *extra: str,
    make: Callable[[Spawner, Path], Fleet] | None = None,
) -> Iterator[Fleet]:
    """Body of a module-scoped fleet fixture: start, yield, stop and check nothing is left
    (``make``: a subclass's constructor instead of ``Fleet(spawner, tmp, name, *extra)``)."""
    tmp = tmp_path_factory.mktemp(name)
    spawner = Spawner(tmp / "procs")
    fl: Fleet | None = None
    try:
        fl = Fleet(spawner, tmp, name, *extra) if make is None else make(spawner, tmp)
        yield fl
    finally:
        if fl is not None:
            fl.obs.close()
        problems = spawner.cleanup()
        assert not problems, problems


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
