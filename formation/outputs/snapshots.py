"""The figure a paper prints (Figs 9 and 11): the robots' paths with the formation drawn at a few
instants, each marked with its time, on tight axes, with disturbances and role changes labelled
where they happen.

Up to :data:`FEW` robots, one plot: each robot has its colour (the paper's red, green, blue
first), its body (a disc of the body radius) and heading at each instant, and the formation's
edges join the robots whose slots are neighbours (slots closer than :data:`EDGE_FACTOR` times the
closest pair). Beyond, a large formation drawn several times over itself is unreadable, so one
panel per instant (:func:`plot_panels`, same scale): the robots as dots on the formation's edges,
the paths so far in grey, and the robots whose role changed during the run in red with their
path, the new leader named.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Final

import matplotlib

matplotlib.use("Agg")
import numpy as np
from matplotlib.axes import Axes
from matplotlib.collections import LineCollection
from matplotlib.patches import Circle

from formation.outputs.figures_style import (
    COLORS,
    draw_stride,
    draw_world,
    new_figure,
    no_data_figure,
    robot_style,
    save_figure,
)
from formation.outputs.metrics import role_changes
from formation.outputs.runlog import RunLog

__all__ = [
    "EDGE_FACTOR",
    "FEW",
    "Event",
    "events_of",
    "plot_panels",
    "plot_snapshots",
    "snapshot_ticks",
]

FEW: Final = 10
"""Per-robot colours, bodies and headings up to this many robots."""
SNAPSHOTS: Final = 5
PANELS: Final = 4
EDGE_FACTOR: Final = 1.2
MARGIN_CM: Final = 8.0

Event = tuple[float, float, str, str]
"""A labelled happening: (time s, duration s, robot id, text), e.g. a scheduled disturbance."""


def events_of(disturbances: Sequence[Any]) -> list[Event]:
    """Labels of a scenario's scheduled disturbances (``scenario.Disturbance``)."""
    out: list[Event] = []
    for d in disturbances:
        if d.kind == "drag":
            text = f"{d.robot} dragged {math.hypot(d.dx, d.dy) * 100:.0f} cm"
        elif d.kind == "teleport":
            text = f"{d.robot} moved by hand"
        else:
            text = f"{d.robot} lost by the camera for {d.duration_s:g} s"
        out.append((float(d.t_s), float(d.duration_s), str(d.robot), text))
    return out


def snapshot_ticks(log: RunLog, events: Sequence[Event], count: int = SNAPSHOTS) -> list[int]:
    """Ticks at which the formation is drawn: the start, the end, evenly between, and just
    before each event (which replaces the nearest even instant); in time order."""
    ticks = log.t_s.size
    if ticks == 0:
        return []
    held = np.flatnonzero((log.slot_of >= 0).any(axis=1))
    first = int(held[0]) if held.size else 0  # the formation exists from the first assignment
    even = [first + round(i * (ticks - 1 - first) / max(count - 1, 1)) for i in range(count)]
    for t_ev, _, _, _ in events:
        k = int(np.searchsorted(log.t_s, t_ev) - 1)
        if 0 < k < ticks - 1:
            inner = [j for j in range(1, len(even) - 1)]
            if inner:
                nearest = min(inner, key=lambda j: abs(even[j] - k))
                even[nearest] = k
            else:
                even.append(k)
    return sorted(set(even))


def _edges(slots_xy: np.ndarray) -> list[tuple[int, int]]:
    """Pairs of slot rows that are neighbours in the formation at one instant."""
    ok = np.flatnonzero(np.all(np.isfinite(slots_xy), axis=1))
    if ok.size < 2:
        return []
    p = slots_xy[ok]
    d = np.hypot(p[:, None, 0] - p[None, :, 0], p[:, None, 1] - p[None, :, 1])
    iu = np.triu_indices(ok.size, k=1)
    closest = float(d[iu].min())
    return [
        (int(ok[a]), int(ok[b]))
        for a, b in zip(*iu, strict=True)
        if d[a, b] <= EDGE_FACTOR * closest
    ]


