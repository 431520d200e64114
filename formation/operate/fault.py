"""``formation fault``: inject a fault into a running fleet (``formation up`` or separate nodes).

Usage::

    formation fault kill-leader                 # SIGKILL the agent of the robot in slot 0
    formation fault kill ROBOT                  # SIGKILL that robot's agent
    formation fault pause ROBOT                 # SIGSTOP it (a hang: detected after the lease)
    formation fault resume ROBOT                # SIGCONT it
    formation fault kill-host NAME              # SIGKILL agent host NAME (--hosts fleets)
    formation fault pause-host NAME / resume-host NAME
    formation fault kill-coordinator [NAME]     # SIGKILL the active coordinator (or NAME)
    formation fault drag ROBOT DX DY [--duration S]   # push the simulated robot (plant only)
    formation fault estop [ROBOT]               # latched emergency stop, fleet or one robot
    formation fault release [ROBOT]             # release it
    formation fault kill-leader --at 30         # at sim time 30 s: the active coordinator
                                                #   schedules it (lockstep: at that very tick)
    ... [--fleet demo] [--timeout 3] [zenoh options: --endpoint tcp/127.0.0.1:7447 ...]
    (the options go before or after the command)

Theory of operation
-------------------
Everything is found on the bus: the leader is the ``leader`` field of the coordinator's
``assignment``; an agent's process is the ``pid`` of its ``robot/<id>/status``, an agent host's
the ``pid`` of ``host/<name>/status``, a coordinator's the ``pid`` of
``coordinator/<name>/status``, and ``host`` must be this host (a signal cannot cross machines).

**Nothing is signalled that was not verified** to belong to the fleet the tool was pointed at
(issue 13): the pid's own command line (``/proc/<pid>/cmdline``) must be ``... -m formation
agent`` (``agent-host``, ``coordinator``) with ``--id ROBOT`` (``--ids`` listing it / ``--name
NAME``), the same ``--fleet`` and the same endpoint (its ``--endpoint``, or the ``connect``
endpoints of its ``--zenoh-config``; loopback names are equal, the protocol is ignored), and
be owned by this user. So a forged status naming a foreign pid, or another fleet's robot of the
same id, is refused. A paused process publishes nothing, so ``resume`` finds it by that same
command-line match among *stopped* processes of this user (and, when a ``formation up`` is
registered on the endpoint, only among its children, formation.outputs.runfile); a robot that is
publishing status is not paused and is refused.

A robot run by an agent host (``formation up --hosts H``) shares its process with others:
``kill``/``pause``/``resume`` of it, and ``kill-leader`` on such a fleet, are refused with a
one-line message naming the host (``kill-host NAME`` does that deliberately). A robot that is
not in the fleet (no status, per robot or in a host's batch, within ``--timeout``) is a one-line
error, status 1; so is ``drag`` of a robot the plant does not simulate (no truth of it).

``estop``/``release`` publish ``estop`` (twice, 20 ms apart: it is idempotent and latched)
and exit 1 unless it is durable where the fleet relies on it (formation.operate.estop_tool: a robot
acknowledged it, every coordinator with a state file saved it, a coordinator or an agent
answering ``estop/held`` holds it; a release: no coordinator still holds it), the line saying
what is not.
Against an authenticated run (``formation up --secure``) the tool uses the run's ``operator``
credentials by itself (formation.outputs.runfile).

``--at T`` (kill-leader, kill, pause, resume, kill-coordinator, estop, release; ``--for S``
undoes a pause or an e-stop S s later): nothing is signalled now; a ``fault`` request goes to the
active coordinator, which adds it to the run's schedule of scripted faults at sim time ``T``
(the scenario's ``[[fault]]`` clock: lockstep sim time, realtime seconds since the trajectory
started) and, when it is due, sends the notice every node acts on (docs/faults.md "Faults in
scenarios"): in lockstep that is the same tick on every run. Exit 1 if no active coordinator
answers within ``--timeout``.

Prints one line saying what was done, with the ``time.monotonic()`` of the action (same clock as
``t`` on a local bus), and exits 0; 1 if the target was not found, not verified or could not be
signalled; 2 for bad arguments.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import os
import signal
import socket
import sys
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import runtime as rt
from bus_schemas import (
    Assignment,
    CoordinatorStatus,
    DecodeError,
    Disturbance,
    Status,
    StatusBatch,
    Truth,
    TruthBatch,
    decode,
    encode,
    keys,
)
from bus_schemas import Fault as FaultMsg
from formation.outputs import runfile

__all__ = [
    "FaultError",
    "Where",
    "apply",
    "build_parser",
    "find_processes",
    "main",
    "request_at",
    "verify_process",
]


class FaultError(RuntimeError):
    """The target could not be found, verified or signalled."""


# ---------------------------------------------------------------------------------------------
# Verification of a process from its own command line
# ---------------------------------------------------------------------------------------------

_LOOPBACK = frozenset({"127.0.0.1", "localhost", "::1", "[::1]", "0.0.0.0"})


def norm_endpoint(endpoint: str) -> tuple[str, str]:
    """``(host, port)`` of an endpoint, loopback names folded to one, protocol ignored
    (``tls/localhost:7447`` and ``tcp/127.0.0.1:7447`` are the same place)."""
    _, _, addr = endpoint.partition("/")
    addr = addr.split("#", 1)[0]
    host, _, port = addr.rpartition(":")
    return ("loopback" if host in _LOOPBACK else host, port)


def config_endpoints(path: str) -> list[str]:
    """The ``connect`` endpoints of a Zenoh JSON5 config file ([] if unreadable)."""
    try:
        import zenoh

        raw = json.loads(zenoh.Config.from_file(path).get_json("connect/endpoints"))
    except Exception:
        return []
    if isinstance(raw, dict):  # per-mode map
        raw = [e for v in raw.values() if isinstance(v, list) for e in v]
    return [str(e) for e in raw] if isinstance(raw, list) else []


@dataclass(frozen=True)
class Where:
    """The fleet the tool was pointed at: its name and where its router is."""

    fleet: str
    endpoints: frozenset[tuple[str, str]]

    @classmethod
    def of(cls, fleet: str, settings: rt.ZenohSettings) -> Where:
        eps = list(settings.connect)
        if settings.config_file is not None and not eps:
            eps = config_endpoints(settings.config_file)
        return cls(fleet, frozenset(norm_endpoint(e) for e in eps))


def cmdline(pid: int) -> list[str] | None:
    try:
        raw = Path(f"/proc/{pid}/cmdline").read_bytes()
    except OSError:
        return None
    return [a.decode(errors="replace") for a in raw.split(b"\0") if a]


def _opt(args: Sequence[str], opt: str) -> list[str]:
    """Every value of ``opt`` in ``args`` (``--opt V`` and ``--opt=V``)."""
    out = []
    for i, a in enumerate(args):
        if a == opt and i + 1 < len(args):
            out.append(args[i + 1])
        elif a.startswith(opt + "="):
            out.append(a[len(opt) + 1 :])
    return out


def _proc_state(pid: int) -> tuple[str, int] | None:
    """(state letter, uid) of ``pid``."""
    try:
        raw = Path(f"/proc/{pid}/stat").read_text(errors="replace")
        uid = os.stat(f"/proc/{pid}").st_uid
    except OSError:
        return None
    return raw[raw.rfind(")") + 2 :].split()[0], uid


def verify_process(pid: int, kind: str, name: str, where: Where) -> str | None:
    """Why ``pid`` is not ``kind`` (``agent``, ``agent-host``, ``coordinator``) ``name`` of
    ``where``'s fleet, or None when its own command line says it is. For ``agent``, ``name``
    is the robot id (``--id``); for ``agent-host`` a robot id it runs (``--ids``) or the host's
    ``--name``; for ``coordinator`` its ``--name`` (``main`` without one)."""
    if pid <= 1 or pid == os.getpid():
        return f"pid {pid} is not a fleet process"
    args = cmdline(pid)
    state = _proc_state(pid)
    if args is None or state is None:
        return f"process {pid} does not exist"
    if state[1] != os.getuid():
        return f"process {pid} belongs to another user"
    # `python -m formation KIND ...` or the `formation` console script (`.../bin/formation KIND`)
    ok = any(
        (a == "formation" and i > 0 and args[i - 1] == "-m")
        or (a.endswith("/formation") and i <= 1)
        for i, a in enumerate(args[:-1])
        if args[i + 1] == kind
    )
    if not ok:
        return f"process {pid} is not `formation {kind}` (`{' '.join(args)[:120]}`)"
    if kind == "agent":
        if _opt(args, "--id") != [name]:
            return f"process {pid} is not the agent of {name}"
    elif kind == "agent-host":
        ids = [r for v in _opt(args, "--ids") for r in v.split(",")]
        if name not in ids and _opt(args, "--name") != [name]:
            return f"process {pid} is not an agent host running {name}"
    elif (_opt(args, "--name") or ["main"]) != [name]:
        return f"process {pid} is not coordinator {name}"
    fleet = (_opt(args, "--fleet") or [keys.DEFAULT_FLEET])[-1]
    if fleet != where.fleet:
        return f"process {pid} is in fleet {fleet!r}, not {where.fleet!r}"
    eps = list(_opt(args, "--endpoint"))
    for conf in _opt(args, "--zenoh-config"):
        eps += config_endpoints(conf)
    if not eps:
        eps = [rt.DEFAULT_ENDPOINT]
    if not {norm_endpoint(e) for e in eps} & where.endpoints:
        return f"process {pid} is connected to {', '.join(eps)}, not this fleet's router"
    return None


def find_processes(kind: str, name: str, where: Where, *, stopped: bool = False) -> list[int]:
    """This user's processes that :func:`verify_process` accepts as ``kind`` ``name`` of
    ``where`` (only stopped ones with ``stopped``): a full command-line match, never a name."""
    found = []
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        pid = int(entry)
        if verify_process(pid, kind, name, where) is not None:
            continue
        state = _proc_state(pid)
        if stopped and (state is None or state[0] not in ("T", "t")):
            continue
        found.append(pid)
    return sorted(found)


# ---------------------------------------------------------------------------------------------
# The bus
# ---------------------------------------------------------------------------------------------


class _Bus:
    """The first decoded message of a key (pattern) that ``parse`` accepts, with a timeout."""

    def __init__(self, session: Any, timeout_s: float) -> None:
        self.session = session
        self.timeout_s = timeout_s

    async def newest(self, key: str, parse: Callable[[bytes], Any]) -> Any:
        """The first message on ``key`` that ``parse`` maps to non-None within the timeout."""
        found = await self.first_of([(key, parse)])
        return None if found is None else found[1]

    async def first_of(self, wants: Iterable[tuple[str, Callable[[bytes], Any]]]) -> Any:
        """``(key, value)`` of the first accepted message on any of ``wants``, or None."""
        loop = asyncio.get_running_loop()
        got: asyncio.Future[Any] = loop.create_future()

        def handler(parse: Callable[[bytes], Any]) -> Callable[[rt.Received], None]:
            def on(rx: rt.Received) -> None:
                if got.done():
                    return
                value = parse(rx.payload)
                if value is not None:
                    got.set_result((rx.key, value))

            return on

        subs = [rt.subscribe(self.session, k, loop, handler(p)) for k, p in wants]
        try:
            return await asyncio.wait_for(got, self.timeout_s)
        except TimeoutError:
            return None
        finally:
            for sub in subs:
                sub.undeclare()


def _decoded(kind: Any, accept: Callable[[Any], bool] = lambda m: True) -> Callable[[bytes], Any]:
    def parse(payload: bytes) -> Any:
        msg = decode(payload, kind)
        return None if isinstance(msg, DecodeError) or not accept(msg) else msg

    return parse


def _check_local(host: Any, what: str) -> None:
    here = socket.gethostname()[:255] or "unknown"
    if host != here:
        raise FaultError(f"{what} runs on host {host!r}, not here ({here!r}): cannot signal it")


def _verified(pid: int, kind: str, name: str, where: Where, what: str) -> int:
    why = verify_process(pid, kind, name, where)
    if why is not None:
        raise FaultError(f"refused: the status of {what} names pid {pid}, but {why}")
    return pid


@dataclass(frozen=True)
class _Found:
    """Where a robot runs: its own agent (``host`` None) or an agent host."""

    pid: int
    host_name: str | None  # agent host name (batched fleets)
    robots: tuple[str, ...]


async def _locate_robot(bus: _Bus, where: Where, robot: str) -> _Found:
    """The verified process running ``robot``: from its status, or a host's batched status."""
    fleet = where.fleet
    found = await bus.first_of(
        [
            (keys.status_key(fleet, robot), _decoded(Status)),
            (
                keys.all_host_status_pattern(fleet),
                _decoded(StatusBatch, lambda m: robot in m.robots),
            ),
        ]
    )
    if found is None:
        raise FaultError(
            f"no robot {robot!r} in fleet {fleet!r} (no status of it within {bus.timeout_s:g} s)"
        )
    key, msg = found
    if isinstance(msg, StatusBatch):
        host_name = key.rsplit("/", 2)[-2]
        _check_local(msg.host, f"agent host {host_name}")
        pid = _verified(msg.pid, "agent-host", robot, where, f"agent host {host_name}")
        return _Found(pid, host_name, tuple(msg.robots))
    _check_local(msg.host, f"agent {robot}")
    return _Found(_verified(msg.pid, "agent", robot, where, f"robot {robot}"), None, (robot,))


