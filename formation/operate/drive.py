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
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Final

import runtime as rt
from bus_schemas import DecodeError, Leader, decode, keys
from bus_schemas.spec import POSITION_MAX_M

__all__ = [
    "SPEED_STEP_MPS",
    "TURN_STEP_RADPS",
    "TeleopKeys",
    "common_options",
    "finite",
    "parse_waypoints",
    "publish_and_watch",
    "watch_leader",
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


async def publish_and_watch(
    session: Any, key: str, payload: bytes, fleet: str, want_mode: str, timeout_s: float
) -> Leader | None:
    """Publish ``payload`` on ``key`` (reliable) and return the first ``leader`` message
    received after it in mode ``want_mode``, or None within ``timeout_s``."""
    return await watch_leader(
        session, key, payload, fleet, lambda m: m.mode == want_mode, timeout_s
    )


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
