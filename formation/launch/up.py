"""``formation up``: start the whole distributed system locally, watch it, measure it.

Usage::

    formation up [--scenario NAME|FILE] [--robots N] [--spares K] [--duration S]
                 [--lockstep [--lockstep-timeout S]] [--endpoint tcp/127.0.0.1:7447]
                 [--fleet F] [--out DIR] [--seed N] [--no-figures] [--quiet]
                 [--record FILE.mcap] [--foxglove [PORT]] [--standby] [--respawn S]
                 [--lease-ms MS] [--hosts H] [--secure]

Theory of operation
-------------------
1. **Plan.** The scenario is loaded and validated (a bad one exits with status 2 before anything
   starts). ``--robots N`` rewrites it with N formation slots, grown by the paper's staged rule
   (Fig 2b: a triangle becomes the triangular lattice; scenario.resize), and ids ``r1..rN``
   (start poses kept for the first robots, new ones placed on their slots); ``--spares K`` adds
   K idle hot spares ``r(N+1)..r(N+K)`` in rows behind the formation. The rewrite goes to
   ``<out>/scenario.toml``, which every process then loads. The plan also decides the agent
   processes: ``--hosts H`` agent hosts, ``--hosts 0`` one process per robot, and without
   ``--hosts`` the automatic rule of ``up_plan.auto_hosts`` (per-robot processes up to 4 robots
   per core, agent hosts beyond; docs/scale.md). The start banner's ``fleet:`` line says slots,
   stages, spares and processes, and why.
2. **Spawn** (fork+exec, ``asyncio.create_subprocess_exec``; this process opens no Zenoh session
   before every child exists): ``formation router --listen EP``, then ``formation plant``,
   ``formation coordinator`` and one ``formation agent --id rK`` per robot, all connecting to EP
   (``--hosts H``: H ``formation agent-host`` processes share the robots instead, and plant and
   coordinator use the batched keys, ``--batch``; docs/scale.md).
   Each child's stderr goes to ``<out>/logs/<name>.log``, its stdout to ``<name>.out``; the
   launcher waits for each one's ready line (``router listening on``, ``plant ready``,
   ``coordinator ready``, ``agent rK ready``) and names the process and its stderr tail if one
   does not come. The children share one process group of their own, so a terminal's Ctrl-C
   reaches only the launcher, which is then the only one signalling them (a second signal to a
   node would force its exit). Every child dies with the launcher, even a SIGKILLed one
   (``FORMATION_PARENT_PID`` -> ``runtime.lifecycle.bind_to_parent``: parent-death signal and a
   ppid watch). With ``--secure`` (docs/security.md) the launcher first makes an ephemeral CA
   and one certificate per process identity, and the router and every node get
   ``--zenoh-config`` (mTLS, access control from the contract) instead of ``--endpoint``. The
   run registers itself (formation.outputs.runfile: ``run-<port>.json`` in the user's runtime
   directory) so ``formation fault``/``top``/``record`` find it and its credentials.
3. **Collect.** Right after the last spawn the launcher opens its client session and subscribes
   a :class:`formation.record.collector.RunCollector` to truth, leader, slots, assignment, wheels,
   status, clock and the liveliness tokens. The plant (``--wait-robots``) starts its clock only
   when every agent's and the coordinator's token is up, which takes each agent a Python start;
   the launcher's subscription is declared long before (a late start is detected in lockstep:
   tick 0 missing).
4. **Run** until the end: lockstep, when the plant exits after ``--duration`` of sim time;
   realtime, when the plant exits after ``--duration`` wall seconds from its clock start (the
   launcher stops it itself 1.5 s later if it has not).
   A live table (robot, slot, role, mode, tracking error, rejected) is redrawn at 2 Hz on a
   terminal; otherwise a one-line summary every 5 s; nothing with ``--quiet``. An agent that
   exits during the run (e.g. ``formation fault kill r2``) is an *event*, printed and kept in
   ``metrics.json`` (``meta.events``): the fleet re-forms without it, and with ``--respawn S`` it
   is started again S s later and rejoins. So is a coordinator while another one runs
   (``--standby``; it is respawned as a standby), and, with ``--respawn``, the router (restarted
   on the same endpoint: the nodes reconnect) and in realtime the plant (restarted for what is
   left of the duration). Any other child that exits ends the run as a failure. Every node
   gets ``--lease-ms`` (default 700): a hung node's tokens vanish within 1 s.
5. **Stop.** SIGTERM to plant, coordinator and agents, at most 2 s wait (a child that is a zombie
   by then has exited: it counts as in time), then SIGABRT (the child's faulthandler writes
   every thread's stack to its log) and SIGKILL, said on stderr; each child's time from SIGTERM
   to exit is ``meta.children.<name>.stop_s`` in metrics.json. The launcher's session is closed;
   then the router gets the same treatment. SIGINT or
   SIGTERM to the launcher starts this at once; a second one kills everything immediately.
   With ``--record FILE`` a :mod:`formation.record.command` recorder subscribes on the launcher's
   session
   right after the collector (so before the plant's clock starts) and writes every key of the
   fleet and its liveliness changes to the MCAP file, with the run's scenario, mode and settling
   time as metadata; ``formation report FILE`` rebuilds this run's metrics from it. With
   ``--foxglove [PORT]`` (default 8765) a :mod:`formation.live.foxglove` Foxglove WebSocket server
   is fed
   from the same session (line ``foxglove live view on ws://HOST:PORT``). Both are closed before
   the launcher's session (the recording is finalized even after an interrupt).
6. **Results.** ``metrics.json`` (``formation.outputs.metrics.compute`` on the RunLog built
   from truth), ``run.npz`` and the figures (``formation.outputs.figures.write_all``) in
   ``--out``. Exit status: 0,
   1 if a child failed (did not start, died, exited non-zero, had to be killed) or an output
   could not be written (a full or read-only disk: each output is tried, written whole or not
   at all, and the ones not written are named; docs/runtime.md), 130 after an
   interrupt (metrics and figures of what was recorded so far are still written, and one line on
   stderr says so), 2 for bad arguments. The plant writes its control-loop latency statistics
   to ``plant_stats.json`` (docs/scale.md; bench/bench_up.py reads them). A child still paused
   (SIGSTOP) at the end is resumed after its SIGTERM: an event, not a failure.
"""

