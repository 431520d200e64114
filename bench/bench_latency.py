"""Pose-to-wheel-command latency of the distributed runtime in realtime, and the agents' cost.

For 3 and 30 robots, ``formation up`` (realtime) runs the chevron scenario resized to N robots
with the camera latency set to 0, so a pose's ``t`` is the instant the plant captured and
published it. This process subscribes (its own Zenoh client session to the run's router) to every
robot's ``pose`` and ``wheels`` and stamps each sample with ``time.monotonic()`` on arrival; every
process of the run is on this host, so all times are on one clock.

* pose -> wheels: for each wheels message, receive time minus its ``pose_t``, counting only the
  first command computed from each pose (the agent steps on the pose's arrival; later commands
  with the same ``pose_t`` come from its 50 Hz watchdog timer and are not a latency).
  The path: plant publishes -> router -> agent (asyncio bridge, strict decode, firmware step,
  encode) -> router -> this process; two router hops, like the bare round trip below.
* pose -> here: the pose's own receive time minus its ``t`` (plant publish + one hop), so the
  difference is what the agent adds.
* the floor: :func:`common.measure_floor` (bare Zenoh round trip through a router between two
  processes; callback receive, and through the asyncio bridge the nodes use), measured in the
  same run.
* per agent process: CPU over the measurement window (``/proc/<pid>/stat`` utime + stime, % of
  one core) and peak resident memory (``VmHWM`` of ``/proc/<pid>/status``).

Usage: ``python bench/bench_latency.py [--robots 3 30] [--window 15]``. Prints; asserts nothing.
"""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
import tomllib
from pathlib import Path
from typing import Any

import msgpack
import zenoh
from common import (
    REPO_ROOT,
    LatencyStats,
    cpu_s,
    free_port,
    measure_floor,
    print_latency,
    print_latency_header,
    vm_hwm_kib,
)

import runtime as rt
import scenario
from scenario import to_toml

FLEET = "bench"


def agent_pids(root: int) -> dict[int, str]:
    """pid -> robot id of every ``formation agent`` descendant of ``root``."""
    children: dict[int, list[int]] = {}
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                raw = Path(f"/proc/{entry}/stat").read_text(errors="replace")
            except OSError:
                continue
            ppid = int(raw[raw.rfind(")") + 2 :].split()[1])
            children.setdefault(ppid, []).append(int(entry))
    out: dict[int, str] = {}
    frontier = [root]
    while frontier:
        for pid in children.get(frontier.pop(), []):
            frontier.append(pid)
            try:
                args = Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")
            except OSError:
                continue
            if b"agent" in args and b"--id" in args:
                out[pid] = args[args.index(b"--id") + 1].decode()
    return out


def bench_scenario(tmp: Path) -> Path:
    """chevron7 with a camera that publishes at capture time (latency 0)."""
    data: dict[str, Any] = tomllib.loads(scenario.resolve("chevron7").read_text())
    data["camera"] = {**data.get("camera", {}), "latency_s": 0.0}
    path = tmp / "latency-bench.toml"
    path.write_text(to_toml(data))
    return path


