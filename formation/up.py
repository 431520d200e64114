"""``formation up``: start the whole distributed system locally, watch it, measure it.

Usage::

    formation up [--scenario NAME|FILE] [--robots N] [--duration S] [--lockstep]
                 [--endpoint tcp/127.0.0.1:7447] [--fleet F] [--out DIR] [--seed N]
                 [--no-figures] [--quiet] [--record FILE.mcap] [--foxglove [PORT]]
                 [--standby] [--respawn S] [--lease-ms MS] [--hosts H]

Theory of operation
-------------------
1. **Plan.** The scenario is loaded and validated (a bad one exits with status 2 before anything
   starts). ``--robots N`` rewrites it with ids ``r1..rN`` (start poses kept for the first robots,
   new ones placed on their formation slots, chevron/lattice formations resized to N slots) and
   writes it to ``<out>/scenario.toml``, which every process then loads.
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
   node would force its exit).
3. **Collect.** Right after the last spawn the launcher opens its client session and subscribes
   a :class:`formation.collector.RunCollector` to truth, leader, slots, assignment, wheels,
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
   (``--standby``; it is respawned as a standby). Any other child that exits ends the run as a
   failure. Every node gets ``--lease-ms`` (default 700): a hung node's tokens vanish within 1 s.
5. **Stop.** SIGTERM to plant, coordinator and agents, at most 2 s wait, then SIGKILL (said on
   stderr); the launcher's session is closed; then the router gets the same treatment. SIGINT or
   SIGTERM to the launcher starts this at once; a second one kills everything immediately.
   With ``--record FILE`` a :mod:`formation.record` recorder subscribes on the launcher's session
   right after the collector (so before the plant's clock starts) and writes every key of the
   fleet and its liveliness changes to the MCAP file, with the run's scenario, mode and settling
   time as metadata; ``formation report FILE`` rebuilds this run's metrics from it. With
   ``--foxglove [PORT]`` (default 8765) a :mod:`formation.live` Foxglove WebSocket server is fed
   from the same session (line ``foxglove live view on ws://HOST:PORT``). Both are closed before
   the launcher's session (the recording is finalized even after an interrupt).
6. **Results.** ``metrics.json`` (``formation.metrics.compute`` on the RunLog built from truth),
   ``run.npz`` and the figures (``formation.figures.write_all``) in ``--out``. Exit status: 0,
   1 if a child failed (did not start, died, exited non-zero, had to be killed), 130 after an
   interrupt (then figures are skipped, metrics of the partial run are still written), 2 for bad
   arguments.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import copy
import json
import math
import os
import re
import signal
import sys
import time
import tomllib
from collections import deque
from collections.abc import Awaitable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final, TextIO

from bus_schemas import keys
from formation import scenario as scenario_mod
from formation.collector import LiveView, RunCollector, key_patterns

__all__ = [
    "LaunchError",
    "Plan",
    "UpConfig",
    "UpResult",
    "build_parser",
    "main",
    "plan_run",
    "run_up",
    "scenario_with_robots",
    "to_toml",
]

REPO_ROOT: Final = Path(__file__).resolve().parents[1]
DEFAULT_ENDPOINT: Final = "tcp/127.0.0.1:7447"
STOP_PATIENCE_S: Final = 2.0
"""How long a child gets between SIGTERM and SIGKILL, seconds."""
DRAIN_S: Final = 0.25
"""Lockstep: time given to the last messages in flight after the plant ended, seconds."""
REALTIME_END_GRACE_S: Final = 1.5
"""Realtime: how long after --duration the launcher stops a plant that did not end the run."""
FIFO_CAPACITY: Final = 1 << 18
"""Samples Zenoh buffers per subscription for the collector (drained every CONSUME_PERIOD_S)."""
CONSUME_PERIOD_S: Final = 0.02
TABLE_PERIOD_S: Final = 0.5
LINE_PERIOD_S: Final = 5.0
EXIT_INTERRUPTED: Final = 130
DEFAULT_LEASE_MS: Final = 700
"""Zenoh lease every node announces: a hung (SIGSTOPped) node's tokens vanish ~0.7 s after it
stopped, inside issue 4's 1 s (keep-alives every lease/4 = 175 ms, sent by Zenoh's own threads,
so a busy Python loop does not expire it)."""


class LaunchError(RuntimeError):
    """A child did not start, died or misbehaved; the message names it and says why."""


class _Interrupted(Exception):
    """The launcher was asked to stop (SIGINT/SIGTERM)."""


# ---------------------------------------------------------------------------------------------
# Configuration and plan
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class UpConfig:
    """Options of one ``formation up`` run (the CLI's, see :func:`build_parser`)."""

    scenario: str = "paper-exp2"
    robots: int | None = None
    duration_s: float | None = None
    lockstep: bool = False
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
    lease_ms: int | None = DEFAULT_LEASE_MS  # Zenoh lease of every node (hang detection)
    standby: bool = False  # run a second, hot-standby coordinator
    respawn_s: float | None = None  # restart a dead agent after this delay (None: never)
    hosts: int = 0  # > 0: that many agent-host processes run the robots, batched bus (scale)
    camera: str = "emulated"  # "rendered": formation camera tracks rendered frames (realtime)


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


# --- TOML output (tomllib only reads) --------------------------------------------------------

_BARE_KEY = re.compile(r"[A-Za-z0-9_-]+")


def _toml_str(s: str) -> str:
    out = ['"']
    for ch in s:
        if ch in '"\\':
            out.append("\\" + ch)
        elif ord(ch) < 0x20 or ord(ch) == 0x7F:
            out.append(f"\\u{ord(ch):04x}")
        else:
            out.append(ch)
    out.append('"')
    return "".join(out)


def _toml_key(k: str) -> str:
    return k if _BARE_KEY.fullmatch(k) else _toml_str(k)


def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return repr(v)  # 0.1, 1e-05, inf, nan: all valid TOML floats
    if isinstance(v, str):
        return _toml_str(v)
    if isinstance(v, Mapping):
        return (
            "{" + ", ".join(f"{_toml_key(str(k))} = {_toml_value(x)}" for k, x in v.items()) + "}"
        )
    if isinstance(v, list | tuple):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    raise TypeError(f"cannot write {type(v).__name__} {v!r} as TOML")


def _is_table_array(v: Any) -> bool:
    return isinstance(v, list) and bool(v) and all(isinstance(x, Mapping) for x in v)


def _write_table(
    lines: list[str], table: Mapping[str, Any], path: tuple[str, ...], header: str
) -> None:
    if header:
        lines.append("")
        lines.append(header)
    for k, v in table.items():
        if not isinstance(v, Mapping) and not _is_table_array(v):
            lines.append(f"{_toml_key(k)} = {_toml_value(v)}")
    for k, v in table.items():
        sub = (*path, k)
        dotted = ".".join(_toml_key(p) for p in sub)
        if isinstance(v, Mapping):
            _write_table(lines, v, sub, f"[{dotted}]")
        elif _is_table_array(v):
            for item in v:
                _write_table(lines, item, sub, f"[[{dotted}]]")


def to_toml(data: Mapping[str, Any]) -> str:
    """``data`` (str keys; bool, int, float, str, lists, tables) as TOML text.

    Raises ValueError if the text would not read back as ``data`` (never silently changes it).
    """
    lines: list[str] = []
    _write_table(lines, data, (), "")
    text = "\n".join(lines).lstrip("\n") + "\n"
    if tomllib.loads(text) != data:
        raise ValueError("scenario does not survive a TOML round trip")
    return text


# --- scenario rewriting -----------------------------------------------------------------------


def _robot_ids(robots: Mapping[str, Any]) -> list[str]:
    if "ids" in robots:
        return [str(r) for r in robots["ids"]]
    return [f"r{i + 1}" for i in range(int(robots.get("count", 0)))]


def _slot_poses(data: Mapping[str, Any]) -> list[tuple[float, float, float]]:
    """Axle-centre poses that put each robot's reference point on a slot at t = 0, in slot
    definition order (the reference point is ``ref_offset_m`` ahead of the axle, eqs 10-11)."""
    from coordinator.formation import FormationSpec, slot_states
    from coordinator.trajectory import make_trajectory

    traj = dict(data["trajectory"])
    kind = str(traj.pop("kind"))
    leader = make_trajectory(kind, traj).sample(0.0)
    spec = FormationSpec.from_dict(dict(data["formation"]))
    l_m = float(data.get("geometry", {}).get("ref_offset_m", 0.05))
    return [
        (s.x - l_m * math.cos(s.theta), s.y - l_m * math.sin(s.theta), s.theta)
        for s in slot_states(spec, leader)
    ]


def scenario_with_robots(data: Mapping[str, Any], n: int) -> dict[str, Any]:
    """A copy of the scenario table ``data`` with robots ``r1..rN``.

    Robots that existed keep their start pose; new ones start on their slot (robot ``rK`` on the
    K-th slot of the formation, in definition order) or, beyond the last slot, in rows 0.5 m
    behind the formation, 0.4 m apart. A chevron or lattice formation gets ``n`` slots; a
    disturbance of a robot that no longer exists is dropped.
    """
    if n < 1:
        raise scenario_mod.ScenarioError(f"--robots: need at least 1 robot, got {n}")
    out = copy.deepcopy(dict(data))
    robots = dict(out.get("robots", {}))
    old_ids = _robot_ids(robots)
    old_initial = robots.get("initial")
    ids = [f"r{i + 1}" for i in range(n)]
    formation = dict(out.get("formation", {}))
    if formation.get("kind") in ("chevron", "lattice"):
        if isinstance(formation.get("params"), Mapping):
            formation["params"] = {**formation["params"], "n": n}
        else:
            formation["n"] = n
        out["formation"] = formation
    try:
        slot_poses = _slot_poses(out)
    except (KeyError, TypeError, ValueError) as exc:
        raise scenario_mod.ScenarioError(f"--robots: cannot place new robots: {exc}") from exc
    # rows behind the formation, in the leader's frame
    leader_x, leader_y, heading = slot_poses[0] if slot_poses else (0.0, 0.0, 0.0)
    c, s = math.cos(heading), math.sin(heading)
    rear = min(((x - leader_x) * c + (y - leader_y) * s for x, y, _ in slot_poses), default=0.0)
    initial: list[list[float]] = []
    for i, rid in enumerate(ids):
        if isinstance(old_initial, list) and i < len(old_initial) and old_ids[i : i + 1] == [rid]:
            initial.append([float(v) for v in old_initial[i]])
        elif i < len(slot_poses):
            initial.append([round(v, 6) for v in slot_poses[i]])
        else:
            extra = i - len(slot_poses)
            row, col = divmod(extra, 5)
            back = rear - 0.5 * (row + 1)
            side = 0.4 * (col - 2)
            initial.append(
                [
                    round(leader_x + back * c - side * s, 6),
                    round(leader_y + back * s + side * c, 6),
                    round(heading, 6),
                ]
            )
    out["robots"] = {"ids": ids, "initial": initial}
    if "disturbance" in out:
        kept = [d for d in out["disturbance"] if d.get("robot") in ids]
        if kept:
            out["disturbance"] = kept
        else:
            del out["disturbance"]
    return out


def plan_run(cfg: UpConfig) -> Plan:
    """Validate the config and the scenario; raise ``ScenarioError``/``ValueError`` (exit 2)."""
    keys.check_fleet(cfg.fleet)
    from bus_schemas.transport import ZenohSettings

    ZenohSettings(connect=(cfg.endpoint,))  # validates the endpoint's shape
    if cfg.duration_s is not None and not (cfg.duration_s > 0 and math.isfinite(cfg.duration_s)):
        raise ValueError(f"--duration must be positive, got {cfg.duration_s}")
    if cfg.seed is not None and cfg.seed < 0:
        raise ValueError(f"--seed must be >= 0, got {cfg.seed}")
    path = scenario_mod.resolve(cfg.scenario)
    try:
        data = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as exc:
        raise scenario_mod.ScenarioError(f"{path}: not valid TOML: {exc}") from exc
    scenario_arg = cfg.scenario if path.parent == scenario_mod.SCENARIO_DIR else str(path.resolve())
    toml_text: str | None = None
    if cfg.robots is not None:
        data = scenario_with_robots(data, cfg.robots)
        toml_text = to_toml(data)
    scn = scenario_mod.parse(data, source=str(path))
    out_dir = cfg.out if cfg.out is not None else Path("runs") / f"up-{scn.name}"
    if toml_text is not None:
        scenario_arg = str((out_dir / "scenario.toml").resolve())
    duration = cfg.duration_s if cfg.duration_s is not None else scn.duration_s
    from formation.metrics import settle_for  # numpy: only when a run is planned

    settle = settle_for(scn.settle_s, duration)
    return Plan(
        scenario=scn,
        scenario_arg=scenario_arg,
        scenario_toml=toml_text,
        duration_s=duration,
        seed=scn.seed if cfg.seed is None else cfg.seed,
        settle_s=settle,
        out_dir=out_dir,
    )


# ---------------------------------------------------------------------------------------------
# Children
# ---------------------------------------------------------------------------------------------


def _child_env() -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(REPO_ROOT), env.get("PYTHONPATH")) if p)
    env["PYTHONUNBUFFERED"] = "1"
    return env


