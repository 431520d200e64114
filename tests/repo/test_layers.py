"""The floor plan (docs/architecture.md): every import points down, nothing imports in a circle.

Plain ``ast`` over every ``.py`` file of the project's packages, every import statement included
(module level, inside functions, under ``if TYPE_CHECKING``). Each module is on one floor; a
module may import modules of its own floor or of a lower one, never of a higher one, and the
graph of imports between the project's modules has no cycle. The last tests show the checker
has teeth: an upward import or a cycle added to a copy of the tree makes it fail.
"""

from __future__ import annotations

import ast
import shutil
from collections.abc import Iterable, Mapping
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]

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

# Floors, bottom up, by folder. A rule ``"pkg"`` covers ``pkg`` and everything under it; a rule
# ``"*.core"`` covers the folder ``core`` of any package (``robot_agent.core.firmware``). A
# package's own ``__init__`` outside its floors (``robot_agent``) holds a docstring only and is
# on the ground floor (test_package_roots_import_nothing).
FLOORS: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("contract", ("bus_schemas",)),
    ("cores", ("*.core",)),
    ("drivers", ("robot_agent.motors",)),
    ("scenario", ("scenario",)),
    ("runtime", ("runtime",)),
    ("shells", ("*.node", "robot_agent.buildtools")),
    ("tools", ("formation",)),
)
ROOTS = ("robot_agent", "coordinator", "sim_plant", "localization", "formation")
# The pure floor: no module under a ``core`` folder reads a clock or touches Zenoh or asyncio.
CLOCK_READS = frozenset(
    {
        "monotonic",
        "monotonic_ns",
        "time",
        "time_ns",
        "perf_counter",
        "perf_counter_ns",
        "now",
        "utcnow",
        "today",
        "sleep",
    }
)
CORE_FORBIDDEN_MODULES = frozenset({"zenoh", "asyncio", "runtime", "scenario", "formation"})


