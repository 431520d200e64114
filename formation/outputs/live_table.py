"""What ``formation up`` shows while a run goes: the live table (robot, slot, role, mode,
tracking error, rejected) on a terminal, or a one-line summary, from a :class:`LiveView` (the
snapshot ``formation.record.collector.RunCollector.live()`` takes)."""

from __future__ import annotations

import asyncio
import math
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Final, Protocol

from formation.outputs.progress import eta_text

__all__ = ["LiveRobot", "LiveView", "RunDisplay", "format_line", "format_table"]

TABLE_PERIOD_S: Final = 0.5
LINE_PERIOD_S: Final = 5.0


@dataclass(frozen=True)
class LiveRobot:
    """One robot as last seen on the bus (for a status display)."""

    robot: str
    alive: bool | None  # liveliness token present (None: not watched)
    slot: int | None  # from the latest assignment
    role: str | None  # from the latest status
    mode: str | None  # from the latest status
    error_m: float | None  # |reference point (truth) - assigned slot|, metres
    rejected: int | None  # the agent's own count of rejected messages
    power: tuple[float, float] | None  # latest wheel command (right, left), fraction of max


@dataclass(frozen=True)
class LiveView:
    """Snapshot of a run in progress."""

    t_s: float | None  # time of the latest truth frame (sim time / since the first frame), s
    tick: int | None  # latest clock tick (lockstep)
    leader: str | None  # robot holding slot 0
    min_distance_m: float | None  # smallest centre distance, latest truth of each robot, m
    robots: list[LiveRobot]
    rejected: int  # payloads the collector itself rejected


def _fmt_opt(v: Any, fmt: str = "{}", none: str = "-") -> str:
    return none if v is None else fmt.format(v)


def format_table(view: LiveView, header: str, speed: float | None, progress: str = "") -> list[str]:
    """The live status table as lines (no terminal control codes); ``progress``: ETA text."""
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


def format_line(view: LiveView, speed: float | None, progress: str = "") -> str:
    """One-line summary of the live view (for logs and pipes); ``progress``: ETA text."""
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
        + (f"  {progress}" if progress else "")
    )


class LiveSource(Protocol):
    """What the display reads of a run (formation.record.collector.RunCollector; this module stays
    below the collector, which imports LiveView from here)."""

    @property
    def first_tick(self) -> int | None: ...

    @property
    def last_clock_tick(self) -> int | None: ...

    def live(self) -> LiveView: ...


class RunDisplay:
    """The launcher's terminal: messages, and the live table (or a line every few seconds).

    ``truth_rx()`` gives the launcher's (first, last) receive times of truth frames (monotonic
    seconds, None before the first)."""

    def __init__(
        self,
        collector: LiveSource,
        *,
        mode: str,
        quiet: bool,
        lockstep: bool,
        dt_s: float,
        duration_s: float,
        truth_rx: Callable[[], tuple[float | None, float | None]],
    ) -> None:
        if quiet:
            mode = "none"
        elif mode == "auto":
            mode = "table" if sys.stdout.isatty() else "lines"
        self.mode = mode
        self.quiet = quiet
        self.collector = collector
        self.lockstep = lockstep
        self.dt_s = dt_s
        self.duration_s = duration_s
        self.truth_rx = truth_rx
        self._table_lines = 0

    def say(self, text: str) -> None:
        if not self.quiet:
            self.clear_table()
            print(text, flush=True)

    def warn(self, text: str) -> None:
        self.clear_table()
        print(f"formation up: {text}", file=sys.stderr, flush=True)

    def clear_table(self) -> None:
        if self._table_lines:
            sys.stdout.write(f"\x1b[{self._table_lines}F\x1b[J")
            sys.stdout.flush()
            self._table_lines = 0

    def speed(self) -> float | None:
        """Simulated seconds per wall second (lockstep), or None."""
        view_t = self.sim_elapsed()
        first, last = self.truth_rx()
        if view_t is None or first is None or last is None:
            return None
        wall = last - first
        return view_t / wall if wall > 0.5 else None

    def sim_elapsed(self) -> float | None:
        if not self.lockstep:
            return None
        first, last = self.collector.first_tick, self.collector.last_clock_tick
        if first is None or last is None:
            return None
        return (last - first) * self.dt_s

    def progress(self) -> str:
        """``"37% of 110 s, ETA 1 min 09 s"`` once the run's clock has started, else ""."""
        if self.lockstep:
            done = self.sim_elapsed()
            return "" if done is None else eta_text(done, self.duration_s, self.speed())
        first, _ = self.truth_rx()
        if first is None:
            return ""
        # realtime: the duration counts from the first truth frame, at 1x
        return eta_text(time.monotonic() - first, self.duration_s, 1.0)

    async def loop(self, header: str) -> None:
        """Show the live view until cancelled."""
        if self.mode == "none":
            return
        period = TABLE_PERIOD_S if self.mode == "table" else LINE_PERIOD_S
        while True:
            await asyncio.sleep(period)
            view = self.collector.live()
            progress = self.progress()
            if self.mode == "table":
                lines = format_table(view, header, self.speed(), progress)
                self.clear_table()
                sys.stdout.write("\n".join(lines) + "\n")
                sys.stdout.flush()
                self._table_lines = len(lines)
            else:
                print(format_line(view, self.speed(), progress), flush=True)