def _tail(path: Path, lines: int = 12) -> str:
    try:
        text = path.read_text(errors="replace")
    except OSError:
        return "(no stderr log)"
    tail = text.rstrip("\n").splitlines()[-lines:]
    return "\n".join("    " + line for line in tail) if tail else "    (stderr empty)"


class _Child:
    """One node process: spawn, ready line, stdout drain, stop."""

    def __init__(
        self, name: str, args: Sequence[str], ready: str, log_dir: Path, generation: int = 0
    ) -> None:
        self.name = name
        self.generation = generation  # respawns of this node (--respawn)
        self.argv = [sys.executable, "-m", "formation", *args]
        self.ready_prefix = ready
        suffix = f".{generation}" if generation else ""
        self.log_path = log_dir / f"{name}{suffix}.log"
        self.out_path = log_dir / f"{name}{suffix}.out"
        self.proc: asyncio.subprocess.Process | None = None
        self.ready_s: float | None = None
        self.started_s = 0.0
        self.stop_sent = False
        self.killed = False
        self._out: TextIO | None = None
        self._drain: asyncio.Task[None] | None = None
        self.stdout_tail: deque[str] = deque(maxlen=20)

    @property
    def pid(self) -> int | None:
        return None if self.proc is None else self.proc.pid

    @property
    def returncode(self) -> int | None:
        return None if self.proc is None else self.proc.returncode

    async def spawn(self, env: Mapping[str, str], process_group: int) -> None:
        with open(self.log_path, "wb") as err:
            self.proc = await asyncio.create_subprocess_exec(
                *self.argv,
                stdin=asyncio.subprocess.DEVNULL,
                stdout=asyncio.subprocess.PIPE,
                stderr=err,
                env=dict(env),
                cwd=os.getcwd(),
                process_group=process_group,
            )
        self.started_s = time.monotonic()
        self._out = open(self.out_path, "w", encoding="utf-8")  # noqa: SIM115 (closed in close())

    def _record(self, line: str) -> None:
        self.stdout_tail.append(line)
        if self._out is not None:
            self._out.write(line + "\n")
            self._out.flush()

    def _failure(self, what: str) -> LaunchError:
        return LaunchError(
            f"{self.name} (pid {self.pid}, `{' '.join(self.argv[2:])}`) {what}; "
            f"stderr ({self.log_path}):\n{_tail(self.log_path)}"
        )

    async def wait_ready(self, timeout_s: float) -> None:
        """Read stdout until the ready line; raise LaunchError on exit or timeout."""
        assert self.proc is not None and self.proc.stdout is not None
        stdout = self.proc.stdout
        deadline = self.started_s + timeout_s
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                raise self._failure(f"printed no {self.ready_prefix!r} line within {timeout_s} s")
            try:
                raw = await asyncio.wait_for(stdout.readline(), timeout=left)
            except TimeoutError:
                continue
            if not raw:
                rc = await self.proc.wait()
                raise self._failure(f"exited with status {rc} before it was ready")
            line = raw.decode(errors="replace").rstrip("\r\n")
            self._record(line)
            if line.startswith(self.ready_prefix):
                self.ready_s = time.monotonic() - self.started_s
                self._drain = asyncio.ensure_future(self._drain_stdout())
                return

    async def _drain_stdout(self) -> None:
        assert self.proc is not None and self.proc.stdout is not None
        while raw := await self.proc.stdout.readline():
            self._record(raw.decode(errors="replace").rstrip("\r\n"))

    def signal(self, sig: int) -> None:
        if self.proc is not None and self.proc.returncode is None:
            with contextlib.suppress(ProcessLookupError):
                self.proc.send_signal(sig)

    async def stop(self, patience_s: float = STOP_PATIENCE_S) -> str | None:
        """SIGTERM, wait ``patience_s``, SIGKILL. Returns a problem description, or None."""
        if self.proc is None:
            return None
        if self.proc.returncode is None:
            self.stop_sent = True
            self.signal(signal.SIGTERM)
            try:
                await asyncio.wait_for(self.proc.wait(), timeout=patience_s)
            except TimeoutError:
                state = _process_state(self.proc.pid)
                self.killed = True
                self.signal(signal.SIGKILL)
                await self.proc.wait()
                return (
                    f"{self.name} (pid {self.pid}) did not exit {patience_s} s after SIGTERM: "
                    f"killed ({state})"
                )
        rc = self.proc.returncode
        if self.stop_sent and rc not in (0, -signal.SIGTERM):
            return f"{self.name} exited with status {rc} after SIGTERM (expected 0)"
        return None

    async def close(self) -> None:
        if self._drain is not None:
            with contextlib.suppress(asyncio.TimeoutError, asyncio.CancelledError):
                await asyncio.wait_for(self._drain, timeout=0.5)
        if self._out is not None:
            self._out.close()
            self._out = None