def _refuse_host(robot: str, found: _Found, cmd: str) -> FaultError:
    others = len(found.robots) - 1
    return FaultError(
        f"{robot} runs in agent host {found.host_name} (pid {found.pid}) with {others} other "
        f"robot(s): a signal would hit them all. To stop {robot} alone, start the fleet with "
        f"one agent process per robot (`formation up --hosts 0`), or on a lockstep fleet "
        f"schedule it (`formation fault {cmd} {robot} --at T`: the host stops that robot "
        f"alone); `formation fault {cmd}-host {found.host_name}` hits the whole host on purpose"
    )


async def _locate_host(bus: _Bus, where: Where, name: str) -> int:
    key = keys.host_status_key(where.fleet, keys.check_name(name))
    msg = await bus.newest(key, _decoded(StatusBatch))
    if msg is None:
        raise FaultError(f"no agent host {name!r} in fleet {where.fleet!r} (no status)")
    _check_local(msg.host, f"agent host {name}")
    return _verified(msg.pid, "agent-host", name, where, f"agent host {name}")


def _signal(pid: int, sig: signal.Signals) -> float:
    try:
        os.kill(pid, sig)
    except ProcessLookupError:
        raise FaultError(f"process {pid} does not exist") from None
    except PermissionError:
        raise FaultError(f"not allowed to signal process {pid}") from None
    return time.monotonic()


