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
    "camera": ("localization.node", "overhead-camera tracker; `camera calibrate` writes its file"),
}


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
        print(f"formation {name}: not available in this install ({exc})", file=sys.stderr)
        return 2
    result: int = module.main(rest)
    return result


if __name__ == "__main__":
    raise SystemExit(main())
