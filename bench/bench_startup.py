"""Start-up cost: what a process of each kind spends on its imports, and a whole short run.

Every fleet this project starts (``formation up``, each test of tier 2, a respawned node) pays
each process's imports once: a fresh interpreter that imports zenoh, numpy, the cores it runs.
This bench prints, for each process kind, the CPU seconds (user + system, of the child) of a
fresh ``python -c "import MODULE"`` of the module its subcommand runs, beside the floors measured
in the same run: ``python -c pass`` (the interpreter alone) and ``import zenoh, numpy``. Then the
CPU seconds of every process of a whole ``formation up --lockstep --duration 2`` of paper-exp2
with 3 robots (router, plant, coordinator, agents, the launcher), and its wall time.

``--against DIR`` runs the same measurements in another checkout of this repository (for
example ``git worktree add DIR <commit>``, with the compiled builds copied in: ``make accel``'s
``robot_agent/_compiled``, ``sim_plant/_compiled``, ``coordinator/_compiled``) alternating with
this one, run by run, so both see the same machine. The medians are printed.

Usage: ``python bench/bench_startup.py [--repeat 5] [--against DIR]``. Prints; asserts nothing.
"""

from __future__ import annotations

import argparse
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from common import REPO_ROOT, free_port

# process kind -> the module its ``formation`` subcommand imports (formation.cli.SUBCOMMANDS)
KINDS: dict[str, str] = {
    "router": "formation.launch.router",
    "plant": "sim_plant.node.main",
    "coordinator": "coordinator.node.main",
    "agent": "robot_agent.node.main",
    "launcher": "formation.launch.launcher",
}
FLOORS: dict[str, str] = {"python -c pass": "pass", "import zenoh, numpy": "import zenoh, numpy"}


def child_cpu_s(argv: list[str], cwd: Path, timeout_s: float = 120.0) -> tuple[float, float]:
    """Run ``argv`` to its end; (CPU seconds of it and its children, wall seconds)."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    env = dict(os.environ, PYTHONPATH=str(cwd))
    t0 = time.monotonic()
    subprocess.run(argv, cwd=cwd, env=env, check=True, timeout=timeout_s, capture_output=True)
    wall = time.monotonic() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return cpu, wall


def import_cpu_s(code: str, cwd: Path) -> float:
    return child_cpu_s([sys.executable, "-c", code], cwd)[0]


def check_cpu_s(cwd: Path) -> float:
    """The launcher's scenario check (``scenario.check.check_cores``) of paper-exp2, imports
    included: what ``formation up`` does before it starts anything."""
    code = (
        "from scenario import load; from scenario.check import check_cores; "
        "check_cores(load('paper-exp2'))"
    )
    return import_cpu_s(code, cwd)


def up_cpu_s(cwd: Path) -> tuple[float, float]:
    """A whole ``formation up --lockstep`` of 2 sim seconds: (CPU of every process, wall)."""
    with tempfile.TemporaryDirectory(prefix="bench-startup-") as tmp:
        argv = [
            sys.executable, "-m", "formation", "up", "--scenario", "paper-exp2", "--lockstep",
            "--duration", "2", "--robots", "3", "--quiet", "--no-figures",
            "--endpoint", f"tcp/127.0.0.1:{free_port()}", "--fleet", "startup",
            "--out", str(Path(tmp) / "run"),
        ]  # fmt: skip
        return child_cpu_s(argv, cwd)


def measure(cwd: Path) -> dict[str, float]:
    """One round of every figure in the checkout ``cwd``."""
    out: dict[str, float] = {}
    for label, code in FLOORS.items():
        out[label] = import_cpu_s(code, cwd)
    for kind, module in KINDS.items():
        out[f"import: {kind}"] = import_cpu_s(f"import {module}", cwd)
    out["launcher's scenario check"] = check_cpu_s(cwd)
    out["formation up, CPU"], out["formation up, wall"] = up_cpu_s(cwd)
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=5, help="rounds (medians are printed)")
    ap.add_argument("--against", type=Path, default=None, help="another checkout to compare")
    args = ap.parse_args()
    trees = {"this tree": REPO_ROOT}
    if args.against is not None:
        trees["against"] = args.against.resolve()
    rounds: dict[str, list[dict[str, float]]] = {name: [] for name in trees}
    for _ in range(args.repeat):
        for name, cwd in trees.items():
            rounds[name].append(measure(cwd))
    names = list(rounds)
    labels = list(rounds[names[0]][0])
    print(f"start-up cost, medians of {args.repeat} rounds (CPU seconds of the child: user + sys)")
    header = "".join(f"{n:>14s}" for n in names)
    print(f"  {'':36s}{header}")
    for label in labels:
        row = "".join(f"{statistics.median(r[label] for r in rounds[n]):14.3f}" for n in names)
        print(f"  {label:36s}{row}")
    for n in names:
        print(f"  ({n}: {trees[n]})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
