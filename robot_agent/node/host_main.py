"""``formation agent-host``: the command line and bootstrap of an agent host process.

Usage::

    formation agent-host --ids r1..r100 [--name NAME] [--scenario NAME|FILE] [--fleet demo]
                         [--lockstep] [--rate-hz 50] [zenoh options]

Checks the ids, names and scenario (a bad one exits 2 before the ready line), then runs
:class:`robot_agent.node.host.HostNode` under ``runtime.serve``: it asks the coordinators for the
latched e-stop state before it subscribes to anything that moves its robots (so robots of a
host that starts or is respawned under an e-stop come up in ESTOP), declares every robot's
token and prints ``agent-host <name> ready``. The node is described in :mod:`robot_agent.node.host`.
"""

from __future__ import annotations

import argparse
import asyncio
import gc
import os
import re
import sys
import threading

import runtime as rt
from bus_schemas import keys
from robot_agent.core import _accel
from robot_agent.core.params import AgentConfig
from robot_agent.node.agent_estop import attach_estop
from robot_agent.node.host import MAX_HOSTED, HostNode
from runtime.sdnotify import Notifier

__all__ = ["attach_host_estop_state", "build_parser", "expand_ids", "main"]

_RANGE = re.compile(r"([a-z_-]*)(\d+)\.\.\1?(\d+)")


def expand_ids(spec: str) -> list[str]:
    """``"r1..r3,x7"`` -> ``["r1", "r2", "r3", "x7"]``; raises ValueError on a bad id or range."""
    out: list[str] = []
    for part in (p.strip() for p in spec.split(",")):
        if not part:
            continue
        m = _RANGE.fullmatch(part)
        if m is not None:
            prefix, lo, hi = m.group(1), int(m.group(2)), int(m.group(3))
            if hi < lo or hi - lo >= MAX_HOSTED:
                raise ValueError(f"bad id range {part!r}")
            out.extend(f"{prefix}{i}" for i in range(lo, hi + 1))
        elif keys.is_robot_id(part):
            out.append(part)
        else:
            raise ValueError(f"invalid robot id {part!r}: must match {keys.ROBOT_ID_PATTERN}")
    if not out:
        raise ValueError("no robot ids")
    if len(set(out)) != len(out):
        raise ValueError("duplicate robot id")
    if len(out) > MAX_HOSTED:
        raise ValueError(f"at most {MAX_HOSTED} robots per host")
    for rid in out:
        keys.check_robot_id(rid)
    return out


def build_parser() -> argparse.ArgumentParser:
    """The ``formation agent-host`` argument parser."""
    parser = argparse.ArgumentParser(
        prog="formation agent-host",
        description="Run the firmware of many robots in one process (simulation at scale).",
    )
    parser.add_argument(
        "--ids", required=True, metavar="IDS", help="robot ids: r1..r100 or r1,r2,r5..r9"
    )
    parser.add_argument(
        "--name", metavar="NAME", help="host name in the keys (default: host-<pid>)"
    )
    parser.add_argument("--scenario", metavar="NAME|FILE", help="robot parameters of a scenario")
    parser.add_argument("--fleet", default=keys.DEFAULT_FLEET, metavar="NAME", help="fleet name")
    parser.add_argument(
        "--lockstep", action="store_true", help="step on the plant's clock (docs/runtime.md)"
    )
    parser.add_argument(
        "--rate-hz",
        type=rt.rate_hz,
        default=50.0,
        metavar="HZ",
        help="watchdog timer rate (50 Hz)",
    )
    rt.add_zenoh_arguments(parser)
    return parser


