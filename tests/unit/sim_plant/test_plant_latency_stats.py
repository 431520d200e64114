"""The plant's realtime latency statistics (``formation plant --stats-out``, read by
bench/bench_up.py and bench/bench_scale.py): whole-run percentiles and the steady-state window
that leaves out the agents' start and the run's shutdown."""

from __future__ import annotations

import pytest

from scenario import load
from sim_plant.node.outputs import STEADY_TAIL_S, STEADY_WARMUP_S
from sim_plant.node.plant import PlantNode


def _plant() -> PlantNode:
    return PlantNode(load("paper-exp1"), "latstats", lambda *_a, **_k: None)


def test_no_commands_no_percentiles() -> None:
    stats = _plant().outputs.latency_stats()
    assert stats["commands"] == 0
    assert stats["latency_ms"] is None and stats["latency_steady_ms"] is None


def test_steady_state_leaves_out_the_start_and_the_shutdown() -> None:
    plant = _plant()
    t0, period = 100.0, 1 / 30
    n = 300  # 10 s of frames at 30 Hz
    for k in range(n):
        published = t0 + k * period
        age = published - t0
        slow = age < STEADY_WARMUP_S - 0.1 or age > (n - 1) * period - STEADY_TAIL_S + 0.1
        plant.outputs.latencies_s.append(0.2 if slow else 0.004 + 0.001 * (k % 3))
        plant.outputs.latency_pub_s.append(published)
    stats = plant.outputs.latency_stats()
    whole, steady = stats["latency_ms"], stats["latency_steady_ms"]
    assert whole["max"] == pytest.approx(200.0) and whole["p99"] == pytest.approx(200.0)
    assert steady["max"] == pytest.approx(6.0) and steady["p50"] == pytest.approx(5.0)
    assert stats["steady_window_s"] == [STEADY_WARMUP_S, STEADY_TAIL_S]
