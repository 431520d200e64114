"""Issue 14 over Zenoh: an e-stopped robot in a moving formation, with real processes.

A real ``formation up`` (realtime: coordinator, plant, one agent process per robot, router) runs
seven robots in a two-stage chevron driving along a line; the robot on slot 1 is e-stopped with
``formation fault estop <id>`` 1.5 s after every robot has a slot (the formation is moving by then:
least separation 0.246 m in two runs, 0.245 m with the 4 s it was before). Slot 3 lies 0.4 m
straight behind slot 1, so the robot on it drives at the stopped one (the issue's case: before the
safety filter it came within 0.033 m and then stayed stuck 0.86 m from its slot). The plant's truth,
read on the bus by an observer session, must never bring two centres closer than two body radii;
every robot but the stopped one must be back on its slot at the end (it went round);
``metrics.json`` of the run must report the same (no collision, separation above 2 r_b, safety
section filled). The run ends (SIGINT) once the observer has seen that end state held for
``HOLD_S``: about 20 s after the e-stop (the in-process run of the same scenario), not the
scenario's 45 s.

Realtime, not lockstep: the assertions are about safety and outcome, not equality with the
in-process simulator (tests/unit/robot_agent/test_safety_filter.py runs the e-stop case in-process).
"""

from __future__ import annotations

import asyncio
import json
import math
import signal
import time
from pathlib import Path

import pytest
from support.fault_fleet import Observer, fault, tracking_err, until
from support.spawn import Spawner, free_port

from coordinator.core.formation import FormationSpec, slot_states
from coordinator.core.trajectory import make_trajectory
from robot_agent.core.kinematics import axle_from_reference_point

pytestmark = [pytest.mark.slow, pytest.mark.zenoh]

BODY_RADIUS_M = 0.075
SPEED_MPS = 0.06
DURATION_S = 45.0  # the longest the run may take; it is stopped once the end state is reached
ESTOP_AFTER_S = 1.5  # the formation is moving by then (it starts on its slots at full speed)
HOLD_S = 2.0  # the end state (went round, every other robot on its slot) held this long


def _scenario() -> str:
    """Seven robots starting with their reference points on their slots (r<k+1> on slot k)."""
    spec = FormationSpec.from_dict({"kind": "chevron", "n": 7, "b_m": 0.4})
    lead = make_trajectory("line", {"x0": 0.0, "y0": 0.0, "heading": 0.0, "speed_mps": 0.0})
    rows = []
    for s in slot_states(spec, lead.sample(0.0)):
        x, y = axle_from_reference_point(s.x, s.y, s.theta, 0.05)
        rows.append(f"[{x!r}, {y!r}, 0.0]")
    return f"""\
name = "estop-chevron"
description = "Seven robots in a chevron on a line; one is e-stopped (issue 14)."
duration_s = {DURATION_S}
dt_s = 0.02
seed = 7
settle_s = 30.0

[robots]
count = 7
initial = [{", ".join(rows)}]

[trajectory]
kind = "line"
x0 = 0.0
y0 = 0.0
heading = 0.0
speed_mps = {SPEED_MPS}

[formation]
kind = "chevron"
n = 7
b_m = 0.4

[assignment]
method = "optimal"
hysteresis_m = 0.05
tie_tol_m = 0.01
"""


def _went_round(obs: Observer, stopped: str, behind: str) -> bool:
    """The end state the test asserts: ``behind`` (last truth) at least 0.3 m ahead of
    ``stopped``, every robot but ``stopped`` tracking (or in HOLD) within 0.30 m (``behind``)
    or 0.15 m (the others) of its slot (last status)."""
    st = obs.latest_status()
    truth = {who: msg.x for _, who, msg in obs.get("truth", time.monotonic() - 0.5)}
    if stopped not in truth or behind not in truth or truth[behind] <= truth[stopped] + 0.3:
        return False
    others = [rid for rid in st if rid != stopped]
    return len(others) == 6 and all(
        st[rid].mode in ("tracking", "hold")
        and tracking_err(st[rid]) < (0.30 if rid == behind else 0.15)
        for rid in others
    )


