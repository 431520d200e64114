"""Scenario ``[[operator]]`` entries (scenario/operator.py): scripted operator commands, each
mistake one line naming the entry, and the pure player (coordinator/core/operator_script.py)
that the in-process simulator and the coordinator node share."""

from __future__ import annotations

import math
import tomllib
from typing import Any

import pytest

from coordinator.core.operator_script import OperatorScript
from scenario.assemble import coordinator_core
from scenario.load import ScenarioError, parse, resolve
from scenario.operator import OperatorEvent, parse_operator

BASE = tomllib.loads(resolve("paper-exp2").read_text())


def _with(*entries: dict[str, Any]) -> Any:
    return parse({**BASE, "operator": list(entries)})


def test_entries_parse_in_time_order() -> None:
    sc = _with(
        {"t_s": 3.0, "command": "goal", "x": 1.0, "y": 0.5, "heading": 1.5},
        {"t_s": 1.0, "command": "shape", "kind": "line", "slots": 2, "spacing_m": 0.5},
        {"t_s": 2.0, "command": "teleop", "v_mps": 0.05, "omega_radps": 0.0, "duration_s": 1},
        {"t_s": 4.0, "command": "path", "waypoints": [[1, 0], [2, 0]]},
        {"t_s": 4.0, "command": "stop"},
    )
    assert [e.command for e in sc.operator] == ["shape", "teleop", "goal", "path", "stop"]
    assert sc.operator[0] == OperatorEvent(
        t_s=1.0, command="shape", kind="line", spacing_m=0.5, slots=2
    )
    assert sc.operator[3].waypoints == ((1.0, 0.0), (2.0, 0.0))
    assert parse_operator(None, 3, 10.0) == ()


@pytest.mark.parametrize(
    ("entry", "needle"),
    [
        ({"t_s": 1.0, "command": "dance"}, "operator[0].command"),
        ({"t_s": 1.0, "command": "shape"}, "needs kind"),
        ({"t_s": 1.0, "command": "shape", "kind": "zigzag"}, "operator[0].kind"),
        ({"t_s": 1.0, "command": "shape", "kind": "line", "slots": 0}, "operator[0].slots"),
        ({"t_s": 1.0, "command": "shape", "kind": "line", "slots": 4}, "[1, 3]"),
        ({"t_s": 1.0, "command": "shape", "kind": "line", "spacing_m": -1}, "spacing_m"),
        ({"t_s": 1.0, "command": "goal", "x": math.nan, "y": 0.0}, "operator[0].x"),
        ({"t_s": 1e9, "command": "stop"}, "outside the run"),
        ({"t_s": 1.0, "command": "stop", "x": 1.0}, "unknown key(s) x"),
        ({"t_s": 1.0, "command": "path", "waypoints": [[1.0]]}, "waypoints[0]"),
        ({"command": "stop"}, "needs t_s"),
        ({"t_s": 1.0, "command": "obstacle", "id": "b"}, "needs action"),
        ({"t_s": 1.0, "command": "obstacle", "id": "b", "action": "hide"}, "operator[0].action"),
        ({"t_s": 1.0, "command": "obstacle", "id": "", "action": "remove"}, "operator[0].id"),
        ({"t_s": 1.0, "command": "obstacle", "id": "b", "action": "add"}, "operator[0].shape"),
        (
            {
                "t_s": 1.0,
                "command": "obstacle",
                "id": "b",
                "action": "add",
                "shape": "circle",
                "x": 1.0,
                "y": 0.0,
            },
            "a circle needs radius_m, x, y",
        ),
        (
            {
                "t_s": 1.0,
                "command": "obstacle",
                "id": "b",
                "action": "add",
                "shape": "circle",
                "x": 1.0,
                "y": 0.0,
                "radius_m": 0.0,
            },
            "radius_m must be > 0",
        ),
        (
            {
                "t_s": 1.0,
                "command": "obstacle",
                "id": "b",
                "action": "move",
                "shape": "polygon",
                "points": [[0, 0], [1, 0]],
            },
            "operator[0].points",
        ),
        (
            {"t_s": 1.0, "command": "obstacle", "id": "b", "action": "remove", "x": 1.0},
            "remove takes no x",
        ),
    ],
)
def test_a_bad_entry_is_one_line_naming_it(entry: dict[str, Any], needle: str) -> None:
    with pytest.raises(ScenarioError) as err:
        _with(entry)
    assert needle in str(err.value) and "\n" not in str(err.value)


