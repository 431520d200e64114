"""The pytest plugin's ``fleet`` fixture (formation.pytest_plugin) on a realtime fleet: the
operator's faults (``formation fault``) through it, and the run's metrics.json listing each one
with its recovery (issue 32). And :class:`FleetRun` on a lockstep run that is over before its
observer's session opens (what a CPU hog did to the tutorial's fault test)."""

from __future__ import annotations

import asyncio
from pathlib import Path

import pytest

from formation.testing import FaultCommandError, FleetRun, FleetRunError

pytestmark = [pytest.mark.slow, pytest.mark.zenoh]


@pytest.mark.fleet("paper-exp2", duration_s=60, hosts=0)
async def test_operator_faults_through_the_fixture_are_listed_with_their_recovery(
    fleet: FleetRun,
) -> None:
    await fleet.wait_in_formation(timeout_s=60, tol_m=0.06)
    assert "acknowledged" in await fleet.estop()
    await asyncio.sleep(0.5)
    await fleet.release()
    await fleet.pause("r3")
    await asyncio.sleep(1.5)  # more than a lease: the coordinator dropped r3
    await fleet.resume("r3")
    leader = fleet.leader
    assert leader is not None
    assert f"killed leader {leader}" in await fleet.kill_leader()
    with pytest.raises(FaultCommandError, match="no robot 'r9'"):
        await fleet.kill("r9")  # a robot the run lacks: the tool looks for it 1 s, not 10
    # the kill's recovery in the run's log: the new leader on the bus, then a second more of it
    deadline = asyncio.get_running_loop().time() + 30.0
    while fleet.leader in (None, leader):
        assert asyncio.get_running_loop().time() < deadline, "no new leader within 30 s"
        await asyncio.sleep(0.05)
    await asyncio.sleep(1.0)
    await fleet.stop()
    got = [(f["kind"], f["robot"]) for f in fleet.recovery()]
    assert got == [
        ("estop", None), ("release", None), ("pause", "r3"), ("resume", "r3"), ("kill", leader),
    ]  # fmt: skip
    kill = fleet.recovery()[-1]
    assert kill["detection_s"] is not None and kill["detection_s"] < 0.5
    assert kill["new_leader"] not in (None, leader)
    pause = fleet.recovery()[2]
    assert pause["detection_s"] is not None and pause["detection_s"] < 1.5  # one lease


class _LateObserver(FleetRun):
    """A FleetRun whose observer connects only once the run has ended: next to a 4-process CPU
    hog the tutorial's 20 s lockstep run ended before the test's imports and session were done
    (the observer then retried a gone router for minutes; a run seen only at its end failed)."""

    async def _observe(self, deadline: float) -> None:
        assert self.proc is not None
        await self.proc.wait()
        await super()._observe(deadline)


@pytest.mark.shares_cpu
async def test_a_lockstep_run_over_before_its_observer_connects_starts_and_finishes(
    tmp_path: Path,
) -> None:
    run = _LateObserver("paper-exp1", workdir=tmp_path / "fleet", lockstep=True, duration_s=3)
    try:
        assert await run.start(timeout_s=120.0) is run  # not a hang, not "ended at start"
        assert run.session is None  # it never saw the run: the run was over
        metrics = await run.finish()
        assert metrics["run"]["duration_s"] == pytest.approx(3.0, abs=0.05)
        assert metrics["meta"]["interrupted"] is False
        assert run.recovery() == []
        with pytest.raises(FleetRunError, match="the run has ended"):
            await run.kill_leader()
    finally:
        await run.close()
