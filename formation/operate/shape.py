"""``formation shape triangle|column|line|chevron [--spacing B]``: reshape the running formation
(issue 28).

Publishes a ``Shape`` on ``formation/<fleet>/operator/shape`` and waits for the coordinator's
``leader`` to report the reshape running (``reshape`` present, ``shape`` the new kind). The slots
move to the new shape over a transition time, never closer than the robots' safety distance,
every robot keeping its slot (coordinator.core.reshape). A shape the coordinator cannot make
safe is refused (its status ``rejects``: ``shape-unsafe``): exit 1 after ``--timeout``. A bad
kind or spacing on the command line is one line and exit 2.
"""

from __future__ import annotations

import argparse
import sys
import time

from bus_schemas import Shape, ShapeKind, encode, keys
from bus_schemas.messages_operator import SPACING_MAX_M
from coordinator.core.reshape import SPACING_RANGE_M
from formation.operate.drive import common_options, finite, send_and_confirm
from formation.outputs import runfile


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="formation shape",
        description="Reshape the running formation; the slots move to the new shape over a "
        "transition time, never closer than the safety distance.",
    )
    p.add_argument("kind", choices=[k.value for k in ShapeKind], metavar="KIND",
                   help="triangle, column, line or chevron")  # fmt: skip
    p.add_argument(
        "--spacing", default=None, metavar="M", help="distance between neighbours (default: as now)"
    )
    common_options(p)
    return p


def main(argv: list[str]) -> int:
    """Entry point of ``formation shape``."""
    ns = build_parser().parse_args(argv)
    try:
        keys.check_fleet(ns.fleet)
        spacing = None
        if ns.spacing is not None:
            spacing = finite("--spacing", ns.spacing, bound=SPACING_MAX_M)
            lo, hi = SPACING_RANGE_M
            if not lo <= spacing <= hi:
                raise ValueError(f"--spacing must be in [{lo:g}, {hi:g}] m, got {ns.spacing}")
        if not ns.timeout > 0:
            raise ValueError(f"--timeout must be positive, got {ns.timeout:g}")
        settings = runfile.tool_settings(ns, "operator")
    except (TypeError, ValueError) as exc:
        print(f"formation shape: error: {exc}", file=sys.stderr)
        return 2
    msg = Shape(t=max(time.monotonic(), 0.0), kind=ns.kind, spacing_m=spacing)

    return send_and_confirm(
        "formation shape",
        settings,
        keys.shape_key(ns.fleet),
        encode(msg),
        ns.fleet,
        lambda m: m.shape == ns.kind and m.reshape is not None,
        ns.timeout,
        taken=lambda _m: f"reshaping into a {ns.kind}",
        missing="started the reshape (refused as unsafe? see `formation top`)",
    )


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main(sys.argv[1:]))