def _launcher_children(where: Where) -> set[int] | None:
    """Pids of the nodes of the ``formation up`` registered on the endpoint, if any."""
    for host, port in where.endpoints:
        if host == "loopback" and port.isdigit():
            info = runfile.lookup(int(port))
            if info is not None and info.fleet == where.fleet:
                return set(info.children.values())
    return None


async def _resume(bus: _Bus, where: Where, kind: str, name: str) -> int:
    """The one stopped process of this fleet that is ``kind`` ``name`` (see the module doc)."""
    pids = find_processes(kind, name, where, stopped=True)
    children = _launcher_children(where)
    if children is not None:
        pids = [p for p in pids if p in children]
    what = f"{'agent host' if kind == 'agent-host' else 'agent'} {name}"
    if not pids:
        raise FaultError(f"no paused {what} of fleet {where.fleet!r} on this host")
    if len(pids) > 1:
        raise FaultError(f"several paused processes match {what}: {pids}")
    if kind == "agent":
        bus.timeout_s = min(bus.timeout_s, 0.5)
        live = await bus.newest(keys.status_key(where.fleet, name), _decoded(Status))
        if live is not None:
            raise FaultError(f"{what} is publishing status (pid {live.pid}): it is not paused")
    return pids[0]


async def _record(session: Any, fleet: str, kind: str, robot: str | None, t: float) -> None:
    """Put a fault done now on the record: a ``fault`` notice without a scenario index (nobody
    acts on it; ``formation up``'s and a recorder's collector list it in metrics.json
    ``faults``), stamped with the action's ``time.monotonic()``."""
    msg = FaultMsg(t=t, kind=kind, robot=robot)
    with contextlib.suppress(Exception):  # the record is a courtesy; the fault is done
        session.put(keys.fault_key(fleet), encode(msg))
        await asyncio.sleep(0.02)


