"""What one coordinator tick publishes with ``--batch`` (coordinator.node.outputs, docs/scale.md):
the ``slot/<k>`` keys once a period, spread over the realtime ticks instead of one burst, all at
once a period in lockstep (a lockstep run's messages do not change)."""

from __future__ import annotations

import math
from collections import Counter

import runtime as rt
from bus_schemas import Slot, decode, keys
from coordinator.node.outputs import BATCH_SLOT_PERIOD_S, TickOutputs
from scenario.assemble import coordinator_core
from scenario.resize import load_with_robots

FLEET = "outs"


def _slots_per_tick(lockstep: bool, n: int, rate_hz: float, seconds: float) -> list[list[int]]:
    """The slot ids each tick of ``seconds`` at ``rate_hz`` publishes on ``slot/<k>``."""
    scn = load_with_robots("paper-exp2", n)
    core = coordinator_core(scn)
    order = {rid: i for i, rid in enumerate(scn.robot_ids)}
    outs = TickOutputs(FLEET, order, lockstep=lockstep, batch=True, log=rt.NodeLog("test"))
    poses = {rid: (p[0], p[1], p[2]) for rid, p in zip(scn.robot_ids, scn.initial, strict=True)}
    prefix = keys.slot_key(FLEET, 0).rsplit("/", 1)[0] + "/"
    ticks: list[list[int]] = []
    for k in range(round(seconds * rate_hz)):
        now = k / rate_hz
        msgs = outs.encode_tick(core.tick(now, poses), now, k if lockstep else None, 0.0)
        slots = []
        for key, payload, _ in msgs:
            if key.startswith(prefix):
                msg = decode(payload, Slot)
                assert isinstance(msg, Slot) and key == keys.slot_key(FLEET, msg.slot)
                slots.append(msg.slot)
        ticks.append(slots)
    return ticks


def test_realtime_spreads_the_slots_over_the_ticks_each_once_a_period() -> None:
    n, rate = 100, 50.0
    ticks = _slots_per_tick(False, n, rate, 3.0 * BATCH_SLOT_PERIOD_S)
    assert sorted(ticks[0]) == list(range(n))  # the first tick: every slot, for observers
    per_tick = math.ceil(n / (rate * BATCH_SLOT_PERIOD_S))
    assert max(len(t) for t in ticks[1:]) <= per_tick  # no burst: 2 of 100 at 50 Hz
    # every slot once in each period after the first tick (give or take one tick's share)
    per_period = round(rate * BATCH_SLOT_PERIOD_S)
    for start in (1, 1 + per_period):
        window = Counter(s for t in ticks[start : start + per_period] for s in t)
        assert set(window) == set(range(n)) and max(window.values()) == 1


def test_lockstep_publishes_every_slot_at_once_a_period_as_before() -> None:
    n, rate = 30, 50.0
    ticks = _slots_per_tick(True, n, rate, 2.5 * BATCH_SLOT_PERIOD_S)
    full = [k for k, t in enumerate(ticks) if t]
    assert full == [0, 50, 100]  # sim time: ticks 0, 1 s, 2 s
    assert all(sorted(ticks[k]) == list(range(n)) for k in full)
