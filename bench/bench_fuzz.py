"""Long outsider fuzz of a running fleet (the short one is tests/fleet/test_outsider_fuzz.py).

Starts a realtime ``formation up`` fleet (3 robots, a slow line), waits until every robot
tracks, then publishes ``--per-key`` seeded hostile payloads (formation/operate/fuzz.py, each
refused by
the strict decoder) on every key the agents, the coordinator and the plant subscribe to, in
rounds, and reports: payloads sent, each node's rejected count against the exact expectation,
crashes (a node's status stopping), robots leaving TRACKING, and the minimum tracking error
budget. Usage::

    python bench/bench_fuzz.py [--per-key 2000] [--seed 1] [--rate 5000]
"""

from __future__ import annotations

import argparse
import contextlib
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import msgpack

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import runtime as rt  # noqa: E402
from bus_schemas import Status, decode  # noqa: E402
from formation.operate.fuzz import fuzz_plan, payloads_for  # noqa: E402

SCENARIO = """\
name = "fuzz"
description = "Three robots on a slow line, for the fuzz bench."
duration_s = 3600.0
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
speed_mps = 0.01

[formation]
kind = "triangle"
b_m = 0.4

[assignment]
method = "greedy"
hysteresis_m = 0.05
tie_tol_m = 0.01
"""
ROBOTS = ("r1", "r2", "r3")


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class Counts:
    """The newest ``rejected`` (and mode) of every node, from their status."""

    def __init__(self, session: Any, fleet: str) -> None:
        self.lock = threading.Lock()
        self.rejected: dict[str, int] = {}
        self.modes: dict[str, set[str]] = {}
        self.last_rx: dict[str, float] = {}

        def agent(sample: Any) -> None:
            msg = decode(sample.payload.to_bytes(), Status)
            if isinstance(msg, Status) and msg.robot is not None:
                self._set(f"agent-{msg.robot}", msg.rejected, msg.mode)

        def plain(sample: Any) -> None:
            m = msgpack.unpackb(sample.payload.to_bytes())
            if isinstance(m, dict) and isinstance(m.get("rejected"), int):
                who = "plant" if "/plant/" in str(sample.key_expr) else "coordinator"
                self._set(who, m["rejected"], None)

        session.declare_subscriber(f"formation/{fleet}/robot/*/status", agent)
        session.declare_subscriber(f"formation/{fleet}/coordinator/main/status", plain)
        session.declare_subscriber(f"formation/{fleet}/plant/status", plain)

    def _set(self, who: str, rejected: int, mode: str | None) -> None:
        with self.lock:
            self.rejected[who] = rejected
            self.last_rx[who] = time.monotonic()
            if mode is not None:
                self.modes.setdefault(who, set()).add(mode)

    def snapshot(self) -> dict[str, int]:
        with self.lock:
            return dict(self.rejected)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--per-key", type=int, default=2000)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--rate", type=float, default=5000.0, help="payloads per second")
    ns = ap.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="bench-fuzz-"))
    (tmp / "fuzz.toml").write_text(SCENARIO)
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    fleet = "fuzz"
    up = subprocess.Popen(
        [sys.executable, "-m", "formation", "up", "--scenario", str(tmp / "fuzz.toml"),
         "--endpoint", endpoint, "--fleet", fleet, "--out", str(tmp / "out"), "--no-figures",
         "--quiet", "--ready-timeout", "60"],
        cwd=ROOT,
    )  # fmt: skip
    try:
        session = rt.open_session(rt.ZenohSettings(connect=(endpoint,)), timeout_s=60.0)
        counts = Counts(session, fleet)
        deadline = time.monotonic() + 90.0
        while len(counts.snapshot()) < 5 or not all(
            "tracking" in counts.modes.get(f"agent-{r}", set()) for r in ROBOTS
        ):
            if time.monotonic() > deadline or up.poll() is not None:
                print("bench_fuzz: the fleet did not start", file=sys.stderr)
                return 1
            time.sleep(0.2)
        time.sleep(1.0)
        with counts.lock:
            counts.modes.clear()
        before = counts.snapshot()
        plan = fuzz_plan(fleet, ROBOTS)
        expected = dict.fromkeys(before, 0)
        pubs = rt.Publishers(session)
        batches = {fk.key: payloads_for(fk, ns.seed, ns.per_key) for fk in plan}
        started = time.monotonic()
        sent = 0
        for i in range(ns.per_key):
            for fk in plan:
                pubs.put(fk.key, batches[fk.key][i], rt.QOS_CRITICAL)
                sent += 1
                for node in fk.receivers:
                    expected[node] += 1
            lag = sent / ns.rate - (time.monotonic() - started)
            if lag > 0:
                time.sleep(lag)
        wall = time.monotonic() - started
        settle = time.monotonic() + 20.0
        while time.monotonic() < settle:
            now = counts.snapshot()
            if all(now.get(n, 0) - before[n] >= expected[n] for n in before):
                break
            time.sleep(0.2)
        time.sleep(1.0)
        now = counts.snapshot()
        delta = {n: now.get(n, 0) - before[n] for n in before}
        alive = {n: time.monotonic() - counts.last_rx.get(n, 0.0) < 2.0 for n in before}
        modes = {n: sorted(m) for n, m in counts.modes.items()}
        exact = delta == expected
        print(
            f"fuzz: {sent} payloads on {len(plan)} keys in {wall:.1f} s "
            f"({sent / wall:.0f}/s), seed {ns.seed}"
        )
        print(f"rejected (delta): {delta}")
        print(f"expected:         {expected}  -> {'exact' if exact else 'MISMATCH'}")
        print(f"nodes alive: {alive}; agent modes during the fuzz: {modes}")
        ok = (
            exact
            and all(alive.values())
            and all(m == ["tracking"] for n, m in modes.items() if n.startswith("agent"))
        )
        session.close()
        return 0 if ok else 1
    finally:
        with contextlib.suppress(Exception):
            up.send_signal(signal.SIGINT)
            up.wait(20)


if __name__ == "__main__":
    raise SystemExit(main())
