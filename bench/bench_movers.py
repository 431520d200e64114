"""Issue 30's movers, measured: the least centre distance (m) between a body carried through a
formation and the fleet, per formation, target robot, direction and speed, including speeds
above the robots' top speed (bodies touch at 0.150 m).

An idle spare is carried (a drag: its wheels do not act) in a straight line through the place
of each robot of paper-exp1's triangle and of a five-robot chevron started in its slots, from
0.9 m before it to 0.9 m past it: head-on (against the formation's motion), from behind,
and across both ways. Prints one row per formation and speed: the least distance over the
targets per direction, the fleet's own least separation, and whether the spare ever held a
slot. The before (issue 30, the triangle, no movers handling): head-on into the leader 0.001-
0.004 m, across its path 0.036-0.067 m.

Run: ``.venv/bin/python bench/bench_movers.py [--speeds 0.05,0.1,...]``. A measurement: it
asserts nothing (tests/unit/formation/test_movers_closed_loop.py asserts the envelope; the
harness is tests/support/carry_runs.py).
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))  # the closed-loop harness: tests/support/carry_runs.py

DIRECTIONS = {"head-on": math.pi, "behind": 0.0, "across+": math.pi / 2, "across-": -math.pi / 2}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--speeds", default="0.05,0.1,0.15,0.2,0.25,0.3,0.4,0.5")
    ap.add_argument("--formations", default="triangle,chevron")
    args = ap.parse_args(argv)
    from support import carry_runs as harness

    speeds = [float(v) for v in args.speeds.split(",")]
    t0 = time.perf_counter()
    print("formation  speed m/s  " + "  ".join(f"{d:>8s}" for d in DIRECTIONS) + "  fleet  slot")
    for kind in args.formations.split(","):
        n = len(harness.formation(kind).robot_ids)
        for v in speeds:
            least = dict.fromkeys(DIRECTIONS, math.inf)
            fleet = math.inf
            took = False
            for name, heading in DIRECTIONS.items():
                for target in range(n):
                    body, fl, slots = harness.carry(kind, target, heading, v)
                    least[name] = min(least[name], body)
                    fleet = min(fleet, fl)
                    took = took or bool((slots != -1).any())
            row = "  ".join(f"{least[d]:8.3f}" for d in DIRECTIONS)
            print(f"{kind:9s}  {v:9.2f}  {row}  {fleet:.3f}  {'yes' if took else 'no'}")
    print(f"({time.perf_counter() - t0:.0f} s)", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
