"""One home for every robot parameter: the declaration in robot_agent/core/params.py (and a motor
backend's settings) is what the robot-config loader, the scenario loader and docs/parameters.md
read; the two loaders refuse the same values with the same words."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

import scenario
from robot_agent.core.config_tables import agent_sections
from robot_agent.core.params import SafetyFilterParams, declared_range
from scenario.docs import attribute_docs, render_markdown
from scenario.robot_config import ConfigError, robot_config_from_dict

REPO = Path(__file__).resolve().parents[3]


def test_docs_parameters_md_is_generated_from_the_declarations() -> None:
    text = (REPO / "docs" / "parameters.md").read_text(encoding="utf-8")
    assert text == render_markdown(), "run: python -m scenario.docs > docs/parameters.md"


def test_every_parameter_has_a_meaning() -> None:
    for section, cls in agent_sections().items():
        docs = attribute_docs(cls)
        for f in dataclasses.fields(cls):
            assert docs.get(f.name), f"{section}.{f.name}: no line in {cls.__name__}'s Attributes"


def test_the_margin_is_declared_once() -> None:
    lo, hi = declared_range(SafetyFilterParams, "margin_m") or (None, None)
    assert (lo, hi) == (0.0, 1.0)
    row = next(r for r in render_markdown().splitlines() if r.startswith("| `margin_m` |"))
    assert "| 0.04 | 0 .. 1 |" in row


@pytest.mark.parametrize(
    ("section", "key", "value"),
    [
        ("safety_filter", "margin_m", 2.0),
        ("safety", "stale_pose_s", 1e6),
        ("gains", "kp", 1e9),
        ("estimator", "reset_after", 0),
        ("geometry", "wheel_radius_m", -0.03),
    ],
)
def test_scenario_and_robot_config_refuse_the_same_value(
    section: str, key: str, value: float
) -> None:
    """The scenario loader used to skip the range check a robot's config applies."""
    base = {
        "name": "t",
        "robots": {"count": 3},
        "duration_s": 1.0,
        "trajectory": {"kind": "line", "speed_mps": 0.02},
        "formation": {"kind": "triangle"},
        section: {key: value},
    }
    with pytest.raises(scenario.ScenarioError) as scen:
        scenario.parse(base)
    with pytest.raises(ConfigError) as conf:
        robot_config_from_dict(
            {
                "robot_id": "r1",
                section: {key: value},
                "zenoh": {"endpoints": ["tcp/127.0.0.1:7447"]},
            }
        )
    scen_msg = str(scen.value)
    conf_msgs = conf.value.problems
    assert f"{section}.{key}" in scen_msg
    assert any(scen_msg in m or m in scen_msg for m in conf_msgs), (scen_msg, conf_msgs)
