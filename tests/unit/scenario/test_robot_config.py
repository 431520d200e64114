"""scenario.robot_config: loading and validating a robot's TOML file."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from robot_agent.core.params import AgentConfig, RobotGeometry, SafetyParams, TrackingGains
from scenario.robot_config import (
    ConfigError,
    MotorConfig,
    RobotConfig,
    ZenohConfig,
    check_config,
    load_robot_config,
    robot_config_from_dict,
)

REPO = Path(__file__).resolve().parents[3]
EXAMPLE = REPO / "deploy" / "config" / "r1.example.toml"

MINIMAL = """
robot_id = "r7"
[zenoh]
endpoints = ["tcp/127.0.0.1:7447"]
"""


def write(tmp_path: Path, text: str, name: str = "robot.toml") -> Path:
    p = tmp_path / name
    p.write_text(text, encoding="utf-8")
    return p


def problems_of(tmp_path: Path, text: str) -> list[str]:
    return check_config(write(tmp_path, text), check_files=True)


def test_example_config_is_valid() -> None:
    assert check_config(EXAMPLE, check_files=False) == []
    cfg = load_robot_config(EXAMPLE, check_files=False)
    assert cfg.robot_id == "r1" and cfg.fleet == "demo"
    assert cfg.agent.geometry == RobotGeometry()  # the example spells out the defaults
    assert cfg.agent.gains == TrackingGains()
    assert cfg.zenoh.mode == "client"
    assert cfg.zenoh.config_file == "/etc/formation/zenoh/robot-mtls.json5"
    assert cfg.motor.backend == "roboclaw"
    rc = cfg.motor.settings
    assert rc is not None
    assert (rc.port, rc.address, rc.mode, rc.invert_left) == ("/dev/roboclaw", 0x80, "speed", True)


def test_minimal_config_takes_defaults(tmp_path: Path) -> None:
    cfg = load_robot_config(write(tmp_path, MINIMAL))
    assert isinstance(cfg, RobotConfig)
    assert cfg.robot_id == "r7"
    assert cfg.fleet == "demo"
    assert cfg.agent == AgentConfig()
    assert cfg.zenoh == ZenohConfig(mode="client", endpoints=("tcp/127.0.0.1:7447",))
    assert cfg.motor == MotorConfig(backend="bus")
    assert cfg.source is not None and cfg.source.endswith("robot.toml")


def test_every_dataclass_field_is_configurable(tmp_path: Path) -> None:
    """Sections and keys come from the params dataclasses themselves."""
    lines = [MINIMAL]
    expected: dict[str, object] = {}
    sections: tuple[tuple[str, type], ...] = (
        ("geometry", RobotGeometry),
        ("gains", TrackingGains),
        ("safety", SafetyParams),
    )
    for section, cls in sections:
        lines.append(f"[{section}]")
        values: dict[str, object] = {}
        for f in dataclasses.fields(cls):
            value = f.default * 2 if isinstance(f.default, float) else f.default
            values[f.name] = value
            lines.append(f"{f.name} = {value!r}")
        expected[section] = cls(**values)
    cfg = load_robot_config(write(tmp_path, "\n".join(lines)))
    assert cfg.agent.geometry == expected["geometry"]
    assert cfg.agent.gains == expected["gains"]
    assert cfg.agent.safety == expected["safety"]


def test_integer_accepted_for_a_float(tmp_path: Path) -> None:
    cfg = load_robot_config(write(tmp_path, MINIMAL + "[geometry]\nmax_wheel_radps = 12\n"))
    assert cfg.agent.geometry.max_wheel_radps == 12.0
    assert isinstance(cfg.agent.geometry.max_wheel_radps, float)


@pytest.mark.parametrize(
    ("snippet", "expected"),
    [
        ("[geometry]\nwheel_radius = 0.03\n", "geometry.wheel_radius: unknown key"),
        ("[geometry]\nwheel_radius_m = 'big'\n", "geometry.wheel_radius_m: expected a number"),
        (
            "[geometry]\nwheel_radius_m = -0.03\n",
            "geometry.wheel_radius_m: -0.03 is outside the plausible range",
        ),
        ("[gains]\nkp = true\n", "gains.kp: expected a number"),
        ("[safety]\nstale_pose_s = 0.0\n", "stale_pose_s"),
        ("[repulsion]\nenabled = 1\n", "repulsion.enabled: expected true or false"),
        ("colour = 'red'\n", "colour: unknown key"),
        ("geometry = 3\n", "geometry: expected a table"),
        ("[motor]\nbackend = 'stepper'\n", "motor.backend: must be one of bus, roboclaw"),
        ("[motor]\nbackend = 'roboclaw'\nmode = 'duty'\n", "motor.port: required"),
        (
            "[motor]\nbackend = 'roboclaw'\nport = '/dev/x'\naddress = 0x90\nmode = 'duty'\n",
            "motor.address: 144 is outside the plausible range [128, 135]",
        ),
        (
            "[motor]\nbackend = 'roboclaw'\nport = '/dev/x'\n",
            "motor.encoder_counts_per_rev: encoder_counts_per_rev must be > 0 in speed mode",
        ),
        (
            "[motor]\nbackend = 'roboclaw'\nport = '/dev/x'\nmode = 'duty'\nbaud = '9600'\n",
            "motor.baud: expected an integer",
        ),
        (
            "[motor]\nbackend = 'roboclaw'\nport = '/dev/x'\nmode = 'duty'\nspeed = 3\n",
            "motor.speed: unknown key",
        ),
    ],
)
def test_field_errors_name_the_field(tmp_path: Path, snippet: str, expected: str) -> None:
    # a top-level key must come before the first [table] of the file
    text = MINIMAL + snippet if snippet.startswith("[") else snippet + MINIMAL
    problems = problems_of(tmp_path, text)
    assert any(expected in p for p in problems), problems


@pytest.mark.parametrize("bad_id", ["R1", "r 1", "r/1", "", "robot*", "r1#"])
def test_robot_id_must_match_pattern(tmp_path: Path, bad_id: str) -> None:
    text = MINIMAL.replace('robot_id = "r7"', f"robot_id = {bad_id!r}")
    problems = problems_of(tmp_path, text)
    assert any(p.startswith("robot_id:") and "[a-z0-9_-]+" in p for p in problems), problems


def test_robot_id_required_and_typed(tmp_path: Path) -> None:
    assert any(
        p.startswith("robot_id: required")
        for p in problems_of(tmp_path, MINIMAL.replace('robot_id = "r7"', ""))
    )
    assert any(
        "robot_id: expected a string" in p
        for p in problems_of(tmp_path, MINIMAL.replace('"r7"', "7"))
    )


def test_fleet_pattern(tmp_path: Path) -> None:
    problems = problems_of(tmp_path, 'fleet = "Demo Fleet"\n' + MINIMAL)
    assert any(p.startswith("fleet:") for p in problems), problems


def test_zenoh_section_rules(tmp_path: Path) -> None:
    assert any(p.startswith("zenoh: required") for p in problems_of(tmp_path, 'robot_id = "r1"\n'))
    bad_endpoint = 'robot_id = "r1"\n[zenoh]\nendpoints = ["127.0.0.1:7447"]\n'
    assert any("zenoh.endpoints[0]" in p for p in problems_of(tmp_path, bad_endpoint))
    bad_mode = 'robot_id = "r1"\n[zenoh]\nmode = "router"\nendpoints = ["tcp/h:7447"]\n'
    assert any("zenoh.mode" in p for p in problems_of(tmp_path, bad_mode))
    empty = 'robot_id = "r1"\n[zenoh]\nmode = "client"\n'
    assert any("set endpoints, config_file or both" in p for p in problems_of(tmp_path, empty))
    unknown = 'robot_id = "r1"\n[zenoh]\nendpoints = ["tcp/h:7447"]\nlisten = []\n'
    assert any("zenoh.listen: unknown key" in p for p in problems_of(tmp_path, unknown))


def test_zenoh_config_file_relative_and_checked(tmp_path: Path) -> None:
    text = 'robot_id = "r1"\n[zenoh]\nconfig_file = "zenoh/robot.json5"\n'
    path = write(tmp_path, text)
    problems = check_config(path)
    assert problems == [f"zenoh.config_file: {tmp_path / 'zenoh' / 'robot.json5'} does not exist"]
    assert check_config(path, check_files=False) == []
    (tmp_path / "zenoh").mkdir()
    (tmp_path / "zenoh" / "robot.json5").write_text("{}")
    cfg = load_robot_config(path)
    assert cfg.zenoh.config_file == str(tmp_path / "zenoh" / "robot.json5")
    assert cfg.zenoh.endpoints == ()


def test_every_problem_is_reported_at_once(tmp_path: Path) -> None:
    text = """
