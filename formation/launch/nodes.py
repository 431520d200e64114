"""What ``formation up`` starts: the router's and every node's command line, the run's bus
identities and (``--secure``) its certificates. Pure apart from :func:`make_secure`, which writes
the run's configs; :mod:`formation.launch.launcher` spawns what this module describes."""

from __future__ import annotations

import os
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any

from bus_schemas.session import LEASE_MS
from formation.launch.plan import PLANT_STATS, LaunchError, Plan, UpConfig

NodeCommand = tuple[str, list[str], str]
"""(child name, ``formation`` arguments, ready-line prefix)."""


def host_parts(robot_ids: list[str], hosts: int) -> list[tuple[str, list[str]]]:
    """Agent hosts ``h1..hN``, each with a contiguous share of the robots (none if hosts <= 0)."""
    if hosts <= 0:
        return []
    h = min(hosts, len(robot_ids))
    n = len(robot_ids)
    return [(f"h{k + 1}", robot_ids[k * n // h : (k + 1) * n // h]) for k in range(h)]


def identities(cfg: UpConfig, plan: Plan) -> list[Any]:
    """The identities of this run (bus_schemas.acl): one per process kind, robot and host."""
    from bus_schemas import acl

    out = [acl.Identity(acl.Kind.PLANT), acl.coordinator("main")]
    if cfg.standby:
        out.append(acl.coordinator("standby"))
    if cfg.camera == "rendered":
        out.append(acl.Identity(acl.Kind.LOCALIZATION))
    for name, part in host_parts(list(plan.scenario.robot_ids), plan.hosts):
        out.append(acl.agent_host(name, part))
    if plan.hosts <= 0:
        out += [acl.robot(rid) for rid in plan.scenario.robot_ids]
    out += [acl.Identity(acl.Kind.OPERATOR), acl.Identity(acl.Kind.OBSERVER)]
    if cfg.ros2:  # the ROS 2 bridge has its own identity (bus_schemas.ros2.graph)
        out.append(acl.Identity(acl.Kind.ROS2))
    return out


def router_args(endpoint: str, secure: Any) -> list[str]:
    """The router's ``formation`` arguments (``secure``: a launch.pki.RunConfigs or None)."""
    if secure is None:
        return ["router", "--listen", endpoint]
    return ["router", "--zenoh-config", str(secure.router)]


def node_commands(
    cfg: UpConfig, plan: Plan, bus_args: Callable[[str], list[str]]
) -> list[NodeCommand]:
    """Every node of the run, in start order; ``bus_args(identity)`` says how a node joins the
    bus (``--endpoint EP`` or, with ``--secure``, its identity's client config)."""
    scn, fleet, scn_arg = plan.scenario, cfg.fleet, plan.scenario_arg
    base = ["--fleet", fleet]
    if cfg.lease_ms is not None:
        base += ["--lease-ms", str(cfg.lease_ms)]

    def common_of(cn: str) -> list[str]:
        return [*bus_args(cn), *base]

    lock = ["--lockstep"] if cfg.lockstep else []
    plant = [
        "plant", "--scenario", scn_arg, "--seed", str(plan.seed),
        "--duration", repr(plan.duration_s), "--wait-robots", *lock, *common_of("plant"),
    ]  # fmt: skip
    # the plant's control-loop latency statistics (realtime: pose frame -> wheel command
    # computed from it, docs/scale.md), written when it exits (bench/bench_up.py reads them)
    plant += ["--stats-out", str(plan.out_dir.resolve() / PLANT_STATS)]
    if cfg.lockstep_timeout_s is not None:
        plant += ["--lockstep-timeout", repr(cfg.lockstep_timeout_s)]
    batch = ["--batch"] if plan.hosts > 0 else []
    plant += batch
    coord = [
        "coordinator", "--scenario", scn_arg, "--name", "main", *batch, *lock,
        *common_of("coordinator.main"),
    ]  # fmt: skip
    out = [("plant", plant, "plant ready"), ("coordinator", coord, "coordinator ready")]
    if cfg.camera == "rendered":  # docs/localization.md: the real tracker in the loop
        from localization.core.rendered import scenario_camera_args

        plant.append("--no-poses")
        cam = scenario_camera_args(
            scn.robot_ids, scn.initial, scn.trajectory,
            float(scn.formation.get("b_m", 0.4)), plan.duration_s,
            str(plan.out_dir / "camera.toml"),
        )  # fmt: skip
        out.insert(1, ("camera", ["camera", *cam, *common_of("localization")], "camera ready"))
    if cfg.ros2:  # docs/ros2.md: the fleet as a ROS 2 node graph, as its own identity
        out.append(("ros2", ["ros2", *common_of("ros2")], "ros2 bridge ready"))
    if cfg.standby:
        standby = [
            "coordinator", "--scenario", scn_arg, "--name", "standby", "--standby",
            *batch, *lock, *common_of("coordinator.standby"),
        ]  # fmt: skip
        out.append(("coordinator-standby", standby, "coordinator ready"))
    if plan.hosts > 0:  # agent hosts, each running a contiguous share of the robots
        for name, part in host_parts(list(scn.robot_ids), plan.hosts):
            host = [
                "agent-host", "--ids", ",".join(part), "--name", name, "--scenario", scn_arg,
                *lock, *common_of(f"host.{name}"),
            ]  # fmt: skip
            out.append((f"agent-host-{name}", host, f"agent-host {name} ready"))
        return out
    for rid in scn.robot_ids:
        agent = ["agent", "--id", rid, "--scenario", scn_arg, *lock, *common_of(f"robot.{rid}")]
        out.append((f"agent-{rid}", agent, f"agent {rid} ready"))
    return out


def make_secure(cfg: UpConfig, plan: Plan) -> tuple[Any, Path]:
    """``--secure``: an ephemeral CA, one certificate per identity, the router's mTLS config
    with the access control generated from the contract, one client config per identity,
    all in a 0700 directory of this user (formation.outputs.runfile); the CA's private key is
    deleted as soon as the certificates are issued (no more can be signed).

    Returns (formation.launch.pki.RunConfigs, the directory to remove when the run ends)."""
    from formation.launch import pki as pki_mod
    from formation.outputs.runfile import endpoint_port, runtime_dir

    port = endpoint_port(cfg.endpoint)
    if port is None:
        raise LaunchError(f"--secure needs a loopback endpoint, got {cfg.endpoint}")
    try:
        for old in runtime_dir().glob("secure-*-*"):  # left by a SIGKILLed launcher
            pid = old.name.rsplit("-", 1)[-1]
            if pid.isdigit() and not Path(f"/proc/{pid}").exists():
                shutil.rmtree(old, ignore_errors=True)
        secure_dir = runtime_dir() / f"secure-{port}-{os.getpid()}"
        secure = pki_mod.write_run_configs(
            secure_dir,
            identities(cfg, plan),
            port=port,
            fleet=cfg.fleet,
            lease_ms=cfg.lease_ms or LEASE_MS,
        )
        (secure.pki.root / "ca" / "ca.key").unlink()
    except OSError as exc:
        raise LaunchError(f"--secure: cannot write the run's certificates: {exc}") from exc
    return secure, secure_dir
