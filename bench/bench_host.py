"""Benchmark: the CPU an agent host spends per pose frame, in process (no Zenoh, no other process).

What ``formation up --robots N`` runs on the pose->wheels path of an agent host, fed from a
script instead of the bus: a :class:`robot_agent.node.host.HostNode` of the N robots of the default
scenario (paper-exp2 grown to N slots by the staged rule), every robot near its slot, the
formation moving along the scenario's line; per frame it gets a ``SetpointBatch`` (the
coordinator's) and a ``PoseBatch`` (the plant's) stamped now, steps its robots and encodes their
``WheelsBatch`` es (a publish callable that keeps nothing). Then a watchdog round (every robot
due, ``HostNode.step_due``), as the realtime host runs between two frames.

It prints, per handler, the **CPU time of this thread** (``time.thread_time``: what the host
costs, unlike wall time, hardly changed by other processes on a shared machine) p50 / mean /
min over the frames, per frame and per robot, and which modules of the path are compiled
(mypyc ``.so``, ``robot_agent.core._accel``) or pure Python, so the gain of compiling a module is
this bench run with and without it. Asserts that every robot tracks (a frame of robots in
HOLD would measure another path).

Usage: ``python bench/bench_host.py [--robots 100] [--frames 600]``. Prints; results:
docs/scale.md.
"""

from __future__ import annotations

import argparse
import gc
import importlib
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import runtime as rt
from bus_schemas import PoseBatch, SetpointBatch, encode, keys
from robot_agent.core.firmware import Mode
from robot_agent.node.host import HostNode
from scenario.resize import load_with_robots

FLEET = "bench"
PATH_MODULES = (
    "robot_agent.core.firmware",
    "robot_agent.core.safety_filter",
    "robot_agent.node.agent",
    "robot_agent.node.host",
    "robot_agent.core.host_grid",
    "robot_agent.core.neighbours",
    "bus_schemas.codec",
    "bus_schemas.spec",
    "bus_schemas.checks",
)


def compiled(module: str) -> bool:
    """The module was loaded from an extension (mypyc), not from its .py file."""
    path = getattr(importlib.import_module(module), "__file__", "") or ""
    return not path.endswith(".py")


def _stats(samples_s: list[float], robots: int) -> str:
    ms = sorted(s * 1e3 for s in samples_s)
    p50, mean = ms[len(ms) // 2], statistics.fmean(ms)
    return (
        f"p50 {p50:.3f} ms, mean {mean:.3f} ms, min {ms[0]:.3f} ms "
        f"({1e3 * p50 / robots:.1f} us per robot)"
    )


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--robots", type=int, default=100, help="robots in the host (100)")
    p.add_argument("--frames", type=int, default=600, help="pose frames (600)")
    args = p.parse_args()
    scn = load_with_robots("paper-exp2", args.robots)
    ids = list(scn.robot_ids)
    n = len(ids)
    slots = [(float(x), float(y)) for x, y, _ in scn.initial]
    speed = getattr(scn.trajectory, "speed_mps", 0.02)
    out = [0]

    def publish(key: str, payload: bytes, qos: object) -> None:
        out[0] += 1

    host = HostNode("h1", ids, FLEET, scn.agent, publish, rate_hz=1.0 / scn.dt_s)
    poses_key, setpoints_key = keys.poses_key(FLEET), keys.setpoints_key(FLEET)
    roles = tuple("leader" if i == 0 else "subleader" for i in range(n))
    frame_dt = 1.0 / scn.camera.rate_hz
    on_poses: list[float] = []
    watchdog: list[float] = []
    setpoints: list[float] = []
    gc.collect()
    gc.freeze()
    gc.disable()  # the realtime host collects by hand between frames (host_main)
    for k in range(args.frames):
        dx = speed * k * frame_dt
        wobble = 0.004 * ((k % 7) - 3)  # poses a few mm off their slots: the PIDs work
        now = time.monotonic()
        sp = SetpointBatch(
            t=now, seq=k + 1, robots=tuple(ids), slot=tuple(range(n)), role=roles,
            stage=(0,) * n, x=tuple(x + dx for x, _ in slots), y=tuple(y for _, y in slots),
            theta=0.0, vx=(speed,) * n, vy=(0.0,) * n,
        )  # fmt: skip
        pb = PoseBatch(
            t=now, seq=k + 1, robots=tuple(ids), x=tuple(x + dx + wobble for x, _ in slots),
            y=tuple(y - wobble for _, y in slots), theta=(0.0,) * n, stamp=now - 0.01,
        )  # fmt: skip
        sp_rx = rt.Received(key=setpoints_key, payload=encode(sp), rx_s=time.monotonic())
        t0 = time.thread_time()
        host.on_setpoints(sp_rx)
        setpoints.append(time.thread_time() - t0)
        pose_rx = rt.Received(key=poses_key, payload=encode(pb), rx_s=time.monotonic())
        t0 = time.thread_time()
        host.on_poses(pose_rx)
        on_poses.append(time.thread_time() - t0)
        t0 = time.thread_time()
        host.step_due(time.monotonic() + 2.0 * host.period_s)  # every robot due
        watchdog.append(time.thread_time() - t0)
        if k % 8 == 7:
            host.collect_garbage(time.monotonic())
    tracking = sum(node.firmware.mode is Mode.TRACKING for node in host.nodes.values())
    assert tracking == n, f"{n - tracking} robots not tracking: this would measure HOLD"
    assert host.faults.internal_errors == 0 and host.faults.rejected == 0
    warm = max(1, args.frames // 20)
    print(
        f"agent host of {n} robots ({scn.name} grown to {n} slots), {args.frames} frames, "
        f"thread CPU time per handler call (first {warm} frames left out):"
    )
    print(f"  pose frame (decode, step every robot, encode): {_stats(on_poses[warm:], n)}")
    print(f"  watchdog round (step every robot, encode):    {_stats(watchdog[warm:], n)}")
    print(f"  setpoint batch (decode, accept):              {_stats(setpoints[warm:], n)}")
    print(f"  {out[0]} messages published")
    done = [m for m in PATH_MODULES if compiled(m)]
    pure = [m for m in PATH_MODULES if not compiled(m)]
    print(f"  compiled: {', '.join(done) or 'none'}")
    print(f"  pure Python: {', '.join(pure) or 'none'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
