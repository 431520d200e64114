"""``formation obstacle add|move|remove ID [--circle X Y R | --polygon X,Y X,Y X,Y ...]``: put
a planning obstacle on the coordinator's map at run time (issue 27).

Publishes an ``Obstacle`` on ``formation/<fleet>/operator/obstacle``; the coordinator replans a
goal the leader follows around it, from where the leader is (no jump,
coordinator.core.planning.replan). The tool waits for the active coordinator's status to show
the map changed (its ``obstacles`` count) and prints the plan state; a refusal (an id that
exists for ``add`` or is unknown for ``move``/``remove``, a degenerate polygon: the status's
``rejects``) is exit 1. A bad number on the command line is one line and exit 2. The obstacle
is the plan's (the first layer): the robots' safety filters keep their own configuration's.
"""

from __future__ import annotations

import argparse
import asyncio
import sys
import time
from typing import Any

import runtime as rt
from bus_schemas import Obstacle, encode, keys
from bus_schemas.messages_operator import OBSTACLE_POINTS_MAX, OBSTACLE_RADIUS_MAX_M
from formation.operate.drive import common_options, finite, parse_waypoints, watch_status
from formation.outputs import runfile


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="formation obstacle",
        description="Add, move or remove a planning obstacle of the running fleet's "
        "coordinator: it replans the goal the leader follows around it.",
    )
    p.add_argument("action", choices=("add", "move", "remove"))
    p.add_argument("id", metavar="ID", help="the obstacle's name ([A-Za-z0-9_-], 1-64)")
    shape = p.add_mutually_exclusive_group()
    shape.add_argument("--circle", nargs=3, metavar=("X", "Y", "R"), help="a disc (m)")
    shape.add_argument(
        "--polygon", nargs="+", metavar="X,Y", help="a filled polygon's vertices (m), 3 to 64"
    )
    common_options(p)
    return p


def message(ns: argparse.Namespace) -> Obstacle:
    """The message the command line asks for; ValueError names what is wrong."""
    keys.check_name(ns.id)
    now = max(time.monotonic(), 0.0)
    if ns.action == "remove":
        if ns.circle or ns.polygon:
            raise ValueError("remove takes no --circle or --polygon")
        return Obstacle(t=now, id=ns.id, action="remove")
    if ns.circle:
        x, y = finite("X", ns.circle[0]), finite("Y", ns.circle[1])
        r = finite("R", ns.circle[2], bound=OBSTACLE_RADIUS_MAX_M)
        if r <= 0.0:
            raise ValueError(f"R must be > 0, got {ns.circle[2]!r}")
        return Obstacle(t=now, id=ns.id, action=ns.action, shape="circle", x=x, y=y, radius_m=r)
    if ns.polygon:
        pts = parse_waypoints(ns.polygon)
        if not 3 <= len(pts) <= OBSTACLE_POINTS_MAX:
            raise ValueError(f"--polygon needs 3 to {OBSTACLE_POINTS_MAX} vertices, got {len(pts)}")
        xs = tuple(p[0] for p in pts)
        ys = tuple(p[1] for p in pts)
        return Obstacle(t=now, id=ns.id, action=ns.action, shape="polygon", xs=xs, ys=ys)
    raise ValueError(f"{ns.action} needs --circle X Y R or --polygon X,Y X,Y X,Y ...")


def main(argv: list[str]) -> int:
    """Entry point of ``formation obstacle``."""
    ns = build_parser().parse_args(argv)
    try:
        keys.check_fleet(ns.fleet)
        msg = message(ns)
        if not ns.timeout > 0:
            raise ValueError(f"--timeout must be positive, got {ns.timeout:g}")
        settings = runfile.tool_settings(ns, "operator")
    except (TypeError, ValueError) as exc:
        print(f"formation obstacle: error: {exc}", file=sys.stderr)
        return 2
    try:
        return asyncio.run(_run(settings, ns.fleet, msg, ns.timeout))
    except rt.TransportError as exc:
        print(f"formation obstacle: {exc}", file=sys.stderr)
        return 1


def _refusals(status: dict[str, Any]) -> int:
    rejects = status.get("rejects") or {}
    return sum(int(n) for k, n in rejects.items() if str(k).startswith("obstacle-"))


async def _run(settings: rt.ZenohSettings, fleet: str, msg: Obstacle, timeout_s: float) -> int:
    session = await rt.open_session_async(settings)
    try:
        before = await watch_status(session, fleet, lambda _m: True, timeout_s, time.monotonic())
        if before is None:
            print(f"formation obstacle: no active coordinator of fleet {fleet!r}", file=sys.stderr)
            return 1
        refused0 = _refusals(before)
        rt.Publishers(session).put(keys.obstacle_key(fleet), encode(msg), rt.QOS_CRITICAL)
        sent = time.monotonic()
        st = await watch_status(
            session, fleet,
            lambda m: _refusals(m) > refused0 or m.get("obstacles") != before.get("obstacles")
            or (msg.action == "move" and m.get("t", 0) > before.get("t", 0) + 0.3),
            timeout_s, sent,
        )  # fmt: skip
    finally:
        session.close()
    if st is None:
        print(f"formation obstacle: the coordinator did not take it within {timeout_s:g} s",
              file=sys.stderr)  # fmt: skip
        return 1
    if _refusals(st) > refused0:
        rejects = {k: v for k, v in (st.get("rejects") or {}).items() if k.startswith("obstacle-")}
        print(f"formation obstacle: refused ({rejects})", file=sys.stderr)
        return 1
    plan = st.get("plan") or "none"
    print(f"obstacle {msg.id} {msg.action}: {st.get('obstacles')} on the map, plan {plan}")
    return 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main(sys.argv[1:]))
