"""What ``formation teleop``, ``formation goal`` and ``formation path`` share (issue 28): the
keyboard's teleop state (pure), the checks of a goal or a path given on the command line, the
common options, and publishing one operator command and watching the leader take it.

Keyboard (``formation teleop``), like TurtleBot3's ``teleop_keyboard``: the twist is a state the
keys step, sent :data:`bus_schemas.messages_operator.CMD_RATE_HZ` times a second whether a key
is pressed or not (so a held key's autorepeat delay never trips the deadman, and the deadman
trips when this tool dies or its link does):

=========  =====================================================
``w``/``x``  faster / slower (``SPEED_STEP_MPS``), forward positive
``a``/``d``  turn left / right (``TURN_STEP_RADPS``)
``s``/space  stop (zero twist, still sent)
``q``        quit (the stream stops: the coordinator's deadman stops the leader)
=========  =====================================================
"""

from __future__ import annotations

import argparse
import asyncio
import itertools
import math
import struct
import sys
import time
from collections.abc import Awaitable, Callable, Sequence
from dataclasses import dataclass
from typing import Any, Final

import runtime as rt
from bus_schemas import DecodeError, Leader, decode, keys
from bus_schemas.spec import POSITION_MAX_M

__all__ = [
    "JS_EVENT",
    "SPEED_STEP_MPS",
    "TURN_STEP_RADPS",
    "Gamepad",
    "TeleopKeys",
    "alive_robots",
    "common_options",
    "find_gamepad",
    "finite",
    "parse_waypoints",
    "send_and_confirm",
    "watch_leader",
    "watch_status",
]

SPEED_STEP_MPS: Final = 0.01
TURN_STEP_RADPS: Final = 0.05
SPEED_MAX_MPS: Final = 0.2
"""The keyboard never asks more than this (m/s); the coordinator clamps to its own limit."""
TURN_MAX_RADPS: Final = 1.0


@dataclass
class TeleopKeys:
    """The twist the keys have set (pure: a key in, the state changes)."""

    v_mps: float = 0.0
    omega_radps: float = 0.0
    quit: bool = False

    def press(self, key: str) -> bool:
        """Apply ``key``; False if it is not a teleop key (ignored)."""
        k = key.lower()
        if k == "w":
            self.v_mps = min(SPEED_MAX_MPS, round(self.v_mps + SPEED_STEP_MPS, 6))
        elif k == "x":
            self.v_mps = max(-SPEED_MAX_MPS, round(self.v_mps - SPEED_STEP_MPS, 6))
        elif k == "a":
            self.omega_radps = min(TURN_MAX_RADPS, round(self.omega_radps + TURN_STEP_RADPS, 6))
        elif k == "d":
            self.omega_radps = max(-TURN_MAX_RADPS, round(self.omega_radps - TURN_STEP_RADPS, 6))
        elif k in ("s", " "):
            self.v_mps = self.omega_radps = 0.0
        elif k == "q" or key == "\x03":
            self.quit = True
        else:
            return False
        return True


JS_EVENT = struct.Struct("<IhBB")
"""The Linux joystick API's event (``linux/joystick.h``): time (ms), value, type, number."""
JS_BUTTON, JS_AXIS, JS_INIT = 0x01, 0x02, 0x80
AXIS_MAX: Final = 32767
DEADZONE: Final = 0.1
"""Stick deflection (fraction of full) read as zero: a centred stick drifts a little."""


@dataclass
class Gamepad:
    """A gamepad read through ``/dev/input/js*`` (pure: bytes in, twist out). The left stick:
    up/down is the speed (up forward), left/right the turn (left positive); button 0 (A /
    cross) stops, as ``s``; any axis moved makes the gamepad the source of the twist."""

    v_axis: int = 1
    w_axis: int = 0
    axes: dict[int, float] | None = None
    stop_pressed: bool = False
    _buf: bytes = b""

    def feed(self, data: bytes) -> None:
        """Events read from the device (any chunking)."""
        buf = self._buf + data
        n = len(buf) // JS_EVENT.size * JS_EVENT.size
        for off in range(0, n, JS_EVENT.size):
            _t, value, kind, number = JS_EVENT.unpack_from(buf, off)
            kind &= ~JS_INIT
            if kind == JS_AXIS:
                if self.axes is None:
                    self.axes = {}
                self.axes[number] = max(-1.0, min(1.0, value / AXIS_MAX))
            elif kind == JS_BUTTON and number == 0 and value:
                self.stop_pressed = True
        self._buf = buf[n:]

    def twist(self, max_v_mps: float, max_w_radps: float) -> tuple[float, float] | None:
        """``(v, omega)`` from the stick (None until an axis was read)."""
        if self.axes is None:
            return None

        def dz(x: float) -> float:
            return 0.0 if abs(x) < DEADZONE else (x - math.copysign(DEADZONE, x)) / (1 - DEADZONE)

        v = -dz(self.axes.get(self.v_axis, 0.0)) * max_v_mps  # stick up is negative
        w = -dz(self.axes.get(self.w_axis, 0.0)) * max_w_radps  # stick left is negative
        return round(v, 6), round(w, 6)


def find_gamepad(root: str = "/dev/input") -> str | None:
    """The first joystick device (``/dev/input/js0``, ...) present, or None."""
    import glob

    found = sorted(glob.glob(f"{root}/js[0-9]*"))
    return found[0] if found else None


def finite(name: str, text: str, *, bound: float = POSITION_MAX_M) -> float:
    """``text`` as a finite float within ``[-bound, bound]``, or ValueError naming ``name``."""
    try:
        value = float(text)
    except ValueError:
        raise ValueError(f"{name} must be a number, got {text!r}") from None
    if not math.isfinite(value):
        raise ValueError(f"{name} must be finite, got {text!r}")
    if abs(value) > bound:
        raise ValueError(f"{name} must be within +-{bound:g}, got {text!r}")
    return value


