"""Lockstep speed of the distributed runtime: sim seconds per wall second (goal >= 20x, 3 robots).

Runs ``formation up --lockstep`` (router, plant, coordinator, one agent per robot, the launcher's
collector) as a subprocess tree for ``--duration`` sim seconds of paper-exp2 and reports:

* speed: sim seconds / wall seconds between the first and the last truth frame the launcher
  received (start-up and shutdown excluded; they are printed separately);
* CPU seconds of every process of the run over the whole run (from ``/proc/<pid>/stat``
  utime + stime, sampled until each process exits) and the launcher's own;
* the in-process simulator on the same scenario and duration, for reference.

Each robot count runs twice: one ``formation agent`` process per robot, and one
``formation agent-host`` for all robots with the batched bus (``--hosts 1``, docs/scale.md).

``--marginal S`` also runs each configuration for ``S`` sim seconds (less than ``--duration``)
and prints the CPU milliseconds per tick of each process kind over the ticks the longer run
added: start-up, shutdown and the launcher's end-of-run work cancel out, what remains is the
steady lockstep's cost per tick (at 50 Hz, 20x real time is 1 ms of wall per tick: on 2 cores
the sum must stay well under 2 ms); and the context switches per tick of each kind (every
thread's, voluntary and not, from ``/proc/<pid>/task/*/status``): the cost of a tick is mostly
wake-ups, and their count moves less with the machine's load than the CPU time does.

Usage: ``python bench/bench_lockstep.py [--duration 60] [--robots 3 ...] [--marginal 6]``.
Prints; asserts nothing.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from common import REPO_ROOT, free_port

CLK_TCK = os.sysconf("SC_CLK_TCK")


def context_switches(pid: int) -> int:
    """Context switches (voluntary and not) of every thread of ``pid`` so far (0 if gone)."""
    total = 0
    try:
        tasks = os.listdir(f"/proc/{pid}/task")
    except OSError:
        return 0
    for tid in tasks:
        try:
            text = Path(f"/proc/{pid}/task/{tid}/status").read_text()
        except OSError:
            continue
        for line in text.splitlines():
            if "ctxt_switches:" in line:
                total += int(line.split()[1])
    return total


def proc_table() -> dict[int, tuple[int, float, str]]:
    """pid -> (ppid, cpu seconds, short command) of every process, from /proc."""
    out: dict[int, tuple[int, float, str]] = {}
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            raw = Path(f"/proc/{entry}/stat").read_text(errors="replace")
            cmd = Path(f"/proc/{entry}/cmdline").read_bytes().split(b"\0")
        except OSError:
            continue
        f = raw[raw.rfind(")") + 2 :].split()
        cpu = (int(f[11]) + int(f[12])) / CLK_TCK
        args = [a.decode(errors="replace") for a in cmd if a]
        name = " ".join(args[3:5]) if len(args) > 4 and args[1:3] == ["-m", "formation"] else "?"
        if name.startswith("agent-host"):
            name = "agent-host"
        elif name.startswith("agent"):
            name = f"agent {args[args.index('--id') + 1]}" if "--id" in args else "agent"
        out[int(entry)] = (int(f[1]), cpu, name.split(" --")[0])
    return out


def descendants(root: int, table: dict[int, tuple[int, float, str]]) -> list[int]:
    found, frontier = [], [root]
    while frontier:
        p = frontier.pop()
        kids = [pid for pid, (ppid, _, _) in table.items() if ppid == p]
        found += kids
        frontier += kids
    return found


def watch_tree_cpu(
    proc: subprocess.Popen[str] | subprocess.Popen[bytes], period_s: float = 0.2
) -> tuple[tuple[float, int], dict[int, tuple[str, float, int]]]:
    """Until ``proc`` exits: its (CPU seconds, context switches) and, per descendant pid, (short
    command, CPU seconds, context switches), each the largest value seen (a process that exited
    keeps its last reading)."""
    cpu: dict[int, tuple[str, float, int]] = {}
    launcher = (0.0, 0)
    while proc.poll() is None:
        table = proc_table()
        if proc.pid in table:
            launcher = (table[proc.pid][1], max(launcher[1], context_switches(proc.pid)))
        for pid in descendants(proc.pid, table):
            old = cpu.get(pid, (table[pid][2], 0.0, 0))  # a zombie has no cmdline: keep it
            switches = max(context_switches(pid), old[2])
            cpu[pid] = (old[0], max(table[pid][1], old[1]), switches)
        time.sleep(period_s)
    return launcher, cpu


def run_lockstep(
    robots: int, duration_s: float, out: Path, hosts: int = 0, *, quiet: bool = False
) -> dict[str, tuple[float, int]] | None:
    """One ``formation up --lockstep`` run; prints its figures (unless ``quiet``) and returns
    the (CPU seconds, context switches) by process kind (None if it failed)."""
    argv = [
        sys.executable, "-m", "formation", "up", "--scenario", "paper-exp2", "--lockstep",
        "--duration", str(duration_s), "--robots", str(robots), "--quiet", "--no-figures",
        "--endpoint", f"tcp/127.0.0.1:{free_port()}", "--fleet", "bench", "--out", str(out),
        "--hosts", str(hosts),
    ]  # fmt: skip
    env = dict(os.environ, PYTHONPATH=str(REPO_ROOT))
    wall0 = time.monotonic()
    proc = subprocess.Popen(argv, cwd=REPO_ROOT, env=env)
    launcher, cpu = watch_tree_cpu(proc, 0.2)
    wall = time.monotonic() - wall0
    if proc.returncode != 0:
        print(f"  formation up failed with status {proc.returncode}; see {out}/logs/")
        return None
    by_name: dict[str, tuple[float, int]] = {}
    for name, seconds, switches in cpu.values():
        key = "agents (sum)" if name.startswith("agent") else name
        had = by_name.get(key, (0.0, 0))
        by_name[key] = (had[0] + seconds, had[1] + switches)
    by_name["launcher (collector)"] = launcher
    if quiet:
        return by_name
    m = json.loads((out / "metrics.json").read_text())
    meta = m["meta"]
    sim_s = m["run"]["duration_s"]
    run_wall = meta["run_wall_s"]
    how = f"{hosts} agent host(s), batched bus" if hosts else "one agent process per robot"
    print(
        f"  {robots} robots, {how}: {sim_s:.1f} sim s in {run_wall:.2f} wall s = "
        f"{sim_s / run_wall:.1f}x real time  (whole command {wall:.1f} s: start-up "
        f"{meta['wall_s'] - run_wall - (meta['stop_s'] or 0):.1f} s, stop {meta['stop_s']:.2f} s)"
    )
    timeouts = (meta.get("plant") or {}).get("timeouts")
    exact = "the plant's account missing" if timeouts is None else f"{timeouts} plant timeouts"
    print(
        f"    ticks {m['run']['ticks']} truth frames; final leader {m['run']['final_leader']}; "
        f"{exact}{'' if not timeouts else ' (NOT the simulator run: not comparable)'}"
    )
    row = ", ".join(f"{k} {v[0]:.1f}" for k, v in sorted(by_name.items(), key=lambda kv: -kv[1][0]))
    print(f"    CPU seconds (2 cores, {2 * wall:.0f} core-s available): {row}")
    return by_name


def print_marginal(
    long: dict[str, tuple[float, int]] | None,
    short: dict[str, tuple[float, int]] | None,
    duration_s: float,
    short_s: float,
    dt_s: float,
) -> None:
    """The CPU and the context switches per tick of the ticks the longer run added, by
    process kind."""
    if long is None or short is None:
        return
    ticks = (duration_s - short_s) / dt_s
    for what, scale, fmt, i in (("CPU ms", 1000.0, ".2f", 0), ("context switches", 1.0, ".1f", 1)):
        per_tick = {k: scale * (v[i] - short.get(k, (0.0, 0))[i]) / ticks for k, v in long.items()}
        ranked = sorted(per_tick.items(), key=lambda kv: -kv[1])
        row = ", ".join(f"{k} {v:{fmt}}" for k, v in ranked)
        total = sum(per_tick.values())
        print(f"    {what} per tick ({duration_s:g} s run minus {short_s:g} s run): {row}; "
              f"total {total:{fmt}}")  # fmt: skip


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--duration", type=float, default=60.0, help="sim seconds per run")
    p.add_argument("--robots", type=int, nargs="+", default=[3], help="robot counts")
    p.add_argument(
        "--marginal",
        type=float,
        default=None,
        metavar="S",
        help="also run S sim seconds and print the CPU per tick of the difference",
    )
    args = p.parse_args()
    if args.marginal is not None and not 0 < args.marginal < args.duration:
        p.error(f"--marginal must be above 0 and below --duration ({args.duration:g})")
    import scenario
    from formation.sim import simulate

    print(f"lockstep speed, paper-exp2, {args.duration:g} sim s per run, {os.cpu_count()} CPUs")
    scn = scenario.load("paper-exp2")
    ref = simulate.run(scn, duration_s=args.duration)
    print(f"  in-process simulator (reference, one process): {ref.realtime_factor:.1f}x real time")
    with tempfile.TemporaryDirectory(prefix="bench-lockstep-") as tmp:
        for n in args.robots:
            for hosts, name in ((0, f"r{n}"), (1, f"r{n}-host")):
                cpu = run_lockstep(n, args.duration, Path(tmp) / name, hosts=hosts)
                if args.marginal is not None:
                    short = run_lockstep(
                        n, args.marginal, Path(tmp) / f"{name}-short", hosts=hosts, quiet=True
                    )
                    print_marginal(cpu, short, args.duration, args.marginal, scn.dt_s)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