def _formation_at(
    ax: Axes, log: RunLog, k: int, few: bool, highlight: set[int], time_label: bool = True
) -> None:
    """The formation at tick ``k``: robots (reference points) joined by the edges of their
    slots, their slots as open rings, and the time."""
    s = log.slot_of[k]
    row_of = {sid: r for r, sid in enumerate(log.slot_ids)}
    holder = {row_of[int(s[j])]: j for j in range(len(s)) if s[j] >= 0 and int(s[j]) in row_of}
    segs = [
        [log.ref[k, holder[a]] * 100, log.ref[k, holder[b]] * 100]
        for a, b in _edges(log.slot_xy[k])
        if a in holder and b in holder
    ]
    ax.add_collection(LineCollection(segs, colors="0.15", linewidths=0.9 if few else 0.5, zorder=4))
    slots = log.slot_xy[k] * 100
    ax.scatter(slots[:, 0], slots[:, 1], s=22 if few else 6, facecolors="none",
               edgecolors="0.45", linewidths=0.6, zorder=4)  # fmt: skip
    xy = log.truth[k, :, :2] * 100
    th = log.truth[k, :, 2]
    if few:
        r_cm = (log.body_radius_m if math.isfinite(log.body_radius_m) else 0.075) * 100
        for j in range(len(log.robot_ids)):
            c = robot_style(j)[0]
            ax.add_patch(Circle(tuple(xy[j]), r_cm, fc=c, ec="k", lw=0.6, alpha=0.35, zorder=5))
            ax.plot(
                [xy[j, 0], xy[j, 0] + r_cm * math.cos(th[j])],
                [xy[j, 1], xy[j, 1] + r_cm * math.sin(th[j])],
                "-", color="k", lw=0.9, zorder=6,
            )  # fmt: skip
            ax.plot(*(log.ref[k, j] * 100), ".", color=c, ms=4, zorder=6)
    else:
        cols = ["tab:red" if j in highlight else "0.25" for j in range(len(log.robot_ids))]
        ax.scatter(log.ref[k, :, 0] * 100, log.ref[k, :, 1] * 100, s=5, c=cols, zorder=6)
    if not time_label:
        return
    top = np.nanmax(np.r_[xy[:, 1], slots[:, 1]])
    cx = float(np.nanmean(np.r_[xy[:, 0], slots[:, 0]]))
    ax.annotate(f"t = {log.t_s[k]:.0f} s", (cx, float(top)), xytext=(0, 12 if few else 6),
                textcoords="offset points", ha="center", fontsize=8, color="0.1",
                bbox={"boxstyle": "round,pad=0.2", "fc": "white", "ec": "0.6", "lw": 0.5},
                zorder=8)  # fmt: skip


def _limits(log: RunLog, few: bool) -> tuple[np.ndarray, np.ndarray]:
    """(lower, upper) corners (cm) of the drawing: every robot and slot, a margin around."""
    pts = np.concatenate([log.truth[:, :, :2].reshape(-1, 2), log.slot_xy.reshape(-1, 2)]) * 100
    pts = pts[np.all(np.isfinite(pts), axis=1)]
    if not pts.size:
        return np.array([-1.0, -1.0]), np.array([1.0, 1.0])
    pad = MARGIN_CM + (
        (log.body_radius_m * 100 if math.isfinite(log.body_radius_m) else 7.5) if few else 0.0
    )
    lo, hi = pts.min(axis=0) - pad, pts.max(axis=0) + pad
    hi[1] += 8.0  # room for the time labels above the top formation
    return lo, hi


def _figure_for(lo: np.ndarray, hi: np.ndarray) -> Any:
    """A figure whose axes have the drawing's aspect ratio (no empty band above or below)."""
    width_in, axes_w_in = 11.0, 8.4  # the rest: the legend on the right and the labels
    ratio = float((hi[1] - lo[1]) / max(hi[0] - lo[0], 1e-9))
    return new_figure(width_in, min(max(axes_w_in * ratio + 1.3, 3.2), 9.0))