_SIG = {"kill": signal.SIGKILL, "pause": signal.SIGSTOP, "resume": signal.SIGCONT}
_DONE = {"kill": "killed", "pause": "paused", "resume": "resumed"}


_AT_KINDS = {
    "kill-leader": ("kill", "leader"),
    "kill": ("kill", None),
    "pause": ("pause", None),
    "resume": ("resume", None),
    "kill-coordinator": ("kill_coordinator", None),
    "estop": ("estop", None),
    "release": ("release", None),
}


async def request_at(session: Any, ns: argparse.Namespace, *, running: bool = False) -> str:
    """``--at T`` (``ns`` as :func:`build_parser` parses it): a request the active coordinator
    schedules (module docstring), over an open ``session``: the CLI's and formation.testing's
    one path. The CLI first waits for the active coordinator's status (a fleet still starting
    has nobody to take the request yet). ``running``: the caller knows the fleet runs (it
    watches it), so the request goes at once; waiting for a status first let a fast lockstep
    run pass T under load."""
    bus = _Bus(session, ns.timeout)
    fleet = keys.check_fleet(ns.fleet)
    kind, role = _AT_KINDS[ns.command]
    robot = getattr(ns, "robot", None)
    if robot is not None:
        robot = keys.check_robot_id(robot)
    msg = FaultMsg(
        t=ns.at,
        request=True,
        kind=kind,
        robot=robot,
        role=role,
        duration_s=getattr(ns, "for_s", None),
    )
    who = f" of {robot}" if robot else " of the leader" if role else ""
    undo = f", undone {msg.duration_s:g} s later" if msg.duration_s else ""
    line = f"requested {kind}{who} at t={ns.at:g} s (sim time){undo}"
    if running:
        session.put(keys.fault_key(fleet), encode(msg))
        return f"{line}: the active coordinator applies it then"
    active = await bus.newest(
        keys.all_coordinator_status_pattern(fleet),
        _decoded(CoordinatorStatus, lambda m: m.role == "active"),
    )
    if active is None:
        raise FaultError(f"no active coordinator of fleet {fleet!r} within {bus.timeout_s:g} s")
    session.put(keys.fault_key(fleet), encode(msg))
    await asyncio.sleep(0.05)  # let it leave before the session closes
    return f"{line}: coordinator {active.name} applies it then"