from __future__ import annotations

import argparse
import asyncio
import sys
from pathlib import Path

import scenario as scenario_mod
from bus_schemas import keys
from bus_schemas.session import DEFAULT_ENDPOINT, LEASE_MS
from formation.launch.plan import (
    LaunchError,
    Plan,
    UpConfig,
    UpResult,
    plan_run,
)
from runtime.args import non_negative_int, positive_float

__all__ = [
    "LaunchError",
    "Plan",
    "UpConfig",
    "UpResult",
    "build_parser",
    "main",
    "plan_run",
    "run_up",
]


async def run_up(cfg: UpConfig, plan: Plan | None = None) -> UpResult:
    """:func:`formation.launch.launcher.run_up`, imported when a run starts: the launcher brings
    the collector (numpy, scipy), which a mistake on the command line need not wait for."""
    from formation.launch.launcher import run_up as run

    return await run(cfg, plan)


# ---------------------------------------------------------------------------------------------


def build_parser() -> argparse.ArgumentParser:
    """The ``formation up`` argument parser."""
    p = argparse.ArgumentParser(
        prog="formation up",
        description="Start router, plant, coordinator and one agent per robot as separate "
        "processes over Zenoh, show their status, and write metrics and figures at the end.",
    )
    p.add_argument(
        "--scenario",
        default="paper-exp2",
        help=f"built-in name ({', '.join(scenario_mod.builtin_names())}) or a TOML file",
    )
    p.add_argument(
        "--robots",
        type=int,
        default=None,
        metavar="N",
        help="grow (or cut) the formation to N slots by the paper's staged rule (Fig 2b) with "
        "robots r1..rN (default: the scenario's)",
    )
    p.add_argument(
        "--spares",
        type=int,
        default=0,
        metavar="K",
        help="add K idle hot spares behind the formation (robots = slots + K; default 0)",
    )
    p.add_argument(
        "--duration",
        type=positive_float,
        default=None,
        help="seconds to run: sim time in lockstep, wall time in realtime (default: scenario's)",
    )
    p.add_argument(
        "--lockstep", action="store_true", help="sim time advances when every process answered"
    )
    p.add_argument(
        "--lockstep-timeout",
        type=positive_float,
        default=None,
        metavar="S",
        help="lockstep: wall seconds the plant waits for a live node's answer before it goes "
        "on without it, which makes the run differ from formation sim's and is reported "
        "(default 2; raise it on a loaded machine; docs/runtime.md)",
    )
    p.add_argument(
        "--endpoint", default=DEFAULT_ENDPOINT, help=f"router endpoint (default {DEFAULT_ENDPOINT})"
    )
    p.add_argument("--fleet", default=keys.DEFAULT_FLEET, help="fleet name in the keys")
    p.add_argument("--out", type=Path, default=None, help="output folder (runs/up-<scenario>)")
    p.add_argument(
        "--seed", type=non_negative_int, default=None, help="override the scenario's seed"
    )
    p.add_argument("--no-figures", action="store_true", help="skip the PNG figures")
    p.add_argument("--quiet", action="store_true", help="print nothing but errors")
    p.add_argument(
        "--ready-timeout",
        type=positive_float,
        default=30.0,
        metavar="S",
        help="seconds each process gets to print its ready line (default 30)",
    )
    p.add_argument(
        "--standby", action="store_true", help="also run a hot-standby coordinator (docs/faults.md)"
    )
    p.add_argument(
        "--hosts",
        type=int,
        default=None,
        metavar="H",
        help="run the robots in H agent-host processes with the batched bus; 0: one agent "
        "process per robot (default: automatic, per-robot processes up to 4 robots per core, "
        "agent hosts beyond; docs/scale.md)",
    )
    p.add_argument(
        "--respawn",
        type=float,
        default=None,
        metavar="S",
        help="restart a dead agent (or coordinator, as a standby) S seconds after it died",
    )
    p.add_argument(
        "--lease-ms",
        type=int,
        default=LEASE_MS,
        metavar="MS",
        help=f"Zenoh lease of every node: a hung node is dead after this (default "
        f"{LEASE_MS}; 0: Zenoh's own, 10 s)",
    )
    p.add_argument(
        "--record",
        type=Path,
        default=None,
        metavar="FILE.mcap",
        help="record every key of the fleet and its liveliness to this MCAP file "
        "(then: formation report FILE.mcap)",
    )
    p.add_argument(
        "--foxglove",
        type=int,
        nargs="?",
        const=8765,
        default=None,
        metavar="PORT",
        help="serve a live Foxglove WebSocket (default port 8765; 0: any free port)",
    )
    p.add_argument(
        "--camera",
        choices=("emulated", "rendered"),
        default="emulated",
        help="poses from the plant's camera emulation (default) or from `formation camera` "
        "tracking rendered frames of the plant's truth (realtime only; docs/localization.md)",
    )
    p.add_argument(
        "--secure",
        action="store_true",
        help="authenticated run: ephemeral CA, one certificate per process, mutual TLS on the "
        "router and the access control generated from the contract; local tools find the "
        "credentials by themselves (docs/security.md)",
    )
    p.add_argument(
        "--ros2",
        action="store_true",
        help="also run `formation ros2`: the fleet as ROS 2 topics over rmw_zenoh, domain 0 "
        "(docs/ros2.md)",
    )
    p.add_argument(
        "--foxglove-host",
        default="127.0.0.1",
        metavar="HOST",
        help="address the Foxglove server binds (default 127.0.0.1; 0.0.0.0: every interface, "
        "no authentication)",
    )
    return p


