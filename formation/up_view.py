"""What ``formation up`` shows while a run goes: the live table (robot, slot, role, mode,
tracking error, rejected) on a terminal, or a one-line summary, from a :class:`LiveView` (the
snapshot ``formation.collector.RunCollector.live()`` takes)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

__all__ = ["LiveRobot", "LiveView", "format_line", "format_table"]


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