def _label(ax: Axes, xy: np.ndarray, text: str, color: str, dy: float) -> None:
    ax.annotate(text, (float(xy[0]), float(xy[1])), xytext=(14, dy), textcoords="offset points",
                fontsize=8, color=color, zorder=9,
                arrowprops={"arrowstyle": "->", "color": color, "lw": 0.8},
                bbox={"boxstyle": "round,pad=0.2", "fc": "white", "ec": color,
                      "lw": 0.5})  # fmt: skip


def plot_snapshots(log: RunLog, path: Path, title: str = "", events: Sequence[Event] = ()) -> None:
    """Write the figure (see the module docstring) to ``path``."""
    if not log.t_s.size:
        save_figure(no_data_figure(title or "Formation"), path)
        return
    n = len(log.robot_ids)
    few = n <= FEW
    if not few:
        plot_panels(log, path, title, events)
        return
    changes = role_changes(log)
    changed = {log.robot_ids.index(c["robot"]) for c in changes}
    lo, hi = _limits(log, few)
    fig = _figure_for(lo, hi)
    ax = fig.add_subplot()
    draw_world(ax, log.world, scale=100.0)
    k = np.unique(np.r_[np.arange(0, log.t_s.size, draw_stride(log.t_s.size)), log.t_s.size - 1])
    lead = log.leader[k, :2] * 100
    ax.plot(lead[:, 0], lead[:, 1], "--", color="0.5", lw=1.0, label="virtual leader", zorder=2)
    if few:
        for j, rid in enumerate(log.robot_ids):
            c, ls = robot_style(j)
            ref = log.ref[k, j] * 100
            ax.plot(ref[:, 0], ref[:, 1], ls, color=c, lw=1.3, label=rid, zorder=3)
    else:
        rest = [log.ref[k, j] * 100 for j in range(n) if j not in changed]
        ax.add_collection(LineCollection(rest, colors="0.7", linewidths=0.4, zorder=3))
        for g, j in enumerate(sorted(changed)):
            ref = log.ref[k, j] * 100
            ax.plot(ref[:, 0], ref[:, 1], "-", color=COLORS[g % len(COLORS)], lw=1.2, zorder=3,
                    label=log.robot_ids[j] if g < 12 else None)  # fmt: skip
    for kk in snapshot_ticks(log, events):
        _formation_at(ax, log, kk, few, changed)
    for i, (t_ev, dur, rid, text) in enumerate(events):
        if rid not in log.robot_ids:
            continue
        j = log.robot_ids.index(rid)
        k0 = max(0, int(np.searchsorted(log.t_s, t_ev)) - 1)
        k1 = min(log.t_s.size - 1, int(np.searchsorted(log.t_s, t_ev + dur)))
        ax.plot(*(log.truth[k0, j, :2] * 100), "X", color="k", ms=7, zorder=7)
        if k1 > k0:  # where the disturbance took it
            ax.annotate("", log.truth[k1, j, :2] * 100, log.truth[k0, j, :2] * 100,
                        arrowprops={"arrowstyle": "-|>", "color": "k", "lw": 1.6,
                                    "shrinkA": 4, "shrinkB": 2}, zorder=7)  # fmt: skip
        _label(ax, log.truth[k0, j, :2] * 100, f"{text} at t = {t_ev:.0f} s", "k", -26 - 14 * i)
    shown = changes if few else [c for c in changes if c["to_slot"] == 0]
    for i, ch in enumerate(shown[:6]):
        j = log.robot_ids.index(ch["robot"])
        kc = min(int(np.searchsorted(log.t_s, ch["t_s"])), log.t_s.size - 1)
        to = "leader" if ch["to_slot"] == 0 else f"slot {ch['to_slot']}"
        _label(ax, log.ref[kc, j] * 100, f"{ch['robot']} -> {to} at t = {ch['t_s']:.1f} s",
               "tab:purple", 16 + 14 * i)  # fmt: skip
    ax.set_xlim(float(lo[0]), float(hi[0]))
    ax.set_ylim(float(lo[1]), float(hi[1]))
    ax.set_aspect("equal", adjustable="box")
    ax.set_xlabel("x (cm)")
    ax.set_ylabel("y (cm)")
    ax.grid(True, alpha=0.25)
    fig.legend(loc="outside right upper", fontsize=8,
              title="robots" if few else f"role changed ({len(changed)} of {n})",
              title_fontsize=8)  # fmt: skip
    what = (
        "reference points' paths; the formation at the marked times (bodies, headings, slots o)"
        if few
        else f"{n} robots: paths (grey), the formation at the marked times (slots o)"
    )
    ax.set_title(title or what, fontsize=10)
    save_figure(fig, path)


