"""``formation check FILE``: every check of a scenario, printed before a run (no Zenoh).

Runs the schema check (the file loads, its trajectory and formation build: a planned
trajectory is planned), the slot-path conflict check and the slot feasibility check
(``scenario.preflight``) and prints ``OK`` or one ``warning:`` line per finding. Exit status: 0
when the scenario is valid (warnings included: the run can go ahead), 2 for a schema problem
(one line naming the field), as every command that takes a scenario.

A fleet file of a real fleet (``scenario.fleet``: ``fleet`` or ``[[robot]]`` tables at its top,
deploy/config/fleet.example.toml) is checked the same way, after the fleet's own rules (every
problem listed, exit 2): ``formation check /etc/formation/fleet.toml``. Its run lasts "for
ever"; the slot feasibility check samples its first hour (``scenario.preflight``).
"""

from __future__ import annotations

import argparse
import sys
import tomllib
from pathlib import Path

from runtime.args import non_negative_int, positive_float

__all__ = ["main"]


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="formation check",
        description="check a scenario before a run: schema (a plan is planned), slot-path "
        "conflicts with obstacles and the arena, slot speed/turn/acceleration feasibility",
    )
    p.add_argument(
        "scenario", help="built-in scenario name, path to a scenario .toml file or a fleet file"
    )
    p.add_argument(
        "--duration",
        type=positive_float,
        default=None,
        help="seconds to check (default: the scenario's)",
    )
    p.add_argument(
        "--robots", type=non_negative_int, default=None, help="resize the fleet to N slots"
    )
    p.add_argument("--strict", action="store_true", help="exit 1 when there is a warning")
    return p


def _fleet_file(arg: str) -> Path | None:
    """``arg`` as a fleet file (``scenario.fleet``: a ``.toml`` file with ``fleet`` or
    ``[[robot]]`` at its top, which no scenario has), else None (a scenario, or a file that
    does not read: the scenario loader names the problem)."""
    path = Path(arg)
    if path.suffix != ".toml" or not path.is_file():
        return None
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError):
        return None
    return path if ("fleet" in data or "robot" in data) else None


def main(argv: list[str]) -> int:
    args = build_parser().parse_args(argv)
    import scenario as scenario_mod
    from scenario.check import check_cores
    from scenario.preflight import preflight_warnings

    fleet_path = _fleet_file(args.scenario)
    what = ""
    try:
        if fleet_path is not None:
            from scenario.fleet import load_fleet

            if args.robots is not None:
                raise scenario_mod.ScenarioError("--robots: a fleet file lists its robots")
            fleet = load_fleet(fleet_path)  # the fleet's rules, then the scenario's validator
            scn, what = fleet.scenario, f"fleet {fleet.fleet} ({fleet_path}), "
        elif args.robots is not None:
            scn = scenario_mod.load_with_robots(args.scenario, args.robots, 0)
        else:
            scn = scenario_mod.load(args.scenario)
        check_cores(scn)
    except scenario_mod.ScenarioError as exc:
        print(f"formation check: {exc}", file=sys.stderr)
        return 2
    warnings = preflight_warnings(scn, args.duration)
    for w in warnings:
        print(f"warning: {w}")
    kind = scn.trajectory.get("kind")
    if not warnings:
        print(
            f"OK: {what or 'scenario '}{scn.name}, robots {len(scn.robot_ids)}, trajectory {kind}, "
            f"formation {scn.formation.get('kind', 'explicit')}: schema, path conflicts and "
            "slot feasibility checked"
        )
    return 1 if (warnings and args.strict) else 0
