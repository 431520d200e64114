"""Lockstep: the CPU of the nodes' tick handlers, hot in one process against inside the real run.

The same handlers measured twice (each call's CPU time on its own thread, ``time.thread_time``;
a handler's own time only: a measured handler called from inside another one is subtracted from
the outer one):

* **hot**: paper-exp2's plant, coordinator and one agent per robot wired in this one process
  through an in-memory bus (every message encoded and decoded, delivered in publication order),
  as ``tests/support/lockstep_equality.py`` wires them: the handlers' work with warm caches;
* **in the run**: ``formation up --lockstep`` over Zenoh with one process per robot, the same
  wrappers installed in every child by a ``sitecustomize`` module put on ``PYTHONPATH`` for
  the run (a temporary folder; nothing in the repository is patched).

The handlers: the agent's clock (the firmware step and the wheels' put included), setpoint and
frame handlers; the plant's answers (wheels, leader); the coordinator's clock (its tick and
puts) and frames. Prints microseconds per call for each, and their ratio: how much slower the
same Python runs when seven processes share two cores (docs/benchmarks.md, "Lockstep 20x with
one process per robot: out of reach on this machine"). Each call also pays two clock reads
(about 1 us). Asserts nothing.

Usage: ``python bench/bench_lockstep_handlers.py [--duration 30]``.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

from common import REPO_ROOT, free_port

# The wrappers, as source: executed here for the hot run and by the children's sitecustomize.
WRAPPERS = r"""
import atexit, json, os, sys, threading, time

STATS = {}
_LOCAL = threading.local()
_OUT = os.environ.get("BENCH_HANDLERS_DIR")


def _dump():
    if _OUT and STATS:
        role = next((a for a in sys.argv[1:] if not a.startswith("-")), "?")
        path = os.path.join(_OUT, f"{role}-{os.getpid()}.json")
        with open(path + ".tmp", "w") as f:
            json.dump(STATS, f)
        os.replace(path + ".tmp", path)


def _wrap(cls, name, label):
    inner = getattr(cls, name)

    def measured(self, *args, **kwargs):
        stack = getattr(_LOCAL, "stack", None)
        if stack is None:
            stack = _LOCAL.stack = [0.0]
        stack.append(0.0)
        t0 = time.thread_time()
        try:
            return inner(self, *args, **kwargs)
        finally:
            spent = time.thread_time() - t0
            nested = stack.pop()
            stack[-1] += spent
            entry = STATS.setdefault(label, [0, 0.0])
            entry[0] += 1
            entry[1] += spent - nested
            if _OUT and entry[0] % 1000 == 0:  # (and at exit: a process that ends fast)
                _dump()

    setattr(cls, name, measured)


def install():
    from coordinator.node.coordinator import CoordinatorNode
    from robot_agent.node.agent import AgentNode
    from sim_plant.node.inputs import PlantInputs

    for cls, name, label in (
        (AgentNode, "on_clock", "agent on_clock"),
        (AgentNode, "on_setpoint", "agent on_setpoint"),
        (AgentNode, "on_poses", "agent on_poses"),
        (PlantInputs, "on_wheels", "plant on_wheels"),
        (PlantInputs, "on_leader", "plant on_leader"),
        (CoordinatorNode, "on_clock", "coordinator on_clock"),
        (CoordinatorNode, "on_poses", "coordinator on_poses"),
    ):
        _wrap(cls, name, label)
    if _OUT:
        atexit.register(_dump)
"""

SITECUSTOMIZE = (
    "import os\n"
    "if os.environ.get('BENCH_HANDLERS_DIR'):\n"
    "    _ns = {}\n"
    f"    exec(compile({WRAPPERS!r}, 'bench_lockstep_handlers', 'exec'), _ns)\n"
    "    _ns['install']()\n"
)


def hot(duration_s: float) -> dict[str, list[float]]:
    """The handlers' own CPU per call, the nodes wired in this process (the in-memory bus of
    ``tests/support/lockstep_equality.py``; the plant's loop on this thread)."""
    sys.path.insert(0, str(REPO_ROOT / "tests"))
    from support.lockstep_equality import wire_in_memory

    from scenario import load

    ns: dict[str, object] = {}
    exec(compile(WRAPPERS, "bench_lockstep_handlers", "exec"), ns)
    ns["install"]()  # type: ignore[operator]
    with contextlib.redirect_stderr(io.StringIO()):  # the nodes' log lines
        wired = wire_in_memory(load("paper-exp2"), duration_s, fleet="hot")
        assert wired.plant.run_lockstep_blocking() is True
    return ns["STATS"]  # type: ignore[return-value]


def in_run(duration_s: float) -> tuple[dict[str, list[float]], float]:
    """The same, summed over the children of one ``formation up --lockstep`` (one agent per
    robot); and the run's speed (sim s per wall s)."""
    with tempfile.TemporaryDirectory() as tmp:
        site = Path(tmp) / "site"
        site.mkdir()
        (site / "sitecustomize.py").write_text(SITECUSTOMIZE)
        stats_dir = Path(tmp) / "stats"
        stats_dir.mkdir()
        out = Path(tmp) / "out"
        env = dict(
            os.environ,
            PYTHONPATH=os.pathsep.join((str(site), str(REPO_ROOT))),
            BENCH_HANDLERS_DIR=str(stats_dir),
        )
        argv = [
            sys.executable, "-m", "formation", "up", "--scenario", "paper-exp2", "--lockstep",
            "--duration", str(duration_s), "--robots", "3", "--quiet", "--no-figures",
            "--endpoint", f"tcp/127.0.0.1:{free_port()}", "--fleet", "handlers",
            "--out", str(out),
        ]  # fmt: skip
        subprocess.run(argv, cwd=REPO_ROOT, env=env, check=True)
        meta = json.loads((out / "metrics.json").read_text())
        speed = meta["run"]["duration_s"] / meta["meta"]["run_wall_s"]
        total: dict[str, list[float]] = {}
        for f in stats_dir.glob("*.json"):
            for label, (calls, cpu) in json.loads(f.read_text()).items():
                entry = total.setdefault(label, [0, 0.0])
                entry[0] += calls
                entry[1] += cpu
        return total, speed


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--duration", type=float, default=30.0, help="sim seconds of each run")
    args = p.parse_args()
    load = os.getloadavg()[0]
    warm = hot(args.duration)
    run, speed = in_run(args.duration)
    print(
        f"lockstep handlers, paper-exp2, 3 robots, {args.duration:g} sim s, "
        f"{os.cpu_count()} CPUs, load {load:.1f}"
    )
    print(f"  the run over Zenoh (one process per robot): {speed:.1f}x real time")
    print(f"  {'handler':24s} {'calls':>7s} {'hot us/call':>12s} {'run us/call':>12s}  ratio")
    for label in sorted(warm):
        h_calls, h_cpu = warm[label]
        r_calls, r_cpu = run.get(label, (0, 0.0))
        hot_us = 1e6 * h_cpu / h_calls if h_calls else float("nan")
        run_us = 1e6 * r_cpu / r_calls if r_calls else float("nan")
        print(
            f"  {label:24s} {int(r_calls):7d} {hot_us:12.1f} {run_us:12.1f}  {run_us / hot_us:5.1f}"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
