"""The ``formation`` command: one entry point, one module per subcommand.

Each subcommand lives in its own module with ``main(argv: list[str]) -> int`` and is imported only
when it is run, so ``formation agent`` on a robot never imports numpy, scipy or matplotlib.

The entry point also fixes how every subcommand reports a mistake, in one place:

* every ``--help`` shows the defaults and ends with an example (:data:`EXAMPLES`);
* a command-line mistake (unknown option, bad value, missing argument) is one line on stderr,
  ``formation <cmd>: error: <what> (see `formation <cmd> --help`)``, exit status 2, no usage
  dump and no traceback (:func:`_one_line_error` replaces ``argparse.ArgumentParser.error`` for
  the parsers of this process);
* a scenario mistake that escapes a subcommand (``ScenarioError``, whose message names the
  field) is one line, exit 2;
* Ctrl-C (SIGINT) that is not handled by the subcommand itself is one line
  (``formation <cmd>: interrupted``), exit status 130 (128 + SIGINT), no traceback.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from typing import NoReturn

# subcommand -> (module, one-line help)
SUBCOMMANDS: dict[str, tuple[str, str]] = {
    "sim": ("formation.sim.command", "run a scenario in-process (no Zenoh), deterministic, fast"),
    "check": (
        "formation.sim.check",
        "check a scenario before a run: schema, path conflicts, slot feasibility",
    ),
    "demo": ("formation.sim.demo", "run the paper's experiment 2 and write metrics and figures"),
    "sweep": ("formation.sweep.command", "run a parameter study: many sims, one table, plots"),
    "up": ("formation.launch.up", "start router, plant, coordinator and one agent per robot"),
    "router": ("formation.launch.router", "run an embedded Zenoh router"),
    "coordinator": ("coordinator.node.main", "run the coordinator process"),
    "agent": ("robot_agent.node.main", "run one robot agent process"),
    "agent-host": (
        "robot_agent.node.host_main",
        "run the agents of many robots in one process (scale)",
    ),
    "plant": ("sim_plant.node.main", "run the plant simulator process"),
    "fault": ("formation.operate.fault", "inject a fault into a running fleet"),
    "teleop": ("formation.operate.teleop", "drive the virtual leader from the keyboard"),
    "goal": ("formation.operate.goal", "send the virtual leader to a point"),
    "path": ("formation.operate.path", "send the virtual leader along waypoints"),
    "shape": ("formation.operate.shape", "reshape the running formation"),
    "obstacle": ("formation.operate.obstacle", "add, move or remove a planning obstacle"),
    "record": ("formation.record.command", "record the fleet's keys to MCAP"),
    "report": ("formation.record.report", "metrics and figures from an MCAP recording"),
    "top": ("formation.live.top", "live fleet status table"),
    "ls": ("formation.operate.ls", "list the fleets on a router"),
    "echo": ("formation.operate.echo", "print a key's messages, decoded, one JSON a line"),
    "acl": ("bus_schemas.acl", "write the Zenoh router ACL and client configs of a fleet"),
    "certs": ("formation.launch.pki", "make the fleet CA and a certificate per identity"),
    "motor-emulator": (
        "robot_agent.motors.emulator",
        "an emulated RoboClaw on a pty: try the motor backend without hardware",
    ),
    "camera": (
        "localization.node.main",
        "overhead-camera tracker; `camera calibrate` writes its file",
    ),
    "ros2": (
        "formation.live.ros2_bridge",
        "show the fleet to ROS 2 over rmw_zenoh (no ROS install)",
    ),
}

# prog -> examples shown at the end of its --help (the epilog), one command per line.
# tests/fleet/test_cli_mistakes.py checks every subcommand has one; docs/runtime.md explains them.
EXAMPLES: dict[str, tuple[str, ...]] = {
    "formation sim": ("formation sim --scenario chevron7 --duration 30 --seed 4",),
    "formation check": ("formation check corridor", "formation check my-mission.toml --strict"),
    "formation demo": ("formation demo --duration 20 --no-figures",),
    "formation sweep": ("formation sweep studies/ref-offset.toml --reduced --no-plots",),
    "formation up": (
        "formation up --scenario paper-exp1 --duration 20",
        "formation up --lockstep --robots 7 --scenario chevron7 --duration 10 --no-figures",
    ),
    "formation router": ("formation router --listen tcp/127.0.0.1:7447",),
    "formation coordinator": (
        "formation coordinator --scenario paper-exp2 --endpoint tcp/127.0.0.1:7447",
    ),
    "formation agent": ("formation agent --id r1 --scenario paper-exp2",),
    "formation agent-host": ("formation agent-host --ids r1..r50 --scenario lattice --name h1",),
    "formation plant": ("formation plant --scenario paper-exp2 --wait-robots",),
    "formation fault": (
        "formation fault kill-leader",
        "formation fault drag r1 -0.6 0",
    ),
    "formation teleop": (
        "formation teleop",
        "formation teleop --v 0.05 --omega 0.1 --duration 10 --quiet",
    ),
    "formation goal": ("formation goal 1.5 0.5 --heading 1.57",),
    "formation path": ("formation path --waypoints 1,0 1.5,0.5 1,1",),
    "formation shape": (
        "formation shape column --spacing 0.5",
        "formation shape chevron --slots 4",
    ),
    "formation obstacle": (
        "formation obstacle add box1 --circle 2.5 0.6 0.25",
        "formation obstacle remove box1",
    ),
    "formation motor-emulator": ("formation motor-emulator --link /tmp/roboclaw",),
    "formation record": ("formation record --out run.mcap --duration 30 --scenario paper-exp2",),
    "formation report": ("formation report run.mcap --out run-report",),
    "formation top": ("formation top --once --wait 2",),
    "formation ls": ("formation ls --endpoint tcp/127.0.0.1:7447",),
    "formation echo": ("formation echo assignment --count 1", "formation echo robot/r1/status"),
    "formation acl": ("formation acl --out acl/ --robots r1,r2,r3",),
    "formation certs": ("formation certs --out pki/ --robots r1,r2,r3",),
    "formation camera": (
        "formation camera --source rendered --calibration cam.toml",
        "formation camera calibrate --help",
    ),
    "formation camera calibrate": ("formation camera calibrate --image floor.png --out cam.toml",),
    "formation ros2": ("formation ros2 --endpoint tcp/127.0.0.1:7447 --domain-id 0",),
}

EXIT_USAGE = 2  # a mistake on the command line or in a scenario file
EXIT_INTERRUPTED = 130  # 128 + SIGINT, what a shell reports for Ctrl-C


def version() -> str:
    """The installed package's version (``importlib.metadata``), or ``unknown``."""
    from importlib.metadata import PackageNotFoundError
    from importlib.metadata import version as _version

    try:
        return _version("formation-control")
    except PackageNotFoundError:
        return "unknown"


