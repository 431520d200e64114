"""``formation shape triangle|column|line|chevron [--spacing B] [--slots N]``: reshape the
running formation, and change its number of slots (issue 28).

Publishes a ``Shape`` on ``formation/<fleet>/operator/shape`` and waits for the coordinator's
``leader`` to report the reshape running (``reshape`` present, ``shape`` the new kind). The slots
move to the new shape over a transition time, never closer than the robots' safety distance,
every robot keeping its slot (coordinator.core.reshape). ``--slots N``: the new shape has N
slots, leader included: fewer drop the rearmost slots at the end of the transition (their robots
become spares and stop), more add slots the spares take. A shape the coordinator cannot make
safe is refused (its status ``rejects``: ``shape-unsafe``): exit 1 after ``--timeout``. A bad
kind, spacing or slot count on the command line (``--slots`` under 1, or more than the robots
whose liveliness token is on the bus) is one line and exit 2.
"""

from __future__ import annotations

import argparse
import sys
import time
from typing import Any

from bus_schemas import Shape, ShapeKind, encode, keys
from bus_schemas.messages_operator import SLOTS_MAX, SPACING_MAX_M, SPACING_MIN_M
from formation.operate.drive import alive_robots, common_options, finite, send_and_confirm
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
    p.add_argument(
        "--slots",
        default=None,
        metavar="N",
        help="number of slots, leader included (default: as now; at most the robots alive)",
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
            lo, hi = SPACING_MIN_M, SPACING_MAX_M
            if not lo <= spacing <= hi:
                raise ValueError(f"--spacing must be in [{lo:g}, {hi:g}] m, got {ns.spacing}")
        slots = None if ns.slots is None else _slot_count(ns.slots)
        if not ns.timeout > 0:
            raise ValueError(f"--timeout must be positive, got {ns.timeout:g}")
        settings = runfile.tool_settings(ns, "operator")
    except (TypeError, ValueError) as exc:
        print(f"formation shape: error: {exc}", file=sys.stderr)
        return 2
    msg = Shape(t=max(time.monotonic(), 0.0), kind=ns.kind, spacing_m=spacing, slots=slots)

    async def enough_robots(session: Any) -> str | None:
        if slots is None:
            return None
        alive = await alive_robots(session, ns.fleet)
        if slots > len(alive):
            return f"--slots {slots} is more than the {len(alive)} robots alive in {ns.fleet!r}"
        return None

    return send_and_confirm(
        "formation shape",
        settings,
        keys.shape_key(ns.fleet),
        encode(msg),
        ns.fleet,
        lambda m: m.shape == ns.kind and m.reshape is not None and slots in (None, m.slots),
        ns.timeout,
        taken=lambda m: f"reshaping into a {ns.kind} of {m.slots} slots",
        missing="started the reshape (refused as unsafe? see `formation top`)",
        check=enough_robots,
    )


def _slot_count(text: str) -> int:
    """``--slots`` as an int in [1, SLOTS_MAX], or ValueError."""
    try:
        n = int(text)
    except ValueError:
        raise ValueError(f"--slots must be a whole number, got {text!r}") from None
    if not 1 <= n <= SLOTS_MAX:
        raise ValueError(f"--slots must be in [1, {SLOTS_MAX}], got {n}")
    return n


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main(sys.argv[1:]))
