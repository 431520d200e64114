"""``formation coordinator``: the command line and bootstrap of a coordinator process.

Checks the names and the scenario (a bad one exits 2 before the ready line), then runs
:class:`coordinator.node.coordinator.CoordinatorNode` under ``runtime.serve``. The node is
described in
:mod:`coordinator.node.coordinator`. The node and its core (numpy, scipy) are imported once the
arguments are checked: a mistake on the command line is reported without them.
"""

from __future__ import annotations

import argparse
import asyncio
import os
import sys
from pathlib import Path
from typing import TYPE_CHECKING

import runtime as rt
from bus_schemas import keys
from runtime.sdnotify import Notifier, pet_watchdog

if TYPE_CHECKING:
    from coordinator.node.coordinator import CoordinatorNode
    from scenario import Scenario

__all__ = ["build_parser", "main"]


def build_parser() -> argparse.ArgumentParser:
    """The ``formation coordinator`` argument parser."""
    parser = argparse.ArgumentParser(
        prog="formation coordinator",
        description="Run the coordinator (virtual leader, slots, roles, setpoints) as a node.",
    )
    task = parser.add_mutually_exclusive_group(required=True)
    task.add_argument("--scenario", metavar="NAME|FILE", help="scenario (simulation)")
    task.add_argument(
        "--fleet-file",
        metavar="FLEET.toml",
        help="real robots: the fleet file (robots, arena, trajectory, formation; "
        "deploy/config/fleet.example.toml); no simulator scenario needed",
    )
    parser.add_argument(
        "--check",
        action="store_true",
        help="check the scenario or fleet file, print OK or the problems, exit 0/2 (no Zenoh)",
    )
    parser.add_argument("--name", default="main", help="coordinator instance name (main)")
    parser.add_argument("--fleet", default=None, help="fleet name (demo, or the fleet file's)")
    parser.add_argument(
        "--rate-hz", type=rt.rate_hz, default=50.0, metavar="HZ", help="realtime tick rate (50)"
    )
    parser.add_argument(
        "--lockstep", action="store_true", help="tick on the plant's clock (docs/runtime.md)"
    )
    parser.add_argument(
        "--standby",
        action="store_true",
        help="start as a hot standby: take over when the active instance is gone (docs/faults.md)",
    )
    parser.add_argument(
        "--batch",
        action="store_true",
        help="large fleets: read the batched pose frames and publish batched setpoints "
        "(agent hosts read them; slot keys at 1 Hz); docs/scale.md",
    )
    parser.add_argument(
        "--estop-state",
        metavar="FILE",
        type=Path,
        default=None,
        help="keep the latched e-stop state in FILE (written on every change, read at start): "
        "an instance restarted alone still holds it (docs/faults.md); default: memory only",
    )
    rt.add_zenoh_arguments(parser)
    return parser


def main(argv: list[str]) -> int:
    """Entry point of ``formation coordinator``; returns the exit status."""
    ns = build_parser().parse_args(argv)
    log = rt.NodeLog(f"coordinator {ns.name}")
    try:
        _check_state_path(ns.estop_state)
        scenario = _scenario(ns)
        rt.check_names(("--name", ns.name), ("--fleet", ns.fleet))
        if ns.check:
            from scenario.preflight import preflight_warnings  # path conflicts, feasibility

            for warning in preflight_warnings(scenario):
                print(f"warning: {warning}", flush=True)
            robots = ", ".join(scenario.robot_ids)
            task = f"trajectory {scenario.trajectory.get('kind')}, "
            task += f"formation {scenario.formation.get('kind')}"
            print(f"OK: fleet {ns.fleet}, robots {robots}, {task}", flush=True)
            return 0
        settings = rt.zenoh_settings(ns)
    except rt.UsageError as exc:
        log.info(str(exc))
        return rt.USAGE_EXIT
    return rt.serve(
        f"coordinator {ns.name}",
        settings,
        lambda io, stop: _node(
            io, stop, scenario, ns.name, ns.fleet, ns.lockstep, ns.rate_hz, ns.standby, ns.batch,
            ns.estop_state,
        ),
    )  # fmt: skip


def _check_state_path(path: Path | None) -> None:
    """``--estop-state``: its directory must exist and be writable, the file (if there is
    one) a regular file; otherwise :class:`runtime.UsageError`."""
    if path is None:
        return
    folder = path.parent
    if not folder.is_dir():
        raise rt.UsageError(f"--estop-state: directory {folder} does not exist")
    if path.exists() and not path.is_file():
        raise rt.UsageError(f"--estop-state: {path} is not a regular file")
    if not os.access(folder, os.W_OK | os.X_OK):
        raise rt.UsageError(f"--estop-state: directory {folder} is not writable")


def _scenario(ns: argparse.Namespace) -> Scenario:
    """The task of ``--fleet-file`` or ``--scenario`` (``ns.fleet`` filled in); a bad one, or
    one whose trajectory or formation the core refuses, as :class:`runtime.UsageError`."""
    if ns.fleet_file is not None:
        fleet_file = rt.load_fleet_file(ns.fleet_file)
        ns.fleet = ns.fleet or fleet_file.fleet or keys.DEFAULT_FLEET
        return fleet_file.scenario
    ns.fleet = ns.fleet or keys.DEFAULT_FLEET
    # the core is built now so that a bad trajectory fails before the ready line
    return rt.load_scenario(ns.scenario, check=_build_core)


