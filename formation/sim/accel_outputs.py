"""The in-process simulator's outputs over a fixed set of runs, one digest line per run.

``python -m formation.sim.accel_outputs`` prints, per case, a SHA-256 of everything a run
returns (the log's arrays, separation, collisions, firmware status, link counters, faults,
operator and mover records). The simulator's and the coordinator's compiled builds
(``formation.sim.accel_build``) run it with the new build and with ``FORMATION_ACCEL=0`` and
install a build only if both print the same; ``tests/unit/sim_plant/test_sim_accel.py`` and
``tests/unit/coordinator/test_coordinator_accel.py`` compare the two again.

The cases cover every path of the compiled modules: the small-fleet plant, camera and link with a
drag (paper-exp2), wheel encoders, scripted faults (leader-kill), an operator reshape, a scenario
mover and motion claims, and a fleet above ``SMALL_N`` (the vectorised paths). About 3 s.
"""

from __future__ import annotations

import hashlib
import json
import sys
import tomllib
from collections.abc import Iterator
from typing import Any

import numpy as np

import scenario as scenario_mod
from coordinator.core import _accel as coordinator_accel
from formation.sim import simulate
from scenario.load import parse, resolve
from sim_plant.core import _accel
from sim_plant.core.plant import SMALL_N

_EXTRA_TOML = """
[[operator]]
t_s = 4.0
command = "shape"
kind = "column"

[[operator]]
t_s = 9.0
command = "shape"
kind = "triangle"
slots = 3

[[mover]]
id = "cart"
radius_m = 0.075
path = [[3.0, 1.5], [0.0, -1.0]]
speed_mps = 0.2
t_s = 2.0
visible = true
"""


def _paper_exp2(extra: str = "", **tables: dict[str, Any]) -> scenario_mod.Scenario:
    data = tomllib.loads(resolve("paper-exp2").read_text(encoding="utf-8") + extra)
    for key, table in tables.items():
        data.setdefault(key, {}).update(table)
    return parse(data, source="<accel_outputs>")


def _large_fleet(n: int) -> scenario_mod.Scenario:
    """``n`` robots on a grid behind a chevron leader: more than ``SMALL_N`` (numpy paths)."""
    initial = [[-0.5 * (j // 8), 0.5 * (j % 8) - 1.75, 0.0] for j in range(n)]
    data: dict[str, Any] = {
        "name": f"grid{n}",
        "duration_s": 1.0,
        "dt_s": 0.02,
        "seed": 3,
        "robots": {"count": n, "initial": initial},
        "trajectory": {"kind": "line", "x0": 0.5, "y0": 0.0, "heading": 0.0, "speed_mps": 0.03},
        "formation": {"kind": "chevron", "n": n, "b_m": 0.4},
        "assignment": {"method": "greedy", "hysteresis_m": 0.05, "tie_tol_m": 0.01},
    }
    return parse(data, source="<accel_outputs>")


def cases() -> Iterator[tuple[str, scenario_mod.Scenario, float]]:
    """``(name, scenario, duration_s)`` of each run."""
    yield "paper-exp2", scenario_mod.load("paper-exp2"), 30.0
    yield (
        "paper-exp2-encoders",
        _paper_exp2(plant={"encoder_counts_per_rev": 2000.0, "encoder_slip_std": 0.01}),
        12.0,
    )
    yield "leader-kill", scenario_mod.load("leader-kill"), 30.0
    yield (
        "operator-mover-claims",
        _paper_exp2(_EXTRA_TOML, safety_filter={"accel_bound_mps2": 2.0}),
        14.0,
    )
    yield f"grid{SMALL_N + 2}", _large_fleet(SMALL_N + 2), 1.0


def digest(res: simulate.SimResult) -> str:
    """SHA-256 (hex, 16 digits) of what ``res`` holds except its wall-clock times."""
    h = hashlib.sha256()
    log = res.log
    for name in ("t_s", "truth", "ref", "target", "slot_of", "slot_xy", "leader", "power", "mode"):
        h.update(name.encode())
        h.update(np.ascontiguousarray(getattr(log, name)).tobytes())
    meta = {k: v for k, v in log.meta.items() if k != "wall_s"}
    record = [
        repr(log.min_separation_m),
        log.collisions,
        log.filter_counts,
        log.reshapes,
        log.replans,
        meta,
        res.firmware_status,
    ]
    h.update(json.dumps(record, sort_keys=True, default=repr).encode())
    for key in sorted(res.movers):
        h.update(np.ascontiguousarray(res.movers[key]).tobytes())
    return h.hexdigest()[:16]


def main() -> int:
    print(f"simulator: {_accel.status()[1]}", file=sys.stderr)
    print(f"coordinator: {coordinator_accel.status()[1]}", file=sys.stderr)
    for name, scn, duration_s in cases():
        print(name, digest(simulate.run(scn, duration_s=duration_s)), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