def test_the_player_applies_each_command_at_its_tick_and_counts_refusals() -> None:
    sc = _with(
        {"t_s": 0.1, "command": "shape", "kind": "column"},
        {"t_s": 0.1, "command": "shape", "kind": "line", "slots": 3},
        {"t_s": 0.2, "command": "teleop", "v_mps": 0.05, "omega_radps": 0.1, "duration_s": 0.1},
        {"t_s": 0.4, "command": "goal", "x": 1.0, "y": 0.0},
    )
    core = coordinator_core(sc)
    script = OperatorScript(sc.operator, sc.agent.safety_distance_m)
    modes = []
    for k in range(30):
        t = k * sc.dt_s
        script.play(core, t, t, robots=2)  # two robots counted: three slots are too many
        core.tick(t, {})
        modes.append(core.leader.mode.value)
    assert [a["applied_s"] for a in script.applied] == [0.1, 0.1, 0.4]
    assert [a["refused"] for a in script.applied] == [None, "too_many_slots", None]
    assert core.shape == "column" and core.reshaping is not None
    assert modes[9] == "script" and modes[10] == "teleop"
    assert script.rejects == {"shape-too_many_slots": 1}
    # a takeover skips what the previous active applied
    again = OperatorScript(sc.operator, sc.agent.safety_distance_m)
    again.skip_until(0.3)
    again.play(core, 0.3, 0.3, robots=3)
    assert again.applied == [] and again.active


def test_a_scripted_obstacle_reaches_the_planner_and_a_degenerate_one_is_refused() -> None:
    """The ``obstacle`` command is applied as the coordinator node's ``Obstacle`` input: the
    same table (``obstacle_table``), refusals counted (``obstacle-<reason>``)."""
    events = parse_operator(
        [
            {"t_s": 0.0, "command": "obstacle", "id": "box", "action": "add", "shape": "polygon",
             "points": [[1, 1], [2, 1], [2, 2], [1, 2]]},
            {"t_s": 0.0, "command": "obstacle", "id": "bow", "action": "add", "shape": "polygon",
             "points": [[0, 0], [1, 1], [1, 0], [0, 1]]},  # crosses itself
            {"t_s": 0.1, "command": "obstacle", "id": "box", "action": "move", "shape": "circle",
             "x": 2.0, "y": 0.5, "radius_m": 0.2},
            {"t_s": 0.2, "command": "obstacle", "id": "nope", "action": "remove"},
        ],
        3,
        10.0,
    )  # fmt: skip
    assert events[2].as_dict()["id"] == "box" and events[0].points[1] == (2.0, 1.0)
    sc = parse(tomllib.loads(resolve("corridor").read_text()))  # a world with obstacles
    core = coordinator_core(sc)
    player = OperatorScript(events, 0.2)
    refused = player.play(core, 0.0, 0.0, 3)
    assert refused == [("obstacle", "degenerate")]
    assert core.replanner.obstacles["box"]["kind"] == "polygon"
    player.play(core, 0.1, 0.1, 3)
    assert core.replanner.obstacles["box"] == {
        "kind": "circle",
        "x": 2.0,
        "y": 0.5,
        "radius_m": 0.2,
    }
    assert player.play(core, 0.2, 0.2, 3) == [("obstacle", "unknown")]
    assert player.rejects == {"obstacle-degenerate": 1, "obstacle-unknown": 1}
