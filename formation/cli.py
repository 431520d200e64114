"""The ``formation`` command: one entry point, one module per subcommand.

Each subcommand lives in its own module with ``main(argv: list[str]) -> int`` and is imported only
when it is run, so ``formation agent`` on a robot never imports numpy, scipy or matplotlib.
"""

from __future__ import annotations

import importlib
import sys

# subcommand -> (module, one-line help)
SUBCOMMANDS: dict[str, tuple[str, str]] = {
    "sim": ("formation.sim_cli", "run a scenario in-process (no Zenoh), deterministic, fast"),
    "demo": ("formation.demo", "run the paper's experiment 2 and write metrics and figures"),
    "up": ("formation.up", "start router, plant, coordinator and one agent per robot"),
    "router": ("formation.router", "run an embedded Zenoh router"),
    "coordinator": ("coordinator.main", "run the coordinator process"),
    "agent": ("robot_agent.main", "run one robot agent process"),
    "agent-host": ("robot_agent.host", "run the agents of many robots in one process (scale)"),
    "plant": ("sim_plant.main", "run the plant simulator process"),
    "fault": ("formation.fault", "inject a fault into a running fleet"),
    "record": ("formation.record", "record the fleet's keys to MCAP"),
    "report": ("formation.report", "metrics and figures from an MCAP recording"),
    "top": ("formation.top", "live fleet status table"),
    "acl": ("bus_schemas.acl", "write the Zenoh router ACL and client configs of a fleet"),
    "certs": ("formation.pki", "make the fleet CA and a certificate per identity"),
    "motor-emulator": (
        "robot_agent.motors.emulator",
        "an emulated RoboClaw on a pty: try the motor backend without hardware",
    ),
    "camera": ("localization.node", "overhead-camera tracker; `camera calibrate` writes its file"),
}


# top-level module of a dependency -> the extra of pyproject.toml that installs it
EXTRA_OF_MODULE: dict[str, str] = {
    "numpy": "sim",
    "scipy": "sim",
    "matplotlib": "sim",
    "mcap": "sim",
    "foxglove": "sim",
    "cryptography": "sim",
    "cv2": "camera",
    "pupil_apriltags": "camera",
    "serial": "agent",
}


def missing_extra_message(exc: ImportError) -> str:
    """One line naming the extra that provides the module ``exc`` could not import."""
    module = (exc.name or "").split(".")[0]
    extra = EXTRA_OF_MODULE.get(module)
    if extra is None:
        return f"not available in this install ({exc})"
    return (
        f"needs the {extra} extra ({module} is not installed): "
        f"pip install 'formation-control[{extra}]'"
    )


def _usage() -> str:
    lines = ["usage: formation <command> [options]", "", "commands:"]
    for name, (_, help_text) in SUBCOMMANDS.items():
        lines.append(f"  {name:<12} {help_text}")
    lines.append("")
    lines.append("`formation <command> --help` for the options of one command.")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    args = list(sys.argv[1:] if argv is None else argv)
    if not args or args[0] in ("-h", "--help", "help"):
        print(_usage())
        return 0
    name, rest = args[0], args[1:]
    if name not in SUBCOMMANDS:
        print(f"formation: unknown command {name!r}\n\n{_usage()}", file=sys.stderr)
        return 2
    module_name = SUBCOMMANDS[name][0]
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:  # e.g. the sim extra is not installed on a robot
        print(f"formation {name}: {missing_extra_message(exc)}", file=sys.stderr)
        return 2
    result: int = module.main(rest)
    return result


if __name__ == "__main__":
    raise SystemExit(main())