def plot_panels(log: RunLog, path: Path, title: str = "", events: Sequence[Event] = ()) -> None:
    """The large-fleet form: one panel per instant of :func:`snapshot_ticks` (at most
    :data:`PANELS`), every panel at the same scale."""
    changes = role_changes(log)
    changed = {log.robot_ids.index(c["robot"]) for c in changes}
    ticks = snapshot_ticks(log, events, count=PANELS)
    lo, hi = _limits(log, False)
    span = hi - lo
    ratio = float(span[1] / max(span[0], 1e-9))
    cols = len(ticks)
    fig = new_figure(min(4.2 * cols, 18.0), min(max(4.2 * ratio + 1.6, 3.0), 8.0))
    axes = fig.subplots(1, cols, squeeze=False, sharex=True, sharey=True)[0]
    stride = draw_stride(log.t_s.size)
    for ax, k in zip(axes, ticks, strict=True):
        upto = np.r_[np.arange(0, k + 1, stride), k]
        ax.add_collection(
            LineCollection([log.ref[upto, j] * 100 for j in range(len(log.robot_ids))],
                           colors="0.8", linewidths=0.4, zorder=2)
        )  # fmt: skip
        lead = log.leader[upto, :2] * 100
        ax.plot(lead[:, 0], lead[:, 1], "--", color="0.5", lw=0.8, zorder=2)
        for j in sorted(changed):
            ref = log.ref[upto, j] * 100
            ax.plot(ref[:, 0], ref[:, 1], "-", color="tab:red", lw=1.0, zorder=3)
        _formation_at(ax, log, k, False, changed, time_label=False)
        for t_ev, dur, rid, text in events:
            if rid in log.robot_ids and t_ev <= log.t_s[k] and k > 0:
                j = log.robot_ids.index(rid)
                k0 = max(0, int(np.searchsorted(log.t_s, t_ev)) - 1)
                k1 = min(k, int(np.searchsorted(log.t_s, t_ev + dur)))
                ax.annotate("", log.truth[k1, j, :2] * 100, log.truth[k0, j, :2] * 100,
                            arrowprops={"arrowstyle": "-|>", "color": "k", "lw": 1.4},
                            zorder=7)  # fmt: skip
                ax.text(0.02, 0.02, f"{text} at t = {t_ev:.0f} s", transform=ax.transAxes,
                        fontsize=7)  # fmt: skip
        for c in changes:
            if c["to_slot"] == 0 and c["t_s"] <= log.t_s[k]:
                j = log.robot_ids.index(c["robot"])
                _label(ax, log.ref[k, j] * 100, f"{c['robot']} leads since {c['t_s']:.1f} s",
                       "tab:purple", 18)  # fmt: skip
        ax.set_title(f"t = {log.t_s[k]:.0f} s", fontsize=9)
        ax.set_xlim(float(lo[0]), float(hi[0]))
        ax.set_ylim(float(lo[1]), float(hi[1]))
        ax.set_aspect("equal", adjustable="box")
        ax.set_xlabel("x (cm)")
        ax.grid(True, alpha=0.25)
    axes[0].set_ylabel("y (cm)")
    n = len(log.robot_ids)
    fig.suptitle(
        title
        or f"{n} robots: the formation at {cols} instants; red: the {len(changed)} robots whose "
        "role changed (their paths); grey: every path so far; o: slots",
        fontsize=10,
    )
    save_figure(fig, path)
