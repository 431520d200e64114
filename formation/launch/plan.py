"""What a ``formation up`` run is: its options (:class:`UpConfig`), the validated plan
(:class:`Plan`: scenario, the ``--robots`` rewrite, duration, seed, settling time, output
directory) and its outcome (:class:`UpResult`). Planning starts nothing, so a bad scenario or
option exits with status 2 before any process exists."""

from __future__ import annotations

import math
import os
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final

import scenario as scenario_mod
from bus_schemas import keys
from bus_schemas.session import DEFAULT_ENDPOINT, LEASE_MS
from scenario import FleetShape, fleet_shape, scenario_with_robots, to_toml

PLANT_STATS: Final = "plant_stats.json"
"""The plant's ``--stats-out`` file in the run's folder: its status and latency statistics as it
exits (formation.launch.nodes; read by formation.launch.results.plant_account)."""
PER_ROBOT_PROCESSES_PER_CORE: Final = 4
"""Automatic agent hosts: one ``formation agent`` process per robot while the fleet has at most
this many robots per core of the machine (``os.cpu_count()``); beyond, agent hosts. One agent
process costs about 2-3 % of a core at 50 Hz and ~13 MiB plus a Python start, but every process
also adds a Zenoh session and a scheduling slot: on this 2-core machine 100 agent processes gave
pose->wheels p99 of 677-889 ms (issue 18) where one agent host gives ~6 ms (docs/scale.md)."""
ROBOTS_PER_HOST: Final = 300
"""Automatic agent hosts: robots one agent host is given at most (docs/scale.md: one host holds
300 robots at 50 Hz with p99 ~15 ms on this machine; it steps them one after another)."""


def auto_hosts(n_robots: int, cores: int | None = None) -> tuple[int, str]:
    """How many agent hosts ``formation up`` runs when ``--hosts`` is not given, and why.

    The rule (docs/scale.md): one process per robot (0 hosts) while ``n_robots <=``
    :data:`PER_ROBOT_PROCESSES_PER_CORE` ``x cores``; otherwise
    ``hosts = min(cores, ceil(n_robots /`` :data:`ROBOTS_PER_HOST` ``))``, at least 1 (more hosts
    than cores only compete with plant, coordinator and router for them). Returns
    ``(hosts, reason)``; ``reason`` is the one line the banner prints.
    """
    c = max(1, cores if cores is not None else (os.cpu_count() or 1))
    limit = PER_ROBOT_PROCESSES_PER_CORE * c
    if n_robots <= limit:
        return (
            0,
            f"automatic: {n_robots} robots <= {limit} ({PER_ROBOT_PROCESSES_PER_CORE} x {c} cores)",
        )
    hosts = max(1, min(c, math.ceil(n_robots / ROBOTS_PER_HOST)))
    return hosts, (
        f"automatic: {n_robots} robots > {limit} ({PER_ROBOT_PROCESSES_PER_CORE} x {c} cores), "
        f"{ROBOTS_PER_HOST} robots per host at most, at most one host per core; "
        "--hosts 0 forces one process per robot"
    )


class LaunchError(RuntimeError):
    """A child did not start, died or misbehaved; the message names it and says why."""


# ---------------------------------------------------------------------------------------------
# Configuration and plan
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class UpConfig:
    """Options of one ``formation up`` run (the CLI's, see :func:`build_parser`)."""

    scenario: str = "paper-exp2"
    robots: int | None = None  # formation slots (grown by the staged rule, Fig 2b)
    spares: int = 0  # idle hot spares beyond the slots (robots = slots + spares)
    duration_s: float | None = None
    lockstep: bool = False
    lockstep_timeout_s: float | None = None  # the plant's --lockstep-timeout (None: its 2 s)
    endpoint: str = DEFAULT_ENDPOINT
    fleet: str = keys.DEFAULT_FLEET
    out: Path | None = None
    seed: int | None = None
    figures: bool = True
    quiet: bool = False
    ready_timeout_s: float = 30.0
    display: str = "auto"  # "auto" (table on a TTY, lines otherwise), "table", "lines", "none"
    record: Path | None = None  # MCAP file to record the run's bus traffic to
    foxglove_port: int | None = None  # serve a live Foxglove WebSocket on this port (0: any)
    foxglove_host: str = "127.0.0.1"
    lease_ms: int | None = LEASE_MS  # Zenoh lease of every node (hang detection)
    standby: bool = False  # run a second, hot-standby coordinator
    respawn_s: float | None = None  # restart a dead agent after this delay (None: never)
    hosts: int | None = None  # agent hosts (batched bus); 0: one process per robot; None: auto
    camera: str = "emulated"  # "rendered": formation camera tracks rendered frames (realtime)
    secure: bool = False  # mTLS + access control, per-process identities (docs/security.md)
    ros2: bool = False  # also run `formation ros2`: the fleet on ROS 2 (docs/ros2.md)


