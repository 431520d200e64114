"""``formation agent``: the command line and bootstrap of one robot agent process.

Resolves the robot id, fleet, parameters (``--config ROBOT.toml``, ``--scenario`` or the
defaults), Zenoh settings and motor backend, then runs :class:`robot_agent.node.agent.AgentNode`
under
``runtime.serve`` (signals, bounded exit). ``--check-config`` checks a robot config file without
Zenoh. The node itself, its inputs and outputs are described in :mod:`robot_agent.node.agent`.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import math
import os
import signal
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final

import runtime as rt
from bus_schemas import keys
from robot_agent.core import _accel
from robot_agent.core.params import AgentConfig
from robot_agent.motors import BackendContext, MotorBackend, create_backend
from robot_agent.node.agent import AgentNode, LoopMode
from robot_agent.node.agent_estop import attach_estop_state
from robot_agent.node.motor_output import MotorOutput
from runtime.sdnotify import Notifier

__all__ = ["build_parser", "main"]


def build_parser() -> argparse.ArgumentParser:
    """The ``formation agent`` argument parser."""
    parser = argparse.ArgumentParser(
        prog="formation agent", description="Run the firmware of one robot as a Zenoh node."
    )
    parser.add_argument("--id", dest="robot_id", metavar="ID", help="robot id ([a-z0-9_-]+)")
    source = parser.add_mutually_exclusive_group()
    source.add_argument(
        "--scenario", metavar="NAME|FILE", help="take the robot parameters from a scenario"
    )
    source.add_argument(
        "--config",
        metavar="ROBOT.toml",
        help="robot config file: id, fleet, parameters, Zenoh connection, motor backend",
    )
    source.add_argument(
        "--check-config",
        metavar="ROBOT.toml",
        help="check a robot config file, print OK or every problem, exit 0/1 (no Zenoh)",
    )
    parser.add_argument("--fleet", metavar="NAME", help="fleet name (default demo, or --config's)")
    parser.add_argument(
        "--lockstep", action="store_true", help="step on the plant's clock (docs/runtime.md)"
    )
    parser.add_argument(
        "--loop",
        choices=("on-pose", "fixed"),
        default="on-pose",
        help="realtime: step on every own pose plus a watchdog timer (default), or on the "
        "timer only",
    )
    parser.add_argument(
        "--rate-hz",
        type=rt.rate_hz,
        default=50.0,
        metavar="HZ",
        help="realtime timer rate (default 50 Hz)",
    )
    rt.add_zenoh_arguments(parser)
    return parser


@dataclass(frozen=True)
class _Setup:
    robot_id: str
    fleet: str
    config: AgentConfig
    settings: rt.ZenohSettings
    motor: MotorBackend | None


def _setup(ns: argparse.Namespace) -> _Setup:
    """Resolve id, fleet, parameters, Zenoh settings and motor backend; a mistake as
    :class:`runtime.UsageError`."""
    from scenario.robot_config import ConfigError, load_robot_config

    robot_id: str | None = ns.robot_id
    fleet: str | None = ns.fleet
    config = AgentConfig()
    motor: MotorBackend | None = None
    if ns.config is not None:
        try:
            rc = load_robot_config(ns.config)
        except ConfigError as exc:
            raise rt.UsageError(str(exc)) from None
        if robot_id is not None and robot_id != rc.robot_id:
            raise rt.UsageError(
                f"--id {robot_id} does not match robot_id {rc.robot_id!r} of {ns.config}"
            )
        robot_id = rc.robot_id
        fleet = fleet or rc.fleet
        config = rc.agent
        # The file's Zenoh section fills in what the command line did not say.
        ns.zenoh_mode = ns.zenoh_mode or rc.zenoh.mode
        ns.zenoh_connect = ns.zenoh_connect or (list(rc.zenoh.endpoints) or None)
        ns.zenoh_config = ns.zenoh_config or rc.zenoh.config_file
        if rc.motor.backend != "bus":
            try:
                context = BackendContext(config.geometry, subscribe=rt.subscribe_on_thread)
                motor = create_backend(rc.motor.backend, rc.motor.settings, context)
            except ValueError as exc:
                raise rt.UsageError(f"motor backend: {exc}") from None
    elif ns.scenario is not None:
        scenario = rt.load_scenario(ns.scenario)
        if robot_id is not None and robot_id not in scenario.robot_ids:
            raise rt.UsageError(
                f"robot {robot_id!r} is not in scenario {scenario.name!r} "
                f"({', '.join(scenario.robot_ids)})"
            )
        config = scenario.agent
    if robot_id is None:
        raise rt.UsageError("--id is required (or --config with a robot_id)")
    fleet = fleet or keys.DEFAULT_FLEET
    if not keys.is_robot_id(robot_id):
        raise rt.UsageError(f"invalid robot id {robot_id!r}: must match {keys.ROBOT_ID_PATTERN}")
    rt.check_names(("--fleet", fleet))
    return _Setup(robot_id, fleet, config, rt.zenoh_settings(ns), motor)


def check_config_command(path: str) -> int:
    """``--check-config``: print OK or every problem (one per line); 0 if valid, else 1."""
    from scenario.robot_config import check_config

    problems = check_config(Path(path))
    print("\n".join(problems) or "OK", flush=True)
    return 1 if problems else 0


def main(argv: list[str]) -> int:
    """Entry point of ``formation agent``; returns the exit status."""
    ns = build_parser().parse_args(argv)
    if ns.check_config is not None:
        return check_config_command(ns.check_config)
    try:
        setup = _setup(ns)
    except rt.UsageError as exc:
        rt.NodeLog("formation agent").info(str(exc))
        return EX_CONFIG if ns.config is not None else rt.USAGE_EXIT
    return rt.run_node(
        lambda stop: _boot(
            stop, setup, lockstep=bool(ns.lockstep), loop_mode=ns.loop, rate_hz=ns.rate_hz
        )
    )


EX_CONFIG: Final = 78
"""Exit status for an invalid configuration (sysexits EX_CONFIG): the systemd unit does not
restart it (RestartPreventExitStatus=78)."""
EX_NO_MOTOR: Final = 69
"""Exit status when the motor backend cannot be opened (EX_UNAVAILABLE): systemd restarts the
unit after RestartSec (a USB controller may be powered after the board)."""
SESSION_CLOSE_S: Final = rt.SESSION_CLOSE_S
"""How long the agent waits for its Zenoh session to close at exit before leaving without it
(``runtime.close_session``)."""
MOTOR_OPEN_ATTEMPTS: Final = 5
MOTOR_OPEN_RETRY_S: Final = 0.2
"""The motor backend is opened up to this many times, this far apart, before the agent gives up
(exit 69; systemd restarts it): the controller must confirm the zero command before READY."""
HOLD_PERIOD_S: Final = 0.1
"""While Zenoh is not connected yet, the wheels are commanded to zero this often."""


def _where(settings: rt.ZenohSettings) -> str:
    """Where a session with ``settings`` tries to connect, for the log."""
    endpoints = list(settings.connect)
    if not endpoints and settings.config_file is not None:
        try:
            conf = rt.make_config(settings)
            endpoints = json.loads(conf.get_json("connect/endpoints")) or []
        except (ValueError, RuntimeError):
            endpoints = []
    where = ", ".join(str(e) for e in endpoints) or "(no endpoint)"
    if settings.config_file is not None:
        where += f" (config {settings.config_file})"
    return where


async def _boot(
    stop: asyncio.Event,
    setup: _Setup,
    *,
    lockstep: bool,
    loop_mode: LoopMode,
    rate_hz: float,
) -> int:
    """The documented boot order (docs/deploy.md, deploy/systemd/formation-agent@.service):

    1. open the motor backend and command zero (this also arms the RoboClaw's own serial
       timeout); a port that cannot be opened is an error naming it (exit 69);
    2. READY=1 to systemd;
    3. connect to Zenoh in a background thread (``zenoh.open`` may block for as long as the
       router is unreachable), logging where; meanwhile the wheels are held at zero and the
       WATCHDOG is petted by that hold loop, and SIGINT/SIGTERM end the process at once;
    4. run the control loop (which pets the WATCHDOG from then on) until stopped.
    """
    log = rt.NodeLog(f"agent {setup.robot_id}")
    notifier = Notifier()
    motor: MotorOutput | None = None
    try:
        if setup.motor is not None:
            port = getattr(getattr(setup.motor, "config", None), "port", None)
            if isinstance(port, str) and not os.path.exists(port):
                log.info(
                    f"motor backend {setup.motor.name}: serial port {port} does not exist "
                    "(controller unplugged or powered off? udev rule not installed? "
                    "[motor] port in the robot config)"
                )
                return EX_NO_MOTOR
            opened = setup.motor.open()
            for _ in range(MOTOR_OPEN_ATTEMPTS - 1):
                if opened or stop.is_set():
                    break
                await asyncio.sleep(MOTOR_OPEN_RETRY_S)  # a busy board may miss one answer
                opened = setup.motor.open()
            if not opened:
                reason = setup.motor.status().last_error or "no answer"
                where = f" on serial port {port}" if port else ""
                log.info(f"motor backend {setup.motor.name}: no controller{where}: {reason}")
                return EX_NO_MOTOR if not stop.is_set() else 0
            setup.motor.stop()  # hold zero (open already did; say it again, it is cheap)
            motor = MotorOutput(setup.motor)
            motor.start()
        backend = setup.motor.name if setup.motor is not None else "bus"
        notifier.ready(f"agent {setup.robot_id}: motors at zero ({backend}), connecting")
        where = _where(setup.settings)
        log.info(f"motor backend {backend} open, wheels at zero; connecting to Zenoh at {where}")
        try:
            session = await _connect(stop, setup.settings, notifier, motor, log, where)
        except rt.TransportError as exc:
            log.info(f"zenoh: {exc}")
            return 1
        if session is None:
            notifier.stopping()
            return 0
        io = rt.NodeIO(
            session, asyncio.get_running_loop(), rt.Publishers(session), log, setup.settings
        )
        status = 1
        try:
            status = await _node(
                io,
                stop,
                setup,
                notifier,
                motor,
                lockstep=lockstep,
                loop_mode=loop_mode,
                rate_hz=rate_hz,
            )
            return status
        finally:
            # Wheels to zero and the port released first, then the session: closing it can
            # block while the router is unreachable (measured: > 1 s with the link down).
            if motor is not None:
                motor.close()
                motor = None
            if not rt.close_session(session, SESSION_CLOSE_S, first=io.close):
                log.info(
                    f"Zenoh session close still blocked after {SESSION_CLOSE_S:g} s (router "
                    "unreachable?); wheels are at zero, exiting without it"
                )
                notifier.stopping()
                sys.stdout.flush()
                sys.stderr.flush()
                os._exit(status)
    finally:
        if motor is not None:
            motor.close()
        elif setup.motor is not None:
            setup.motor.close()
        notifier.close()


async def _connect(
    stop: asyncio.Event,
    settings: rt.ZenohSettings,
    notifier: Notifier,
    motor: MotorOutput | None,
    log: rt.NodeLog,
    where: str,
) -> Any:
    """Open the session in a daemon thread, holding the wheels at zero until it is open; None
    if ``stop`` came first (the thread is abandoned: the process is about to exit)."""
    loop = asyncio.get_running_loop()
    opened: asyncio.Future[Any] = loop.create_future()

    def worker() -> None:
        try:
            result: object = rt.open_session(settings, timeout_s=math.inf)
        except BaseException as exc:
            result = exc
        with contextlib.suppress(RuntimeError):  # the loop is closed: nobody waits any more
            loop.call_soon_threadsafe(_settle, opened, result)

    threading.Thread(target=worker, name="zenoh-connect", daemon=True).start()
    wd_period = notifier.watchdog_interval_s()
    started = next_note = time.monotonic()
    while not opened.done() and not stop.is_set():
        now = time.monotonic()
        if motor is not None:
            motor.command(0.0, 0.0, now, True)
        if wd_period is not None:
            notifier.watchdog()  # this loop is what commands the wheels now
        if now >= next_note + 10.0:
            next_note = now
            log.info(f"still connecting to Zenoh at {where} ({now - started:.0f} s)")
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(asyncio.shield(opened), HOLD_PERIOD_S)
    if stop.is_set() and not opened.done():
        return None
    exc = opened.exception()
    if exc is not None:
        raise rt.TransportError(str(exc)) from exc
    session = opened.result()
    if stop.is_set():
        session.close()
        return None
    log.info(f"connected to Zenoh at {where} after {time.monotonic() - started:.1f} s")
    return session


def _settle(fut: asyncio.Future[Any], result: object) -> None:
    """On the loop: hand the opened session (or the error) to ``_connect``."""
    if isinstance(result, BaseException):
        if not fut.done():
            fut.set_exception(result)
    elif fut.done():
        result.close()  # type: ignore[attr-defined]  # opened after the stop: close it
    else:
        fut.set_result(result)


async def _node(
    io: rt.NodeIO,
    stop: asyncio.Event,
    setup: _Setup,
    notifier: Notifier,
    motor: MotorOutput | None,
    *,
    lockstep: bool,
    loop_mode: LoopMode,
    rate_hz: float,
) -> int:
    node = AgentNode(
        setup.robot_id,
        setup.fleet,
        setup.config,
        io.pubs.put,
        lockstep=lockstep,
        loop_mode=loop_mode,
        rate_hz=rate_hz,
        motor=motor,
        log=io.log,
    )
    node.stall.gap_s = rt.hang_gap_for(setup.settings.lease_ms)
    # Declare the publishers first, so the first command is not delayed by a declaration.
    io.pubs.get(node.wheels_key, node.wheels_qos)
    io.pubs.get(node.status_key, rt.QOS_TELEMETRY)
    if lockstep:  # the tick thread's lock, before anything the loop runs takes it
        node.guard = threading.RLock()
    await attach_estop_state(node, io)  # comes up stopped under a latched e-stop
    if lockstep:
        # One thread takes each clock and, just before it, the inputs that only a clock reads
        # (runtime.bridge.TickPump; docs/runtime.md): setpoints, movers and fault notices name
        # their tick, the plant's poses come before its clock. A scripted kill is this
        # process's death (robot_agent.node.agent_faults).
        node.scripted.die = lambda: os.kill(os.getpid(), signal.SIGKILL)
        pump = io.tick_pump(node.guard, name=f"agent-{setup.robot_id}-ticks")
        pump.side(node.fault_key, node.on_fault)
        pump.side(node.setpoint_key, node.on_setpoint)
        pump.side(node.poses_key, node.on_poses)
        pump.side(node.movers_key, node.on_movers)
        # (no robot/<id>/pose: a lockstep plant puts it only while someone subscribes to it,
        # and the agent takes its own pose from the frame, AgentNode.on_poses)
        pump.start(node.clock_key, node.on_clock)
    else:
        io.subscribe(node.setpoint_key, node.on_setpoint)
        io.subscribe(node.poses_key, node.on_poses)
        io.subscribe(node.movers_key, node.on_movers)
        # the other robots' modes: cooperative neighbours (robot_agent.core.neighbours)
        io.subscribe(keys.all_status_pattern(setup.fleet), node.peer_status.on_status)
        io.subscribe(keys.all_host_status_pattern(setup.fleet), node.peer_status.on_host_status)
        if node.claims_on:  # the other robots' motion claims (robot_agent.core.neighbour_motion)
            io.subscribe(keys.all_wheels_pattern(setup.fleet), node.on_wheels)
        io.subscribe(node.pose_key, node.on_pose)
    io.declare_token(node.alive_key)
    print(f"agent {setup.robot_id} ready", flush=True)
    notifier.status(f"agent {setup.robot_id}: connected, control loop running")
    mode = "lockstep" if lockstep else f"realtime, loop {loop_mode} at {rate_hz:g} Hz"
    backend = setup.motor.name if setup.motor is not None else "bus"
    io.log.info(f"fleet {setup.fleet}, {mode}, motor backend {backend}; core {_accel.STATUS}")
    await node.run(stop, notifier)
    notifier.stopping()
    return 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main(sys.argv[1:]))
