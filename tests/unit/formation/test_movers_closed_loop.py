"""Issue 30, "Movers", in whole in-process runs (``formation.sim.simulate``): bodies carried
through every robot of a triangle and a chevron from four directions never come within
touching distance of a fleet robot (centres > 0.150 m), nor is the fleet pushed into itself; a
carried robot never takes a slot; scenario ``[[mover]]`` bodies (visible and not). Speeds: the
envelope that holds today (docs/faults.md has the whole table up to 0.5 m/s).

The firmware's part (IDLE / HOLD evade): tests/unit/robot_agent/test_firmware_evade.py; the
coordinator's detector: tests/unit/coordinator/test_coord_movers.py.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from support.carry_runs import BODY_RADIUS_M, RUN_M, SETTLE_S, TOUCH_M, carry, formation, where

from formation.sim import simulate
from scenario.load import ScenarioError, parse
from scenario.movers import MoverBody


@pytest.mark.parametrize(
    ("kind", "speed_mps"), [("triangle", 0.05), ("triangle", 0.25), ("chevron", 0.3)]
)
def test_a_spare_carried_through_every_robot_never_touches_the_fleet(
    kind: str, speed_mps: float
) -> None:
    """Through every robot, head-on, from behind and across both ways: the spare never
    touches a fleet robot, the fleet never touches itself, and the spare is never given a
    slot. Up to the robots' top speed (0.3 m/s) in both formations; docs/faults.md has the
    table to 0.5 m/s (``python bench/bench_movers.py`` measures it)."""
    n = len(formation(kind).robot_ids)
    for target in range(n):
        for heading in (math.pi, 0.0, math.pi / 2, -math.pi / 2):
            body, fleet, slots = carry(kind, target, heading, speed_mps)
            where = f"{kind} r{target + 1} heading {heading:.2f} at {speed_mps} m/s"
            assert body > TOUCH_M, f"{where}: body at {body:.3f} m"
            assert fleet > TOUCH_M, f"{where}: fleet at {fleet:.3f} m"
            assert (slots == -1).all(), f"{where}: the carried spare took a slot"


@settings(max_examples=8, deadline=None, derandomize=True)
@given(
    kind=st.sampled_from(["triangle", "chevron"]),
    target=st.integers(0, 4),
    heading_rad=st.floats(-math.pi, math.pi),
    speed_mps=st.floats(0.05, 0.3),
    offset_m=st.floats(-0.1, 0.1),
)
def test_any_direction_and_speed_through_eitherformation(
    kind: str, target: int, heading_rad: float, speed_mps: float, offset_m: float
) -> None:
    """Any direction, any speed up to the robots' top speed, a little off any robot's centre:
    the spare never touches a fleet robot, the fleet never touches itself, no slot for it."""
    target %= len(formation(kind).robot_ids)
    body, fleet, slots = carry(kind, target, heading_rad, speed_mps, offset_m)
    assert body > TOUCH_M
    assert fleet > TOUCH_M
    assert (slots == -1).all()


def _body_run(kind: str, target: int, speed_mps: float, visible: bool) -> float:
    """A ``[[mover]]`` body (radius 0.075 m) head-on through robot ``target``; least centre
    distance to the fleet."""
    base = formation(kind)
    lead_s = round(RUN_M / speed_mps, 2)
    t_pass = SETTLE_S + lead_s
    tx, ty = where(kind, t_pass)[target]
    run_m = lead_s * speed_mps
    body = MoverBody(
        "cart", BODY_RADIUS_M, ((tx + run_m, ty), (tx - run_m, ty)), speed_mps, SETTLE_S, visible
    )
    sc = dataclasses.replace(base, movers=(body,), duration_s=t_pass + lead_s + 1.0)
    res = simulate.run(sc)
    xy = np.asarray(res.log.truth)[:, :, :2]
    track = res.movers["cart"]
    assert track.shape == (xy.shape[0], 2)
    return float(np.hypot(*(xy - track[:, None, :]).transpose(2, 0, 1)).min())


@pytest.mark.parametrize("speed_mps", [0.05, 0.2, 0.3])
def test_a_visible_mover_body_is_avoided(speed_mps: float) -> None:
    assert _body_run("triangle", 0, speed_mps, visible=True) > TOUCH_M


def test_an_invisible_mover_is_not_seen() -> None:
    """An untracked person walking head-on into the leader: nobody sees it, so it runs into
    the leader (the measurement the visible case is compared with)."""
    assert _body_run("triangle", 0, 0.2, visible=False) < 0.05


def test_mover_entries_in_a_scenario_file() -> None:
    data = {
        "name": "m",
        "duration_s": 10.0,
        "robots": {"ids": ["r1"]},
        "trajectory": {"kind": "line", "x0": 0.0, "y0": 0.0, "heading": 0.0, "speed_mps": 0.0},
        "formation": {"kind": "triangle", "b_m": 0.4},
        "mover": [
            {"radius_m": 0.1, "path": [[1.0, 0.0], [1.0, 1.0], [0.0, 1.0]], "speed_mps": 0.5},
            {"id": "person", "radius_m": 0.2, "path": [[0, 0], [1, 0]], "speed_mps": 1,
             "t_s": 2.0, "visible": False},
        ],
    }  # fmt: skip
    sc = parse(data)
    a, b = sc.movers
    assert (a.id, a.visible, b.id, b.visible) == ("mover1", True, "person", False)
    assert a.state(1.0) == pytest.approx((1.0, 0.5, 0.0, 0.5))
    assert a.state(3.0) == pytest.approx((0.5, 1.0, -0.5, 0.0))
    assert a.state(100.0) == (0.0, 1.0, 0.0, 0.0)
    assert b.state(1.0) == (0.0, 0.0, 0.0, 0.0)  # before its start: at the first waypoint
    for bad in (
        {"radius_m": 0.1, "path": [[1.0, 0.0]], "speed_mps": 0.5},
        {"radius_m": -0.1, "path": [[0, 0], [1, 0]], "speed_mps": 0.5},
        {"radius_m": 0.1, "path": [[0, 0], [1, 0]], "speed_mps": 0.5, "colour": "red"},
        {"id": "r1", "radius_m": 0.1, "path": [[0, 0], [1, 0]], "speed_mps": 0.5},
        {"radius_m": 0.1, "path": [[0, 0], [1, math.nan]], "speed_mps": 0.5},
        {"radius_m": 0.1, "path": [[0, 0], [1, 0]], "speed_mps": 0.5, "visible": 1},
    ):
        with pytest.raises(ScenarioError):
            parse({**data, "mover": [bad]})
