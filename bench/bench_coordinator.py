"""Benchmark: the coordinator core's tick alone (``CoordinatorCore.tick``), replayed.

One in-process run of each fleet (``formation.sim.simulate.run``: paper-exp2, 3 robots,
greedy, a drag mid-run; chevron7, 7 robots, optimal, a circle; chevron30, 30 robots, greedy, a
straight line; ``bench_sim.py``'s fleets) records every input the coordinator got (the time, the
fresh poses, the held robots, the tracked objects, and the operator's reshapes between ticks).
Those inputs are then fed, tick by tick, to a fresh ``CoordinatorCore`` (``scenario.assemble.
coordinator_core``): the time per tick is the coordinator's alone, without the firmware, plant or
camera around it, and the outputs (leader, slot rows, assignment, approach points, movers) are
hashed, so two versions of the code can be shown to decide the same, bit for bit.

``--against DIR`` replays the same inputs with a second source tree (e.g. ``git archive`` of the
baseline commit, extracted): the two trees run in alternating child processes (A, B, A, B, ...:
a busy machine slows both alike), each child timing ``--runs`` replays; the best and median per
tree are printed side by side with their output digests, which must be equal. Times are process
CPU time (a shared VM's stolen time is not counted). Measures only; asserts nothing.

Run: ``.venv/bin/python bench/bench_coordinator.py [--against DIR] [--pairs 5] [--only chevron30]``
"""

from __future__ import annotations

import argparse
import json
import pickle
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
FLEETS = {"paper-exp2": 40.0, "chevron7": 40.0, "chevron30": 20.0}
"""Fleet -> simulated seconds recorded (2001, 2001 and 1001 ticks)."""

# The child: replays a recorded input file on the coordinator core of the tree ``root``.
_CHILD = """
import hashlib, json, pickle, sys, time
root, path, runs = sys.argv[1], sys.argv[2], int(sys.argv[3])
sys.path.insert(0, root)
sys.path.insert(0, root + "/bench")
import scenario
from coordinator.core.coordinator import CoordinatorOutput
from scenario.assemble import coordinator_core
with open(path, "rb") as f:
    name, scn, calls = pickle.load(f)

def replay():
    core = coordinator_core(scn)
    tick, reshape = core.tick, core.reshape
    outs = []
    t0 = time.process_time()
    for c in calls:
        outs.append(reshape(*c[1]) if c[0] == "reshape" else tick(*c[1]))
    return time.process_time() - t0, outs

def digest(outs):
    h = hashlib.sha256()
    for o in outs:
        if isinstance(o, CoordinatorOutput):
            o = (o.leader, o.theta, o.rows, o.slot_ids, list(o.assignment.items()), o.changed,
                 sorted(o.approach.items()), o.movers)
        h.update(repr(o).encode())
    return h.hexdigest()[:16]

times, dig = [], None
for _ in range(runs):
    dt, outs = replay()
    times.append(dt / len(calls) * 1e6)
    dig = digest(outs)
print(json.dumps({"us": times, "digest": dig}))
"""


def record(name: str, duration_s: float) -> tuple[Any, list[tuple[Any, ...]]]:
    """The scenario of fleet ``name`` and every coordinator input of one in-process run."""
    sys.path.insert(0, str(ROOT))
    sys.path.insert(0, str(ROOT / "bench"))
    import bench_sim

    import scenario
    from coordinator.core.coordinator import CoordinatorCore
    from formation.sim import simulate

    scn = bench_sim.chevron_scenario(30) if name == "chevron30" else scenario.load(name)
    calls: list[tuple[Any, ...]] = []
    tick, reshape = CoordinatorCore.tick, CoordinatorCore.reshape

    def rec_tick(self: Any, now_s: float, poses: Any, held: Any = (), objects: Any = None) -> Any:
        calls.append(
            ("tick", (now_s, dict(poses), tuple(held), None if objects is None else dict(objects)))
        )
        return tick(self, now_s, poses, held, objects)

    def rec_reshape(self: Any, *args: Any) -> Any:
        calls.append(("reshape", args))
        return reshape(self, *args)

    CoordinatorCore.tick = rec_tick  # type: ignore[method-assign,assignment]
    CoordinatorCore.reshape = rec_reshape  # type: ignore[method-assign,assignment]
    try:
        simulate.run(scn, duration_s=duration_s)
    finally:
        CoordinatorCore.tick = tick  # type: ignore[method-assign]
        CoordinatorCore.reshape = reshape  # type: ignore[method-assign]
    return scn, calls


def child(root: Path, path: Path, runs: int) -> dict[str, Any]:
    cmd = [sys.executable, "-c", _CHILD, str(root), str(path), str(runs)]
    done = subprocess.run(cmd, capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise SystemExit(f"bench_coordinator: the replay in {root} failed:\n{done.stderr[-2000:]}")
    result: dict[str, Any] = json.loads(done.stdout.strip().splitlines()[-1])
    return result


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    ap.add_argument("--against", type=Path, help="a second source tree, replayed alternately")
    ap.add_argument("--pairs", type=int, default=5, help="child processes per tree (5)")
    ap.add_argument("--runs", type=int, default=3, help="replays per child, best kept (3)")
    ap.add_argument("--only", choices=sorted(FLEETS), help="one fleet")
    args = ap.parse_args(argv)
    print("$ " + " ".join([Path(sys.executable).name, *sys.argv]))
    trees = [("this tree", ROOT)]
    if args.against is not None:
        trees.append(("against", args.against.resolve()))
    with tempfile.TemporaryDirectory(prefix="bench_coordinator_") as tmp:
        for name, duration_s in FLEETS.items():
            if args.only and name != args.only:
                continue
            scn, calls = record(name, duration_s)
            path = Path(tmp) / f"{name}.pkl"
            path.write_bytes(pickle.dumps((name, scn, calls)))
            ticks = sum(1 for c in calls if c[0] == "tick")
            print(f"\n{name}: {len(scn.robot_ids)} robots, {ticks} ticks replayed")
            best: dict[str, list[float]] = {label: [] for label, _ in trees}
            digests: dict[str, set[str]] = {label: set() for label, _ in trees}
            for _ in range(args.pairs):  # alternating pairs: A, B, A, B, ...
                for label, root in trees:
                    got = child(root, path, args.runs)
                    best[label].append(min(got["us"]))
                    digests[label].add(got["digest"])
            for label, root in trees:
                us = best[label]
                print(
                    f"  {label:9s} best {min(us):7.2f} us/tick, median {statistics.median(us):7.2f}"
                    f"  outputs {'/'.join(sorted(digests[label]))}  ({root})"
                )
            if args.against is not None:
                a, b = (statistics.median(best[label]) for label, _ in trees)
                same = digests["this tree"] == digests["against"]
                print(
                    f"  this tree / against: {a / b:.2f} of the time (median), {b / a:.1f}x faster;"
                    f" outputs {'identical' if same else 'DIFFERENT'}"
                )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
