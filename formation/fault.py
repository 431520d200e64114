"""``formation fault``: inject a fault into a running fleet (``formation up`` or separate nodes).

Usage::

    formation fault kill-leader                 # SIGKILL the agent of the robot in slot 0
    formation fault kill ROBOT                  # SIGKILL that robot's agent
    formation fault pause ROBOT                 # SIGSTOP it (a hang: detected after the lease)
    formation fault resume ROBOT                # SIGCONT it
    formation fault kill-coordinator [NAME]     # SIGKILL the active coordinator (or NAME)
    formation fault drag ROBOT DX DY [--duration S]   # push the simulated robot (plant only)
    formation fault estop [ROBOT]               # latched emergency stop, fleet or one robot
    formation fault release [ROBOT]             # release it
    ... [--fleet demo] [--timeout 3] [zenoh options: --endpoint tcp/127.0.0.1:7447 ...]

Theory of operation
-------------------
Everything is found on the bus, so the tool needs no state of its own: the leader is the
``leader`` field of the coordinator's ``assignment`` (re-published at least once a second); an
agent's process is the ``pid`` of its ``robot/<id>/status`` (5 Hz), a coordinator's the ``pid``
of ``coordinator/<name>/status``, and ``host`` must be this host (a signal cannot cross
machines; the tool refuses otherwise). A paused agent publishes nothing, so ``resume`` (and any
lookup that times out) falls back to this host's ``/proc``: the process whose command line is
``... -m formation agent ... --id ROBOT``. ``drag`` publishes a ``disturbance`` (the plant drags
the robot by (DX, DY) m over ``--duration`` s); ``estop``/``release`` publish ``estop`` (twice,
20 ms apart: it is idempotent and latched, and a second copy costs nothing).

Prints one line saying what was done, with the ``time.monotonic()`` of the action (same clock as
``t`` on a local bus), and exits 0; 1 if the target was not found or could not be signalled; 2
for bad arguments.
"""

from __future__ import annotations

import argparse
import asyncio
import os
import signal
import socket
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import msgpack

import runtime as rt
from bus_schemas import Assignment, DecodeError, Disturbance, Status, decode, encode, keys

__all__ = ["build_parser", "find_agent_pids", "main"]


class FaultError(RuntimeError):
    """The target could not be found or signalled."""


def find_agent_pids(robot: str, fleet: str | None = None) -> list[int]:
    """Local processes running ``formation agent --id ROBOT`` (and ``--fleet FLEET`` when it is
    given and not the default), from ``/proc``."""
    found: list[int] = []
    for entry in os.listdir("/proc"):
        if not entry.isdigit() or int(entry) == os.getpid():
            continue
        try:
            argv = Path(f"/proc/{entry}/cmdline").read_bytes().split(b"\0")
        except OSError:
            continue
        args = [a.decode(errors="replace") for a in argv if a]
        if "formation" not in args or "agent" not in args:
            continue
        if not _has_opt(args, "--id", robot):
            continue
        if (
            fleet is not None
            and fleet != keys.DEFAULT_FLEET
            and not _has_opt(args, "--fleet", fleet)
        ):
            continue
        found.append(int(entry))
    return sorted(found)


def _has_opt(args: list[str], opt: str, value: str) -> bool:
    return any(a == opt and i + 1 < len(args) and args[i + 1] == value for i, a in enumerate(args))


class _Bus:
    """The newest decoded message of a few keys, waited for with a timeout."""

    def __init__(self, session: Any, timeout_s: float) -> None:
        self.session = session
        self.timeout_s = timeout_s

    async def newest(self, key: str, parse: Callable[[bytes], Any]) -> Any:
        """The first valid message on ``key`` within the timeout, or None."""
        loop = asyncio.get_running_loop()
        got: asyncio.Future[Any] = loop.create_future()

        def on(rx: rt.Received) -> None:
            if got.done():
                return
            value = parse(rx.payload)
            if value is not None:
                got.set_result(value)

        sub = rt.subscribe(self.session, key, loop, on)
        try:
            return await asyncio.wait_for(got, self.timeout_s)
        except TimeoutError:
            return None
        finally:
            sub.undeclare()


def _decoded(kind: Any) -> Callable[[bytes], Any]:
    def parse(payload: bytes) -> Any:
        msg = decode(payload, kind)
        return None if isinstance(msg, DecodeError) else msg

    return parse


def _plain_map(payload: bytes) -> Any:
    try:
        value = msgpack.unpackb(payload, raw=False)
    except Exception:
        return None
    return value if isinstance(value, dict) else None


def _check_local(host: Any, what: str) -> None:
    here = socket.gethostname()[:255] or "unknown"
    if host != here:
        raise FaultError(f"{what} runs on host {host!r}, not here ({here!r}): cannot signal it")


async def _agent_pid(bus: _Bus, fleet: str, robot: str) -> int:
    status = await bus.newest(keys.status_key(fleet, robot), _decoded(Status))
    if status is not None and status.pid > 0:
        _check_local(status.host, f"agent {robot}")
        return int(status.pid)
    pids = find_agent_pids(robot, fleet)
    if len(pids) == 1:
        return pids[0]
    if not pids:
        raise FaultError(f"no status from robot {robot!r} and no local agent process for it")
    raise FaultError(f"several local agent processes for {robot!r}: {pids}")


