"""The look every figure of :mod:`formation.outputs.figures` shares: sizes (at most :data:`MAX_PX`
pixels a side), one colour and line style per robot, decimation of long series for drawing
only (extremes kept), NaN-tolerant statistics, and the world's obstacles and arena.

Split out of ``formation/outputs/figures.py``, which re-exports the public names.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Final

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.figure import Figure

__all__ = [
    "COLORS",
    "DETAIL_MAX",
    "DPI",
    "LEGEND_MAX",
    "MAX_POINTS",
    "MAX_PX",
    "STYLES",
    "draw_stride",
    "draw_world",
    "envelope",
    "nan_percentiles",
    "nanmax",
    "new_figure",
    "no_data_figure",
    "robot_style",
    "save_figure",
]

MAX_PX: Final = 2000
"""No figure is wider or taller than this many pixels."""
DPI: Final = 110
DETAIL_MAX: Final = 10
"""Per-robot panels/lines up to this many robots; aggregate views beyond."""
LEGEND_MAX: Final = 20
"""Per-robot colours and a legend in the trajectory plot up to this many robots."""
MAX_POINTS: Final = 1500  # points drawn per time series (decimation for drawing only)

# 20 qualitative colours, the paper's red, green, blue first (its robots wore those colours).
COLORS: Final = (
    "#d62728", "#2ca02c", "#1f77b4", "#ff7f0e", "#9467bd", "#8c564b", "#e377c2", "#17becf",
    "#bcbd22", "#7f7f7f", "#000075", "#800000", "#469990", "#f032e6", "#b8860b", "#6a3d9a",
    "#4b0082", "#00a86b", "#ff1493", "#2f4f4f",
)  # fmt: skip
STYLES: Final = ("-", "--", ":", "-.")


def robot_style(i: int) -> tuple[str, str]:
    """``(colour, line style)`` of robot ``i``: 20 distinct colours drawn solid for robots
    0-19, the same colours dashed for 20-39, dotted for 40-59, dash-dot for 60-79, so no two of
    the first 80 robots look the same (per-robot views stop at :data:`LEGEND_MAX` anyway)."""
    return COLORS[i % len(COLORS)], STYLES[(i // len(COLORS)) % len(STYLES)]


def _color(i: int) -> str:
    return robot_style(i)[0]


def new_figure(w_in: float, h_in: float) -> Figure:
    w = min(w_in, MAX_PX / DPI)
    h = min(h_in, MAX_PX / DPI)
    return plt.figure(figsize=(w, h), dpi=DPI, layout="constrained")


def save_figure(fig: Figure, path: Path) -> None:
    fig.savefig(path, dpi=DPI)  # no bbox_inches="tight": the size stays the figure's
    plt.close(fig)


def no_data_figure(title: str) -> Figure:
    """A small figure saying the run recorded no tick (an empty or at once interrupted run)."""
    fig = new_figure(6.0, 2.0)
    fig.text(0.5, 0.6, title, ha="center", va="center", fontsize=11)
    fig.text(0.5, 0.3, "no tick recorded: nothing to plot", ha="center", color="0.4")
    return fig


def draw_stride(ticks: int) -> int:
    return max(1, math.ceil(ticks / MAX_POINTS))


def envelope(t: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Decimate a series for drawing without losing its extremes: per bucket of ticks, the
    minimum and the maximum (NaN ignored), so no peak disappears from a line plot."""
    k = draw_stride(t.size)
    if k == 1:
        return t, y
    nb = math.ceil(t.size / k)
    pad = nb * k - t.size
    if pad:
        y = np.concatenate([y, np.repeat(y[-1:], pad, axis=0)])
    yb = y.reshape(nb, k, *y.shape[1:])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        lo, hi = np.nanmin(yb, axis=1), np.nanmax(yb, axis=1)
    tb = t[::k]
    return np.repeat(tb, 2), np.stack([lo, hi], axis=1).reshape(2 * nb, *y.shape[1:])


def nan_percentiles(a: np.ndarray, qs: Sequence[float]) -> np.ndarray:
    """Percentiles over axis 1, NaN ignored; NaN for rows with no finite value."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return np.asarray(np.nanpercentile(a, qs, axis=1))


def nanmax(a: np.ndarray, axis: int | None = None) -> Any:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return np.nanmax(a, axis=axis)


def draw_world(ax: Any, world: Any, scale: float = 100.0) -> int:
    """Draw a ``WorldMap``'s obstacles (grey: discs, thick lines for segments) and its arena
    (a dotted rectangle) on ``ax`` in units of ``1 / scale`` m; returns how many were drawn."""
    if world is None:
        return 0
    from matplotlib.patches import Circle, Rectangle

    from robot_agent.core.params import CircleObstacle

    drawn = 0
    label: str | None = "obstacles"
    for o in world.obstacles:
        if isinstance(o, CircleObstacle):
            ax.add_patch(
                Circle((o.x * scale, o.y * scale), o.radius_m * scale, fc="0.6", ec="0.2",
                       lw=0.8, zorder=2, label=label)
            )  # fmt: skip
        else:
            lw = max(2.0, 2.0 * o.radius_m * scale * 0.5)
            ax.plot([o.x1 * scale, o.x2 * scale], [o.y1 * scale, o.y2 * scale], "-",
                    color="0.35", lw=lw, solid_capstyle="round", zorder=2, label=label)  # fmt: skip
        label = None
        drawn += 1
    a = world.arena
    if a is not None:
        ax.add_patch(
            Rectangle((a.x_min * scale, a.y_min * scale), (a.x_max - a.x_min) * scale,
                      (a.y_max - a.y_min) * scale, fill=False, ec="0.3", ls=":", lw=1.0,
                      zorder=1, label="arena")
        )  # fmt: skip
        drawn += 1
    return drawn
