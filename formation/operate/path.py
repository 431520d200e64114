"""``formation path --waypoints X,Y X,Y ...``: send the virtual leader along waypoints
(issue 28).

Publishes a ``Path`` on ``formation/<fleet>/operator/path`` and waits for the coordinator's
``leader`` to say mode ``path`` (a continuous join from where the leader is,
coordinator.core.leader). Refused by the coordinator (a point outside the arena, more than 256
points): exit 1 after ``--timeout``. A bad waypoint on the command line is one line, exit 2.
"""

from __future__ import annotations

import argparse
import math
import sys
import time

from bus_schemas import Path, encode, keys
from bus_schemas.messages_operator import PATH_POINTS_MAX
from formation.operate.drive import (
    common_options,
    finite,
    parse_waypoints,
    send_and_confirm,
)
from formation.outputs import runfile


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="formation path",
        description="Drive the virtual leader through waypoints (m, world frame) from where it "
        "is, then turn to --heading (rad) if given.",
    )
    p.add_argument(
        "--waypoints", nargs="+", required=True, metavar="X,Y", help="the points, in order"
    )
    p.add_argument("--heading", default=None, metavar="RAD", help="heading at the last point")
    common_options(p)
    return p


def main(argv: list[str]) -> int:
    """Entry point of ``formation path``."""
    ns = build_parser().parse_args(argv)
    try:
        keys.check_fleet(ns.fleet)
        points = parse_waypoints(ns.waypoints)
        if len(points) > PATH_POINTS_MAX:
            raise ValueError(f"at most {PATH_POINTS_MAX} waypoints, got {len(points)}")
        heading = None
        if ns.heading is not None:
            heading = math.remainder(finite("--heading", ns.heading, bound=1e3), 2 * math.pi)
        if not ns.timeout > 0:
            raise ValueError(f"--timeout must be positive, got {ns.timeout:g}")
        settings = runfile.tool_settings(ns, "operator")
    except (TypeError, ValueError) as exc:
        print(f"formation path: error: {exc}", file=sys.stderr)
        return 2
    msg = Path(
        t=max(time.monotonic(), 0.0),
        xs=tuple(p[0] for p in points),
        ys=tuple(p[1] for p in points),
        heading=heading,
    )

    return send_and_confirm(
        "formation path",
        settings,
        keys.path_key(ns.fleet),
        encode(msg),
        ns.fleet,
        lambda m: m.mode == "path",
        ns.timeout,
        taken=lambda m: (
            f"path of {len(points)} points taken: the leader leaves ({m.x:.3f}, {m.y:.3f})"
        ),
        missing="took the path (refused? see `formation top`)",
    )


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main(sys.argv[1:]))