robot_id = "R1"
[geometry]
wheel_radius_m = "x"
bogus = 1
[zenoh]
endpoints = ["nonsense"]
[motor]
backend = "roboclaw"
"""
    with pytest.raises(ConfigError) as info:
        load_robot_config(write(tmp_path, text))
    problems = info.value.problems
    assert len(problems) == 5, problems
    assert "robot.toml" in str(info.value)
    for fragment in ("robot_id", "geometry.wheel_radius_m", "geometry.bogus", "zenoh.endpoints"):
        assert any(fragment in p for p in problems), (fragment, problems)
    assert any("motor.port: required" in p for p in problems)


def test_unreadable_and_invalid_toml(tmp_path: Path) -> None:
    assert check_config(tmp_path / "missing.toml")[0].startswith("cannot read the file")
    problems = problems_of(tmp_path, 'robot_id = "r1"\n[zenoh\n')
    assert len(problems) == 1 and problems[0].startswith("not valid TOML")


def test_from_dict_roboclaw() -> None:
    cfg = robot_config_from_dict(
        {
            "robot_id": "r2",
            "fleet": "lab_1",
            "zenoh": {"endpoints": ["tcp/10.0.0.1:7447"], "mode": "peer"},
            "motor": {
                "backend": "roboclaw",
                "port": "/dev/ttyACM0",
                "address": 0x81,
                "encoder_counts_per_rev": 64,
                "gear_ratio": 30,
                "right_channel": "m2",
            },
        }
    )
    rc = cfg.motor.settings
    assert rc is not None
    assert (rc.address, rc.encoder_counts_per_rev, rc.gear_ratio) == (0x81, 64.0, 30.0)
    assert rc.right_channel == "m2"
    assert cfg.zenoh.mode == "peer" and cfg.fleet == "lab_1"


def test_absurd_values_are_refused_with_their_dotted_names(tmp_path: Path) -> None:
    text = MINIMAL + "[gains]\nkp = 1e9\n[safety]\nstale_pose_s = 1e6\n"
    problems = problems_of(tmp_path, text)
    assert any(p.startswith("gains.kp: 1000000000.0 is outside") for p in problems), problems
    assert any(p.startswith("safety.stale_pose_s: 1000000.0 is outside") for p in problems)
    assert len(problems) == 2, problems


def test_every_numeric_parameter_declares_a_plausible_range() -> None:
    """Every numeric field of every section (and of every motor backend's settings) is declared
    with ``ranged`` (or its ``range`` metadata), and its default lies inside."""
    import dataclasses
    import typing

    from robot_agent.core.config_tables import agent_sections
    from robot_agent.core.params import declared_range
    from robot_agent.motors import BACKENDS

    sections: dict[str, type] = dict(agent_sections())
    for name, kind in BACKENDS.items():
        if kind.settings is not None:
            sections[f"motor ({name})"] = kind.settings
    missing = []
    for section, cls in sections.items():
        hints = typing.get_type_hints(cls)
        for f in dataclasses.fields(cls):
            numeric = hints[f.name] in (int, float) or hints[f.name] == (float | None)
            rng = declared_range(cls, f.name)
            if numeric and rng is None:
                missing.append(f"{section}.{f.name}")
            if rng is not None and f.default not in (None, dataclasses.MISSING):
                assert rng[0] <= f.default <= rng[1], (section, f.name, f.default)
    assert not missing, f"declare a plausible range (params.ranged) for: {missing}"


def test_every_motor_problem_is_listed_not_only_the_first(tmp_path: Path) -> None:
    text = MINIMAL + (
        "[motor]\nbackend = 'roboclaw'\nport = '/dev/x'\nbaud = 12\naddress = 0x10\n"
        "serial_timeout_s = 100.0\ngear_ratio = -1.0\nmode = 'duty'\n"
    )
    problems = problems_of(tmp_path, text)
    for name in ("motor.baud", "motor.address", "motor.serial_timeout_s", "motor.gear_ratio"):
        assert any(p.startswith(name + ":") for p in problems), (name, problems)


def test_bus_backend_ignores_the_roboclaw_keys_of_the_example() -> None:
    example = Path(__file__).resolve().parents[3] / "deploy" / "config" / "r1.example.toml"
    import tomllib

    data = tomllib.loads(example.read_text())
    assert check_config(example, check_files=False) == []
    data["motor"]["backend"] = "bus"
    cfg = robot_config_from_dict(data)  # no ConfigError: 0 problems
    assert cfg.motor.backend == "bus" and cfg.motor.settings is None
    # ... but with backend = "roboclaw" the same keys are checked
    data["motor"]["backend"] = "roboclaw"
    data["motor"]["baud"] = 7
    with pytest.raises(ConfigError) as info:
        robot_config_from_dict(data)
    assert [p for p in info.value.problems if p.startswith("motor.baud:")], info.value.problems
