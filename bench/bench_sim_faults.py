"""Benchmark: what scripted faults cost the in-process loop (``formation.sim.simulate.run``).

The built-in ``leader-kill`` (4 robots, 40 s, a leader kill on a condition) with its
``[[fault]]`` entries, beside the same scenario without them (the loop's fault-free path) and
with every kind of fault scripted (pause, e-stops, a cut link, a camera loss, a coordinator
kill, a leader kill), measured in the same run: the real-time factor (sim seconds per wall
second; best and median of ``--runs``). Measures only; asserts nothing.

Run: .venv/bin/python bench/bench_sim_faults.py [--runs 5]
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import scenario
from formation.sim import simulate
from scenario.faults import parse_faults

EVERY_KIND = [
    {"kind": "pause", "robot": "r4", "t_s": 2.0, "duration_s": 1.0},
    {"kind": "estop", "robot": "r3", "t_s": 3.5, "duration_s": 0.6},
    {"kind": "cut_link", "robot": "r2", "t_s": 4.5, "duration_s": 0.8},
    {"kind": "camera_loss", "robot": "r3", "t_s": 5.5, "duration_s": 0.5},
    {"kind": "estop", "t_s": 6.2, "duration_s": 0.3},
    {"kind": "kill_coordinator", "t_s": 7.0, "takeover_s": 0.4},
    {"kind": "kill", "role": "leader", "t_s": 8.0},
]


def factors(scn: scenario.Scenario, runs: int) -> list[float]:
    return [simulate.run(scn).realtime_factor for _ in range(runs)]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=5)
    ns = ap.parse_args()
    base = scenario.load("leader-kill")
    cases = {
        "no [[fault]] (baseline)": dataclasses.replace(base, faults=()),
        "leader-kill's [[fault]]": base,
        "every kind": dataclasses.replace(
            base, faults=parse_faults(EVERY_KIND, base.robot_ids, base.duration_s)
        ),
    }
    print(f"formation sim, leader-kill (4 robots, {base.duration_s:g} s), {ns.runs} runs each")
    print(f"{'case':<26}{'best x':>10}{'median x':>10}{'vs baseline':>13}")
    ref = None
    for name, scn in cases.items():
        got = factors(scn, ns.runs)
        med = statistics.median(got)
        ref = med if ref is None else ref
        print(f"{name:<26}{max(got):>10.0f}{med:>10.0f}{med / ref:>12.2f}x")


if __name__ == "__main__":
    main()