def config_from_args(ns: argparse.Namespace) -> UpConfig:
    return UpConfig(
        scenario=ns.scenario,
        robots=ns.robots,
        spares=ns.spares,
        duration_s=ns.duration,
        lockstep=ns.lockstep,
        lockstep_timeout_s=ns.lockstep_timeout,
        endpoint=ns.endpoint,
        fleet=ns.fleet,
        out=ns.out,
        seed=ns.seed,
        figures=not ns.no_figures,
        quiet=ns.quiet,
        ready_timeout_s=ns.ready_timeout,
        record=ns.record,
        foxglove_port=ns.foxglove,
        foxglove_host=ns.foxglove_host,
        lease_ms=ns.lease_ms or None,
        standby=ns.standby,
        respawn_s=ns.respawn,
        hosts=ns.hosts,
        camera=ns.camera,
        secure=ns.secure,
        ros2=ns.ros2,
    )


def main(argv: list[str]) -> int:
    """Entry point of ``formation up`` (dispatched by ``formation.cli``)."""
    cfg = config_from_args(build_parser().parse_args(argv))
    if cfg.hosts is not None and not 0 <= cfg.hosts <= 256:
        print(f"formation up: --hosts: expected 0..256, got {cfg.hosts}", file=sys.stderr)
        return 2
    if cfg.lockstep_timeout_s is not None and not cfg.lockstep:
        print("formation up: --lockstep-timeout needs --lockstep", file=sys.stderr)
        return 2
    if cfg.camera == "rendered" and cfg.lockstep:
        print("formation up: --camera rendered runs in realtime only", file=sys.stderr)
        return 2
    if cfg.foxglove_port is not None and not 0 <= cfg.foxglove_port <= 65535:
        print(f"formation up: --foxglove: bad port {cfg.foxglove_port}", file=sys.stderr)
        return 2
    try:
        plan = plan_run(cfg)
    except (scenario_mod.ScenarioError, ValueError) as exc:
        print(f"formation up: {exc}", file=sys.stderr)
        return 2
    from formation.launch.fault_actions import check_layout

    why = check_layout(plan.scenario, lockstep=cfg.lockstep, hosts=plan.hosts, standby=cfg.standby)
    if why is not None:
        print(f"formation up: {why}", file=sys.stderr)
        return 2
    try:
        result = asyncio.run(run_up(cfg, plan))
    except KeyboardInterrupt:  # a second Ctrl-C while the results of a stopped run are written
        print("formation up: interrupted while writing the results", file=sys.stderr)
        return 130
    return result.exit_code