def _build_core(scenario: Scenario) -> object:
    """The coordinator core of ``scenario`` (imported here: numpy and scipy, ~0.5 s)."""
    from scenario.assemble import coordinator_core

    return coordinator_core(scenario)


async def _node(
    io: rt.NodeIO,
    stop: asyncio.Event,
    scenario: Scenario,
    name: str,
    fleet: str,
    lockstep: bool,
    rate_hz: float,
    standby: bool = False,
    batch: bool = False,
    estop_state: Path | None = None,
) -> int:
    from coordinator.node.coordinator import CoordinatorNode
    from coordinator.node.estop_source import attach_estop_source
    from coordinator.node.estop_store import EstopStore

    node = CoordinatorNode(
        scenario, name, fleet, io.pubs.put, lockstep=lockstep, standby=standby, batch=batch,
        log=io.log,
    )  # fmt: skip
    # Only a stop of the whole process lets the token expire (keep-alives come from Zenoh's own
    # threads, not this loop), after a whole lease of silence (runtime.stall).
    node.stall.gap_s = rt.hang_gap_for(io.settings.lease_ms, default_s=rt.HANG_GAP_NO_LEASE_S)
    io.pubs.get(node.leader_key, node.leader_qos)
    for rid in () if batch else scenario.robot_ids:
        io.pubs.get(keys.setpoint_key(fleet, rid), node.sp_qos)

    def on_alive(key: str, alive: bool) -> None:
        # Stopping: the fleet's tokens vanish together (`formation up` stops every node at once)
        # and each vanished robot was re-assigned at once (a tick over the whole fleet, ~2.5 ms
        # with 300 robots): the 300 tokens of an agent host, queued on the loop ahead of the stop
        # callback, held the coordinator ~0.9 s and its watchdog forced it out (status 70;
        # bench/bench_exit.py --robots 300). A stopping coordinator assigns nothing more; the
        # signal handler's flag is seen before the loop gets to set the stop Event.
        if alive or not (stop.is_set() or rt.stop_signalled()):
            node.on_alive(key, alive)

    io.watch_liveliness(node.alive_pattern, on_alive)
    io.watch_liveliness(node.coordinators_pattern, on_alive)
    io.subscribe(node.heartbeats_pattern, node.election_io.on_heartbeat)
    io.subscribe(node.assignment_key, node.election_io.on_assignment)
    io.subscribe(node.fault_key, node.on_fault)  # operators' requests (--at T)
    io.pubs.get(node.fault_key, node.scripted.qos)
    if not lockstep:  # a standby checks trajectory origins against the leader (election)
        io.subscribe(node.leader_key, node.election_io.on_leader)
        io.subscribe(node.leader_key, node.operator.on_leader)  # and continues it (issue 28)
    # teleop, goals, paths, shapes: one subscription per key (under --secure the router's
    # access control admits a declaration on exactly the keys a coordinator may read)
    for key in node.operator.command_keys:
        io.subscribe(key, node.operator.on_command)
    # durable e-stop state (docs/faults.md): the other coordinators', then the state file's
    store = None if estop_state is None else EstopStore(estop_state, fleet, io.log.info)
    try:
        await attach_estop_source(node.estop_source, io, store)
        return await _run(io, stop, node, scenario, name, fleet, lockstep, rate_hz, standby)
    finally:
        if store is not None:
            store.close()


async def _run(
    io: rt.NodeIO,
    stop: asyncio.Event,
    node: CoordinatorNode,
    scenario: Scenario,
    name: str,
    fleet: str,
    lockstep: bool,
    rate_hz: float,
    standby: bool,
) -> int:
    batch = node.batch
    # Lockstep: the poses are read at the next clock only (they precede it: same publisher),
    # so they wait for it (runtime.bridge.LoopFeed) instead of waking the loop each
    lazy = not lockstep
    if batch:
        io.pubs.get(node.setpoints_key, node.sp_qos)
    if batch or lockstep:  # (every lockstep node reads the plant's frames as batches)
        io.subscribe(node.poses_key, node.on_poses, wake=lazy)
    else:
        io.subscribe(node.poses_pattern, node.on_pose, wake=lazy)
    if lockstep:
        io.subscribe(node.clock_key, node.on_clock)
    io.declare_token(node.alive_key)
    print("coordinator ready", flush=True)
    mode = "lockstep" if lockstep else f"realtime at {rate_hz:g} Hz"
    role = "standby" if standby else "active"
    io.log.info(f"fleet {fleet}, scenario {scenario.name}, {mode}, {role}")
    # Type=notify under systemd (deploy/systemd/formation-coordinator@.service): READY once the
    # subscriptions are declared; WATCHDOG from this event loop, the one the ticks run on.
    notifier = Notifier()
    notifier.ready(f"coordinator {name}: {role}, fleet {fleet}")
    pet = asyncio.ensure_future(pet_watchdog(notifier, stop))
    try:
        await node.run(stop, rate_hz)
        notifier.stopping()
    finally:
        pet.cancel()
        notifier.close()
    return 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main(sys.argv[1:]))