def _signal(pid: int, sig: signal.Signals) -> float:
    try:
        os.kill(pid, sig)
    except ProcessLookupError:
        raise FaultError(f"process {pid} does not exist") from None
    except PermissionError:
        raise FaultError(f"not allowed to signal process {pid}") from None
    return time.monotonic()


async def _run(ns: argparse.Namespace, settings: rt.ZenohSettings) -> str:
    fleet = keys.check_fleet(ns.fleet)
    session = await rt.open_session_async(settings)
    try:
        bus = _Bus(session, ns.timeout)
        cmd = ns.command
        if cmd == "kill-leader":
            amsg = await bus.newest(keys.assignment_key(fleet), _decoded(Assignment))
            if amsg is None:
                raise FaultError(f"no assignment on the bus within {ns.timeout} s")
            if amsg.leader is None:
                raise FaultError("the assignment has no leader")
            pid = await _agent_pid(bus, fleet, amsg.leader)
            t = _signal(pid, signal.SIGKILL)
            return f"killed leader {amsg.leader} (pid {pid}) at t={t:.6f}"
        if cmd in ("kill", "pause", "resume"):
            robot = keys.check_robot_id(ns.robot)
            sig = {"kill": signal.SIGKILL, "pause": signal.SIGSTOP, "resume": signal.SIGCONT}[cmd]
            if cmd == "resume":  # a stopped agent publishes no status
                pids = find_agent_pids(robot, fleet)
                if not pids:
                    raise FaultError(f"no local agent process for {robot!r}")
                pid = pids[0]
            else:
                pid = await _agent_pid(bus, fleet, robot)
            t = _signal(pid, sig)
            done = {"kill": "killed", "pause": "paused", "resume": "resumed"}[cmd]
            return f"{done} {robot} (pid {pid}) at t={t:.6f}"
        if cmd == "kill-coordinator":
            key = f"{keys.ROOT}/{fleet}/coordinator/*/status"
            name = ns.name

            def parse(payload: bytes) -> Any:
                m = _plain_map(payload)
                if m is None or not isinstance(m.get("pid"), int):
                    return None
                if name is not None:
                    return m if m.get("name") == name else None
                return m if m.get("role", "active") == "active" else None

            st = await bus.newest(key, parse)
            if st is None:
                raise FaultError(f"no status of coordinator {name or '(active)'} within timeout")
            _check_local(st.get("host"), f"coordinator {st.get('name')}")
            t = _signal(int(st["pid"]), signal.SIGKILL)
            return f"killed coordinator {st.get('name')} (pid {st['pid']}) at t={t:.6f}"
        if cmd == "drag":
            robot = keys.check_robot_id(ns.robot)
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
            from formation.estop_tool import send_estop  # publish + acknowledgements

            target = keys.check_robot_id(ns.robot) if ns.robot is not None else None
            report = await send_estop(session, fleet, cmd == "estop", target)
            if not report.ok:
                raise FaultError(report.line() + " (no robot acknowledged)")
            return report.line()
        raise FaultError(f"unknown command {cmd!r}")
    finally:
        session.close()


def build_parser() -> argparse.ArgumentParser:
    """The ``formation fault`` argument parser."""
    p = argparse.ArgumentParser(
        prog="formation fault", description="Inject a fault into a running fleet."
    )
    p.add_argument("--fleet", default=keys.DEFAULT_FLEET, help="fleet name (demo)")
    p.add_argument(
        "--timeout", type=float, default=3.0, metavar="S", help="bus lookup timeout (3 s)"
    )
    sub = p.add_subparsers(dest="command", required=True)
    sub.add_parser("kill-leader", help="SIGKILL the leader's agent")
    for name, text in (
        ("kill", "SIGKILL a robot's agent"),
        ("pause", "SIGSTOP a robot's agent (a hung process)"),
        ("resume", "SIGCONT a paused agent"),
    ):
        sub.add_parser(name, help=text).add_argument("robot", metavar="ROBOT")
    kc = sub.add_parser("kill-coordinator", help="SIGKILL the active coordinator (or NAME)")
    kc.add_argument("name", nargs="?", default=None, metavar="NAME")
    drag = sub.add_parser("drag", help="drag a simulated robot by (DX, DY) m")
    drag.add_argument("robot", metavar="ROBOT")
    drag.add_argument("dx", type=float, metavar="DX")
    drag.add_argument("dy", type=float, metavar="DY")
    drag.add_argument("--duration", type=float, default=0.5, metavar="S", help="(0.5 s)")
    for name, text in (("estop", "engage the e-stop"), ("release", "release the e-stop")):
        sp = sub.add_parser(name, help=f"{text} of the fleet or of ROBOT")
        sp.add_argument("robot", nargs="?", default=None, metavar="ROBOT")
    rt.add_zenoh_arguments(p)
    return p


def main(argv: list[str]) -> int:
    """Entry point of ``formation fault``; returns the exit status."""
    ns = build_parser().parse_args(argv)
    try:
        settings = rt.settings_from_args(ns)
        keys.check_fleet(ns.fleet)
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
