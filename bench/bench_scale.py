"""Benchmark: the distributed system at scale, N = 3 ... 1000 robots on this machine, realtime.

For each N it starts, as separate processes on a loopback router (fork+exec, free port):
``formation plant --batch``, ``formation coordinator --batch`` and ``--hosts`` agent hosts
(``formation agent-host``: each runs the firmware of N/hosts robots with batched I/O); with
``--per-robot`` (small N only) one ``formation agent`` per robot instead and no batching. The
scenario is ``lattice`` resized to N slots, every robot starting on its slot, at the control
rate asked (50 Hz for N <= 300, 20 Hz for N = 1000 by default: dt and camera rate both). It runs
``--duration`` s of wall time after the fleet is up, then prints, per N:

* **real time held**: frames the plant published / frames due (the camera rate x duration),
  the coordinator's ticks / ticks due, and the share of (robot, frame) pairs that got a command
  back computed from that frame (a robot whose loop falls behind skips frames);
* **control-loop latency** p50/p99/max: a frame's poses published by the plant -> the wheel
  command computed from it received back by the plant (plant's monotonic clock, both ends in one
  process: two Zenoh hops through the router plus the agent's decode, firmware step and
  encode), beside the bare Zenoh round trip measured in the same run;
* plant frame lateness p99 (a frame published after its due time: the plant fell behind);
* CPU (% of one core) and peak RSS of every process, and per robot;
* the coordinator's assignment time per tick (its status).

Measures only; asserts nothing. Results and the command: docs/scale.md.

Run: .venv/bin/python bench/bench_scale.py [--sizes 3,30,100,300,1000] [--duration 20]
     [--hosts 1] [--per-robot] [--rate-hz HZ] [--json FILE] [--quick]
"""

from __future__ import annotations

import argparse
import contextlib
import json
import sys
import tempfile
import threading
import time
import tomllib
from collections.abc import Iterator
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import msgpack
from common import cpu_s, free_port, measure_floor, running, vm_hwm_kib

import runtime as rt
import scenario as scenario_mod
from bus_schemas import keys
from scenario import scenario_with_robots, to_toml

PY = sys.executable


def scale_scenario(n: int, rate_hz: float, duration_s: float, tmp: Path) -> Path:
    """``lattice`` with N robots on their slots, control period = camera period = 1/rate."""
    data: dict[str, Any] = tomllib.loads(scenario_mod.resolve("lattice").read_text())
    data = scenario_with_robots(data, n)
    data["dt_s"] = round(1.0 / rate_hz, 6)
    data["duration_s"] = duration_s + 10.0
    data["camera"] = {**data.get("camera", {}), "rate_hz": rate_hz}
    path = tmp / f"lattice-{n}.toml"
    path.write_text(to_toml(data))
    scenario_mod.load(path)  # validate
    return path


class CoordinatorWatch:
    """The coordinator's status map (ticks, assignment timing) from a Zenoh subscription."""

    def __init__(self, endpoint: str, fleet: str) -> None:
        settings = rt.ZenohSettings(mode="client", connect=(endpoint,))
        self.session = rt.open_session(settings)
        self.latest: dict[str, Any] = {}
        self._lock = threading.Lock()
        self._sub = self.session.declare_subscriber(
            keys.coordinator_status_key(fleet, "main"), self._on
        )

    def _on(self, sample: Any) -> None:
        with contextlib.suppress(Exception):
            m = msgpack.unpackb(sample.payload.to_bytes())
            with self._lock:
                self.latest = m

    def snapshot(self) -> dict[str, Any]:
        with self._lock:
            return dict(self.latest)

    def close(self) -> None:
        self.session.close()