def module_files(root: Path) -> dict[str, Path]:
    """Dotted module name -> file, for every ``.py`` file of :data:`PACKAGES` under ``root``."""
    out: dict[str, Path] = {}
    for pkg in PACKAGES:
        base = root / pkg
        if not base.is_dir():
            continue
        for path in sorted(base.rglob("*.py")):
            parts = list(path.relative_to(root).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts.pop()
            out[".".join(parts)] = path
    return out


def _covers(rule: str, module: str) -> bool:
    parts = module.split(".")
    if rule.startswith("*."):
        return len(parts) >= 2 and parts[1] == rule[2:]
    return module == rule or module.startswith(rule + ".")


def floor_of(module: str) -> int:
    """Index of ``module``'s floor in :data:`FLOORS` (KeyError if no rule covers it)."""
    if module in ROOTS:
        return 0
    found = [i for i, (_, rules) in enumerate(FLOORS) if any(_covers(r, module) for r in rules)]
    if len(found) != 1:
        raise KeyError(f"{module}: on {len(found)} floors of tests/repo/test_layers.py FLOORS")
    return found[0]


def _imported(module: str, is_package: bool, node: ast.AST, known: Iterable[str]) -> list[str]:
    """Project modules an import statement loads (``from pkg import sub`` -> ``pkg.sub``)."""
    known = set(known)
    targets: list[str] = []
    if isinstance(node, ast.Import):
        targets = [alias.name for alias in node.names]
    elif isinstance(node, ast.ImportFrom):
        if node.level:
            base = module.split(".")
            if not is_package:
                base = base[:-1]
            if node.level > 1:
                base = base[: len(base) - (node.level - 1)]
            parent = ".".join(base + ([node.module] if node.module else []))
        else:
            parent = node.module or ""
        subs = [f"{parent}.{a.name}" for a in node.names if f"{parent}.{a.name}" in known]
        targets = subs if len(subs) == len(node.names) else [parent, *subs]
    out: list[str] = []
    for target in targets:
        while target and target not in known and "." in target:
            target = target.rsplit(".", 1)[0]
        if target in known and target != module:
            out.append(target)
    return out


def import_graph(root: Path) -> dict[str, dict[str, int]]:
    """module -> {imported project module: line of the first such import}."""
    files = module_files(root)
    graph: dict[str, dict[str, int]] = {}
    for module, path in files.items():
        tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
        edges: dict[str, int] = {}
        for node in ast.walk(tree):
            if isinstance(node, ast.Import | ast.ImportFrom):
                for target in _imported(module, path.name == "__init__.py", node, files):
                    edges.setdefault(target, node.lineno)
        graph[module] = edges
    return graph


def upward_imports(graph: Mapping[str, Mapping[str, int]]) -> list[str]:
    """Every import of a module on a higher floor, as readable lines."""
    bad: list[str] = []
    for module, edges in sorted(graph.items()):
        mine = floor_of(module)
        for target, line in sorted(edges.items()):
            theirs = floor_of(target)
            if theirs > mine:
                bad.append(
                    f"{module}:{line} ({FLOORS[mine][0]}) imports {target} ({FLOORS[theirs][0]})"
                )
    return bad


def _facade(module: str, graph: Mapping[str, Mapping[str, int]]) -> bool:
    """A package ``__init__`` that only re-exports its own submodules."""
    return any(other.startswith(module + ".") for other in graph)


def cycles(graph: Mapping[str, Mapping[str, int]]) -> list[list[str]]:
    """The strongly connected components with more than one module (Tarjan), sorted.

    An edge from a package's submodule to the package itself (``from bus_schemas import keys``
    loads ``bus_schemas/__init__``, which imports the submodules back) is not a cycle of the
    design, so edges into a package's own ``__init__`` from inside the package are left out.
    """
    edges = {
        m: [t for t in targets if not (_facade(t, graph) and m.startswith(t + "."))]
        for m, targets in graph.items()
    }
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []
    counter = 0

    def visit(v: str) -> None:
        nonlocal counter
        index[v] = low[v] = counter
        counter += 1
        stack.append(v)
        on_stack.add(v)
        for w in edges.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp: list[str] = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                found.append(sorted(comp))

    for v in sorted(edges):
        if v not in index:
            visit(v)
    return sorted(found)


# --------------------------------------------------------------------------------------------
# The checks on this repository
# --------------------------------------------------------------------------------------------


def test_every_module_is_on_a_floor() -> None:
    modules = module_files(ROOT)
    assert len(modules) > 50, "the scanner found too few modules"
    for module in modules:
        floor_of(module)  # raises for a module no rule covers


def test_floor_rules_place_the_shells_above_the_runtime() -> None:
    names = [name for name, _ in FLOORS]
    assert names.index("contract") < names.index("cores") < names.index("scenario")
    assert names.index("scenario") < names.index("runtime") < names.index("shells")
    assert floor_of("robot_agent.core.firmware") == names.index("cores")
    assert floor_of("robot_agent.node.agent") == names.index("shells")
    assert floor_of("coordinator.node.coordinator") == names.index("shells")
    assert floor_of("runtime.bridge") == names.index("runtime")
    assert floor_of("formation.launch.up") == names.index("tools")


def test_scanner_sees_function_level_imports() -> None:
    graph = import_graph(ROOT)
    # scenario.resize imports the coordinator cores inside a function only.
    assert "coordinator.core.formation" in graph["scenario.resize"]


def test_every_import_points_down() -> None:
    bad = upward_imports(import_graph(ROOT))
    assert not bad, "imports pointing up (docs/architecture.md):\n" + "\n".join(bad)


def test_no_import_cycles() -> None:
    found = cycles(import_graph(ROOT))
    assert not found, f"import cycles: {found}"


def test_contract_imports_neither_zenoh_nor_asyncio() -> None:
    for module, path in module_files(ROOT).items():
        if not module.startswith("bus_schemas"):
            continue
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            names: list[str] = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names = [node.module]
            for name in names:
                assert name.split(".")[0] not in ("zenoh", "asyncio"), f"{module} imports {name}"


def subscriber_declarations(root: Path) -> list[str]:
    """``module:line`` of every ``declare_subscriber`` call in the project's packages."""
    out: list[str] = []
    for module, path in module_files(root).items():
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if (
                isinstance(node, ast.Call)
                and isinstance(node.func, ast.Attribute)
                and node.func.attr == "declare_subscriber"
            ):
                out.append(f"{module}:{node.lineno}")
    return out


def test_one_subscription_bridge() -> None:
    """Every subscription goes through runtime.bridge (docs/architecture.md, *One subscription
    bridge*): no other module of the packages declares a subscriber."""
    found = subscriber_declarations(ROOT)
    assert found, "the bridge itself declares subscribers"
    assert all(f.startswith("runtime.bridge:") for f in found), found


def test_one_subscription_bridge_has_teeth(tmp_path: Path) -> None:
    root = _copy_tree(tmp_path)
    _append(
        root / "formation" / "live" / "top.py",
        "def _tap(session):\n    return session.declare_subscriber('formation/**', print)\n",
    )
    assert [f for f in subscriber_declarations(root) if not f.startswith("runtime.bridge:")] == [
        f"formation.live.top:{len((root / 'formation/live/top.py').read_text().splitlines()) - 1}"
    ]


def test_no_process_shell_imports_the_cli() -> None:
    graph = import_graph(ROOT)
    shells = [m for m in graph if floor_of(m) == [n for n, _ in FLOORS].index("shells")]
    assert len(shells) > 15
    for shell in shells:
        assert not [t for t in graph[shell] if t.startswith("formation")], shell


# --------------------------------------------------------------------------------------------
# Teeth: the checker fails on a copy of the tree with a bad import added
# --------------------------------------------------------------------------------------------


def _copy_tree(tmp_path: Path) -> Path:
    for pkg in PACKAGES:
        shutil.copytree(ROOT / pkg, tmp_path / pkg, ignore=shutil.ignore_patterns("__pycache__"))
    return tmp_path


def _append(path: Path, text: str) -> None:
    path.write_text(path.read_text(encoding="utf-8") + "\n" + text + "\n", encoding="utf-8")


def test_teeth_copy_is_clean(tmp_path: Path) -> None:
    root = _copy_tree(tmp_path)
    graph = import_graph(root)
    assert not upward_imports(graph)
    assert not cycles(graph)


@pytest.mark.parametrize(
    ("file", "statement", "expected"),
    [
        # a function-level import of the CLI from the contract
        ("bus_schemas/keys.py", "def _late():\n    from formation import cli\n", "formation.cli"),
        # a core that reaches up into the runtime
        ("robot_agent/core/firmware.py", "import runtime.bridge\n", "runtime.bridge"),
        # a process shell importing the CLI package (the old formation.scenario habit)
        (
            "sim_plant/node/plant.py",
            "from formation.launch.up import UpConfig\n",
            "formation.launch.up",
        ),
    ],
)
def test_teeth_upward_import_fails(
    tmp_path: Path, file: str, statement: str, expected: str
) -> None:
    root = _copy_tree(tmp_path)
    _append(root / file, statement)
    bad = upward_imports(import_graph(root))
    assert any(expected in line for line in bad), bad


def test_teeth_cycle_fails(tmp_path: Path) -> None:
    root = _copy_tree(tmp_path)
    # coordinator.core.assignment already imports coordinator.core.formation: close the loop.
    _append(
        root / "coordinator" / "core" / "formation.py",
        "def _late():\n    import coordinator.core.assignment\n",
    )
    found = cycles(import_graph(root))
    assert any(
        {"coordinator.core.assignment", "coordinator.core.formation"} <= set(c) for c in found
    ), found
    assert not upward_imports(import_graph(root))  # same floor: only the cycle check catches it


# --------------------------------------------------------------------------------------------
# The pure floor: what a module under a ``core`` folder may not do
# --------------------------------------------------------------------------------------------


def core_impurities(root: Path) -> list[str]:
    """``module:line what`` for every clock read, Zenoh, asyncio or upper-floor import in a core."""
    bad: list[str] = []
    for module, path in module_files(root).items():
        if floor_of(module) != [n for n, _ in FLOORS].index("cores"):
            continue
        tree = ast.parse(path.read_text(encoding="utf-8"))
        clock_modules = {"time", "datetime"}
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                for alias in node.names:
                    if alias.name.split(".")[0] in CORE_FORBIDDEN_MODULES:
                        bad.append(f"{module}:{node.lineno} imports {alias.name}")
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                top = node.module.split(".")[0]
                if top in CORE_FORBIDDEN_MODULES:
                    bad.append(f"{module}:{node.lineno} imports {node.module}")
                if top in clock_modules:
                    bad += [
                        f"{module}:{node.lineno} imports {node.module}.{a.name}"
                        for a in node.names
                        if a.name in CLOCK_READS or a.name == "datetime"
                    ]
            elif (
                isinstance(node, ast.Attribute)
                and node.attr in CLOCK_READS
                and isinstance(node.value, ast.Name | ast.Attribute)
                and (node.value.id if isinstance(node.value, ast.Name) else node.value.attr)
                in clock_modules
            ):
                bad.append(f"{module}:{node.lineno} reads the clock ({node.attr})")
    return bad


def test_cores_read_no_clock_and_touch_no_zenoh() -> None:
    bad = core_impurities(ROOT)
    assert not bad, "impure cores (time is an argument: now_s, dt_s):\n" + "\n".join(bad)


@pytest.mark.parametrize(
    ("file", "statement", "expected"),
    [
        ("robot_agent/core/tracking.py", "import time\n_T0 = time.monotonic()\n", "monotonic"),
        ("coordinator/core/trajectory.py", "from time import perf_counter\n", "perf_counter"),
        ("sim_plant/core/plant.py", "def _late():\n    import zenoh\n", "zenoh"),
        ("localization/core/tracker.py", "import datetime\n_X = datetime.datetime.now()\n", "now"),
    ],
)
def test_teeth_impure_core_fails(tmp_path: Path, file: str, statement: str, expected: str) -> None:
    root = _copy_tree(tmp_path)
    _append(root / file, statement)
    assert any(expected in line for line in core_impurities(root))


def test_every_package_with_cores_and_shells_has_both_folders() -> None:
    """The folders are the floors: no module sits beside ``core/`` and ``node/`` in a package."""
    for pkg in ("robot_agent", "coordinator", "sim_plant", "localization"):
        assert (ROOT / pkg / "core" / "__init__.py").is_file(), pkg
        assert (ROOT / pkg / "node" / "__init__.py").is_file(), pkg
        loose = sorted(p.name for p in (ROOT / pkg).glob("*.py") if p.name != "__init__.py")
        assert not loose, f"{pkg}/ has modules outside its floor folders: {loose}"


def test_package_roots_import_nothing() -> None:
    """A package's own ``__init__`` (robot_agent, coordinator, ...) is its table of contents."""
    graph = import_graph(ROOT)
    for root in ROOTS:
        assert not graph[root], f"{root}/__init__.py imports {sorted(graph[root])}"
