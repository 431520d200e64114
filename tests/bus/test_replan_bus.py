"""Goals planned around obstacles and replanned at run time (issue 27 item 5) with a real
``formation coordinator`` on a real router: ``formation goal`` on a map with a pillar is
planned (the CLI reports the plan), ``formation obstacle add`` replans from the moving leader,
an obstacle on the goal stops it with the reason in the status, and a standby that takes over a
planned goal continues it without a jump.

The robots are perfect followers published from the test (tests/bus/test_operator.py's).
"""

from __future__ import annotations

import itertools
import math
import signal
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import msgpack
import pytest
import zenoh
from support.bus_watch import Recorder, decoder_of
from support.operator_bus import Followers, leader_jumps
from support.routers import RouterHandle
from support.spawn import Spawner
from support.yard import yard_toml

import runtime as rt
from bus_schemas import Leader, keys

FLEET = "demo"
YARD = yard_toml(duration_s=600.0, pillar_x=1.0)
START = {"r1": (0.0, 0.0, 0.0), "r2": (-0.4, 0.2, 0.0), "r3": (-0.4, -0.2, 0.0)}


@pytest.fixture
def client(session: Callable[..., zenoh.Session]) -> zenoh.Session:
    return session()


@pytest.fixture
def yard(tmp_path: Path) -> str:
    path = tmp_path / "yard.toml"
    path.write_text(YARD)
    return str(path)


def _coordinator(spawn: Spawner, router: RouterHandle, yard: str, *extra: str) -> Any:
    return spawn(
        "coordinator", "--scenario", yard, "--endpoint", router.endpoint, *extra,
        ready="coordinator ready",
    )  # fmt: skip


def _followers(client: zenoh.Session) -> Followers:
    f = Followers(client)
    f.at = dict(START)
    return f


def test_a_goal_is_planned_replanned_round_a_new_obstacle_and_stopped_by_one_on_it(
    spawn: Spawner, router: RouterHandle, client: zenoh.Session, yard: str
) -> None:
    tokens = [rt.declare_token(client, keys.alive_robot_key(FLEET, r)) for r in START]
    leaders = Recorder(client, keys.leader_key(FLEET), decoder_of(Leader))
    status = Recorder(client, keys.coordinator_status_key(FLEET, "main"), msgpack.unpackb)
    _coordinator(spawn, router, yard)
    ep = ("--endpoint", router.endpoint)
    with _followers(client):
        leaders.wait_for(lambda *_: True)
        goal = spawn("goal", "2.2", "0.0", "--timeout", "5", *ep)
        assert goal.proc.wait(timeout=60) == 0, goal.describe()
        assert "planned around the obstacles" in goal.stdout(), goal.describe()
        # the leader leaves the straight line to pass the pillar: the box is added while the
        # formation rounds it (the replan's bridge keeps to the followed plan, docs/planning.md)
        leaders.wait_for(lambda _r, _k, m: m.mode == "goal" and abs(m.y) > 0.03, timeout_s=30.0)
        box = spawn("obstacle", "add", "box", "--circle", "1.8", "0.45", "0.15", *ep)
        assert box.proc.wait(timeout=30) == 0, box.describe()
        _, _, st = status.wait_for(
            lambda _r, _k, s: s.get("replans", 0) >= 1 and s.get("plan") == "following",
            timeout_s=30.0,
        )
        assert st["plan_why"] == "obstacle box added" and st["obstacles"] == 1
        assert st["plan_clearance_m"] > 0.18 and st["plan_ms"] > 0.0
        again = spawn("obstacle", "add", "box", "--circle", "1.8", "0.45", "0.15", *ep)
        assert again.proc.wait(timeout=30) == 1 and "exists" in again.stderr()
        # an obstacle on the goal: no way, the leader decelerates to a stop, the status says why
        t_block = time.monotonic()
        block = spawn("obstacle", "add", "goalbox", "--circle", "2.2", "0.0", "0.1", *ep)
        assert block.proc.wait(timeout=30) == 0, block.describe()
        _, _, st = status.wait_for(lambda _r, _k, s: s.get("plan") == "no_way", timeout_s=30.0)
        assert "inside an obstacle" in st["plan_why"], st["plan_why"]
        r_stop, _, _ = leaders.wait_for(
            lambda r, _k, m: r > t_block and m.mode == "stop" and m.v_mps == 0.0, timeout_s=20.0
        )
    msgs = [m for r, _k, m in leaders.snapshot()]
    assert not leader_jumps(leaders.snapshot()), leader_jumps(leaders.snapshot())[:5]
    for a, b in itertools.pairwise(msgs):  # no velocity step at any join either
        assert abs(b.v_mps - a.v_mps) <= 0.1 * max(b.t - a.t, 0.0) + 1e-6, (a, b)
    assert r_stop > t_block
    del tokens


def test_a_standby_continues_a_planned_goal_without_a_jump(
    spawn: Spawner, router: RouterHandle, client: zenoh.Session, yard: str
) -> None:
    tokens = [rt.declare_token(client, keys.alive_robot_key(FLEET, r)) for r in START]
    leaders = Recorder(client, keys.leader_key(FLEET), decoder_of(Leader))
    status = Recorder(client, keys.all_coordinator_status_pattern(FLEET), msgpack.unpackb)
    main = _coordinator(spawn, router, yard)
    _coordinator(spawn, router, yard, "--name", "b", "--standby")
    with _followers(client):
        leaders.wait_for(lambda *_: True)
        goal = spawn("goal", "2.2", "0.0", "--timeout", "5", "--endpoint", router.endpoint)
        assert goal.proc.wait(timeout=60) == 0, goal.describe()
        # on the plan, moving, before the pillar (a takeover replans with the nominal formation)
        leaders.wait_for(
            lambda _r, _k, m: m.mode == "goal" and m.progress_s and m.v_mps > 0.05, timeout_s=30.0
        )
        main.stop(signal.SIGKILL)
        t_kill = time.monotonic()
        _, _, b_st = status.wait_for(
            lambda r, _k, s: r > t_kill and s["name"] == "b" and s.get("plan") == "following",
            timeout_s=30.0,
        )
        time.sleep(1.0)
    assert b_st["plan_why"] == "takeover" and b_st["plans"] == 1, b_st
    msgs = leaders.snapshot()
    before = [m for r, _, m in msgs if r <= t_kill]
    after = [m for r, _, m in msgs if r > t_kill + 0.05]
    assert before and after
    last, first = before[-1], after[0]
    assert first.mode == "goal"
    assert math.hypot(first.x - last.x, first.y - last.y) <= 0.1 * 0.1 + 1e-6
    assert abs(first.v_mps - last.v_mps) <= 0.1 * 0.1 + 1e-9
    assert not leader_jumps([(r, k, m) for r, k, m in msgs if r > t_kill + 0.05])
    del tokens