@contextlib.contextmanager
def fleet(
    n: int, scenario: Path, endpoint: str, hosts: int, per_robot: bool, rate_hz: float,
    duration_s: float, stats: Path, log: Any,
) -> Iterator[dict[str, Any]]:  # fmt: skip
    """Start plant, coordinator and agents (stderr to ``log``); yields {name: Popen}."""
    common = ["--endpoint", endpoint, "--lease-ms", "2000"]
    batch = [] if per_robot else ["--batch"]
    ids = [f"r{i + 1}" for i in range(n)]
    with contextlib.ExitStack() as stack:
        procs: dict[str, Any] = {}
        plant = [
            PY, "-m", "formation", "plant", "--scenario", str(scenario), "--wait-robots",
            "--duration", str(duration_s), "--stats-out", str(stats), *batch, *common,
        ]  # fmt: skip
        procs["plant"] = stack.enter_context(
            running(plant, ready="plant ready", timeout_s=60, stderr=log)
        )
        coord = [
            PY, "-m", "formation", "coordinator", "--scenario", str(scenario),
            "--rate-hz", str(rate_hz), *batch, *common,
        ]  # fmt: skip
        procs["coordinator"] = stack.enter_context(
            running(coord, ready="coordinator ready", timeout_s=60, stderr=log)
        )
        if per_robot:
            for rid in ids:
                argv = [
                    PY, "-m", "formation", "agent", "--id", rid, "--scenario", str(scenario),
                    "--rate-hz", str(rate_hz), *common,
                ]  # fmt: skip
                procs[f"agent {rid}"] = stack.enter_context(
                    running(argv, ready=f"agent {rid} ready", timeout_s=60, stderr=log)
                )
        else:
            h = max(1, min(hosts, n))
            for k in range(h):
                part = ids[k * n // h : (k + 1) * n // h]
                name = f"h{k + 1}"
                argv = [
                    PY, "-m", "formation", "agent-host", "--ids", ",".join(part), "--name", name,
                    "--scenario", str(scenario), "--rate-hz", str(rate_hz), *common,
                ]  # fmt: skip
                procs[f"agent-host {name}"] = stack.enter_context(
                    running(argv, ready=f"agent-host {name} ready", timeout_s=120, stderr=log)
                )
        yield procs


def measure(
    n: int, rate_hz: float, duration_s: float, hosts: int, per_robot: bool, floor_us: float,
    tmp: Path,
) -> dict[str, Any]:  # fmt: skip
    scenario = scale_scenario(n, rate_hz, duration_s, tmp)
    stats_path = tmp / f"plant-{n}.json"
    stats_path.unlink(missing_ok=True)
    router_argv = [PY, "-m", "formation", "router", "--listen", f"tcp/127.0.0.1:{free_port()}"]
    endpoint = router_argv[-1]
    with running(router_argv, ready="router listening on"):
        watch: CoordinatorWatch | None = None
        try:
            with (
                open(tmp / f"logs-{n}.txt", "wb") as log,
                fleet(
                    n, scenario, endpoint, hosts, per_robot, rate_hz, duration_s, stats_path, log
                ) as procs,
            ):
                # This process opens its session only after every child was spawned (fork+exec
                # after Zenoh started in this process is what the field notes forbid).
                watch = CoordinatorWatch(endpoint, "demo")
                pids = {name: p.pid for name, p in procs.items()}
                # The plant starts its clock once every token is up; measure from then on.
                deadline = time.monotonic() + 120.0
                while not watch.snapshot().get("ticks") and time.monotonic() < deadline:
                    time.sleep(0.1)
                c0 = {name: cpu_s(pid) for name, pid in pids.items()}
                s0, t0 = watch.snapshot(), time.monotonic()
                # Sample just before the plant's --duration ends (it exits then).
                time.sleep(max(0.0, 0.9 * duration_s - 0.5))
                t1 = time.monotonic()
                s1 = watch.snapshot()
                c1 = {}
                for name, pid in pids.items():
                    with contextlib.suppress(OSError):
                        c1[name] = cpu_s(pid)
                rss = {}
                for name, pid in pids.items():
                    with contextlib.suppress(OSError):
                        rss[name] = vm_hwm_kib(pid) / 1024.0
                procs["plant"].wait(timeout=duration_s + 60.0)
        finally:
            if watch is not None:
                watch.close()
    plant = json.loads(stats_path.read_text()) if stats_path.exists() else {}
    wall = t1 - t0
    cpu = {name: 100.0 * (c1.get(name, c0[name]) - c0[name]) / wall for name in c0}
    ticks = (s1.get("ticks", 0) or 0) - (s0.get("ticks", 0) or 0)
    frames_due = rate_hz * duration_s
    return {
        "n": n,
        "rate_hz": rate_hz,
        "mode": "per-robot agents" if per_robot else f"{min(hosts, n)} agent hosts, batched",
        "frames_ratio": plant.get("frames", 0) / frames_due if frames_due else 0.0,
        "ticks_ratio": ticks / (rate_hz * wall) if wall > 0 else 0.0,
        "answered": plant.get("commands", 0) / max(1, plant.get("frames", 0) * n),
        "latency_ms": plant.get("latency_ms"),
        "lateness_ms": plant.get("lateness_ms"),
        "floor_us": floor_us,
        "cpu": cpu,
        "rss_mib": rss,
        "collisions": plant.get("collisions"),
        "min_separation_m": plant.get("min_separation_m"),
        "coordinator": {"tick_ms": {"p50": s1.get("tick_p50_ms"), "max": s1.get("tick_max_ms")}},
    }


def report(r: dict[str, Any]) -> None:
    lat = r["latency_ms"] or {}
    late = r["lateness_ms"] or {}
    cpu = r["cpu"]
    agents = {k: v for k, v in cpu.items() if k.startswith("agent")}
    agent_cpu = sum(agents.values())
    agent_rss = sum(v for k, v in r["rss_mib"].items() if k.startswith("agent"))
    print(
        f"N={r['n']:5d} @ {r['rate_hz']:g} Hz ({r['mode']}): frames {100 * r['frames_ratio']:.1f} %"
        f", coordinator ticks {100 * r['ticks_ratio']:.1f} %, commands answered "
        f"{100 * r['answered']:.1f} %"
    )
    if lat:
        print(
            f"    latency pose->wheels p50 {lat['p50']:.2f} ms p99 {lat['p99']:.2f} ms "
            f"max {lat['max']:.1f} ms (bare Zenoh RTT p50 {r['floor_us'] / 1000:.3f} ms); "
            f"plant frame lateness p99 {late.get('p99', float('nan')):.2f} ms"
        )
    print(
        f"    CPU % of a core: plant {cpu.get('plant', 0):.0f}, coordinator "
        f"{cpu.get('coordinator', 0):.0f}, agents {agent_cpu:.0f} ({agent_cpu / r['n']:.2f} per "
        f"robot); peak RSS MiB: plant {r['rss_mib'].get('plant', 0):.0f}, coordinator "
        f"{r['rss_mib'].get('coordinator', 0):.0f}, agents {agent_rss:.0f} "
        f"({agent_rss / r['n']:.2f} per robot)"
    )
    coord = r["coordinator"]
    if coord:
        print(f"    coordinator: {coord}")
    print(f"    collisions {r['collisions']}, min separation {r['min_separation_m']}", flush=True)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--sizes", default="3,30,100,300,1000", help="robot counts")
    ap.add_argument("--duration", type=float, default=20.0, help="wall seconds measured per N")
    ap.add_argument("--hosts", type=int, default=1, help="agent-host processes (1)")
    ap.add_argument("--per-robot", action="store_true", help="one agent process per robot")
    ap.add_argument("--rate-hz", type=float, default=None, help="force one rate for every N")
    ap.add_argument("--json", metavar="FILE", help="also write the results as JSON")
    ap.add_argument("--quick", action="store_true", help="smoke run: N = 3, 100 for 8 s each")
    ns = ap.parse_args()
    if ns.quick:
        ns.sizes, ns.duration = "3,100", 8.0
    sizes = [int(s) for s in ns.sizes.split(",") if s.strip()]
    floor = measure_floor(n=1000, warmup=100)
    floor_us = floor.p50_us
    print(
        f"bare Zenoh round trip (router, same run): p50 {floor_us:.0f} us p99 {floor.p99_us:.0f} us"
    )
    results = []
    with tempfile.TemporaryDirectory(prefix="bench-scale-") as tmp:
        for n in sizes:
            rate = ns.rate_hz or (50.0 if n <= 300 else 20.0)
            r = measure(n, rate, ns.duration, ns.hosts, ns.per_robot, floor_us, Path(tmp))
            report(r)
            results.append(r)
    if ns.json:
        Path(ns.json).write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