async def test_estopped_robot_in_a_moving_formation_over_zenoh(
    spawn: Spawner, tmp_path: Path
) -> None:
    scn = tmp_path / "estop-chevron.toml"
    scn.write_text(_scenario())
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    fleet = "safety14"
    out = tmp_path / "out"
    up = spawn(
        "up", "--scenario", str(scn), "--endpoint", endpoint, "--fleet", fleet,
        "--out", str(out), "--no-figures", "--ready-timeout", "60",
        ready="  7 agents", timeout_s=90.0,
    )  # fmt: skip
    obs = Observer(endpoint, fleet)
    try:
        # the run is going: truth flows and every robot has a slot
        await until(
            lambda: (a := obs.latest_assignment()) is not None and len(a.robots) == 7,
            30.0,
            "all seven robots assigned",
        )
        t0 = time.monotonic()
        await asyncio.sleep(ESTOP_AFTER_S)
        a = obs.latest_assignment()
        assert a is not None
        on_slot = {slot: rid for rid, slot in a.robots.items()}
        stopped, behind = on_slot[1], on_slot[3]
        _line, t_stop = fault(endpoint, fleet, "estop", stopped)
        await until(
            lambda: (s := obs.latest_status().get(stopped)) is not None and s.mode == "estop",
            3.0,
            f"{stopped} in estop",
        )
        # the end state, then still so HOLD_S later: asked of the bus, not slept for
        await until(lambda: _went_round(obs, stopped, behind), DURATION_S, "the end state")
        await asyncio.sleep(HOLD_S)
        await until(lambda: _went_round(obs, stopped, behind), 1.0, "the end state held")
        up.send_signal(signal.SIGINT)
        up.proc.wait(timeout=90.0)
        if up.proc.returncode != 130:  # on an overloaded box a child may outlive its 2 s grace
            # period at shutdown (formation up then exits 1); that is tests/fleet/test_up.py's and
            # tests/fleet/test_faults.py's subject, not this one's: accept it, and only it
            problems = [ln for ln in up.stderr().splitlines() if ln.startswith("formation up:")]
            assert problems and all("did not exit" in ln for ln in problems), up.describe()
        sep = obs.min_separation(t0)
        final = {who: (msg.x, msg.y) for _, who, msg in obs.get("truth")}
        st = obs.get("status")
        last: dict[str, object] = {}
        for _, who, msg in st:
            last[who] = msg
    finally:
        obs.close()
    print(
        f"\ne-stopped {stopped} (slot 1) {t_stop - t0:.1f} s after all had slots; {behind} was on"
        f" slot 3; min separation from truth {sep:.3f} m"
    )
    assert math.isfinite(sep)
    assert sep >= 2 * BODY_RADIUS_M, f"bodies touched: {sep:.3f} m"
    m = json.loads((out / "metrics.json").read_text())
    assert m["meta"]["interrupted"] is True  # stopped by the SIGINT above, not by the duration
    assert m["run"]["collisions"] == 0
    assert m["run"]["min_separation_m"] >= 2 * BODY_RADIUS_M
    saf = m["safety"]
    assert saf["safety_distance_m"] == pytest.approx(0.19)
    assert saf["time_touching_s"] == 0.0
    assert saf["boundary_violations"] == 0
    # the filter counters, from each agent's status (formation.record.collector)
    assert saf["filter_source"] == "status" and set(saf["filter_per_robot"]) == set(last)
    assert saf["filter_active_fraction"] > 0.0  # the one behind went round the stopped one
    # the robot that was behind the stopped one went round it (before the filter: stuck 0.86 m
    # from its slot, behind it): it ends well ahead of it (the formation moved on >= 1 m)
    assert final[behind][0] > final[stopped][0] + 0.3, (final[behind], final[stopped])
    # everyone else is back on a slot and tracking it closely; the one that went round is on its
    # way (on a loaded machine the e-stop can come late, leaving it less time)
    for rid, msg in last.items():
        if rid == stopped:
            continue
        err = math.hypot(getattr(msg, "ex", 0.0) or 0.0, getattr(msg, "ey", 0.0) or 0.0)
        # (at the end of the run the setpoints stop: a robot may already be in HOLD)
        assert getattr(msg, "mode", None) in ("tracking", "hold"), (rid, msg)
        assert err < (0.30 if rid == behind else 0.15), (rid, err, msg)
