"""Scenarios: one experiment, read the same way by every runtime.

A scenario fixes everything about a run: robots and their start poses, robot parameters, the
virtual leader's trajectory, the formation, the assignment rule, the plant's sensor and link
models and scheduled disturbances. ``formation sim`` (in-process) and ``formation up`` (one
process per node over Zenoh) read the same file, so both runs are the same experiment.

* :mod:`scenario.load`: the loader and the one validator (errors name the field);
* :mod:`scenario.write`: TOML writer (``to_toml``);
* :mod:`scenario.resize`: ``--robots N`` / ``--spares K`` (``scenario_with_robots``,
  ``fleet_shape``);
* ``scenario/builtin/*.toml``: the built-in scenarios, named without the extension.

This package sits above the pure cores and below the runtime's process shells
(docs/architecture.md); it imports nothing numeric at module level (an agent loads scenarios).
"""

from scenario.load import (
    SCENARIO_DIR,
    AssignmentConfig,
    CameraModel,
    Disturbance,
    LinkModel,
    PlantModel,
    Scenario,
    ScenarioError,
    builtin_names,
    load,
    parse,
    resolve,
)
from scenario.resize import FleetShape, fleet_shape, load_with_robots, scenario_with_robots
from scenario.write import to_toml

__all__ = [
    "SCENARIO_DIR",
    "AssignmentConfig",
    "CameraModel",
    "Disturbance",
    "FleetShape",
    "LinkModel",
    "PlantModel",
    "Scenario",
    "ScenarioError",
    "builtin_names",
    "fleet_shape",
    "load",
    "load_with_robots",
    "parse",
    "resolve",
    "scenario_with_robots",
    "to_toml",
]