def _process_state(pid: int) -> str:
    """What a process is doing, from /proc: its state and its threads' kernel wait channels
    (e.g. ``state S, 9 threads: futex_wait_queue x8, do_epoll_wait x1``), for a stuck child."""
    try:
        raw = Path(f"/proc/{pid}/stat").read_text(errors="replace")
        state = raw[raw.rfind(")") + 2 :].split()[0]
        waits: dict[str, int] = {}
        tids = os.listdir(f"/proc/{pid}/task")
        for tid in tids:
            try:
                wchan = Path(f"/proc/{pid}/task/{tid}/wchan").read_text().strip() or "running"
            except OSError:
                continue
            waits[wchan] = waits.get(wchan, 0) + 1
    except OSError:
        return "gone"
    detail = ", ".join(f"{w} x{n}" for w, n in sorted(waits.items(), key=lambda kv: -kv[1]))
    return f"state {state}, {len(tids)} threads: {detail}"


async def _all_or_first_error(aws: Iterable[Awaitable[Any]]) -> None:
    """Await all of ``aws``; on the first exception cancel the rest and raise it."""
    tasks = [asyncio.ensure_future(a) for a in aws]
    try:
        done, _ = await asyncio.wait(tasks, return_when=asyncio.FIRST_EXCEPTION)
        for t in done:
            if t.exception() is not None:
                raise t.exception()  # type: ignore[misc]
    finally:
        for t in tasks:
            if not t.done():
                t.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)


