"""Benchmark: a realtime fleet while one process floods a robot's key with junk.

Runs ``formation up --scenario paper-exp1`` (realtime, no ``--secure``: anyone on the bus may
publish) and, from a separate observer session, records when every robot's ``wheels`` arrive.
After the fleet has run a while, a second process (this file with ``--flooder``) puts junk on
``robot/r1/<KEY>`` as fast as it can for ``--seconds`` (empty, truncated, not-a-map and random
payloads, Zenoh's data priority, dropped when congested), once per key given. Printed per key
and robot: the wheels' rate in the seconds before the flood (the anchor, measured in the same
run) and during it, and the longest gap between two wheels during it; and how many junk puts a
second the flooder made. A gap is a pause of that robot's control loop: its firmware holds the
robot on stale data when it steps again, and a real robot's motor controller stops it after its
own serial timeout (``robot_agent/motors``).

Everything runs on this machine's cores: the flooder, the router and every robot share them, so
the other robots' gaps here say what the shared CPU costs, and only r1's what a flood on its own
keys costs a robot on a computer of its own.

Usage: ``python bench/bench_flood.py [--keys setpoint pose] [--seconds 6]``. Prints; asserts
nothing. Results and their meaning: docs/security.md ("What someone can still do") and
docs/benchmarks.md.
"""

from __future__ import annotations

import argparse
import collections
import itertools
import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

from common import REPO_ROOT, free_port

import runtime as rt

ROBOTS = ("r1", "r2", "r3")
WARM_S = 4.0
"""Seconds after the fleet's start before the anchor window (start-up, first assignment)."""
ANCHOR_S = 3.0
"""Seconds of wheels before each flood: the anchor rate."""
JUNK = (b"", b"\xc1", b"\x81\xa1v\x01", os.urandom(200))


def flooder(endpoint: str, key: str, seconds: float) -> int:
    """Put junk on ``key`` as fast as one thread can for ``seconds``; prints the count and the
    flood's first and last instant (``time.monotonic()``: the machine's clock, as the caller's)."""
    session = rt.open_session(rt.ZenohSettings(connect=(endpoint,)), timeout_s=10.0)
    pubs = rt.Publishers(session)
    n, start = 0, time.monotonic()
    end = start + seconds
    while time.monotonic() < end:
        for _ in range(1000):
            pubs.put(key, JUNK[n % len(JUNK)], rt.QOS_TELEMETRY)
            n += 1
    stop = time.monotonic()
    session.close()
    print(n, start, stop, flush=True)
    return 0


def window(times: list[float], t0: float, t1: float) -> tuple[float, float]:
    """Rate (Hz) and the longest gap (s) of ``times`` in ``[t0, t1)`` (gap from ``t0`` too)."""
    inside = [t for t in times if t0 <= t < t1]
    edges = [t0, *inside, t1]
    gap = max(b - a for a, b in itertools.pairwise(edges))
    return len(inside) / (t1 - t0), gap


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--keys", nargs="+", default=["setpoint", "pose"], help="r1's keys to flood")
    p.add_argument("--seconds", type=float, default=6.0, help="length of each flood")
    p.add_argument("--flooder", nargs=3, metavar=("ENDPOINT", "KEY", "SECONDS"), help="internal")
    args = p.parse_args()
    if args.flooder:
        return flooder(args.flooder[0], args.flooder[1], float(args.flooder[2]))

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    per_key = ANCHOR_S + args.seconds + 1.0
    duration = WARM_S + per_key * len(args.keys) + 3.0
    env = dict(os.environ, PYTHONPATH=str(REPO_ROOT))
    print(f"realtime paper-exp1, 3 robots, {os.cpu_count()} CPUs; junk on robot/r1/<key>")
    with tempfile.TemporaryDirectory(prefix="bench-flood-") as tmp:
        up = subprocess.Popen(
            [sys.executable, "-m", "formation", "up", "--scenario", "paper-exp1",
             "--duration", str(duration), "--endpoint", endpoint, "--fleet", "flood",
             "--out", str(Path(tmp) / "up"), "--no-figures", "--quiet"],
            cwd=REPO_ROOT, env=env,
        )  # fmt: skip
        session = rt.open_session(rt.ZenohSettings(connect=(endpoint,)), timeout_s=30.0)
        arrivals: dict[str, list[float]] = collections.defaultdict(list)
        lock = threading.Lock()

        def on_wheels(sample: object) -> None:
            robot = str(sample.key_expr).split("/")[3]  # type: ignore[attr-defined]
            with lock:
                arrivals[robot].append(time.monotonic())

        sub = session.declare_subscriber("formation/flood/robot/*/wheels", on_wheels)
        try:
            time.sleep(WARM_S)
            for key in args.keys:
                t_anchor = time.monotonic()
                time.sleep(ANCHOR_S)
                t_before = time.monotonic()
                fl = subprocess.run(
                    [sys.executable, __file__, "--flooder", endpoint,
                     f"formation/flood/robot/r1/{key}", str(args.seconds)],
                    cwd=REPO_ROOT, env=env, capture_output=True, text=True, timeout=60,
                )  # fmt: skip
                words = fl.stdout.split()
                if fl.returncode != 0 or len(words) != 3:
                    print(f"  robot/r1/{key}: the flooder failed ({fl.returncode}): "
                          f"{fl.stderr[-300:]}")  # fmt: skip
                    continue
                puts, t0, t1 = int(words[0]), float(words[1]), float(words[2])
                print(f"  robot/r1/{key}: {puts / (t1 - t0):,.0f} junk puts a second "
                      f"for {t1 - t0:.1f} s")  # fmt: skip
                with lock:
                    seen = {r: list(arrivals[r]) for r in ROBOTS}
                for robot in ROBOTS:
                    before, _ = window(seen[robot], t_anchor, t_before)
                    during, gap = window(seen[robot], t0, t1)
                    print(f"    {robot}: wheels {before:5.1f} Hz before (anchor), {during:5.1f} "
                          f"Hz during; longest gap during {gap * 1000:6.0f} ms")  # fmt: skip
                time.sleep(1.0)
        finally:
            sub.undeclare()
            session.close()
            up.wait(timeout=120)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