def main(argv: list[str]) -> int:
    """Entry point of ``formation agent-host``; returns the exit status."""
    ns = build_parser().parse_args(argv)
    log = rt.NodeLog("formation agent-host")
    try:
        ids = expand_ids(ns.ids)
    except ValueError as exc:
        log.info(f"--ids: {exc}")
        return 2
    name = ns.name or f"host-{os.getpid()}"
    if not keys.is_name(name) or not keys.is_name(ns.fleet):
        log.info(f"invalid --name {name!r} or --fleet {ns.fleet!r}: must match {keys.NAME_PATTERN}")
        return 2
    config = AgentConfig()
    if ns.scenario is not None:
        from scenario import ScenarioError, load

        try:
            config = load(ns.scenario).agent
        except (ScenarioError, OSError) as exc:
            log.info(f"scenario: {exc}")
            return 2
    try:
        settings = rt.settings_from_args(ns)
    except (TypeError, ValueError) as exc:
        log.info(f"zenoh settings: {exc}")
        return 2
    return rt.serve(
        f"agent-host {name}",
        settings,
        lambda io, stop: _node(io, stop, name, ids, ns.fleet, config, ns.lockstep, ns.rate_hz),
    )


async def _node(
    io: rt.NodeIO,
    stop: asyncio.Event,
    name: str,
    ids: list[str],
    fleet: str,
    config: AgentConfig,
    lockstep: bool,
    rate_hz: float,
) -> int:
    notifier = Notifier()
    try:
        host = HostNode(
            name, ids, fleet, config, io.pubs.put, lockstep=lockstep, rate_hz=rate_hz, log=io.log
        )
        host.stall.gap_s = rt.hang_gap_for(io.settings.lease_ms)
        io.pubs.get(host.wheels_key, host.wheels_qos)
        io.pubs.get(host.status_key, rt.QOS_TELEMETRY)
        if lockstep:  # the tick thread's lock, before anything the loop runs takes it
            host.guard = threading.RLock()
        # the latched e-stop first: robots that start under an e-stop come up in ESTOP
        await attach_host_estop_state(host, io)
        if lockstep:
            # One thread takes each clock and, just before it, the inputs only a clock reads
            # (runtime.bridge.TickPump, as a lockstep agent's; docs/runtime.md): fault notices,
            # setpoint batches and movers name their tick, the plant's poses come before it.
            pump = io.tick_pump(host.guard, name=f"agent-host-{name}-ticks")
            pump.side(keys.fault_key(fleet), host.on_fault)
            pump.side(host.setpoints_key, host.on_setpoints)
            pump.side(host.movers_key, host.on_movers)
            pump.side(host.poses_key, host.on_poses)
            pump.start(host.clock_key, host.on_clock)
        else:
            io.subscribe(host.setpoints_key, host.on_setpoints)
            io.subscribe(host.movers_key, host.on_movers)
            io.subscribe(host.poses_key, host.on_poses)
            # the other robots' modes: cooperative neighbours
            io.subscribe(keys.all_status_pattern(fleet), host.peer_status.on_status)
            io.subscribe(keys.all_host_status_pattern(fleet), host.peer_status.on_host_status)
        for r in ids:
            io.declare_token(keys.alive_robot_key(fleet, r))
        # the robots' firmware lives as long as the process: out of the collector's sight too
        # (runtime.serve froze the imports; a full collection then walks only new objects)
        gc.collect()
        gc.freeze()
        if not lockstep:  # collections between frames only (HostNode.collect_garbage)
            gc.disable()
            host.manual_gc = True
        print(f"agent-host {name} ready", flush=True)
        notifier.ready(f"agent-host {name} connected ({len(ids)} robots)")
        mode = "lockstep" if lockstep else f"realtime, watchdog {rate_hz:g} Hz"
        io.log.info(
            f"fleet {fleet}, {len(ids)} robots ({ids[0]}..{ids[-1]}), {mode}; core {_accel.STATUS}"
        )
        await host.run(stop, notifier)
        notifier.stopping()
        return 0
    finally:
        notifier.close()


async def attach_host_estop_state(host: HostNode, io: rt.NodeIO) -> None:
    """``robot_agent.node.agent_estop.attach_estop`` for an agent host: every hosted robot merges
    the answers, and the host answers ``estop/held/<host>`` with every hosted robot's
    engagements."""
    await attach_estop(
        io,
        fleet=host.fleet,
        name=host.name,
        on_estop=host.on_estop,
        query=host.estop_query,
        witness=host.witness,
        internal=host.faults.internal,
        on_state=host.on_estop_state,
        on_held=host.on_estop_held,
    )


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main(sys.argv[1:]))
