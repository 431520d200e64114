"""``formation ls`` and ``formation echo``: what is on a router, and what a key carries.

Usage::

    formation ls [--wait 1.0] [--endpoint tcp/HOST:7447 ...]
    formation echo KEY [--fleet demo] [--count N] [--wait S] [--endpoint ...]

``ls`` lists the fleets whose processes hold liveliness tokens on the router (robots,
coordinators, plant, agent hosts), with the ``formation up`` runs registered on this host; exit 1
when the router has none. ``echo`` prints each message on ``KEY`` decoded and validated against
the bus contract, one JSON object a line (``{"key": ..., "msg": {...}}``; a payload that does
not decode: ``{"key": ..., "error": ...}``, counted). ``KEY`` is relative to the fleet
(``assignment``, ``robot/r1/status``, ``robot/*/wheels``) or absolute (``formation/...``);
``--count`` stops after N messages, ``--wait`` after S seconds (exit 1 if nothing came).

The endpoint and fleet come from the options, else ``$FORMATION_ENDPOINT``/``$FORMATION_FLEET``,
else the one ``formation up`` running on this host (formation.outputs.runfile). Both only listen.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import sys
from collections import defaultdict
from typing import Any

import runtime as rt
from bus_schemas import keys
from formation.outputs import runfile

__all__ = ["echo_main", "ls_main"]


def _parser(prog: str, text: str) -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=prog, description=text)
    rt.add_zenoh_arguments(p)
    return p


def fleets_of(tokens: set[str]) -> dict[str, dict[str, list[str]]]:
    """Liveliness keys -> fleet -> kind (robot, coordinator, plant, host...) -> names."""
    out: dict[str, dict[str, list[str]]] = defaultdict(lambda: defaultdict(list))
    for key in sorted(tokens):
        parsed = keys.parse_alive_key(key)
        if parsed is None:
            continue
        fleet, kind, ident = parsed
        out[fleet][kind].append(ident or "")
    return {f: {k: sorted(v) for k, v in kinds.items()} for f, kinds in out.items()}


async def _tokens(settings: rt.ZenohSettings, wait_s: float) -> set[str]:
    session = await rt.open_session_async(settings)
    alive: set[str] = set()
    try:
        loop = asyncio.get_running_loop()

        def on(key: str, up: bool) -> None:
            (alive.add if up else alive.discard)(key)

        sub = rt.watch_liveliness(session, "formation/*/alive/**", loop, on)
        await asyncio.sleep(wait_s)
        sub.undeclare()
    finally:
        session.close()
    return alive


def ls_main(argv: list[str]) -> int:
    """``formation ls``: 0 when a fleet was found, 1 when none (or no router), 2 bad options."""
    p = _parser("formation ls", "List the fleets on a router (from their liveliness tokens).")
    p.add_argument("--wait", type=float, default=1.0, metavar="S", help="listen this long")
    ns = p.parse_args(argv)
    if not 0 < ns.wait <= 60:
        print("formation ls: --wait must be in (0, 60] s", file=sys.stderr)
        return 2
    ns.fleet = "unused"  # ls is about every fleet
    settings = runfile.tool_settings(ns, "observer")
    where = ", ".join(settings.connect) or "(the config file's endpoints)"
    try:
        found = fleets_of(asyncio.run(_tokens(settings, ns.wait)))
    except rt.TransportError as exc:
        print(f"formation ls: {exc}", file=sys.stderr)
        return 1
    runs = {r.fleet: r for r in runfile.live_runs()}
    if not found:
        print(f"no fleet on {where} (no liveliness token within {ns.wait:g} s)")
        return 1
    print(f"fleets on {where}:")
    for fleet, kinds in sorted(found.items()):
        parts = []
        for kind in ("robot", "coordinator", "plant", "host"):
            names = kinds.get(kind, [])
            if names:
                shown = ", ".join(n for n in names[:6] if n)
                more = f", ... ({len(names)})" if len(names) > 6 else ""
                parts.append(f"{len(names)} {kind}(s)" + (f" [{shown}{more}]" if shown else ""))
        run = runs.get(fleet)
        up = f"  (formation up, pid {run.pid}, out {run.out})" if run is not None else ""
        print(f"  {fleet}: {'; '.join(parts) or 'tokens only'}{up}")
    return 0


def _absolute(key: str, fleet: str) -> str:
    if key.startswith("formation/"):
        return key
    return f"{keys.fleet_pattern(fleet).removesuffix('/**')}/{key.strip('/')}"


def echo_main(argv: list[str]) -> int:
    """``formation echo``: 0 when messages came, 1 when none (or no router), 2 bad options."""
    p = _parser("formation echo", "Print the decoded messages of a key, one JSON a line.")
    p.add_argument("key", metavar="KEY", help="e.g. assignment, robot/r1/status, robot/*/wheels")
    p.add_argument("--fleet", default=None, help="fleet (default: $FORMATION_FLEET, ...)")
    p.add_argument("--count", type=int, default=None, metavar="N", help="stop after N messages")
    p.add_argument("--wait", type=float, default=None, metavar="S", help="stop after S seconds")
    ns = p.parse_args(argv)
    settings = runfile.tool_settings(ns, "observer")
    try:
        keys.check_fleet(ns.fleet)
        if ns.count is not None and ns.count < 1:
            raise ValueError("--count must be >= 1")
        if ns.wait is not None and not 0 < ns.wait <= 86400:
            raise ValueError("--wait must be in (0, 86400] s")
    except ValueError as exc:
        print(f"formation echo: {exc}", file=sys.stderr)
        return 2
    key = _absolute(ns.key, ns.fleet)
    try:
        import zenoh

        zenoh.KeyExpr(key)
    except Exception:
        print(
            f"formation echo: KEY: {key!r} is not a key expression (an empty chunk `//`, or a "
            "leading or trailing `/`)",
            file=sys.stderr,
        )
        return 2
    try:
        got = asyncio.run(_echo(settings, key, ns.count, ns.wait))
    except rt.TransportError as exc:
        print(f"formation echo: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        return 0
    return 0 if got else 1


async def _echo(
    settings: rt.ZenohSettings, key: str, count: int | None, wait_s: float | None
) -> int:
    from formation.outputs.bus_json import decode_sample, jsonable

    session = await rt.open_session_async(settings)
    seen = 0
    done = asyncio.Event()
    loop = asyncio.get_running_loop()

    def on(rx: rt.Received) -> None:
        nonlocal seen
        if done.is_set():
            return
        got = decode_sample(rx.key, bytes(rx.payload))
        line: dict[str, Any] = {"key": rx.key}
        if got is None:
            line["error"] = "no message type for this key (a token or a foreign key)"
        elif isinstance(got, tuple):
            line["msg"] = jsonable(got.obj)
        else:
            line["error"] = str(got)
        print(json.dumps(line, sort_keys=True), flush=True)
        seen += 1
        if count is not None and seen >= count:
            done.set()

    sub = rt.subscribe(session, key, loop, on)
    try:
        if wait_s is None:
            await done.wait()
        else:
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(done.wait(), wait_s)
    finally:
        sub.undeclare()
        session.close()
    if not seen:
        print(f"formation echo: nothing on {key}", file=sys.stderr)
    return seen
