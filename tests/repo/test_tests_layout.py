"""tests/ mirrors the code: unit tests by package, tests over real Zenoh, whole fleets of real
processes, checks of the repository, and the shared support, so the test of a feature is found
by its place (docs/architecture.md). pytest imports test modules by their basename, so two test
files of one name in different folders would shadow each other: every name is unique. A helper
that more than one test file uses lives in tests/support/ (imported as ``support.<module>``):
no test file, and no support module, imports a test file or tests/conftest.py."""

from __future__ import annotations

import ast
from collections import Counter
from collections.abc import Iterable
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


def imports_of_tests(source: str, test_modules: Iterable[str]) -> list[str]:
    """The imports in ``source`` (any depth: function-level ones too) of a module named in
    ``test_modules`` or of ``conftest``, as ``line: module``."""
    forbidden = {*test_modules, "conftest"}
    found = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names = [node.module]
        elif isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        else:
            continue
        found += [f"{node.lineno}: {n}" for n in names if n.split(".")[0] in forbidden]
    return found


def test_no_test_file_imports_another_test_file() -> None:
    test_modules = {p.stem for p in _test_files()}
    offenders = {
        str(p.relative_to(ROOT)): hits
        for p in sorted(TESTS.rglob("*.py"))
        if "__pycache__" not in p.parts and p.name != "conftest.py"
        for hits in [imports_of_tests(p.read_text(), test_modules)]
        if hits
    }
    assert not offenders, f"move the shared helpers into tests/support/: {offenders}"


def test_the_import_check_has_teeth() -> None:
    planted = (
        "import os\n"
        "from test_up import finish\n"
        "def f():\n"
        "    import test_acl.sub\n"
        "    from conftest import Spawner\n"
        "from support.spawn import Spawner\n"
        "from . import test_up\n"
    )
    assert imports_of_tests(planted, {"test_up", "test_acl"}) == [
        "2: test_up",
        "4: test_acl.sub",
        "5: conftest",
    ]
