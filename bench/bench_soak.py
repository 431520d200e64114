"""Soak: kill the leader's agent again and again; how often and how fast the fleet recovers.

``formation up --standby --respawn 0.5`` runs 3 robots (realtime) on a slow line (the scenario of
``tests/fleet/test_faults.py``). This process is a Zenoh client of the run's router and stamps every
message with ``time.monotonic()`` on receipt (every process is on this host: one clock). Each
round:

1. wait until the fleet is formed: every robot assigned, TRACKING, tracking error < 6 cm;
2. wait a random 0-1 s (a random moment of the loops), read the leader from ``assignment`` and
   its agent's pid from its ``status``, and SIGKILL it (``t_kill``);
3. *reassignment time*: from ``t_kill`` to the receipt of the first ``assignment`` without it;
4. *recovery time*: from ``t_kill`` until the survivors are formed again (same 6 cm criterion,
   judged on their status at 5 Hz, so it is quantised by ~0.2 s);
5. *minimum separation*: the smallest distance between two robots' truth poses (same frame),
   from the kill until the killed robot's respawned agent has rejoined the formation (the dead
   robot stays on the floor as an obstacle until then); a collision is a separation below two
   body radii (0.15 m).

A round *recovered* when the reassignment came within 1 s, the survivors re-formed within 30 s,
nobody collided and the survivors never left TRACKING. Prints the counts and the distributions
(p50/p95/max); asserts nothing.

Usage: ``python bench/bench_soak.py [--kills 100] [--seed 1] [--endpoint tcp/127.0.0.1:PORT]``.
"""

from __future__ import annotations

import argparse
import itertools
import math
import os
import random
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))
sys.path.insert(0, str(HERE))

from common import free_port, percentile  # noqa: E402

import runtime as rt  # noqa: E402
from bus_schemas import Assignment, Status, Truth, decode, keys  # noqa: E402

SCENARIO = (
    (HERE.parent / "tests" / "support" / "fault_fleet.py")
    .read_text()
    .split('SCENARIO = """\\\n')[1]
)
SCENARIO = SCENARIO.split('"""')[0]
ROBOTS = ("r1", "r2", "r3")
TOL_M = 0.06
COLLISION_M = 0.15


class Observer:
    def __init__(self, endpoint: str, fleet: str) -> None:
        self.lock = threading.Lock()
        self.assign: list[tuple[float, Any]] = []
        self.status: dict[str, tuple[float, Any]] = {}
        self.status_log: list[tuple[float, str, Any]] = []
        self.truth: list[tuple[float, str, Any]] = []
        self.session = rt.open_session(rt.ZenohSettings(connect=(endpoint,)))
        self._sub(keys.assignment_key(fleet), Assignment, self._on_assign)
        self._sub(keys.all_status_pattern(fleet), Status, self._on_status)
        self._sub(keys.all_truth_pattern(fleet), Truth, self._on_truth)

    def _sub(self, key: str, cls: Any, fn: Any) -> None:
        def on(sample: Any) -> None:
            rx = time.monotonic()
            msg = decode(sample.payload.to_bytes(), cls)
            parsed = keys.parse_robot_key(str(sample.key_expr))
            with self.lock:
                fn(rx, parsed[1] if parsed else "", msg)

        self.session.declare_subscriber(key, on)

    def _on_assign(self, rx: float, _: str, m: Any) -> None:
        self.assign.append((rx, m))

    def _on_status(self, rx: float, who: str, m: Any) -> None:
        self.status[who] = (rx, m)
        self.status_log.append((rx, who, m))

    def _on_truth(self, rx: float, who: str, m: Any) -> None:
        self.truth.append((rx, who, m))
        if len(self.truth) > 200_000:
            del self.truth[:100_000]

    def formed(self, robots: set[str], since: float = -math.inf) -> bool:
        """The latest assignment holds ``robots`` and each one's status, received after
        ``since``, is TRACKING its assigned slot within TOL_M."""
        now = time.monotonic()
        with self.lock:
            if not self.assign or not robots <= set(self.assign[-1][1].robots):
                return False
            slots = self.assign[-1][1].robots
            for r in robots:
                rx, st = self.status.get(r, (-math.inf, None))
                if now - rx > 0.5 or rx < since or st.mode != "tracking":
                    return False
                if st.slot != slots[r]:
                    return False
                if math.hypot(st.ex or 0.0, st.ey or 0.0) >= TOL_M:
                    return False
        return True

    def min_sep(self, since: float, until: float) -> float:
        frames: dict[float, list[tuple[float, float]]] = {}
        with self.lock:
            for rx, _, m in self.truth:
                if since <= rx <= until:
                    frames.setdefault(m.t, []).append((m.x, m.y))
        best = math.inf
        for pts in frames.values():
            for a, b in itertools.combinations(pts, 2):
                best = min(best, math.dist(a, b))
        return best


def wait(pred: Any, timeout_s: float) -> float | None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if pred():
            return time.monotonic()
        time.sleep(0.01)
    return None


