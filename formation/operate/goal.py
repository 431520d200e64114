"""``formation goal X Y [--heading H]``: send the virtual leader to a point (issue 28).

Publishes a ``Goal`` on ``formation/<fleet>/operator/goal`` and waits for the coordinator's
``leader`` to say mode ``goal`` (it replaces the leader's plan with a continuous join: no jump
in position or velocity, coordinator.core.leader). A goal the coordinator refuses (outside the
arena, see its status ``rejects``) is never taken: exit 1 after ``--timeout``. A bad number on
the command line is one line and exit 2.

On a map with obstacles the coordinator PLANS the goal (issue 27,
coordinator.core.planning.replan): the tool then also waits for the plan (its status's
``plans`` goes up) and prints it, or, when there is no way (the leader decelerates to a stop),
prints the planner's reason and exits 1.
"""

from __future__ import annotations

import argparse
import asyncio
import math
import sys
import time
from typing import Any

import runtime as rt
from bus_schemas import Goal, encode, keys
from formation.operate.drive import common_options, finite, watch_leader, watch_status
from formation.outputs import runfile

PLAN_WAIT_S = 30.0
"""How long the tool waits for the coordinator's plan once the goal is taken (s)."""


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
    try:
        return asyncio.run(_run(settings, ns.fleet, encode(msg), x, y, ns.timeout))
    except rt.TransportError as exc:
        print(f"formation goal: {exc}", file=sys.stderr)
        return 1


async def _run(
    settings: rt.ZenohSettings, fleet: str, payload: bytes, x: float, y: float, timeout_s: float
) -> int:
    session = await rt.open_session_async(settings)
    try:
        # the coordinator's figures before the goal (a status every 0.2 s)
        before = await watch_status(session, fleet, lambda _m: True, 1.0, time.monotonic())
        got = await watch_leader(
            session, keys.goal_key(fleet), payload, fleet, lambda m: m.mode == "goal", timeout_s
        )
        if got is None:
            print(
                f"formation goal: no coordinator of fleet {fleet!r} took the goal (refused? see "
                f"`formation top`) within {timeout_s:g} s",
                file=sys.stderr,
            )
            return 1
        print(f"goal ({x:g}, {y:g}) taken: the leader leaves ({got.x:.3f}, {got.y:.3f})")
        if before is None or "plans" not in before:
            return 0  # an open field: the leader drives there straight, nothing is planned
        return await _planned(session, fleet, before, timeout_s)
    finally:
        session.close()


async def _planned(session: Any, fleet: str, before: dict[str, Any], timeout_s: float) -> int:
    """Wait for the plan of the goal and report it (0), or the reason there is none (1)."""
    n0 = int(before.get("plans") or 0)
    st = await watch_status(
        session, fleet, lambda m: int(m.get("plans") or 0) > n0, max(timeout_s, PLAN_WAIT_S),
        time.monotonic(),
    )  # fmt: skip
    if st is None:
        print("formation goal: the coordinator did not answer with a plan", file=sys.stderr)
        return 1
    if st.get("plan") == "no_way":
        print(f"formation goal: no way: {st.get('plan_why')}; the leader stops", file=sys.stderr)
        return 1
    clear = st.get("plan_clearance_m")
    ms = st.get("plan_ms")
    print(
        "planned around the obstacles: least clearance "
        f"{'-' if clear is None else f'{clear:.3f} m'}, planned in "
        f"{'-' if ms is None else f'{ms:.0f} ms'}"
    )
    return 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main(sys.argv[1:]))
