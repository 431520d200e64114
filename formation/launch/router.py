"""``formation router``: an embedded Zenoh router, so a local run needs no separate server binary.

Usage::

    formation router [--listen tcp/127.0.0.1:7447] [--endpoint tcp/other-host:7447]
                     [--zenoh-config FILE] [--lease-ms N] [--multicast-scouting]

It opens a Zenoh session in mode ``router`` listening on the given endpoints (multicast scouting
off unless asked for), prints exactly one line ``router listening on <endpoints>`` to stdout when
ready (launchers and tests wait for it), runs until SIGINT/SIGTERM, closes the session and exits
with status 0 (measured: well under 100 ms after the signal). ``--endpoint`` connects this router
to other routers (e.g. one per host). Exit status 1 if the router cannot open (port in use).
"""

from __future__ import annotations

import argparse
import asyncio
import json
import sys

import runtime as rt
from runtime.sdnotify import Notifier, pet_watchdog

READY_PREFIX = "router listening on "
"""Start of the single line printed on stdout once the router accepts connections."""


def build_parser() -> argparse.ArgumentParser:
    """The ``formation router`` argument parser."""
    parser = argparse.ArgumentParser(prog="formation router", description=__doc__.splitlines()[0])
    parser.add_argument(
        "--listen",
        action="append",
        metavar="ENDPOINT",
        help=f"endpoint to listen on, repeatable (default {rt.DEFAULT_ENDPOINT}, "
        "or the config file's)",
    )
    parser.add_argument(
        "--endpoint",
        action="append",
        metavar="ENDPOINT",
        help="another router to connect to, repeatable (default: none)",
    )
    parser.add_argument("--zenoh-config", metavar="FILE", help="Zenoh JSON5 config, loaded first")
    parser.add_argument(
        "--lease-ms",
        type=int,
        metavar="MS",
        help="transport lease in ms announced by this router (Zenoh default 10000)",
    )
    parser.add_argument(
        "--multicast-scouting", action="store_true", help="enable multicast discovery (off)"
    )
    return parser


def settings_from_router_args(ns: argparse.Namespace) -> rt.ZenohSettings:
    """Router settings: mode ``router``; listen defaults to :data:`rt.DEFAULT_ENDPOINT` unless a
    config file is given (then its ``listen`` is kept)."""
    listen: tuple[str, ...]
    if ns.listen:
        listen = tuple(ns.listen)
    elif ns.zenoh_config is None:
        listen = (rt.DEFAULT_ENDPOINT,)
    else:
        listen = ()
    return rt.ZenohSettings(
        connect=tuple(ns.endpoint or ()),
        listen=listen,
        mode="router",
        config_file=ns.zenoh_config,
        lease_ms=ns.lease_ms,
        multicast_scouting=bool(ns.multicast_scouting),
    )


def _listen_endpoints(settings: rt.ZenohSettings) -> str:
    if settings.listen:
        return ", ".join(settings.listen)
    # From the config file: a list, or Zenoh's per-mode map {"router": [...], ...}.
    value = json.loads(rt.make_config(settings).get_json("listen/endpoints"))
    if isinstance(value, dict):
        value = value.get("router", [])
    return ", ".join(str(v) for v in value) or "(no endpoint)"


async def _serve(stop: asyncio.Event, settings: rt.ZenohSettings) -> int:
    try:
        session = rt.open_session(settings)  # a router opens at once or fails (port in use)
    except (rt.TransportError, ValueError) as exc:
        print(f"formation router: {exc}", file=sys.stderr)
        return 2  # a busy port or an endpoint that cannot be opened: the caller's to fix
    notifier = Notifier()  # Type=notify under systemd (deploy/systemd/formation-router.service)
    try:
        where = _listen_endpoints(settings)
        print(f"{READY_PREFIX}{where}", flush=True)
        notifier.ready(f"router listening on {where}")
        await pet_watchdog(notifier, stop)
        await stop.wait()
        notifier.stopping()
        return 0
    finally:
        if not rt.close_session(session):
            print(
                f"formation router: session close still blocked after {rt.SESSION_CLOSE_S:g} s: "
                "exiting without it",
                file=sys.stderr,
            )
        notifier.close()


def main(argv: list[str]) -> int:
    """Entry point of ``formation router`` (dispatched by ``formation.cli``)."""
    ns = build_parser().parse_args(argv)
    try:
        settings = settings_from_router_args(ns)
    except ValueError as exc:
        print(f"formation router: {exc}", file=sys.stderr)
        return 2
    return rt.run_node(lambda stop: _serve(stop, settings))
