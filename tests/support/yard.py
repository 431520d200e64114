"""The yard of the replanning tests (issue 27): a triangle on an arena with one pillar on its
way; goals are planned around it."""

from __future__ import annotations


def yard_toml(duration_s: float, pillar_x: float) -> str:
    """The scenario's TOML text: a run of ``duration_s`` with the pillar (0.2 m) at
    ``(pillar_x, 0)``."""
    return f"""\
name = "yard"
description = "A triangle in a yard with a pillar: goals are planned around obstacles."
duration_s = {duration_s!r}
dt_s = 0.02
seed = 27

[robots]
ids = ["r1", "r2", "r3"]
initial = [[0.0, 0.0, 0.0], [-0.4, 0.2, 0.0], [-0.4, -0.2, 0.0]]

[trajectory]
kind = "line"
x0 = 0.05
y0 = 0.0
heading = 0.0
speed_mps = 0.0

[formation]
kind = "triangle"
b_m = 0.4

[assignment]
method = "greedy"
hysteresis_m = 0.05
tie_tol_m = 0.01

[arena]
x_min = -1.5
y_min = -2.0
x_max = 4.0
y_max = 2.0

[[obstacle]]
kind = "circle"
x = {pillar_x!r}
y = 0.0
radius_m = 0.2
"""