def stats(label: str, values: list[float], unit: str, scale: float) -> str:
    if not values:
        return f"{label}: no data"
    v = sorted(values)
    return (
        f"{label}: n={len(v)} p50 {percentile(v, 50) * scale:.1f} {unit}, "
        f"p95 {percentile(v, 95) * scale:.1f} {unit}, max {v[-1] * scale:.1f} {unit}"
    )


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--kills", type=int, default=100)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--endpoint", default=None)
    ns = ap.parse_args(argv)
    rng = random.Random(ns.seed)
    endpoint = ns.endpoint or f"tcp/127.0.0.1:{free_port()}"
    fleet = "soak"
    tmp = Path(tempfile.mkdtemp(prefix="soak-"))
    scn = tmp / "soak.toml"
    scn.write_text(SCENARIO.replace("duration_s = 120.0", "duration_s = 100000.0"))
    duration = 60 + 30 * ns.kills
    env = dict(os.environ, PYTHONPATH=str(HERE.parent))
    argv_up = [
        sys.executable, "-m", "formation", "up", "--scenario", str(scn), "--duration",
        str(duration), "--standby", "--respawn", "0.5", "--endpoint", endpoint, "--fleet", fleet,
        "--out", str(tmp / "out"), "--no-figures", "--quiet",
    ]  # fmt: skip
    print(f"# {' '.join(argv_up[1:])}", flush=True)
    up = subprocess.Popen(argv_up, env=env, cwd=HERE.parent, start_new_session=True)
    obs: Observer | None = None
    reassign: list[float] = []
    recover: list[float] = []
    seps: list[float] = []
    recovered = collisions = 0
    t_start = time.monotonic()
    try:
        deadline = time.monotonic() + 60
        while obs is None:
            try:
                obs = Observer(endpoint, fleet)
            except rt.TransportError:
                if time.monotonic() > deadline or up.poll() is not None:
                    raise
        for i in range(ns.kills):
            if wait(lambda: obs.formed(set(ROBOTS)), 60.0) is None:
                print(f"round {i + 1}: the fleet did not form within 60 s; stopping", flush=True)
                break
            time.sleep(rng.uniform(0.0, 1.0))
            with obs.lock:
                a = obs.assign[-1][1]
                leader = a.leader
                st = obs.status.get(leader, (0, None))[1] if leader else None
            if leader is None or st is None:
                print(f"round {i + 1}: no leader/status; skipped", flush=True)
                continue
            os.kill(st.pid, signal.SIGKILL)
            t_kill = time.monotonic()
            survivors = set(ROBOTS) - {leader}

            def reassigned(t_kill: float = t_kill, leader: str = leader) -> bool:
                with obs.lock:
                    return any(rx >= t_kill and leader not in m.robots for rx, m in obs.assign)

            t_re = wait(reassigned, 1.0)
            with obs.lock:
                rx_re = next(
                    (rx for rx, m in obs.assign if rx >= t_kill and leader not in m.robots), None
                )
            since = rx_re if rx_re is not None else t_kill
            t_rec = wait(lambda s=survivors, since=since: obs.formed(s, since), 30.0)
            t_back = wait(lambda: obs.formed(set(ROBOTS)), 60.0) or time.monotonic()
            sep = obs.min_sep(t_kill, t_back)
            with obs.lock:
                left = {
                    m.mode
                    for rx, who, m in obs.status_log
                    if who in survivors and t_kill <= rx <= (t_rec or t_back)
                }
                obs.status_log = [e for e in obs.status_log if e[0] > t_back - 1.0]
            ok_sep = sep > COLLISION_M
            collisions += not ok_sep
            ok = t_re is not None and t_rec is not None and ok_sep and left <= {"tracking"}
            recovered += ok
            if rx_re is not None:
                reassign.append(rx_re - t_kill)
            if t_rec is not None:
                recover.append(t_rec - t_kill)
            if math.isfinite(sep):
                seps.append(sep)
            print(
                f"round {i + 1:3d}: killed {leader}; reassigned "
                f"{'-' if rx_re is None else f'{(rx_re - t_kill) * 1000:.1f} ms'}, re-formed "
                f"{'-' if t_rec is None else f'{t_rec - t_kill:.2f} s'}, min separation "
                f"{sep:.3f} m, survivor modes {sorted(left)}{'' if ok else '  NOT RECOVERED'}",
                flush=True,
            )
    finally:
        if obs is not None:
            obs.session.close()
        if up.poll() is None:
            up.send_signal(signal.SIGINT)
            try:
                up.wait(timeout=15)
            except subprocess.TimeoutExpired:
                os.killpg(up.pid, signal.SIGKILL)
                up.wait()
    print(
        f"\nsoak: {ns.kills} leader kills requested, {len(reassign)} done, "
        f"{recovered} recovered, {collisions} collisions, wall {time.monotonic() - t_start:.0f} s"
    )
    print(stats("reassignment (kill -> assignment received)", reassign, "ms", 1000.0))
    print(stats("recovery (kill -> survivors within 6 cm)", recover, "s", 1.0))
    print(
        f"min separation (truth): {min(seps):.3f} m over all rounds"
        if seps
        else "min separation: no data"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
