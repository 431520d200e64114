"""``formation goal X Y [--heading H]``: send the virtual leader to a point (issue 28).

Publishes a ``Goal`` on ``formation/<fleet>/operator/goal`` and waits for the coordinator's
``leader`` to say mode ``goal`` (it replaces the leader's plan with a continuous join: no jump
in position or velocity, coordinator.core.leader). A goal the coordinator refuses (outside the
arena, see its status ``rejects``) is never taken: exit 1 after ``--timeout``. A bad number on
the command line is one line and exit 2.
"""

from __future__ import annotations

import argparse
import math
import sys
import time

from bus_schemas import Goal, encode, keys
from formation.operate.drive import common_options, finite, send_and_confirm
from formation.outputs import runfile


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="formation goal",
        description="Drive the virtual leader to (X, Y) in m from where it is, then turn to "
        "--heading (rad) if given.",
    )
    p.add_argument("x", metavar="X", help="goal x (m, world frame)")
    p.add_argument("y", metavar="Y", help="goal y (m, world frame)")
    p.add_argument("--heading", default=None, metavar="RAD", help="heading at the goal (rad)")
    common_options(p)
    return p


def main(argv: list[str]) -> int:
    """Entry point of ``formation goal``."""
    ns = build_parser().parse_args(argv)
    try:
        keys.check_fleet(ns.fleet)
        x, y = finite("X", ns.x), finite("Y", ns.y)
        heading = None
        if ns.heading is not None:
            heading = math.remainder(finite("--heading", ns.heading, bound=1e3), 2 * math.pi)
        if not ns.timeout > 0:
            raise ValueError(f"--timeout must be positive, got {ns.timeout:g}")
        settings = runfile.tool_settings(ns, "operator")
    except (TypeError, ValueError) as exc:
        print(f"formation goal: error: {exc}", file=sys.stderr)
        return 2
    msg = Goal(t=max(time.monotonic(), 0.0), x=x, y=y, heading=heading)

    return send_and_confirm(
        "formation goal",
        settings,
        keys.goal_key(ns.fleet),
        encode(msg),
        ns.fleet,
        lambda m: m.mode == "goal",
        ns.timeout,
        taken=lambda m: f"goal ({x:g}, {y:g}) taken: the leader leaves ({m.x:.3f}, {m.y:.3f})",
        missing="took the goal (refused? see `formation top`)",
    )


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main(sys.argv[1:]))
