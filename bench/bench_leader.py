"""Benchmark: what the virtual leader as a state (issue 28, ``coordinator.core.leader``) costs on
the coordinator's tick, beside the baseline of sampling the trajectory directly (the leader
before issue 28), measured in the same run.

Per call, best of ``--repeat`` timings of ``--n`` calls each (``time.perf_counter``):

* ``trajectory.sample(t)``: the baseline (a circle);
* ``LeaderCore.step(t)``, scripted (the default of every scenario: the same bits as the baseline);
* ``LeaderCore.step(t, rate)`` waiting for the team (the progress integrates, velocity scaled);
* ``LeaderCore.step(t)`` under teleop (a twist each tick: the limited unicycle integration);
* ``LeaderCore.step(t)`` along a path (pursuit of the waypoints);
* ``CoordinatorCore.tick`` of paper-exp2's triangle with 3 robots, default (script) and with
  ``[leader] wait = "on"`` (the tracking errors of the assigned robots each tick).

Measures only; asserts nothing. Run: .venv/bin/python bench/bench_leader.py [--n 20000]
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from collections.abc import Callable
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from coordinator.core.assignment import RoleAssigner
from coordinator.core.coordinator import CoordinatorCore
from coordinator.core.formation import FormationSpec
from coordinator.core.leader import LeaderConfig, LeaderCore, WaitSetting
from coordinator.core.trajectory import Circle

DT = 0.02


def best_us(fn: Callable[[int], object], n: int, repeat: int) -> float:
    """Best time per call (us) of ``fn(k)`` for k in range(n), over ``repeat`` runs."""
    best = math.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        for k in range(n):
            fn(k)
        best = min(best, time.perf_counter() - t0)
    return best / n * 1e6


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    p.add_argument("--n", type=int, default=20000)
    p.add_argument("--repeat", type=int, default=5)
    ns = p.parse_args(argv)
    traj = Circle(cx=0.0, cy=0.0, radius_m=1.0, speed_mps=0.08)
    rows: list[tuple[str, float]] = []
    rows.append(
        ("trajectory.sample (baseline)", best_us(lambda k: traj.sample(k * DT), ns.n, ns.repeat))
    )
    script = LeaderCore(traj)
    rows.append(
        ("LeaderCore.step, script", best_us(lambda k: script.step(k * DT), ns.n, ns.repeat))
    )
    waiting = LeaderCore(traj, LeaderConfig(wait=WaitSetting.ON))
    rows.append(
        (
            "LeaderCore.step, waiting (rate 0.5)",
            best_us(lambda k: waiting.step(k * DT, 0.5), ns.n, ns.repeat),
        )
    )
    teleop = LeaderCore(traj)

    def tele(k: int) -> None:
        teleop.command_twist(0.08, 0.2, k * DT)
        teleop.step(k * DT)

    rows.append(("LeaderCore.step, teleop (a twist a tick)", best_us(tele, ns.n, ns.repeat)))
    path = LeaderCore(traj)
    pts = [(math.cos(a) * 50, math.sin(a) * 50) for a in (0.1 * i for i in range(60))]
    path.command_path(pts)
    rows.append(("LeaderCore.step, path", best_us(lambda k: path.step(k * DT), ns.n, ns.repeat)))

    def core(wait: WaitSetting) -> Callable[[int], object]:
        c = CoordinatorCore(
            traj, FormationSpec.triangle(0.4), RoleAssigner(), ref_offset_m=0.05,
            leader=LeaderCore(traj, LeaderConfig(wait=wait)),
        )  # fmt: skip
        poses = {"r1": (0.0, -1.05, 0.0), "r2": (-0.3, -0.8, 0.0), "r3": (-0.3, -1.2, 0.0)}
        return lambda k: c.tick(k * DT, poses)

    rows.append(
        ("CoordinatorCore.tick, 3 robots, script", best_us(core(WaitSetting.OFF), ns.n, ns.repeat))
    )
    rows.append(
        ("CoordinatorCore.tick, 3 robots, waiting", best_us(core(WaitSetting.ON), ns.n, ns.repeat))
    )
    base = rows[0][1]
    print(f"{'per call':<44} {'us':>8} {'x baseline':>11}")
    for name, us in rows:
        print(f"{name:<44} {us:8.2f} {us / base:11.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