def _group_members(pgid: int) -> list[int]:
    """Live (non-zombie) processes of process group ``pgid``, from /proc."""
    found = []
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/stat", encoding="ascii", errors="replace") as f:
                raw = f.read()
        except OSError:
            continue
        fields = raw[raw.rfind(")") + 2 :].split()
        if fields[0] not in ("Z", "X") and int(fields[2]) == pgid:
            found.append(int(entry))
    return found


# ---------------------------------------------------------------------------------------------
# Display
# ---------------------------------------------------------------------------------------------


def _fmt_opt(v: Any, fmt: str = "{}", none: str = "-") -> str:
    return none if v is None else fmt.format(v)


def format_table(view: LiveView, header: str, speed: float | None) -> list[str]:
    """The live status table as lines (no terminal control codes)."""
    t = _fmt_opt(view.t_s, "{:7.2f} s")
    sp = f"  {speed:5.1f}x real time" if speed is not None and math.isfinite(speed) else ""
    lines = [
        header,
        f"t {t}{sp}   leader {view.leader or '-'}   min distance "
        f"{_fmt_opt(view.min_distance_m, '{:.3f} m')}   rejected by collector {view.rejected}",
        f"{'robot':<8}{'alive':<7}{'slot':>5}  {'role':<10}{'mode':<10}{'error (cm)':>11}"
        f"{'power R/L (%)':>16}{'rejected':>10}",
    ]
    for r in view.robots:
        alive = {True: "yes", False: "NO", None: "?"}[r.alive]
        err = _fmt_opt(None if r.error_m is None else r.error_m * 100, "{:.2f}")
        power = "-" if r.power is None else f"{r.power[0] * 100:5.1f}/{r.power[1] * 100:5.1f}"
        lines.append(
            f"{r.robot:<8}{alive:<7}{_fmt_opt(r.slot):>5}  {_fmt_opt(r.role):<10}"
            f"{_fmt_opt(r.mode):<10}{err:>11}"
            f"{power:>16}{_fmt_opt(r.rejected):>10}"
        )
    return lines


def format_line(view: LiveView, speed: float | None) -> str:
    """One-line summary of the live view (for logs and pipes)."""
    errs = [r.error_m for r in view.robots if r.error_m is not None]
    modes: dict[str, int] = {}
    for r in view.robots:
        modes[r.mode or "?"] = modes.get(r.mode or "?", 0) + 1
    sp = f" ({speed:.1f}x)" if speed is not None and math.isfinite(speed) else ""
    return (
        f"t {_fmt_opt(view.t_s, '{:.2f} s')}{sp}  leader {view.leader or '-'}  "
        f"max error {_fmt_opt(max(errs) * 100 if errs else None, '{:.2f} cm')}  "
        f"min distance {_fmt_opt(view.min_distance_m, '{:.3f} m')}  "
        f"modes {' '.join(f'{k}:{v}' for k, v in sorted(modes.items()))}"
    )


# ---------------------------------------------------------------------------------------------
# The launcher
# ---------------------------------------------------------------------------------------------


