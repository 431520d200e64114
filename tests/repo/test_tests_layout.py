"""tests/ mirrors the code: unit tests by package, tests over real Zenoh, whole fleets of real
processes, checks of the repository, and the shared support, so the test of a feature is found
by its place (docs/architecture.md). pytest imports test modules by their basename, so two test
files of one name in different folders would shadow each other: every name is unique."""

from __future__ import annotations

from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
TESTS = ROOT / "tests"
PACKAGES = (
    "bus_schemas",
    "robot_agent",
    "coordinator",
    "sim_plant",
    "localization",
    "scenario",
    "runtime",
    "formation",
)
FOLDERS = {"bus", "fleet", "repo", *(f"unit/{p}" for p in PACKAGES)}


def _test_files() -> list[Path]:
    return sorted(p for p in TESTS.rglob("test_*.py") if "__pycache__" not in p.parts)


def test_every_test_module_has_a_unique_basename() -> None:
    names = Counter(p.name for p in _test_files())
    assert len(names) > 100
    assert not [n for n, c in names.items() if c > 1], names.most_common(3)


def test_every_test_module_is_in_a_floor_folder() -> None:
    misplaced = [
        str(p.relative_to(TESTS))
        for p in _test_files()
        if str(p.parent.relative_to(TESTS)) not in FOLDERS
    ]
    assert not misplaced, f"tests outside {sorted(FOLDERS)}: {misplaced}"


def test_support_holds_no_tests() -> None:
    assert not list((TESTS / "support").glob("test_*.py"))