class Recorder:
    """Receive times of every pose and wheels sample (Zenoh callback: stamp, copy, return)."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.samples: list[tuple[float, str, bytes]] = []

    def __call__(self, sample: zenoh.Sample) -> None:
        rx = time.monotonic()
        item = (rx, str(sample.key_expr), sample.payload.to_bytes())
        with self.lock:
            self.samples.append(item)

    def take(self) -> list[tuple[float, str, bytes]]:
        with self.lock:
            out, self.samples = self.samples, []
        return out


def measure(n: int, window_s: float, tmp: Path) -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    argv = [
        sys.executable, "-m", "formation", "up", "--scenario", str(bench_scenario(tmp)),
        "--robots", str(n), "--duration", "600", "--quiet", "--no-figures",
        "--endpoint", endpoint, "--fleet", FLEET, "--out", str(tmp / f"run{n}"),
        "--ready-timeout", "120",
    ]  # fmt: skip
    env = dict(os.environ, PYTHONPATH=str(REPO_ROOT))
    up = subprocess.Popen(argv, cwd=REPO_ROOT, env=env)
    rec = Recorder()
    session = rt.open_session(rt.ZenohSettings(connect=(endpoint,), open_timeout_s=60.0))
    try:
        session.declare_subscriber(f"formation/{FLEET}/robot/*/wheels", rec)
        session.declare_subscriber(f"formation/{FLEET}/robot/*/pose", rec)
        # steady state: every robot's agent commands from poses
        deadline = time.monotonic() + 180.0
        tracking: set[str] = set()
        while len(tracking) < n:
            if time.monotonic() > deadline or up.poll() is not None:
                print(f"  {n} robots: no steady state (formation up status {up.poll()})")
                return
            for _, key, payload in rec.take():
                if key.endswith("/wheels") and msgpack.unpackb(payload).get("pose_t"):
                    tracking.add(key.split("/")[-2])
            time.sleep(0.1)
        time.sleep(1.0)
        rec.take()
        agents = agent_pids(up.pid)
        cpu0 = {pid: cpu_s(pid) for pid in agents}
        t0 = time.monotonic()
        time.sleep(window_s)
        samples = rec.take()
        wall = time.monotonic() - t0
        cpu_pct = [100.0 * (cpu_s(pid) - cpu0[pid]) / wall for pid in agents]
        hwm_mib = [vm_hwm_kib(pid) / 1024.0 for pid in agents]
    finally:
        session.close()
        up.send_signal(signal.SIGINT)
        try:
            up.wait(timeout=30)
        except subprocess.TimeoutExpired:
            up.kill()
            up.wait()

    pose_rx: dict[tuple[str, float], float] = {}
    first_cmd: dict[tuple[str, float], float] = {}
    for rx, key, payload in samples:
        m = msgpack.unpackb(payload)
        robot, leaf = key.split("/")[-2:]
        if leaf == "pose":
            pose_rx.setdefault((robot, m["t"]), rx)
        elif m.get("pose_t") is not None:
            first_cmd.setdefault((robot, m["pose_t"]), rx)
    wheels_lat = [rx - pose_t for (_, pose_t), rx in first_cmd.items()]
    pose_lat = [rx - pose_t for (_, pose_t), rx in pose_rx.items()]
    agent_lat = [rx - pose_rx[k] for k, rx in first_cmd.items() if k in pose_rx]
    label = f"{n} robots"
    print_latency(f"{label}: pose t -> wheels here", LatencyStats.from_samples(wheels_lat))
    print_latency(f"{label}: pose t -> pose here", LatencyStats.from_samples(pose_lat))
    print_latency(f"{label}: pose here -> wheels here", LatencyStats.from_samples(agent_lat))
    rate = len(first_cmd) / wall / n
    print(
        f"   {n} agents over {wall:.1f} s ({rate:.1f} pose-driven commands/s per robot): CPU "
        f"mean {sum(cpu_pct) / len(cpu_pct):.1f}% max {max(cpu_pct):.1f}% of one core; "
        f"peak RSS (VmHWM) mean {sum(hwm_mib) / len(hwm_mib):.1f} MiB max {max(hwm_mib):.1f} MiB",
        flush=True,
    )


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--robots", type=int, nargs="+", default=[3, 30], help="robot counts")
    p.add_argument("--window", type=float, default=15.0, help="measurement window, s")
    args = p.parse_args()
    print(f"pose -> wheels latency, realtime, {os.cpu_count()} CPUs, one host (monotonic clock)")
    floor = measure_floor()
    floor_asyncio = measure_floor(receive="asyncio")
    print_latency_header()
    print_latency("zenoh floor: round trip via router", floor)
    print_latency("  same, received through asyncio", floor_asyncio)
    with tempfile.TemporaryDirectory(prefix="bench-latency-") as tmp:
        for n in args.robots:
            measure(n, args.window, Path(tmp))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