class _Launcher:
    def __init__(self, cfg: UpConfig, plan: Plan) -> None:
        self.cfg = cfg
        self.plan = plan
        self.scn = plan.scenario
        self.out_dir = plan.out_dir
        self.log_dir = plan.out_dir / "logs"
        self.stop = asyncio.Event()
        self.kill_now = False
        self.signals: list[int] = []
        self.failures: list[str] = []
        self.collector = RunCollector.for_scenario(self.scn, fleet=cfg.fleet, lockstep=cfg.lockstep)
        self.router: _Child | None = None
        self.nodes: list[_Child] = []
        self.retired: list[_Child] = []  # dead nodes replaced by a respawn
        self.events: list[dict[str, Any]] = []  # deaths and respawns during the run
        self.session: Any = None
        self.first_truth_rx: float | None = None
        self.last_truth_rx: float | None = None
        self._subscribers: list[Any] = []
        display = cfg.display
        if cfg.quiet:
            display = "none"
        elif display == "auto":
            display = "table" if sys.stdout.isatty() else "lines"
        self.display = display
        self._table_lines = 0
        self.stop_s: float | None = None
        self.recorder: Any = None  # formation.record.RecorderHandle with --record
        self.live: Any = None  # formation.live.LiveHandle with --foxglove
        self.record_stats: Any = None

    # -- output ---------------------------------------------------------------------------------

    def say(self, text: str) -> None:
        if not self.cfg.quiet:
            self._clear_table()
            print(text, flush=True)

    def warn(self, text: str) -> None:
        self._clear_table()
        print(f"formation up: {text}", file=sys.stderr, flush=True)

    def _clear_table(self) -> None:
        if self._table_lines:
            sys.stdout.write(f"\x1b[{self._table_lines}F\x1b[J")
            sys.stdout.flush()
            self._table_lines = 0

    def _speed(self) -> float | None:
        view_t = self._sim_elapsed()
        if view_t is None or self.first_truth_rx is None or self.last_truth_rx is None:
            return None
        wall = self.last_truth_rx - self.first_truth_rx
        return view_t / wall if wall > 0.5 else None

    def _sim_elapsed(self) -> float | None:
        if not self.cfg.lockstep:
            return None
        first, last = self.collector.first_tick, self.collector.last_clock_tick
        if first is None or last is None:
            return None
        return (last - first) * self.scn.dt_s

    async def _display_loop(self) -> None:
        if self.display == "none":
            return
        mode = "lockstep" if self.cfg.lockstep else "realtime"
        header = (
            f"formation up: {self.scn.name}, {len(self.scn.robot_ids)} robots, {mode}, "
            f"fleet {self.cfg.fleet} on {self.cfg.endpoint}  (Ctrl-C stops)"
        )
        period = TABLE_PERIOD_S if self.display == "table" else LINE_PERIOD_S
        while True:
            await asyncio.sleep(period)
            view = self.collector.live()
            if self.display == "table":
                lines = format_table(view, header, self._speed())
                self._clear_table()
                sys.stdout.write("\n".join(lines) + "\n")
                sys.stdout.flush()
                self._table_lines = len(lines)
            else:
                print(format_line(view, self._speed()), flush=True)

    # -- signals --------------------------------------------------------------------------------

    def _on_signal(self, signum: int) -> None:
        self.signals.append(signum)
        if self.stop.is_set():
            if not self.kill_now:
                self.kill_now = True
                self.warn("second signal: killing every process of the run now")
            for child in self._all_children():
                child.signal(signal.SIGKILL)
            return
        self.stop.set()

    async def _or_stop(self, aw: Awaitable[Any]) -> Any:
        """Await ``aw`` unless a stop signal comes first (then raise _Interrupted)."""
        task = asyncio.ensure_future(aw)
        stopper = asyncio.ensure_future(self.stop.wait())
        try:
            await asyncio.wait({task, stopper}, return_when=asyncio.FIRST_COMPLETED)
        finally:
            stopper.cancel()
        if not task.done():
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await task
            raise _Interrupted
        return task.result()

    def _all_children(self) -> list[_Child]:
        return [*self.retired, *self.nodes, *([self.router] if self.router is not None else [])]

    # -- start ----------------------------------------------------------------------------------

    def _node_args(self) -> list[tuple[str, list[str], str]]:
        ep, fleet, scn_arg = self.cfg.endpoint, self.cfg.fleet, self.plan.scenario_arg
        common = ["--endpoint", ep, "--fleet", fleet]
        if self.cfg.lease_ms is not None:
            common += ["--lease-ms", str(self.cfg.lease_ms)]
        lock = ["--lockstep"] if self.cfg.lockstep else []
        plant = [
            "plant", "--scenario", scn_arg, "--seed", str(self.plan.seed),
            "--duration", repr(self.plan.duration_s), "--wait-robots", *lock, *common,
        ]  # fmt: skip
        batch = ["--batch"] if self.cfg.hosts > 0 else []
        plant += batch
        coord = [
            "coordinator", "--scenario", scn_arg, "--name", "main", *batch, *lock, *common,
        ]  # fmt: skip
        out = [("plant", plant, "plant ready"), ("coordinator", coord, "coordinator ready")]
        if self.cfg.camera == "rendered":  # docs/localization.md: the real tracker in the loop
            from localization.rendered import scenario_camera_args

            plant.append("--no-poses")
            cam = scenario_camera_args(
                self.scn.robot_ids, self.scn.initial, self.scn.trajectory,
                float(self.scn.formation.get("b_m", 0.4)), self.plan.duration_s,
                str(self.plan.out_dir / "camera.toml"),
            )  # fmt: skip
            out.insert(1, ("camera", ["camera", *cam, *common], "camera ready"))
        if self.cfg.standby:
            standby = [
                "coordinator", "--scenario", scn_arg, "--name", "standby", "--standby",
                *batch, *lock, *common,
            ]  # fmt: skip
            out.append(("coordinator-standby", standby, "coordinator ready"))
        ids = list(self.scn.robot_ids)
        if self.cfg.hosts > 0:  # agent hosts, each running a contiguous share of the robots
            h = min(self.cfg.hosts, len(ids))
            for k in range(h):
                part = ids[k * len(ids) // h : (k + 1) * len(ids) // h]
                name = f"h{k + 1}"
                host = [
                    "agent-host", "--ids", ",".join(part), "--name", name, "--scenario", scn_arg,
                    *lock, *common,
                ]  # fmt: skip
                out.append((f"agent-host-{name}", host, f"agent-host {name} ready"))
            return out
        for rid in ids:
            agent = ["agent", "--id", rid, "--scenario", scn_arg, *lock, *common]
            out.append((f"agent-{rid}", agent, f"agent {rid} ready"))
        return out

    async def _start(self) -> None:
        env = _child_env()
        self.router = _Child(
            "router", ["router", "--listen", self.cfg.endpoint], "router listening on ",
            self.log_dir,
        )  # fmt: skip
        await self.router.spawn(env, process_group=0)
        assert self.router.pid is not None
        group = self.router.pid
        await self._or_stop(self.router.wait_ready(self.cfg.ready_timeout_s))
        self.say(f"  router       pid {self.router.pid:<7} ready in {self.router.ready_s:.2f} s")
        for name, args, ready in self._node_args():
            child = _Child(name, args, ready, self.log_dir)
            self.nodes.append(child)
            await child.spawn(env, process_group=group)
        # Every child exists: only now may this process start Zenoh (no fork after Zenoh).
        await self._or_stop(self._open_session())
        await self._or_stop(
            _all_or_first_error(c.wait_ready(self.cfg.ready_timeout_s) for c in self.nodes)
        )
        agents = [c for c in self.nodes if c.name.startswith("agent-")]
        for c in self.nodes:
            if not c.name.startswith("agent-"):
                self.say(f"  {c.name:<12} pid {c.pid:<7} ready in {c.ready_s:.2f} s")
        slowest = max((c.ready_s or 0.0) for c in agents)
        self.say(f"  {len(agents)} agents    ready in {slowest:.2f} s (slowest)")

    async def _open_session(self) -> None:
        import zenoh

        from bus_schemas import transport as tp

        loop = asyncio.get_running_loop()
        settings = tp.ZenohSettings(connect=(self.cfg.endpoint,), open_timeout_s=5.0)
        self.session = await tp.open_session_async(settings)
        # Zenoh buffers the samples in its own FIFO and the loop drains it every CONSUME_PERIOD_S:
        # no Python callback per sample on Zenoh's threads, no loop wake-up per burst. On two
        # cores this keeps the launcher from slowing down the lockstep it is watching. The
        # collector does not need the order across keys (it places samples by tick / time).
        self._subscribers = [
            self.session.declare_subscriber(p, zenoh.handlers.FifoChannel(FIFO_CAPACITY))
            for p in key_patterns(self.cfg.fleet)
        ]
        tp.watch_liveliness(
            self.session, keys.alive_pattern(self.cfg.fleet), loop, self.collector.feed_alive
        )
        self._start_observers()

    def _start_observers(self) -> None:
        """``--record`` and ``--foxglove``: recorder and live server on the launcher's session."""
        if self.cfg.record is not None:
            from formation.record import run_info, start_recorder

            run = run_info(
                self.plan.scenario_arg,
                lockstep=self.cfg.lockstep,
                settle_s=self.plan.settle_s,
                seed=self.plan.seed,
                duration_s=self.plan.duration_s,
                endpoint=self.cfg.endpoint,
            )
            try:
                self.recorder = start_recorder(
                    self.session, self.cfg.fleet, self.cfg.record, run=run
                )
            except OSError as exc:
                raise LaunchError(f"--record {self.cfg.record}: {exc}") from exc
            self.say(f"  recording    {keys.fleet_pattern(self.cfg.fleet)} to {self.cfg.record}")
        if self.cfg.foxglove_port is not None:
            from formation.live import start_live

            geom = self.scn.agent.geometry
            try:
                self.live = start_live(
                    self.session,
                    self.cfg.fleet,
                    host=self.cfg.foxglove_host,
                    port=self.cfg.foxglove_port,
                    ref_offset_m=geom.ref_offset_m,
                    body_radius_m=geom.body_radius_m,
                )
            except RuntimeError as exc:
                raise LaunchError(f"--foxglove {self.cfg.foxglove_port}: {exc}") from exc
            # printed even with --quiet: a client needs the address
            print(f"foxglove live view on {self.live.url}", flush=True)

    async def _stop_observers(self) -> None:
        """Close the live server and finalize the recording (before the session closes)."""
        live, self.live = self.live, None
        if live is not None:
            await asyncio.to_thread(live.close)
        recorder, self.recorder = self.recorder, None
        if recorder is not None:
            stats = await asyncio.to_thread(recorder.close)
            self.record_stats = stats
            if stats.dropped or stats.handler_errors:
                self.warn(
                    f"recording {recorder.path}: {stats.dropped} samples dropped, "
                    f"{stats.handler_errors} write errors"
                )
            self.say(
                f"recorded {stats.samples} samples ({stats.rejected} rejected, "
                f"{stats.liveliness} liveliness changes) to {recorder.path}"
            )

    def _drain_subscribers(self) -> None:
        """Feed every sample buffered by Zenoh to the collector."""
        truth_leaves = (f"/{keys.TRUTH}", f"/{keys.TRUTHS}")  # per robot, or batched
        feed = self.collector.feed
        for sub in self._subscribers:
            while (sample := sub.try_recv()) is not None:
                key = str(sample.key_expr)
                if feed(key, sample.payload.to_bytes()) and key.endswith(truth_leaves):
                    now = time.monotonic()
                    if self.first_truth_rx is None:
                        self.first_truth_rx = now
                    self.last_truth_rx = now

    async def _consume(self) -> None:
        while True:
            self._drain_subscribers()
            await asyncio.sleep(CONSUME_PERIOD_S)

    # -- run ------------------------------------------------------------------------------------

    async def _first_truth(self) -> None:
        while self.first_truth_rx is None:
            await asyncio.sleep(0.02)

    def _survivable(self, child: _Child) -> bool:
        """An agent's death is an event of the run (issue 4: the fleet re-forms without it); a
        coordinator's too while another coordinator process is running (``--standby``)."""
        if child.name.startswith("agent-"):
            return True
        if child.name.startswith("coordinator"):
            return any(
                c is not child and c.name.startswith("coordinator") and c.returncode is None
                for c in self.nodes
            )
        return False

    def _event(self, text: str) -> None:
        self.events.append({"t": time.monotonic(), "event": text})
        self.say(f"formation up: {text}")

    async def _respawn(self, old: _Child) -> _Child:
        """Start ``old``'s command again after ``--respawn`` seconds (a coordinator always as a
        standby: the survivor took over and must not be fought)."""
        assert self.cfg.respawn_s is not None and self.router is not None
        await asyncio.sleep(self.cfg.respawn_s)
        args = list(old.argv[3:])
        if old.name.startswith("coordinator") and "--standby" not in args:
            args.append("--standby")
        child = _Child(
            old.name, args, old.ready_prefix, self.log_dir, generation=old.generation + 1
        )
        # fork+exec of a fresh interpreter: the child never runs this process's Zenoh state
        # (the fork hazard of the field notes is a forked child *using* it).
        assert self.router.pid is not None
        await child.spawn(_child_env(), process_group=self.router.pid)
        self.retired.append(old)
        self.nodes[self.nodes.index(old)] = child
        await child.wait_ready(self.cfg.ready_timeout_s)
        self._event(f"{child.name} respawned (pid {child.pid}), ready in {child.ready_s:.2f} s")
        return child

    async def _run(self) -> None:
        plant = self.nodes[0]
        assert plant.proc is not None
        waits: dict[asyncio.Future[Any], _Child] = {
            asyncio.ensure_future(c.proc.wait()): c for c in self.nodes if c.proc is not None
        }
        assert self.router is not None and self.router.proc is not None
        waits[asyncio.ensure_future(self.router.proc.wait())] = self.router
        respawns: set[asyncio.Future[Any]] = set()
        timer: asyncio.Future[Any] | None = None
        stopper: asyncio.Future[Any] | None = None
        try:
            if not self.cfg.lockstep:
                # realtime: the duration counts from the first truth frame
                try:
                    await self._or_stop(
                        asyncio.wait_for(self._first_truth(), self.cfg.ready_timeout_s)
                    )
                except TimeoutError:
                    raise LaunchError(
                        f"no truth from the plant within {self.cfg.ready_timeout_s} s of start"
                    ) from None
                # The plant ends a realtime run itself after --duration (from its clock start,
                # which is the first truth frame); the timer is the backstop for a plant that
                # does not, late enough not to race with the plant's own clean exit.
                timer = asyncio.ensure_future(
                    asyncio.sleep(self.plan.duration_s + REALTIME_END_GRACE_S)
                )
            stopper = asyncio.ensure_future(self.stop.wait())
            while True:
                pending = {*waits, *respawns, stopper, *([timer] if timer is not None else [])}
                done, _ = await asyncio.wait(pending, return_when=asyncio.FIRST_COMPLETED)
                if stopper in done:
                    raise _Interrupted
                if timer is not None and timer in done:
                    return
                for fut in done:
                    if fut in respawns:
                        respawns.discard(fut)
                        if fut.exception() is not None:
                            self._event(f"respawn failed: {fut.exception()}")
                            continue
                        new: _Child = fut.result()
                        assert new.proc is not None
                        waits[asyncio.ensure_future(new.proc.wait())] = new
                        continue
                    child = waits.pop(fut, None)
                    if child is None:
                        continue
                    rc = child.returncode
                    if child is plant and rc == 0:
                        return  # the plant ran its duration
                    if self._survivable(child):
                        what = "killed by SIGKILL" if rc == -signal.SIGKILL else f"status {rc}"
                        self._event(f"{child.name} (pid {child.pid}) exited ({what})")
                        if self.cfg.respawn_s is not None:
                            respawns.add(asyncio.ensure_future(self._respawn(child)))
                        continue
                    raise LaunchError(
                        f"{child.name} (pid {child.pid}) exited with status {rc} during the "
                        f"run; stderr ({child.log_path}):\n{_tail(child.log_path)}"
                    )
        finally:
            leftovers: list[asyncio.Future[Any] | None] = [*waits, *respawns, stopper, timer]
            for pending_fut in leftovers:
                if pending_fut is not None:
                    pending_fut.cancel()
            await asyncio.gather(*respawns, return_exceptions=True)

    # -- stop -----------------------------------------------------------------------------------

    async def _stop_children(self, children: list[_Child]) -> None:
        if self.kill_now:
            for c in children:
                c.signal(signal.SIGKILL)
        problems = await asyncio.gather(*(c.stop() for c in children))
        for p in problems:
            if p is not None:
                self.failures.append(p)
                self.warn(p)

    async def _shutdown(self) -> None:
        t0 = time.monotonic()
        await self._stop_children(self.nodes)
        if self.session is not None:
            self._drain_subscribers()  # what arrived before the nodes stopped
            self._subscribers = []
            await self._stop_observers()
            with contextlib.suppress(Exception):
                self.session.close()
        if self.router is not None:
            await self._stop_children([self.router])
            group = self.router.pid
            assert group is not None
            leftovers = _group_members(group)
            if leftovers:
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(group, signal.SIGKILL)
                msg = f"processes left in the run's group killed: {leftovers}"
                self.failures.append(msg)
                self.warn(msg)
        for c in self._all_children():
            await c.close()
        self.stop_s = time.monotonic() - t0

    # -- main -----------------------------------------------------------------------------------

    async def run(self) -> UpResult:
        loop = asyncio.get_running_loop()
        wall0 = time.monotonic()
        self.log_dir.mkdir(parents=True, exist_ok=True)
        if self.plan.scenario_toml is not None:
            (self.out_dir / "scenario.toml").write_text(self.plan.scenario_toml)
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(sig, self._on_signal, sig)
        mode = "lockstep" if self.cfg.lockstep else "realtime"
        self.say(
            f"formation up: {self.scn.name} ({len(self.scn.robot_ids)} robots, {mode}, "
            f"{self.plan.duration_s:g} s, seed {self.plan.seed}) on {self.cfg.endpoint}, "
            f"fleet {self.cfg.fleet}; logs in {self.log_dir}/"
        )
        interrupted = False
        consumer: asyncio.Task[None] | None = None
        display: asyncio.Task[None] | None = None
        try:
            try:
                await self._start()
                consumer = asyncio.ensure_future(self._consume())
                display = asyncio.ensure_future(self._display_loop())
                await self._run()
                if self.cfg.lockstep:
                    await asyncio.sleep(DRAIN_S)  # the plant's last messages may be in flight
            except _Interrupted:
                interrupted = True
                name = signal.Signals(self.signals[0]).name if self.signals else "signal"
                self.warn(f"{name}: stopping the run")
            except LaunchError as exc:
                self.failures.append(str(exc))
                self.warn(str(exc))
            finally:
                if display is not None:
                    display.cancel()
                self._clear_table()
                if consumer is not None:
                    consumer.cancel()
                await self._shutdown()
        finally:
            for sig in (signal.SIGINT, signal.SIGTERM):
                loop.remove_signal_handler(sig)
        return self._results(interrupted, time.monotonic() - wall0)

    def _results(self, interrupted: bool, wall_s: float) -> UpResult:
        run_wall = (
            self.last_truth_rx - self.first_truth_rx
            if self.first_truth_rx is not None and self.last_truth_rx is not None
            else None
        )
        code = 1 if self.failures else (EXIT_INTERRUPTED if interrupted else 0)
        result = UpResult(
            exit_code=code,
            out_dir=self.out_dir,
            failures=list(self.failures),
            interrupted=interrupted,
            wall_s=wall_s,
            run_wall_s=run_wall,
        )
        first = self.collector.first_tick
        if self.cfg.lockstep and first not in (None, 0):
            self.warn(f"the collector joined late: ticks 0..{first - 1} are missing from the log")
        meta = {
            "scenario": self.scn.name,
            "seed": self.plan.seed,
            "dt_s": self.scn.dt_s,
            "mode": "lockstep" if self.cfg.lockstep else "realtime",
            "wall_s": wall_s,
            "run_wall_s": run_wall,
            "stop_s": self.stop_s,
            "endpoint": self.cfg.endpoint,
            "fleet": self.cfg.fleet,
            "record": None if self.cfg.record is None else str(self.cfg.record),
            "interrupted": interrupted,
            "failures": list(self.failures),
            "events": list(self.events),
            "children": {
                f"{c.name}.{c.generation}" if c.generation else c.name: {
                    "pid": c.pid,
                    "returncode": c.returncode,
                    "ready_s": c.ready_s,
                    "killed": c.killed,
                }
                for c in self._all_children()
            },
        }
        log = self.collector.build(meta)
        if log.t_s.size == 0:
            self.warn("no truth was received: no metrics written")
            return result
        from formation import metrics as metrics_mod

        m = metrics_mod.compute(log, self.plan.settle_s, self.scn.settle_tol_m)
        sim_s = float(log.t_s[-1] - log.t_s[0])
        m["meta"]["realtime_factor"] = sim_s / run_wall if run_wall else None
        self.out_dir.mkdir(parents=True, exist_ok=True)
        (self.out_dir / "metrics.json").write_text(json.dumps(m, indent=2, sort_keys=True) + "\n")
        log.save_npz(str(self.out_dir / "run.npz"))
        result.metrics = m
        if self.cfg.figures and not interrupted:
            from formation import figures as fig_mod

            fig_mod.write_all(
                log,
                self.out_dir,
                title=f"{self.scn.name} over Zenoh ({m['meta']['mode']}): reference points "
                "(solid), virtual trajectories (dashed)",
                settle_s=self.plan.settle_s,
            )
        if not self.cfg.quiet:
            from formation.sim_cli import summary

            print(summary(m))
            rf = m["meta"]["realtime_factor"]
            speed = f", {rf:.1f}x real time" if rf else ""
            what = "metrics" if interrupted or not self.cfg.figures else "metrics and figures"
            print(f"{sim_s:.2f} s of {m['meta']['mode']} run{speed}; {what} in {self.out_dir}/")
        return result


async def run_up(cfg: UpConfig, plan: Plan | None = None) -> UpResult:
    """Run the whole system once (see the module docstring); call from an event loop on the
    main thread (it installs SIGINT/SIGTERM handlers for its duration)."""
    plan = plan if plan is not None else plan_run(cfg)
    return await _Launcher(cfg, plan).run()


# ---------------------------------------------------------------------------------------------
# CLI
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
    p.add_argument("--robots", type=int, default=None, help="number of robots r1..rN")
    p.add_argument(
        "--duration",
        type=float,
        default=None,
        help="seconds to run: sim time in lockstep, wall time in realtime (default: scenario's)",
    )
    p.add_argument(
        "--lockstep", action="store_true", help="sim time advances when every process answered"
    )
    p.add_argument(
        "--endpoint", default=DEFAULT_ENDPOINT, help=f"router endpoint (default {DEFAULT_ENDPOINT})"
    )
    p.add_argument("--fleet", default=keys.DEFAULT_FLEET, help="fleet name in the keys")
    p.add_argument("--out", type=Path, default=None, help="output folder (runs/up-<scenario>)")
    p.add_argument("--seed", type=int, default=None, help="override the scenario's seed")
    p.add_argument("--no-figures", action="store_true", help="skip the PNG figures")
    p.add_argument("--quiet", action="store_true", help="print nothing but errors")
    p.add_argument(
        "--ready-timeout",
        type=float,
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
        default=0,
        metavar="H",
        help="run the robots in H agent-host processes with the batched bus instead of one "
        "agent process per robot (large fleets, docs/scale.md)",
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
        default=DEFAULT_LEASE_MS,
        metavar="MS",
        help=f"Zenoh lease of every node: a hung node is dead after this (default "
        f"{DEFAULT_LEASE_MS}; 0: Zenoh's own, 10 s)",
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
        duration_s=ns.duration,
        lockstep=ns.lockstep,
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
    )


def main(argv: list[str]) -> int:
    """Entry point of ``formation up`` (dispatched by ``formation.cli``)."""
    cfg = config_from_args(build_parser().parse_args(argv))
    if not 0 <= cfg.hosts <= 256:
        print(f"formation up: --hosts: expected 0..256, got {cfg.hosts}", file=sys.stderr)
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
    result = asyncio.run(run_up(cfg, plan))
    return result.exit_code
