"""Outsider fuzz of a running fleet (issue 13 item 10, short variant; long: bench/bench_fuzz.py).

A realtime ``formation up`` fleet of 3 robots holds its formation; a plain Zenoh client publishes
seeded hostile payloads (formation/operate/fuzz.py: every one refused by the strict decoder) on
every
key the agents, the coordinator and the plant subscribe to. Checked: no process dies, each node's
``rejected`` grows by exactly the number of payloads it received, and no robot moves because of
them (every robot stays TRACKING in its slot within 6 cm, no collision).
"""

from __future__ import annotations

import asyncio
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import msgpack
import pytest
from support.fault_fleet import Fleet as _BaseFleet
from support.fault_fleet import fleet_fixture, formed, until
from support.spawn import Spawner

import runtime as rt
from formation.operate.fuzz import fuzz_plan, payloads_for

pytestmark = [pytest.mark.slow, pytest.mark.zenoh]

ROBOTS = ("r1", "r2", "r3")
SEED = 13
PER_KEY = 15


class Fleet(_BaseFleet):
    def __init__(self, spawner: Spawner, tmp: Path) -> None:
        super().__init__(spawner, tmp)
        self.plant: list[tuple[float, dict[str, Any]]] = []
        lock = threading.Lock()

        def on(sample: Any) -> None:
            with lock:
                self.plant.append((time.monotonic(), msgpack.unpackb(sample.payload.to_bytes())))

        self.obs.session.declare_subscriber(f"formation/{self.fleet}/plant/status", on)


@pytest.fixture(scope="module")
def fleet(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Fleet]:
    yield from fleet_fixture(tmp_path_factory, "fuzz", make=Fleet)


def rejected_counts(fl: Fleet, since: float) -> dict[str, int]:
    """The newest ``rejected`` of every node heard since ``since``."""
    out: dict[str, int] = {}
    for _rx, who, st in fl.obs.get("status", since):
        out[f"agent-{who}"] = st.rejected
    for _rx, _who, st in fl.obs.get("cst", since):
        if isinstance(st, dict) and st.get("name") == "main":
            out["coordinator"] = st["rejected"]
    for rx, st in list(fl.plant):
        if rx >= since and isinstance(st, dict) and isinstance(st.get("rejected"), int):
            out["plant"] = st["rejected"]
    return out


async def test_seeded_fuzz_on_every_subscribed_key(fleet: Fleet) -> None:
    obs = fleet.obs
    await until(lambda: formed(obs, set(ROBOTS)), 40.0, "the formation")
    t0 = time.monotonic()
    await asyncio.sleep(0.5)
    before = rejected_counts(fleet, t0)
    assert set(before) == {"agent-r1", "agent-r2", "agent-r3", "coordinator", "plant"}, before

    plan = fuzz_plan(fleet.fleet, ROBOTS)
    expected = dict.fromkeys(before, 0)
    pubs = rt.Publishers(obs.session)
    t_fuzz = time.monotonic()
    sent = 0
    for fk in plan:
        for payload in payloads_for(fk, SEED, PER_KEY):
            pubs.put(fk.key, payload, rt.QOS_CRITICAL)
            sent += 1
            for node in fk.receivers:
                expected[node] += 1
        await asyncio.sleep(0.01)
    t_done = time.monotonic()

    def settled() -> dict[str, int] | None:
        now = rejected_counts(fleet, t_done + 0.5)
        if set(now) != set(before):
            return None
        delta = {n: now[n] - before[n] for n in before}
        return delta if delta == expected else None

    try:
        await until(settled, 10.0, "every payload counted")
    except AssertionError:
        now = rejected_counts(fleet, t_done + 0.5)
        got = {n: now.get(n, 0) - before[n] for n in before}
        raise AssertionError(f"rejects: expected {expected}, got {got}") from None
    # nobody moved because of it: still formed, never left TRACKING, no collision
    modes = {st.mode for _rx, _who, st in obs.get("status", t_fuzz)}
    assert modes == {"tracking"}, modes
    assert formed(obs, set(ROBOTS))
    assert obs.min_separation(t_fuzz) > 0.15
    print(f"\nfuzz: {sent} payloads on {len(plan)} keys, rejects {expected}")
