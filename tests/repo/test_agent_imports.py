"""The robot's pure cores import only the standard library (they could run on a bare robot).

Everything under robot_agent/core/ (the firmware) may import the standard library, robot_agent
itself and, from the contract below it, only modules that import nothing but the standard
library (``bus_schemas.modes``: the one ``Mode`` enum); robot_agent/motors/ (the backends) also
the contract and Zenoh; the process shell (robot_agent/node/) is tested below by importing it
without numpy. bus_schemas/ may also import msgpack, and nothing else (Zenoh lives in the
runtime package). The whole floor plan is tests/repo/test_layers.py.
"""

from __future__ import annotations

import ast
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
STDLIB = frozenset(sys.stdlib_module_names)


def _top_level_imports(path: Path) -> set[str]:
    """Top-level names of every absolute import in ``path`` (relative imports are first-party)."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    names: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(alias.name.split(".")[0] for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.add(node.module.split(".")[0])
    return names


def _core_files(*folders: str) -> list[Path]:
    return sorted(p for folder in folders for p in (ROOT / folder).rglob("*.py"))


def test_scanner_sees_the_agent_core() -> None:
    names = {p.name for p in _core_files("robot_agent/core", "robot_agent/motors")}
    assert {"params.py", "kinematics.py", "tracking.py", "repulsion.py", "firmware.py"} <= names
    assert {"roboclaw.py", "base.py"} <= names
    assert _top_level_imports(ROOT / "robot_agent" / "core" / "firmware.py") >= {"math"}


def _contract_imports(path: Path) -> set[str]:
    """Dotted names of the ``bus_schemas`` modules (or the package) ``path`` imports."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    names: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(a.name for a in node.names if a.name.split(".")[0] == "bus_schemas")
        elif (
            isinstance(node, ast.ImportFrom)
            and node.level == 0
            and (node.module or "").split(".")[0] == "bus_schemas"
        ):
            names.add(str(node.module))
    return names


@pytest.mark.parametrize("path", _core_files("robot_agent/core"), ids=lambda p: p.name)
def test_robot_agent_core_imports_only_stdlib(path: Path) -> None:
    """The standard library, robot_agent, and stdlib-only modules of the contract (never the
    package ``bus_schemas`` itself: its ``__init__`` is the codec and every message)."""
    foreign = _top_level_imports(path) - STDLIB - {"robot_agent", "bus_schemas"}
    assert not foreign, f"{path.name} imports non-stdlib modules: {sorted(foreign)}"
    for module in sorted(_contract_imports(path)):
        source = ROOT.joinpath(*module.split(".")).with_suffix(".py")
        assert source.is_file(), f"{path.name} imports {module}: only a stdlib-only module of it"
        beyond = _top_level_imports(source) - STDLIB
        assert not beyond, f"{path.name} imports {module}, which imports {sorted(beyond)}"


def test_the_core_takes_mode_from_the_contract() -> None:
    """The scan above is not vacuous: the firmware's Mode is the contract's (declared once)."""
    assert _contract_imports(ROOT / "robot_agent" / "core" / "firmware_modes.py") == {
        "bus_schemas.modes"
    }
    assert not _contract_imports(ROOT / "bus_schemas" / "modes.py")
    assert not _top_level_imports(ROOT / "bus_schemas" / "modes.py") - STDLIB


@pytest.mark.parametrize("path", _core_files("robot_agent/motors"), ids=lambda p: p.name)
def test_motor_backends_import_only_what_a_robot_has(path: Path) -> None:
    """A driver may also use the contract (``bus_schemas``, e.g. the ROS 2 wire format) and
    open its own Zenoh session to a ROS 2 base (zenoh is in the base install); pyserial is
    loaded by name when a port opens."""
    foreign = _top_level_imports(path) - STDLIB - {"robot_agent", "bus_schemas", "zenoh"}
    assert not foreign, f"{path.name} imports {sorted(foreign)}"


@pytest.mark.parametrize("path", _core_files("bus_schemas"), ids=lambda p: p.name)
def test_bus_schemas_import_only_stdlib_and_msgpack(path: Path) -> None:
    allowed = STDLIB | {"bus_schemas", "msgpack"}
    foreign = _top_level_imports(path) - allowed
    assert not foreign, f"bus_schemas/{path.name} imports {sorted(foreign)}"


def test_agent_imports_without_numpy_or_scipy() -> None:
    """Run in a fresh interpreter where importing numpy or scipy fails."""
    code = (
        "import sys; sys.modules['numpy'] = None; sys.modules['scipy'] = None; "
        "import robot_agent.core; "
        "fw = robot_agent.core.Firmware(robot_agent.core.AgentConfig()); "
        "c = fw.step(0.0, pose=robot_agent.core.Pose(0.0, 0.0, 0.0, 0.0), pose_rx_s=0.0, "
        "setpoint=robot_agent.core.Setpoint(0.5, 0.0, 0.0, 0.0, 0.0, 1, 0.0), setpoint_rx_s=0.0); "
        "assert c.mode == 'tracking' and c.omega_r > 0, c; "
        "assert 'numpy' not in sys.modules or sys.modules['numpy'] is None; print('ok')"
    )
    env = dict(os.environ)
    env["PYTHONPATH"] = str(ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    proc = subprocess.run(
        [sys.executable, "-c", code],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "ok"


def test_agent_process_modules_import_without_numpy() -> None:
    """The agent's whole process (its shell, the runtime, the scenario loader) stays numpy-free:
    ``pip install .[agent]`` on a robot pulls in no numpy/scipy."""
    code = (
        "import sys; sys.modules['numpy'] = None; sys.modules['scipy'] = None; "
        "import robot_agent.node.main, robot_agent.node.host, runtime, scenario; "
        "s = scenario.load('paper-exp2'); assert s.robot_ids; print('ok')"
    )
    env = dict(os.environ)
    env["PYTHONPATH"] = str(ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    proc = subprocess.run(
        [sys.executable, "-c", code],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "ok"
