"""Which coordinator core runs: the pure-Python sources or their compiled build (mypyc).

The coordinator's per-tick modules (:data:`COMPILED_MODULES`: the tick of ``CoordinatorCore``,
the virtual leader's state and step, the movers' pass, the slot matching, the role assignment
and the formation geometry) are plain, fully annotated Python. ``python -m
formation.sim.accel_build build`` compiles *the same files* with mypyc into
``coordinator/_compiled/`` (one group, ``coordinator_accel``), checks that the
in-process simulator's outputs (which run this core every tick) are equal bit for bit to the pure
sources' before installing, and ``tests/unit/coordinator/test_coordinator_accel.py`` checks it
again. The same build serves the in-process simulator and the coordinator process over Zenoh.

The decision follows the rules of every compiled build (``robot_agent/core/_accel.py``,
:class:`~robot_agent.core._accel.CompiledBuild`): ``FORMATION_ACCEL=0``, no build, another
interpreter or edited sources mean pure Python. ``coordinator/core/__init__.py`` calls
:func:`activate` before it imports anything. The modules left out gain nothing from mypyc (their
work is numpy's: ``slots``, the planner), run once per run, not per tick, or must stay Python:
``trajectory`` (a ``runtime_checkable`` protocol; frozen dataclasses that validate by coercing and
pickle: its per-tick ``LeaderState``, the closed-form samples' arithmetic and their samplers,
which the leader calls every tick, are compiled in ``leader_state``) and ``leader_config`` (the
same; docs/architecture.md). Standard library only.
"""

from __future__ import annotations

from pathlib import Path

from robot_agent.core._accel import CompiledBuild

#: The compiled modules, by dotted name, in dependency order.
COMPILED_MODULES: tuple[str, ...] = (
    "coordinator.core.leader_state",  # LeaderState, made every tick (trajectory re-exports it)
    "coordinator.core.assignment",
    "coordinator.core.formation",
    "coordinator.core.matching",
    "coordinator.core.movers",
    "coordinator.core.leader",
    "coordinator.core.coordinator",
)
#: The project's root: the folder holding the ``coordinator`` package.
ROOT = Path(__file__).resolve().parents[2]
#: The coordinator's build: ``coordinator/_compiled``, group ``coordinator_accel``.
BUILD = CompiledBuild(
    "coordinator_accel", COMPILED_MODULES, ROOT, ROOT / "coordinator" / "_compiled"
)
status = BUILD.status
activate = BUILD.activate