# top-level module of a dependency -> the extra of pyproject.toml that installs it
EXTRA_OF_MODULE: dict[str, str] = {
    "numpy": "sim",
    "scipy": "sim",
    "matplotlib": "sim",
    "mcap": "sim",
    "foxglove": "sim",
    "cryptography": "sim",
    "pyarrow": "sim",
    "shapely": "sim",
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
    lines = ["usage: formation [--version] <command> [options]", "", "commands:"]
    for name, (_, help_text) in SUBCOMMANDS.items():
        lines.append(f"  {name:<12} {help_text}")
    lines.append("")
    lines.append("`formation <command> --help` for the options of one command.")
    lines.append("example: formation sim --scenario paper-exp2 --duration 20")
    return "\n".join(lines)


def _one_line_error(self: argparse.ArgumentParser, message: str) -> NoReturn:
    """``ArgumentParser.error`` as one line: what is wrong and where to look, exit 2."""
    self.exit(EXIT_USAGE, f"{self.prog}: error: {message} (see `{self.prog} --help`)\n")


def _format_help(self: argparse.ArgumentParser) -> str:
    """--help with defaults shown and the examples of :data:`EXAMPLES` as the epilog."""
    from runtime.args import HelpFormatter

    if self.formatter_class is argparse.HelpFormatter:
        self.formatter_class = HelpFormatter
    examples = EXAMPLES.get(self.prog)
    if examples and "example" not in (self.epilog or ""):
        block = "examples:\n" + "\n".join(f"  {e}" for e in examples)
        self.epilog = f"{self.epilog}\n\n{block}" if self.epilog else block
        if self.formatter_class is argparse.ArgumentDefaultsHelpFormatter:
            self.formatter_class = HelpFormatter  # keep the examples' lines
    return _PLAIN_FORMAT_HELP(self)


_PLAIN_FORMAT_HELP = argparse.ArgumentParser.format_help


def install_conventions() -> None:
    """The CLI's conventions for every argparse parser of this process: one-line errors,
    defaults shown and an example in every --help."""
    argparse.ArgumentParser.error = _one_line_error  # type: ignore[method-assign]
    argparse.ArgumentParser.format_help = _format_help  # type: ignore[method-assign]


def main(argv: list[str] | None = None) -> int:
    """The ``formation`` command; ``argv`` None: this process's command line (the entry point).

    As the entry point, a subcommand that ran a node (``runtime.lifecycle.run_node``, sessions
    closed) or a launcher ends the process at once (``runtime.lifecycle.exit_fast``: no
    interpreter teardown, which under CPU load can exceed a node's stop bound)."""
    code = _dispatch(sys.argv[1:] if argv is None else argv)
    if argv is None:
        lifecycle = sys.modules.get("runtime.lifecycle")  # loaded only by Zenoh subcommands
        if lifecycle is not None and lifecycle.fast_exit_requested():
            lifecycle.exit_fast(code)
    return code


def _dispatch(argv: list[str]) -> int:
    args = list(argv)
    if not args or args[0] in ("-h", "--help", "help"):
        print(_usage())
        return 0
    if args[0] in ("-V", "--version"):
        print(f"formation {version()}")
        return 0
    name, rest = args[0], args[1:]
    if name not in SUBCOMMANDS:
        known = ", ".join(SUBCOMMANDS)
        what = "option" if name.startswith("-") else "command"
        print(
            f"formation: error: unknown {what} {name!r} "
            f"(commands: {known}; see `formation --help`)",
            file=sys.stderr,
        )
        return EXIT_USAGE
    install_conventions()
    prog = f"formation {name}"
    try:
        module_name = SUBCOMMANDS[name][0]
        try:
            module = importlib.import_module(module_name)
        except ImportError as exc:  # e.g. the sim extra is not installed on a robot
            print(f"{prog}: {missing_extra_message(exc)}", file=sys.stderr)
            return EXIT_USAGE
        result: int = module.main(rest)
        return result
    except KeyboardInterrupt:
        print(f"{prog}: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except BaseException as exc:
        # A scenario mistake that a subcommand did not catch: one line naming the field.
        from scenario.load import ScenarioError  # stdlib-only module: fine on a robot

        if isinstance(exc, ScenarioError):
            print(f"{prog}: {exc}", file=sys.stderr)
            return EXIT_USAGE
        raise


if __name__ == "__main__":
    raise SystemExit(main())