@dataclass(frozen=True)
class Plan:
    """What will run: the validated scenario and the arguments derived from the config."""

    scenario: scenario_mod.Scenario
    scenario_arg: str  # what every node gets as --scenario (a built-in name or a file)
    scenario_toml: str | None  # the rewritten scenario to write into out_dir, if any
    duration_s: float
    seed: int
    settle_s: float
    out_dir: Path
    hosts: int = 0  # agent-host processes (0: one agent process per robot)
    hosts_reason: str = "--hosts"  # why (the banner's line): "--hosts" or auto_hosts' reason
    shape: FleetShape | None = None  # slots, robots, spares, stages

    def banner(self) -> str:
        """One line saying what the fleet is and which processes run it."""
        n = len(self.scenario.robot_ids)
        shape = self.shape.describe() if self.shape is not None else f"{n} robots"
        if self.hosts > 0:
            procs = f"{self.hosts} agent host{'s' if self.hosts > 1 else ''} (batched bus)"
        else:
            procs = f"{n} agent process{'es' if n > 1 else ''}"
        return f"fleet: {shape}; robots run in {procs} [{self.hosts_reason}]"


@dataclass
class UpResult:
    """Outcome of :func:`run_up`."""

    exit_code: int
    out_dir: Path
    metrics: dict[str, Any] | None = None
    failures: list[str] = field(default_factory=list)
    interrupted: bool = False
    wall_s: float = 0.0
    run_wall_s: float | None = None  # from the first to the last truth frame received


MAX_DURATION_S = 1e6  # the bound of a scenario file's duration_s


def busy_endpoint(endpoint: str) -> str | None:
    """Why the router cannot listen on a local TCP ``endpoint`` (one line), or None.

    ``formation up`` starts its own router on ``--endpoint``; checking the port first turns a
    busy port into one line before anything starts (not the router's Zenoh error).
    """
    import socket

    proto, _, addr = endpoint.partition("/")
    host, _, port_text = addr.rpartition(":")
    host = host.strip("[]")
    if proto != "tcp" or not port_text.isdigit() or host not in ("127.0.0.1", "localhost", "::1"):
        return None
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    with socket.socket(family, socket.SOCK_STREAM) as s:
        try:
            s.bind((host, int(port_text)))
        except OSError as exc:
            return (
                f"--endpoint {endpoint}: port busy ({exc.strerror}); is another `formation up` "
                "or `formation router` running? stop it or pass another --endpoint"
            )
    return None


def plan_run(cfg: UpConfig) -> Plan:
    """Validate the config and the scenario; raise ``ScenarioError``/``ValueError`` (exit 2)."""
    keys.check_fleet(cfg.fleet)
    from runtime.transport import ZenohSettings

    ZenohSettings(connect=(cfg.endpoint,))  # validates the endpoint's shape
    if cfg.duration_s is not None and not (cfg.duration_s > 0 and math.isfinite(cfg.duration_s)):
        raise ValueError(f"--duration must be positive, got {cfg.duration_s}")
    if cfg.duration_s is not None and cfg.duration_s > MAX_DURATION_S:
        raise ValueError(f"--duration: {cfg.duration_s:g} s is more than {MAX_DURATION_S:g} s")
    port_busy = busy_endpoint(cfg.endpoint)
    if port_busy is not None:
        raise ValueError(port_busy)
    if cfg.seed is not None and cfg.seed < 0:
        raise ValueError(f"--seed must be >= 0, got {cfg.seed}")
    path = scenario_mod.resolve(cfg.scenario)
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))  # TOML is UTF-8, whatever the locale
    except tomllib.TOMLDecodeError as exc:
        raise scenario_mod.ScenarioError(f"{path}: not valid TOML: {exc}") from exc
    scenario_arg = cfg.scenario if path.parent == scenario_mod.SCENARIO_DIR else str(path.resolve())
    toml_text: str | None = None
    if cfg.robots is not None or cfg.spares:
        data = scenario_with_robots(data, cfg.robots, cfg.spares)
        toml_text = to_toml(data)
    scn = scenario_mod.parse(data, source=str(path))
    from scenario.check import check_cores

    check_cores(scn)  # trajectory/formation tables: one ScenarioError, before anything starts
    n = len(scn.robot_ids)
    if cfg.hosts is None:
        hosts, reason = auto_hosts(n)
    elif not 0 <= cfg.hosts <= 256:
        raise ValueError(f"--hosts: expected 0..256, got {cfg.hosts}")
    else:
        hosts, reason = min(cfg.hosts, n), f"--hosts {cfg.hosts}"
    try:
        shape: FleetShape | None = fleet_shape(scn.formation, n)
    except (KeyError, TypeError, ValueError):
        shape = None
    out_dir = cfg.out if cfg.out is not None else Path("runs") / f"up-{scn.name}"
    if toml_text is not None:
        scenario_arg = str((out_dir / "scenario.toml").resolve())
    duration = cfg.duration_s if cfg.duration_s is not None else scn.duration_s
    from formation.outputs.metrics import settle_for  # numpy: only when a run is planned

    settle = settle_for(scn.settle_s, duration)
    return Plan(
        scenario=scn,
        scenario_arg=scenario_arg,
        scenario_toml=toml_text,
        duration_s=duration,
        seed=scn.seed if cfg.seed is None else cfg.seed,
        settle_s=settle,
        out_dir=out_dir,
        hosts=hosts,
        hosts_reason=reason,
        shape=shape,
    )


# ---------------------------------------------------------------------------------------------
# Children
