"""``formation teleop``: drive the virtual leader from the terminal's keyboard (issue 28).

Sends the twist the keys set (:class:`formation.operate.drive.TeleopKeys`: ``w``/``x`` speed,
``a``/``d`` turn, ``s`` stop, ``q`` quit) on ``formation/<fleet>/operator/cmd_vel`` 20 times a
second, and shows on one line the twist asked, the leader's speed and heading as the
coordinator publishes them, its mode and whether the deadman has tripped. The coordinator
integrates the twist within its limits (coordinator.core.leader); when this tool stops (``q``,
Ctrl-C, a crash, a lost link) its deadman stops the leader within a few hundred ms.

A gamepad (``/dev/input/js*``, the Linux joystick API; ``--gamepad``, by default the first one
present) drives too: left stick up/down the speed, left/right the turn, button 0 stops
(:class:`formation.operate.drive.Gamepad`); once its stick moved it sets the twist.

Without a terminal (stdin not a TTY), keys are read from stdin as they come (a script can pipe
them); ``--v`` / ``--omega`` set the starting twist and ``--duration`` ends the stream after
that long (scripted teleop: ``formation teleop --v 0.05 --duration 10``). Under ``--secure``
this tool connects as the operator identity: only it may command the leader.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import math
import os
import sys
import time
from collections.abc import Iterator

import runtime as rt
from bus_schemas import CmdVel, DecodeError, Leader, decode, encode, keys
from bus_schemas.messages_operator import CMD_RATE_HZ
from formation.operate.drive import SPEED_MAX_MPS as KEY_SPEED_MAX_MPS
from formation.operate.drive import (
    TURN_MAX_RADPS,
    Gamepad,
    TeleopKeys,
    common_options,
    find_gamepad,
    finite,
)
from formation.outputs import runfile


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="formation teleop",
        description="Drive the virtual leader from the keyboard: w/x speed, a/d turn, s stop, "
        "q quit. The coordinator's deadman stops the leader when this stream stops.",
    )
    common_options(p)
    p.add_argument("--v", default="0", metavar="MPS", help="starting forward speed (m/s)")
    p.add_argument("--omega", default="0", metavar="RADPS", help="starting turn rate (rad/s)")
    p.add_argument("--duration", default=None, metavar="S", help="stop the stream after S seconds")
    p.add_argument("--quiet", action="store_true", help="no status line")
    p.add_argument(
        "--gamepad",
        default="auto",
        metavar="DEV",
        help="a joystick device (/dev/input/jsN) to drive with; auto: the first one present; "
        "none: the keyboard only",
    )
    return p


@contextlib.contextmanager
def _raw_keys() -> Iterator[bool]:
    """The terminal in cbreak mode (keys as they are pressed) while in the block; yields
    whether stdin is a terminal."""
    if not sys.stdin.isatty():
        yield False
        return
    import termios
    import tty

    fd = sys.stdin.fileno()
    old = termios.tcgetattr(fd)
    try:
        tty.setcbreak(fd)
        yield True
    finally:
        termios.tcsetattr(fd, termios.TCSADRAIN, old)


def _status_line(keys_: TeleopKeys, leader: Leader | None, age_s: float | None) -> str:
    asked = f"asked v {keys_.v_mps:+.2f} m/s, omega {keys_.omega_radps:+.2f} rad/s"
    if leader is None or age_s is None or age_s > 1.0:
        return f"{asked} | leader: not heard"
    deadman = "TRIPPED" if leader.deadman else "ok"
    return (
        f"{asked} | leader {leader.mode or 'script'}: v {leader.v_mps:+.3f} m/s, "
        f"heading {math.degrees(leader.theta):+6.1f} deg, rate {leader.rate or 1.0:.2f}, "
        f"deadman {deadman}"
    )


async def _run(ns: argparse.Namespace, settings: rt.ZenohSettings, state: TeleopKeys) -> int:
    fleet = ns.fleet
    session = await rt.open_session_async(settings)
    loop = asyncio.get_running_loop()
    latest: list[tuple[float, Leader]] = []

    def on_leader(rx: rt.Received) -> None:
        msg = decode(rx.payload, Leader)
        if not isinstance(msg, DecodeError):
            latest[:] = [(rx.rx_s, msg)]

    sub = rt.subscribe(session, keys.leader_key(fleet), loop, on_leader)
    pubs = rt.Publishers(session)
    key = keys.cmd_vel_key(fleet)
    period = 1.0 / CMD_RATE_HZ
    end = None if ns.duration is None else time.monotonic() + ns.duration
    seq = 0
    pad, pad_fd = Gamepad(), ns.gamepad_fd
    if pad_fd is not None:
        loop.add_reader(pad_fd, _read_pad, pad_fd, pad)
        print(f"formation teleop: gamepad {ns.gamepad_path}", file=sys.stderr)
    with _raw_keys() as tty_mode:
        reader = _KeyReader(loop, tty_mode)
        try:
            next_t = time.monotonic()
            while not state.quit and (end is None or time.monotonic() < end):
                for k in reader.take():
                    state.press(k)
                if state.quit:
                    break
                stick = pad.twist(KEY_SPEED_MAX_MPS, TURN_MAX_RADPS)
                if pad.stop_pressed:
                    pad.stop_pressed = False
                    state.press("s")
                elif stick is not None:
                    state.v_mps, state.omega_radps = stick
                seq += 1
                msg = CmdVel(
                    t=max(time.monotonic(), 0.0),
                    seq=seq,
                    v_mps=state.v_mps,
                    omega_radps=state.omega_radps,
                )
                pubs.put(key, encode(msg), rt.QOS_CONTROL)
                if not ns.quiet:
                    rx_s, leader = latest[0] if latest else (None, None)
                    age = None if rx_s is None else time.monotonic() - rx_s
                    line = _status_line(state, leader, age)
                    print(f"\r{line}\x1b[K" if tty_mode else line, end="" if tty_mode else "\n",
                          flush=True)  # fmt: skip
                next_t += period
                await asyncio.sleep(max(0.0, next_t - time.monotonic()))
        finally:
            reader.close()
            if pad_fd is not None:
                with contextlib.suppress(Exception):
                    loop.remove_reader(pad_fd)
                os.close(pad_fd)
            sub.undeclare()
            if tty_mode and not ns.quiet:
                print()
            session.close()
    print(f"formation teleop: stream stopped after {seq} twists", file=sys.stderr)
    return 0


def _read_pad(fd: int, pad: Gamepad) -> None:
    with contextlib.suppress(OSError):  # unplugged: the last twist stays until a key changes it
        pad.feed(os.read(fd, 8 * 64))


def _open_gamepad(choice: str) -> tuple[str | None, int | None]:
    """``--gamepad``: (path, non-blocking fd) of the device to read, or (None, None). A device
    asked for that cannot be opened is a ValueError; one found by ``auto`` is skipped."""
    path = find_gamepad() if choice == "auto" else None if choice == "none" else choice
    if path is None:
        return None, None
    try:
        return path, os.open(path, os.O_RDONLY | os.O_NONBLOCK)
    except OSError as exc:
        if choice != "auto":
            raise ValueError(f"--gamepad {path}: {exc.strerror}") from None
        return None, None


class _KeyReader:
    """Keys from stdin without blocking the loop (a terminal in cbreak mode, or a pipe)."""

    def __init__(self, loop: asyncio.AbstractEventLoop, tty_mode: bool) -> None:
        self._keys: list[str] = []
        self._loop = loop
        self._fd: int | None = None
        try:
            fd = sys.stdin.fileno()
        except (OSError, ValueError):
            return
        self._fd = fd
        try:
            loop.add_reader(fd, self._read)
        except (OSError, ValueError, NotImplementedError):
            self._fd = None

    def _read(self) -> None:
        assert self._fd is not None
        try:
            data = os.read(self._fd, 64)
        except OSError:
            data = b""
        if not data:  # end of a pipe: no more keys (the stream goes on until --duration or q)
            self.close()
            return
        self._keys.extend(data.decode("utf-8", "replace"))

    def take(self) -> list[str]:
        out, self._keys = self._keys, []
        return out

    def close(self) -> None:
        if self._fd is not None:
            with contextlib.suppress(Exception):
                self._loop.remove_reader(self._fd)
            self._fd = None


def main(argv: list[str]) -> int:
    """Entry point of ``formation teleop``."""
    ns = build_parser().parse_args(argv)
    try:
        keys.check_fleet(ns.fleet)
        state = TeleopKeys(
            v_mps=finite("--v", ns.v, bound=KEY_SPEED_MAX_MPS),
            omega_radps=finite("--omega", ns.omega, bound=TURN_MAX_RADPS),
        )
        if ns.duration is not None:
            ns.duration = finite("--duration", ns.duration, bound=1e6)
            if ns.duration <= 0:
                raise ValueError(f"--duration must be positive, got {ns.duration:g}")
        settings = runfile.tool_settings(ns, "operator")
        ns.gamepad_path, ns.gamepad_fd = _open_gamepad(ns.gamepad)
    except (TypeError, ValueError) as exc:
        print(f"formation teleop: error: {exc}", file=sys.stderr)
        return 2
    try:
        return asyncio.run(_run(ns, settings, state))
    except rt.TransportError as exc:
        print(f"formation teleop: {exc}", file=sys.stderr)
        return 1


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main(sys.argv[1:]))