async def _run(ns: argparse.Namespace, settings: rt.ZenohSettings) -> str:
    where = Where.of(keys.check_fleet(ns.fleet), settings)
    session = await rt.open_session_async(settings)
    try:
        return await apply(session, ns, where)
    finally:
        session.close()


async def apply(session: Any, ns: argparse.Namespace, where: Where) -> str:  # noqa: PLR0915 (one branch per fault verb)
    """The fault ``ns`` asks for (as :func:`build_parser` parses it) on the fleet ``where``,
    over an open ``session``: the CLI's and formation.testing's one path (a test that watches
    the fleet already has a session; a new ``formation fault`` process costs 1-2 s)."""
    fleet = keys.check_fleet(ns.fleet)
    bus = _Bus(session, ns.timeout)
    cmd = ns.command
    if getattr(ns, "at", None) is not None:
        return await request_at(session, ns)
    if cmd == "kill-leader":
        amsg = await bus.newest(keys.assignment_key(fleet), _decoded(Assignment))
        if amsg is None:
            raise FaultError(f"no assignment of fleet {fleet!r} within {ns.timeout:g} s")
        if amsg.leader is None:
            raise FaultError("the assignment has no leader")
        found = await _locate_robot(bus, where, amsg.leader)
        if found.host_name is not None:
            raise _refuse_host(amsg.leader, found, "kill")
        t = _signal(found.pid, signal.SIGKILL)
        await _record(session, fleet, "kill", amsg.leader, t)
        return f"killed leader {amsg.leader} (pid {found.pid}) at t={t:.6f}"
    if cmd in ("kill", "pause", "resume"):
        robot = keys.check_robot_id(ns.robot)
        if cmd == "resume":  # a stopped agent publishes nothing
            pid = await _resume(bus, where, "agent", robot)
        else:
            found = await _locate_robot(bus, where, robot)
            if found.host_name is not None:
                raise _refuse_host(robot, found, cmd)
            pid = found.pid
        t = _signal(pid, _SIG[cmd])
        await _record(session, fleet, cmd, robot, t)
        return f"{_DONE[cmd]} {robot} (pid {pid}) at t={t:.6f}"
    if cmd in ("kill-host", "pause-host", "resume-host"):
        action = cmd.removesuffix("-host")
        name = keys.check_name(ns.name)
        if action == "resume":
            pid = await _resume(bus, where, "agent-host", name)
        else:
            pid = await _locate_host(bus, where, name)
        t = _signal(pid, _SIG[action])
        return f"{_DONE[action]} agent host {name} (pid {pid}) at t={t:.6f}"
    if cmd == "kill-coordinator":
        key = keys.all_coordinator_status_pattern(fleet)
        name = ns.name

        def wanted(m: CoordinatorStatus) -> bool:
            return m.name == name if name is not None else m.role == "active"

        st = await bus.newest(key, _decoded(CoordinatorStatus, wanted))
        if st is None:
            raise FaultError(f"no status of coordinator {name or '(active)'} within timeout")
        cname = st.name
        _check_local(st.host, f"coordinator {cname}")
        pid = _verified(st.pid, "coordinator", cname, where, f"coordinator {cname}")
        t = _signal(pid, signal.SIGKILL)
        await _record(session, fleet, "kill_coordinator", None, t)
        return f"killed coordinator {cname} (pid {pid}) at t={t:.6f}"
    if cmd == "drag":
        robot = keys.check_robot_id(ns.robot)
        seen = await bus.first_of(
            [
                (keys.truth_key(fleet, robot), _decoded(Truth)),
                (keys.truths_key(fleet), _decoded(TruthBatch, lambda m: robot in m.robots)),
            ]
        )
        if seen is None:
            raise FaultError(
                f"no robot {robot!r} simulated in fleet {fleet!r} (no truth of it within "
                f"{ns.timeout:g} s): nothing to drag"
            )
        msg = Disturbance(
            t=time.monotonic(),
            robot=robot,
            kind="drag",
            dx=ns.dx,
            dy=ns.dy,
            duration_s=ns.duration,
        )
        session.put(keys.disturbance_key(fleet), encode(msg))
        await asyncio.sleep(0.05)  # let it leave before the session closes
        return f"dragged {robot} by ({ns.dx:g}, {ns.dy:g}) m over {ns.duration:g} s"
    if cmd in ("estop", "release"):
        from formation.operate.estop_tool import send_estop  # publish + acknowledgements

        target = keys.check_robot_id(ns.robot) if ns.robot is not None else None
        report = await send_estop(session, fleet, cmd == "estop", target)
        await _record(session, fleet, cmd, target, report.t)
        if not report.ok:  # the line says what is not acknowledged or not durable
            raise FaultError(report.line())
        return report.line()
    raise FaultError(f"unknown command {cmd!r}")


