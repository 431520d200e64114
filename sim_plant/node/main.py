"""``formation plant``: the command line and bootstrap of the plant simulator process.

Checks the options and the scenario, then runs :class:`sim_plant.node.plant.PlantNode` under
``runtime.serve``; ``--stats-out`` writes the status and latency statistics at the end. The node
is described in :mod:`sim_plant.node.plant`.
"""

from __future__ import annotations

import argparse
import asyncio
import sys
from typing import Final

import runtime as rt
from bus_schemas import keys
from runtime.lifecycle import OUTPUT_ERROR_EXIT
from scenario import Scenario
from sim_plant.node.plant import WAIT_ROBOTS_S, PlantNode

__all__ = ["MAX_PHYSICS_HZ", "build_parser", "main"]

MAX_PHYSICS_HZ: Final = 10000.0


def build_parser() -> argparse.ArgumentParser:
    """The ``formation plant`` argument parser."""
    parser = argparse.ArgumentParser(
        prog="formation plant",
        description="Run the plant simulator (robots, camera, command link) as a Zenoh node.",
    )
    parser.add_argument("--scenario", required=True, metavar="NAME|FILE", help="scenario")
    parser.add_argument("--fleet", default=keys.DEFAULT_FLEET, help="fleet name (demo)")
    parser.add_argument(
        "--seed", type=rt.non_negative_int, help="random seed (default: the scenario's)"
    )
    parser.add_argument("--lockstep", action="store_true", help="lockstep (docs/runtime.md)")
    parser.add_argument(
        "--lockstep-timeout",
        type=rt.positive_float,
        default=2.0,
        metavar="S",
        help="lockstep: go on after this long without every answer (2.0 s, counted)",
    )
    parser.add_argument(
        "--physics-hz",
        type=rt.positive_float,
        default=100.0,
        metavar="HZ",
        help="realtime physics rate (100 Hz); lockstep uses the scenario's dt_s",
    )
    parser.add_argument(
        "--duration",
        type=rt.positive_float,
        metavar="S",
        help="stop after this much sim time (lockstep) or wall time (realtime) and exit 0",
    )
    parser.add_argument(
        "--wait-robots",
        action="store_true",
        help=f"start only once every robot's and a coordinator's token are present "
        f"(gives up after {WAIT_ROBOTS_S:g} s)",
    )
    parser.add_argument(
        "--batch",
        action="store_true",
        help="large fleets: poses only as batched frames, truth as batches (no per-robot "
        "pose/truth keys); docs/scale.md",
    )
    parser.add_argument(
        "--no-poses",
        action="store_true",
        help="publish no emulated camera poses (a `formation camera --source rendered` does)",
    )
    parser.add_argument(
        "--stats-out",
        metavar="FILE.json",
        help="at exit, write the run's statistics (latency, frames, lateness, rx) as JSON",
    )
    rt.add_zenoh_arguments(parser)
    return parser


def main(argv: list[str]) -> int:
    """Entry point of ``formation plant``; returns the exit status."""
    ns = build_parser().parse_args(argv)
    log = rt.NodeLog("plant")
    try:
        rt.check_names(("--fleet", ns.fleet))
        if ns.physics_hz > MAX_PHYSICS_HZ:
            raise rt.UsageError(f"--physics-hz {ns.physics_hz:g} is above {MAX_PHYSICS_HZ:g}")
        scenario = rt.load_scenario(ns.scenario)
        settings = rt.zenoh_settings(ns)
    except rt.UsageError as exc:
        log.info(str(exc))
        return rt.USAGE_EXIT
    return rt.serve("plant", settings, lambda io, stop: _node(io, stop, scenario, ns))


def write_stats(node: PlantNode, path: str, log: rt.NodeLog) -> bool:
    """``--stats-out``: the status map plus the latency statistics, as JSON (never raises).
    Written whole or not at all (a temporary file renamed into place: a full disk leaves no
    empty or cut file); False, logged, if it could not be."""
    import json

    from runtime.files import write_atomic

    try:
        stats = {**node.status_map(), **node.outputs.latency_stats(), "n_robots": node.n}
        write_atomic(path, json.dumps(stats, indent=1).encode())
    except Exception as exc:
        log.info(f"--stats-out {path}: not written: {exc!r}")
        return False
    return True


async def _node(
    io: rt.NodeIO, stop: asyncio.Event, scenario: Scenario, ns: argparse.Namespace
) -> int:
    node = PlantNode(
        scenario,
        ns.fleet,
        io.pubs.put,
        seed=ns.seed,
        lockstep=ns.lockstep,
        lockstep_timeout_s=ns.lockstep_timeout,
        physics_hz=ns.physics_hz,
        duration_s=ns.duration,
        batch=ns.batch,
        poses=not ns.no_poses,
        log=io.log,
        wanted=io.pubs.matching,
    )
    outputs, inputs = node.outputs, node.inputs
    io.pubs.get(outputs.poses_key, outputs.data_qos)
    for key in () if ns.batch else outputs.pose_keys:
        io.pubs.get(key, outputs.data_qos)
    if ns.lockstep and not ns.batch:  # each robot's truth and pose while anyone reads them:
        for key in outputs.truth_keys:  # their matching listeners, before the tick thread asks
            io.pubs.matching(key, outputs.truth_qos)
        for key in outputs.pose_keys:
            io.pubs.matching(key, outputs.data_qos)
    if ns.lockstep:
        io.pubs.get(node.clock_key, rt.QOS_CRITICAL)
    io.watch_liveliness(node.alive_robots_pattern, inputs.on_alive_robot)
    io.watch_liveliness(node.alive_coordinators_pattern, inputs.on_alive_coordinator)
    # lockstep: the inputs are handled on Zenoh's thread, in the order the session received
    # them (a fault notice for tick k+1 before the leader of tick k), the tick thread woken
    # once a tick (PlantNode)
    inputs_on = io.subscribe_on_thread if ns.lockstep else io.subscribe
    inputs_on(node.wheels_pattern, inputs.on_wheels)
    inputs_on(node.host_wheels_pattern, inputs.on_host_wheels)
    inputs_on(node.disturbance_key, inputs.on_disturbance)
    inputs_on(node.fault_key, node.on_fault)
    if ns.lockstep:
        inputs_on(node.leader_key, inputs.on_leader)
    io.declare_token(node.alive_key)
    print("plant ready", flush=True)
    code = await node.run(stop, ns.wait_robots)
    if ns.stats_out and not write_stats(node, ns.stats_out, io.log) and code == 0:
        code = OUTPUT_ERROR_EXIT  # the run ended; its statistics are lost (formation up says)
    return code


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main(sys.argv[1:]))