def parse_waypoints(items: Sequence[str]) -> list[tuple[float, float]]:
    """``["X,Y", ...]`` (or ``"X,Y X,Y"``) as points; ValueError names the bad one."""
    out: list[tuple[float, float]] = []
    for item in (p for chunk in items for p in chunk.split()):
        parts = item.split(",")
        if len(parts) != 2:
            raise ValueError(f"waypoint {item!r} is not X,Y")
        out.append((finite("waypoint x", parts[0]), finite("waypoint y", parts[1])))
    if not out:
        raise ValueError("--waypoints needs at least one X,Y")
    for a, b in itertools.pairwise(out):
        if math.hypot(b[0] - a[0], b[1] - a[1]) < 1e-6:
            raise ValueError(f"two consecutive waypoints are the same point {a}")
    return out


def common_options(parser: argparse.ArgumentParser) -> None:
    """--fleet, --timeout and the Zenoh options."""
    parser.add_argument("--fleet", default=keys.DEFAULT_FLEET, help="fleet name")
    parser.add_argument(
        "--timeout",
        type=float,
        default=3.0,
        metavar="S",
        help="how long to wait for the coordinator to take the command",
    )
    rt.add_zenoh_arguments(parser)


async def alive_robots(session: Any, fleet: str, wait_s: float = 0.3) -> set[str]:
    """The robots of ``fleet`` whose liveliness token is on the bus (seen within ``wait_s``)."""
    loop = asyncio.get_running_loop()
    alive: set[str] = set()

    def on(key: str, up: bool) -> None:
        parsed = keys.parse_alive_key(key)
        if parsed is not None and parsed[1] == "robot" and parsed[2] is not None:
            (alive.add if up else alive.discard)(parsed[2])

    sub = rt.watch_liveliness(session, keys.alive_robots_pattern(fleet), loop, on)
    try:
        await asyncio.sleep(wait_s)
    finally:
        sub.undeclare()
    return alive


async def watch_leader(
    session: Any,
    key: str,
    payload: bytes,
    fleet: str,
    want: Callable[[Leader], bool],
    timeout_s: float,
) -> Leader | None:
    """Publish ``payload`` on ``key`` (reliable) and return the first ``leader`` message
    received after it for which ``want`` is true, or None within ``timeout_s``."""
    loop = asyncio.get_running_loop()
    got: list[Leader] = []
    t_pub = time.monotonic()

    def on_leader(rx: rt.Received) -> None:
        if rx.rx_s <= t_pub:
            return
        msg = decode(rx.payload, Leader)
        if not isinstance(msg, DecodeError) and want(msg):
            got.append(msg)

    sub = rt.subscribe(session, keys.leader_key(fleet), loop, on_leader)
    try:
        await asyncio.sleep(0.1)  # the subscriber is declared at the router
        pubs = rt.Publishers(session)
        pubs.put(key, payload, rt.QOS_CRITICAL)
        deadline = time.monotonic() + timeout_s
        while not got and time.monotonic() < deadline:
            await asyncio.sleep(0.02)
    finally:
        sub.undeclare()
    return got[0] if got else None


async def watch_status(
    session: Any,
    fleet: str,
    want: Callable[[dict[str, Any]], bool],
    timeout_s: float,
    after_s: float,
) -> dict[str, Any] | None:
    """The first status (a plain map) of an ACTIVE coordinator of ``fleet`` received after
    ``after_s`` (``time.monotonic()``) for which ``want`` is true, or None within
    ``timeout_s``."""
    import msgpack

    loop = asyncio.get_running_loop()
    got: list[dict[str, Any]] = []

    def on_status(rx: rt.Received) -> None:
        if rx.rx_s <= after_s or got:
            return
        try:
            m = msgpack.unpackb(rx.payload)
        except Exception:
            return
        if isinstance(m, dict) and m.get("role") == "active" and want(m):
            got.append(m)

    sub = rt.subscribe(session, keys.all_coordinator_status_pattern(fleet), loop, on_status)
    try:
        deadline = time.monotonic() + timeout_s
        while not got and time.monotonic() < deadline:
            await asyncio.sleep(0.02)
    finally:
        sub.undeclare()
    return got[0] if got else None


def send_and_confirm(
    prog: str,
    settings: rt.ZenohSettings,
    key: str,
    payload: bytes,
    fleet: str,
    want: Callable[[Leader], bool],
    timeout_s: float,
    *,
    taken: Callable[[Leader], str],
    missing: str,
    check: Callable[[Any], Awaitable[str | None]] | None = None,
) -> int:
    """One operator command end to end (``formation goal``, ``path``, ``shape``): publish it,
    wait for the coordinator's ``leader`` message that shows it was taken (``want``), print
    ``taken(leader)`` and return 0; else print ``missing`` (what did not happen within
    ``timeout_s``) and return 1, as for a bus that cannot be reached. ``check(session)``, if
    given, runs first: an error it returns is printed as one line, nothing is sent, exit 2."""

    async def run() -> int:
        session = await rt.open_session_async(settings)
        try:
            why = None if check is None else await check(session)
            if why is not None:
                print(f"{prog}: error: {why}", file=sys.stderr)
                return 2
            got = await watch_leader(session, key, payload, fleet, want, timeout_s)
        finally:
            session.close()
        if got is None:
            print(
                f"{prog}: no coordinator of fleet {fleet!r} {missing} within {timeout_s:g} s",
                file=sys.stderr,
            )
            return 1
        print(taken(got))
        return 0

    try:
        return asyncio.run(run())
    except rt.TransportError as exc:
        print(f"{prog}: {exc}", file=sys.stderr)
        return 1