# ---------------------------------------------------------------------------------------------
# Command line
# ---------------------------------------------------------------------------------------------

EXAMPLES = """\
examples:
  formation fault kill-leader                          # against `formation up` on the default
  formation fault kill r2 --endpoint tcp/127.0.0.1:7500 --fleet demo
  formation fault pause r2; formation fault resume r2
  formation fault kill-host h1                         # a `formation up --hosts` fleet
  formation fault estop; formation fault release
  formation fault drag r1 -0.6 0                       # push r1 0.6 m back (simulated plant)
An authenticated run (`formation up --secure`) is found by its endpoint's port: no certificate
options needed. Exit status: 0 done, 1 target not found / not verified, 2 bad arguments."""


def _common_options(parser: argparse.ArgumentParser, *, suppress: bool) -> None:
    """--fleet, --timeout and the Zenoh options; ``suppress``: no defaults (a subcommand's copy,
    so an option given before the command is not reset by the subparser)."""

    def d(value: Any) -> Any:
        return argparse.SUPPRESS if suppress else value

    parser.add_argument(
        "--fleet",
        default=d(None),
        help="fleet name (default: $FORMATION_FLEET, else the running `formation up`'s, else "
        f"{keys.DEFAULT_FLEET})",
    )
    parser.add_argument(
        "--timeout",
        type=float,
        default=d(3.0),
        metavar="S",
        help="how long to wait for the target on the bus (default 3 s)",
    )
    rt.add_zenoh_arguments(parser)
    if suppress:
        for action in parser._actions:
            if action.dest != "help":
                action.default = argparse.SUPPRESS


