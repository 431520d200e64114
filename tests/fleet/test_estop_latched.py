"""The e-stop as latched fleet state (issue 13 item 4), with real processes and signals.

One ``formation up --respawn`` fleet of 3 robots (realtime). Under a fleet e-stop engaged with
``formation fault estop`` (which must report the robots that acknowledged it): a paused and
resumed agent comes back in ESTOP and never drives; a killed and respawned agent comes up in
ESTOP; r1's own release does not clear the fleet's e-stop for r1; the fleet's release lets the
fleet re-form. ``formation fault estop`` on a fleet without robots exits non-zero.
"""

from __future__ import annotations

import asyncio
import subprocess
import sys
import time
from collections.abc import Iterator

import pytest
from support.fault_fleet import Fleet, fleet_fixture, formed, until
from support.spawn import child_env

pytestmark = [pytest.mark.slow, pytest.mark.zenoh]


@pytest.fixture(scope="module")
def fleet(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Fleet]:
    yield from fleet_fixture(tmp_path_factory, "latched")


def zero(w: object) -> bool:
    return getattr(w, "omega_r", 1.0) == 0.0 and getattr(w, "omega_l", 1.0) == 0.0


def status_of(fl: Fleet, robot: str, since: float) -> list[object]:
    return [st for _rx, who, st in fl.obs.get("status", since) if who == robot]


async def test_estop_survives_pause_resume_and_respawn_and_honours_scopes(fleet: Fleet) -> None:
    obs = fleet.obs
    await until(lambda: formed(obs, {"r1", "r2", "r3"}), 40.0, "the formation")

    line, t_stop = fleet.fault("estop")
    assert "acknowledged by" in line and "acknowledged by none" not in line, line
    assert "latched by coordinator main" in line, line
    await until(
        lambda: {s.mode for s in obs.latest_status().values()} == {"estop"}, 3.0, "all in ESTOP"
    )

    # pause r2 past its lease (700 ms): its token goes; resume: it must come back stopped
    fleet.fault("pause", "r2")
    await asyncio.sleep(1.5)
    _, t_resume = fleet.fault("resume", "r2")
    await asyncio.sleep(1.5)
    r2_wheels = [w for rx, who, w in obs.get("wheels", t_resume) if who == "r2"]
    assert r2_wheels and all(zero(w) for w in r2_wheels)
    late = status_of(fleet, "r2", t_resume + 0.5)
    assert late and {getattr(s, "mode", None) for s in late} == {"estop"}, late

    # kill r3: respawned 1 s later, it must come up in ESTOP (it asked the coordinator)
    old_pid = obs.latest_status()["r3"].pid
    _, t_kill = fleet.fault("kill", "r3")

    def respawned() -> list[object]:
        return [s for s in status_of(fleet, "r3", t_kill) if getattr(s, "pid", None) != old_pid]

    fresh = await until(respawned, 15.0, "r3 respawned")
    assert {getattr(s, "mode", None) for s in fresh} == {"estop"}, fresh
    await asyncio.sleep(0.6)
    assert {getattr(s, "mode", None) for s in respawned()} == {"estop"}
    r3_new = [w for rx, who, w in obs.get("wheels", t_kill + 0.5) if who == "r3"]
    assert all(zero(w) for w in r3_new)

    # scopes: r1's release does not clear the fleet's e-stop for r1
    line, t_rel = fleet.fault("release", "r1")
    await asyncio.sleep(0.8)
    assert {getattr(s, "mode", None) for s in status_of(fleet, "r1", t_rel + 0.3)} == {"estop"}
    assert all(zero(w) for rx, who, w in obs.get("wheels", t_rel) if who == "r1")
    assert "still stopped: r1" in line or "acknowledged by none" in line, line

    line, _ = fleet.fault("release")
    await until(lambda: formed(obs, {"r1", "r2", "r3"}), 30.0, "re-formed after the release")
    stop_all = obs.get("truth", t_stop)
    assert stop_all  # the plant kept publishing
    assert obs.min_separation(t_stop) > 0.15


def test_estop_exits_non_zero_when_no_robot_acknowledges(fleet: Fleet) -> None:
    started = time.monotonic()
    proc = subprocess.run(
        [sys.executable, "-m", "formation", "fault", "--fleet", "nobody", "--endpoint",
         fleet.endpoint, "estop"],
        capture_output=True, text=True, timeout=20, env=child_env(),
    )  # fmt: skip
    assert proc.returncode != 0, proc.stdout
    assert "acknowledged by none" in proc.stderr and "no coordinator holds it" in proc.stderr
    assert time.monotonic() - started < 10.0
