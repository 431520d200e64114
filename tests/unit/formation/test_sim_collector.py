"""formation.sim.collector: the cyclic collector paused over the simulator's loop, and restored."""

from __future__ import annotations

import gc
from collections.abc import Iterator

import pytest

import scenario
from formation.sim import simulate
from formation.sim.collector import CollectorPause


@pytest.fixture
def collector_state() -> Iterator[None]:
    """Whatever a test does to the process's collector, it is on again afterwards."""
    was = gc.isenabled()
    try:
        yield
    finally:
        if was:
            gc.enable()


@pytest.mark.usefixtures("collector_state")
def test_pause_turns_automatic_collection_off_and_back_on() -> None:
    gc.enable()
    pause = CollectorPause()
    assert not gc.isenabled()
    pause.resume()
    assert gc.isenabled()
    pause.resume()  # idempotent
    assert gc.isenabled()


@pytest.mark.usefixtures("collector_state")
def test_pause_keeps_a_callers_collector_off() -> None:
    gc.disable()
    pause = CollectorPause()
    pause.resume()
    assert not gc.isenabled()


@pytest.mark.usefixtures("collector_state")
def test_collect_young_frees_a_cycle_made_while_paused() -> None:
    gc.enable()
    pause = CollectorPause()
    try:
        pause.collect_young()  # nothing older than this call is young any more

        class Node:
            def __init__(self) -> None:
                self.other: Node = self

        Node()  # a cycle nothing refers to: only the collector can free it
        assert pause.collect_young() >= 1
    finally:
        pause.resume()


@pytest.mark.usefixtures("collector_state")
@pytest.mark.parametrize("enabled", [True, False])
def test_run_restores_the_collector_and_an_interrupted_run_too(enabled: bool) -> None:
    import threading

    (gc.enable if enabled else gc.disable)()
    scn = scenario.load("paper-exp2")
    res = simulate.run(scn, duration_s=1.0)
    assert res.log.t_s.size == 51
    assert gc.isenabled() is enabled
    stop = threading.Event()
    stop.set()
    res = simulate.run(scn, duration_s=1.0, stop=stop)
    assert res.interrupted and res.log.t_s.size == 1
    assert gc.isenabled() is enabled


@pytest.mark.usefixtures("collector_state")
def test_run_restores_the_collector_when_a_tick_raises() -> None:
    gc.enable()
    scn = scenario.load("paper-exp2")

    def boom(t_s: float, duration_s: float) -> None:
        raise RuntimeError("progress callback failed")

    with pytest.raises(RuntimeError, match="progress callback failed"):
        simulate.run(scn, duration_s=1.0, progress=boom)
    assert gc.isenabled()