def build_parser() -> argparse.ArgumentParser:
    """The ``formation fault`` argument parser (options before or after the command)."""
    fmt = argparse.RawDescriptionHelpFormatter
    p = argparse.ArgumentParser(
        prog="formation fault",
        description="Inject a fault into a running fleet; every process signalled is verified "
        "to be the target of this fleet first (docs/faults.md).",
        epilog=EXAMPLES,
        formatter_class=fmt,
    )
    _common_options(p, suppress=False)
    common = argparse.ArgumentParser(add_help=False)
    _common_options(common, suppress=True)
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")

    def add(name: str, text: str) -> argparse.ArgumentParser:
        return sub.add_parser(
            name, help=text, description=text, parents=[common], epilog=EXAMPLES,
            formatter_class=fmt,
        )  # fmt: skip

    def at(sp: argparse.ArgumentParser, undo: bool = False) -> argparse.ArgumentParser:
        sp.add_argument(
            "--at", type=float, default=None, metavar="T",
            help="at sim time T s instead of now: the active coordinator schedules it",
        )  # fmt: skip
        if undo:
            sp.add_argument(
                "--for", dest="for_s", type=float, default=None, metavar="S",
                help="with --at: undo it S s later",
            )  # fmt: skip
        return sp

    at(add("kill-leader", "SIGKILL the leader's agent"))
    for name, text in (
        ("kill", "SIGKILL a robot's agent"),
        ("pause", "SIGSTOP a robot's agent (a hung process)"),
        ("resume", "SIGCONT a paused agent"),
    ):
        at(add(name, text), undo=name == "pause").add_argument("robot", metavar="ROBOT")
    for name, text in (
        ("kill-host", "SIGKILL an agent host (every robot it runs)"),
        ("pause-host", "SIGSTOP an agent host"),
        ("resume-host", "SIGCONT a paused agent host"),
    ):
        add(name, text).add_argument("name", metavar="NAME")
    kc = at(add("kill-coordinator", "SIGKILL the active coordinator (or NAME)"))
    kc.add_argument("name", nargs="?", default=None, metavar="NAME")
    drag = add("drag", "drag a simulated robot by (DX, DY) m")
    drag.add_argument("robot", metavar="ROBOT")
    drag.add_argument("dx", type=float, metavar="DX")
    drag.add_argument("dy", type=float, metavar="DY")
    drag.add_argument("--duration", type=float, default=0.5, metavar="S", help="(default 0.5 s)")
    for name, text in (("estop", "engage the e-stop"), ("release", "release the e-stop")):
        at(add(name, f"{text} of the fleet or of ROBOT"), undo=name == "estop").add_argument(
            "robot", nargs="?", default=None, metavar="ROBOT"
        )
    return p


def main(argv: list[str]) -> int:
    """Entry point of ``formation fault``; returns the exit status."""
    ns = build_parser().parse_args(argv)
    try:
        settings = runfile.tool_settings(ns, "operator")
        keys.check_fleet(ns.fleet)
        if not ns.timeout > 0:
            raise ValueError(f"--timeout must be positive, got {ns.timeout}")
        at_s = getattr(ns, "at", None)
        if at_s is not None and not (0.0 <= at_s < 1e6):
            raise ValueError(f"--at must be a sim time in [0, 1e6) s, got {at_s}")
        for_s = getattr(ns, "for_s", None)
        if for_s is not None and (at_s is None or not 0.0 < for_s < 1e6):
            raise ValueError("--for S needs --at T and 0 < S < 1e6")
    except (TypeError, ValueError) as exc:
        print(f"formation fault: {exc}", file=sys.stderr)
        return 2
    try:
        print(asyncio.run(_run(ns, settings)), flush=True)
    except (FaultError, rt.TransportError, ValueError) as exc:
        print(f"formation fault: {exc}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main(sys.argv[1:]))
