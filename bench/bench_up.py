"""Benchmark: ``formation up --robots N`` with no fleet option, realtime (issue 18, goal: N = 100
holds real time with pose->wheels p99 < 10 ms on this machine).

Runs, as a subprocess tree, exactly::

    formation up --robots N --duration D --endpoint tcp/127.0.0.1:<port> --out <tmp> --no-figures

(the endpoint only to stay off other runs' default port; ``--out``/``--duration``/
``--no-figures`` do not change the fleet). So the launcher decides the processes itself (the
automatic agent-host rule of ``formation.launch.plan.auto_hosts``; its ``fleet:`` banner line is
printed here) on the default scenario (paper-exp2's triangle grown to N slots by the staged
rule, its 50 Hz control and 30 Hz camera). Per run it prints:

* the fleet line of the banner (slots, stages, spares, processes and why);
* **real time held**: pose frames the plant published / frames due (camera rate x duration),
  commands answered / (robots x frames), the launcher's realtime factor;
* **pose->wheels latency** p50 / p99 / max, measured inside the plant as in bench_scale.py
  (``plant_stats.json`` the plant writes: a frame's poses published -> the wheel command
  computed from that frame received back; two Zenoh hops through the router plus the agent's
  decode, firmware step and encode), and the plant's frame lateness p99;
* CPU seconds of every process of the run (``/proc``), and the machine's load average before
  and after (the machine is shared: a load well above 2 inflates the tail);
* once, which modules of the frame path are compiled (mypyc) and which run as Python
  (``bench_host.PATH_MODULES``; the nodes load the same tree with the same environment).

Usage: ``python bench/bench_up.py [--robots 100] [--duration 20] [--repeat 3] [--keep DIR]
[--hosts N]`` (``--keep``: leave each run's directory, logs included, under DIR; ``--hosts``:
pass ``--hosts N`` to ``formation up``, for a comparison with the automatic choice). Prints;
asserts nothing.
Results and the command: docs/benchmarks.md, docs/scale.md.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

from bench_host import PATH_MODULES, compiled
from bench_lockstep import watch_tree_cpu
from common import REPO_ROOT, free_port


def run_up(
    robots: int, duration_s: float, out: Path, extra: list[str] | None = None
) -> dict[str, object] | None:
    argv = [
        sys.executable, "-m", "formation", "up", "--robots", str(robots),
        "--duration", str(duration_s), "--endpoint", f"tcp/127.0.0.1:{free_port()}",
        "--out", str(out), "--no-figures", *(extra or []),
    ]  # fmt: skip
    env = dict(os.environ, PYTHONPATH=str(REPO_ROOT))
    load0 = os.getloadavg()[0]
    proc = subprocess.Popen(argv, cwd=REPO_ROOT, env=env, stdout=subprocess.PIPE, text=True)
    launcher_cpu, cpu = watch_tree_cpu(proc, 0.5)
    stdout = proc.stdout.read() if proc.stdout is not None else ""
    load1 = os.getloadavg()[0]
    banner = next((ln.strip() for ln in stdout.splitlines() if "fleet:" in ln), "(no banner)")
    print(f"  {banner}")
    if proc.returncode != 0:
        print(f"  formation up exited with status {proc.returncode}; see {out}/logs/")
        if not (out / "plant_stats.json").exists() or not (out / "metrics.json").exists():
            return None
        print("  (the run itself completed: its figures follow)")
    stats = json.loads((out / "plant_stats.json").read_text())
    m = json.loads((out / "metrics.json").read_text())
    import scenario

    rate = scenario.load(str(out / "scenario.toml")).camera.rate_hz
    frames, commands = stats["frames"], stats["commands"]
    lat, late = stats["latency_ms"] or {}, stats["lateness_ms"] or {}
    by_name: dict[str, float] = {}
    for name, seconds in cpu.values():
        key = "agents (sum)" if name.startswith("agent") else name
        by_name[key] = by_name.get(key, 0.0) + seconds
    by_name["launcher"] = launcher_cpu
    rf = m["meta"]["realtime_factor"]
    print(
        f"  frames {100 * frames / (rate * duration_s):.1f} % of due ({frames} at {rate:g} Hz), "
        f"answered {100 * commands / max(1, frames * robots):.1f} %, realtime factor "
        f"{rf if rf is None else f'{rf:.2f}'}; collisions {m['run']['collisions']}"
    )
    if lat:
        print(
            f"  latency pose->wheels p50 {lat['p50']:.2f} ms p99 {lat['p99']:.2f} ms "
            f"max {lat['max']:.1f} ms; frame lateness p99 {late.get('p99', float('nan')):.2f} ms"
        )
    steady = stats.get("latency_steady_ms")
    if steady:
        print(
            f"  steady state (from 2 s after the first answer to 0.5 s before the end): "
            f"p50 {steady['p50']:.2f} ms p99 {steady['p99']:.2f} ms max {steady['max']:.1f} ms"
        )
    row = ", ".join(f"{k} {v:.1f}" for k, v in sorted(by_name.items(), key=lambda kv: -kv[1]))
    print(f"  CPU seconds: {row}")
    print(f"  load average (1 min) before {load0:.2f}, after {load1:.2f}", flush=True)
    return {
        "latency_ms": lat, "latency_steady_ms": steady, "lateness_ms": late, "frames": frames,
        "commands": commands,
    }  # fmt: skip


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--robots", type=int, default=100, help="robots (default 100)")
    p.add_argument("--duration", type=float, default=20.0, help="wall seconds per run (20)")
    p.add_argument("--repeat", type=int, default=3, help="runs (3)")
    p.add_argument(
        "--keep",
        metavar="DIR",
        help="write the runs' directories (logs, stats) under DIR and keep them",
    )
    p.add_argument(
        "--hosts",
        type=int,
        metavar="N",
        help="pass --hosts N to formation up (a comparison; the issue's figure is without it)",
    )
    args = p.parse_args()
    extra = [] if args.hosts is None else ["--hosts", str(args.hosts)]
    print(
        f"formation up --robots {args.robots}, realtime, {args.duration:g} s per run, "
        f"{os.cpu_count()} CPUs{'' if not extra else ', ' + ' '.join(extra)}"
    )
    # what the nodes load (same tree, same environment): compiled (mypyc) or pure Python
    done = [m for m in PATH_MODULES if compiled(m)]
    print(f"compiled on the frame path: {', '.join(done) or 'nothing (pure Python)'}")
    with tempfile.TemporaryDirectory(prefix="bench-up-") as tmp:
        base = Path(args.keep or tmp)
        base.mkdir(parents=True, exist_ok=True)
        for k in range(args.repeat):
            print(f"run {k + 1}:")
            run_dir = Path(tempfile.mkdtemp(prefix=f"run{k}-", dir=base))
            run_up(args.robots, args.duration, run_dir, extra)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
