"""Benchmark: how long a coordinator's loop is held when many robot tokens vanish together.

An agent host that dies (or is stopped) takes the liveliness tokens of all its robots with it:
the coordinator gets one callback per robot, back to back on its loop. It used to re-assign
(a tick over the whole fleet) for each; it now queues one re-assignment behind the burst
(``CoordinatorNode._reassign_soon``, tests/bus/test_coord_reassign.py). In process, no Zenoh: a
realtime :class:`coordinator.node.coordinator.CoordinatorNode` of ``--robots`` robots of paper-sim
grown by
the staged rule, every robot alive with a fresh pose, one tick, then ``--lost`` tokens vanish in
one burst; prints the wall time until the loop has run the burst and what it queued, and the
ticks it took (the re-assignments). The node's log lines (one per robot gone, one per
assignment) are written to /dev/null: formatted, as in a real run, not shown.

Usage: ``python bench/bench_token_burst.py [--robots 300] [--lost 150] [--repeat 3]``. Results:
docs/benchmarks.md ("A dead agent host").
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import os
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import runtime as rt
from bus_schemas import Pose, encode, keys
from coordinator.node.coordinator import CoordinatorNode
from scenario.resize import load_with_robots

FLEET = "bench"


async def one(robots: int, lost: int) -> tuple[float, int]:
    scn = load_with_robots("paper-sim", robots)
    node = CoordinatorNode(scn, "main", FLEET, lambda *_a: None)
    now = time.monotonic()
    for rid, (x, y, th) in zip(scn.robot_ids, scn.initial, strict=True):
        node.on_alive(keys.alive_robot_key(FLEET, rid), True)
        pose = Pose(t=now, seq=1, x=x, y=y, theta=th, robot=rid)
        node.on_pose(rt.Received(keys.pose_key(FLEET, rid), encode(pose), now))
    node.tick(now)
    ticks = node.ticks
    t0 = time.perf_counter()
    for rid in scn.robot_ids[:lost]:
        node.on_alive(keys.alive_robot_key(FLEET, rid), False)
    await asyncio.sleep(0)  # the loop's next turn: what the burst queued
    held = time.perf_counter() - t0
    return held, node.ticks - ticks


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--robots", type=int, default=300, help="fleet size (default 300)")
    p.add_argument("--lost", type=int, default=150, help="tokens lost in one burst (default 150)")
    p.add_argument("--repeat", type=int, default=3, help="runs (default 3)")
    ns = p.parse_args(argv)
    if not 1 <= ns.lost <= ns.robots:
        p.error("--lost must be in 1..--robots")
    held: list[float] = []
    for _ in range(ns.repeat):
        # the node's log lines are written (their cost is real) but not shown
        with open(os.devnull, "w") as null, contextlib.redirect_stderr(null):
            s, ticks = asyncio.run(one(ns.robots, ns.lost))
        held.append(s)
        print(f"{ns.lost} of {ns.robots} tokens lost: loop held {1e3 * s:.1f} ms, {ticks} tick(s)")
    print(
        f"loop held p50 {1e3 * statistics.median(held):.1f} ms, max {1e3 * max(held):.1f} ms "
        f"over {ns.repeat} run(s)"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
