"""Paper-style figures from a RunLog, readable at any fleet size, and an index page per run.

Figures (``write_all``):

* ``trajectories.png``: the robots' reference points and the virtual trajectories (paper Figs 6,
  9, 11). Up to :data:`LEGEND_MAX` robots: one colour and line style per robot, a legend beside
  the plot and the slot labels ``v1..`` offset from the end of each virtual trajectory. Beyond:
  thin lines, no per-robot legend, the leader's path and the final formation drawn on top.
* ``motor_power.png``: commanded motor power per wheel (Figs 7, 10, 12). Up to
  :data:`DETAIL_MAX` robots one panel per robot; beyond, the distribution over robots (median,
  5-95 % band, extremes) per wheel and a heat map robots x time of the larger wheel's |power|.
* ``formation_error.png``: distance of each robot's reference point to its slot (eqs 17-18). Up to
  :data:`DETAIL_MAX` robots one line per robot, beyond the median, 90th percentile and maximum
  over robots; a linear panel from 0 to above the largest value (no peak is clipped) over a log
  panel with positive limits (the settled part, readable).
* ``roles.png``: up to :data:`DETAIL_MAX` robots the slot of each robot over time (integer
  ticks); beyond, the role changes as events (robot x time) and the number of robots holding a
  slot.
* ``formation.png``: the figure a paper prints (Figs 9, 11): paths with the formation drawn at a
  few instants and their times, tight axes, disturbances and role changes labelled; one panel
  per instant beyond 10 robots, the robots whose role changed highlighted
  (:mod:`formation.outputs.snapshots`).
* ``index.md``: one line per file of the run directory (``metrics.json``, ``run.npz``, every
  figure) with a caption, and a short summary from ``metrics.json`` when it is there.

Every image has a fixed size in inches and dots per inch, at most :data:`MAX_PX` pixels on each
side whatever the number of robots or ticks; long series are decimated for drawing only (the
shared look, sizes and decimation: :mod:`formation.outputs.figures_style`).
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Final

import matplotlib

matplotlib.use("Agg")
import contextlib

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.collections import LineCollection
from matplotlib.colors import to_rgba
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator

from formation.outputs.figure_marks import mark_time_axes
from formation.outputs.figures_style import (
    DETAIL_MAX,
    LEGEND_MAX,
    draw_stride,
    draw_world,
    envelope,
    nan_percentiles,
    nanmax,
    new_figure,
    no_data_figure,
    robot_style,
    save_figure,
)
from formation.outputs.metrics import formation_error, role_changes
from formation.outputs.plan_view import PlanView, draw_plan, draw_replans, plan_summary, replans_of
from formation.outputs.runlog import RunLog
from formation.outputs.snapshots import Event, plot_snapshots

__all__ = [
    "FIGURES",
    "caption",
    "error_figure",
    "plot_error",
    "plot_motor_power",
    "plot_roles",
    "plot_trajectories",
    "roles_figure",
    "write_all",
    "write_index",
]

FIGURES: Final = {
    "trajectories.png": "robots' reference points (solid) and the virtual trajectories (dashed)",
    "motor_power.png": "commanded motor power per wheel, % of maximum",
    "formation_error.png": "distance from each robot's reference point to its slot (eqs 17-18), "
    "linear and log scale",
    "roles.png": "slots held over time and role changes (the initial assignment is not a change)",
    "formation.png": "the formation at a few instants with their times, disturbances and role "
    "changes labelled (paper Figs 9, 11)",
}
"""The figures of :func:`write_all` with a generic one-line caption (:func:`caption` is exact)."""


def caption(name: str, n_robots: int) -> str:
    """One-line caption of figure ``name`` as drawn for ``n_robots`` robots."""
    many, legend = n_robots > DETAIL_MAX, n_robots > LEGEND_MAX
    if name == "trajectories.png":
        if legend:
            return (
                f"{n_robots} robots' reference points (thin, colour = robot index), virtual "
                "trajectories (dashed), the virtual leader (black) and the final formation"
            )
        return "each robot's reference point (start o, end s) and the virtual trajectories v1.. "
    if name == "motor_power.png":
        if many:
            return (
                "motor power per wheel over the robots (median, 5-95 %, min-max) and a heat "
                "map robots x time of the larger wheel's |power|, % of maximum"
            )
        return "motor power of each robot's right and left wheel, % of maximum"
    if name == "formation_error.png":
        what = "median, 90th percentile and maximum over robots" if many else "per robot"
        return f"distance from reference point to assigned slot (eqs 17-18), {what}; linear/log"
    if name == "roles.png":
        if many:
            return "robots holding a slot, and every role change after the initial assignment"
        return "slot of each robot over time; | marks a role change"
    return FIGURES.get(name, "")


# -- trajectories ----------------------------------------------------------------------------


def plot_trajectories(
    log: RunLog, path: Path, title: str = "", plan: PlanView | None = None
) -> None:
    """The robots' reference points and the virtual trajectories; with ``plan`` (issue 27)
    also the footprint corridor (translucent), the planned leader path, the goal and each
    replan under them (:func:`formation.outputs.plan_view.draw_plan`); without it, the
    run-time plans of ``log.replans`` (:func:`formation.outputs.plan_view.draw_replans`)."""
    if not log.t_s.size:
        save_figure(no_data_figure(title or "Trajectories"), path)
        return
    n = len(log.robot_ids)
    m = log.slot_xy.shape[1]
    ticks = log.t_s.size
    k = np.unique(np.r_[np.arange(0, ticks, draw_stride(ticks)), max(ticks - 1, 0)])[: ticks or 0]
    fig = new_figure(11.0 if n <= LEGEND_MAX else 10.0, 7.5)
    ax = fig.add_subplot()
    few_slots = m <= LEGEND_MAX
    slot_lw = 1.0 if few_slots else 0.5
    segs = [log.slot_xy[k, s, :] * 100 for s in range(m)]
    ax.add_collection(
        LineCollection(
            segs, colors="0.55", linestyles="--", linewidths=slot_lw, label="virtual trajectories"
        )
    )
    draw_world(ax, log.world, scale=100.0)
    if plan is not None:
        draw_plan(ax, plan, scale=100.0, log=log)
    elif log.replans:  # plans made at run time only (an operator's goal around an obstacle)
        draw_replans(ax, replans_of(log.replans), scale=100.0, log=log)
    if few_slots and log.t_s.size:
        for s in range(m):
            end = log.slot_xy[-1, s, :] * 100
            if np.all(np.isfinite(end)):
                ax.annotate(
                    f"v{log.slot_ids[s] + 1}",
                    (float(end[0]), float(end[1])),
                    xytext=(8, 6),
                    textcoords="offset points",
                    color="0.25",
                    fontsize=8,
                    bbox={"boxstyle": "round,pad=0.15", "fc": "white", "ec": "none", "alpha": 0.7},
                    zorder=5,
                )
    if n <= LEGEND_MAX:
        for j, rid in enumerate(log.robot_ids):
            ref = log.ref[k, j, :] * 100
            c, ls = robot_style(j)
            ax.plot(ref[:, 0], ref[:, 1], ls, color=c, lw=1.5, label=rid, zorder=3)
            if log.t_s.size:
                first, last = log.ref[0, j] * 100, log.ref[-1, j] * 100
                ax.plot(*first, "o", color=c, ms=5, mfc="white", zorder=4)
                ax.plot(*last, "s", color=c, ms=5, zorder=4)
        fig.legend(loc="outside right upper", fontsize=8, title="robots", title_fontsize=8)
    else:
        cmap = plt.get_cmap("viridis")
        cols = [to_rgba(cmap(j / max(1, n - 1)), 0.55) for j in range(n)]
        ax.add_collection(
            LineCollection(
                [log.ref[k, j, :] * 100 for j in range(n)], colors=cols, linewidths=0.6, zorder=3
            )
        )
        if log.t_s.size:
            last = log.ref[-1] * 100
            ax.scatter(last[:, 0], last[:, 1], s=6, c=cols, zorder=4, label="robots at the end")
            slots_end = log.slot_xy[-1] * 100
            ax.scatter(
                slots_end[:, 0], slots_end[:, 1], s=14, facecolors="none", edgecolors="0.3",
                linewidths=0.5, zorder=4, label="slots at the end",
            )  # fmt: skip
        lead = log.leader[k, :2] * 100
        ax.plot(lead[:, 0], lead[:, 1], "k--", lw=1.2, label="virtual leader", zorder=5)
        ax.legend(loc="best", fontsize=8)
        ax.text(
            0.01, 0.01, f"{n} robots, colour = robot index (r1 purple ... r{n} yellow)",
            transform=ax.transAxes, fontsize=8, color="0.3",
        )  # fmt: skip
    ax.autoscale_view()
    ax.set_xlabel("x (cm)")
    ax.set_ylabel("y (cm)")
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(True, alpha=0.3)
    ax.set_title(title or "Robots' reference points (solid) and virtual trajectories (dashed)")
    save_figure(fig, path)


# -- motor power -----------------------------------------------------------------------------


def plot_motor_power(log: RunLog, path: Path) -> None:
    if not log.t_s.size:
        save_figure(no_data_figure("Motor power"), path)
        return
    n = len(log.robot_ids)
    if n <= DETAIL_MAX:
        t, pw = envelope(log.t_s, log.power * 100)
        fig = new_figure(9.0, 1.5 * max(n, 1) + 1.0)
        axes = fig.subplots(max(n, 1), 1, sharex=True, squeeze=False)
        for j, rid in enumerate(log.robot_ids):
            ax = axes[j, 0]
            ax.plot(t, pw[:, j, 0], color="tab:red", lw=0.8, label="right wheel")
            ax.plot(t, pw[:, j, 1], color="tab:blue", lw=0.8, label="left wheel")
            ax.set_ylabel(f"{rid} (%)")
            ax.grid(True, alpha=0.3)
        axes[-1, 0].set_xlabel("time (s)")
        mark_time_axes(list(axes[:, 0]), log)  # faults and disturbances
        if n:
            h, lab = axes[0, 0].get_legend_handles_labels()
            fig.legend(h, lab, loc="outside upper right", ncols=2, fontsize=8)
        fig.suptitle("Motor power per wheel (% of maximum)")
        save_figure(fig, path)
        return
    fig = new_figure(11.0, 9.0)
    axes = fig.subplots(3, 1, sharex=True, height_ratios=[1, 1, 1.4])
    t_full, pw_full = log.t_s, log.power * 100
    for w, (name, c) in enumerate((("right wheel", "tab:red"), ("left wheel", "tab:blue"))):
        ax = axes[w]
        stats = np.stack(
            [
                *nan_percentiles(pw_full[:, :, w], (5, 50, 95)),
                np.nanmin(pw_full[:, :, w], axis=1),
                nanmax(pw_full[:, :, w], axis=1),
            ],
            axis=1,
        )
        t, env = envelope(t_full, stats)
        p5, p50, p95, lo, hi = env.T
        ax.fill_between(t, lo, hi, color=c, alpha=0.12, lw=0, label="min-max")
        ax.fill_between(t, p5, p95, color=c, alpha=0.35, lw=0, label="5-95 %")
        ax.plot(t, p50, color=c, lw=1.0, label="median")
        ax.set_ylabel(f"{name} (%)")
        ax.grid(True, alpha=0.3)
        ax.legend(loc="upper right", fontsize=7, ncols=3)
    k = draw_stride(t_full.size)
    nb = math.ceil(t_full.size / k)
    mag_full = np.max(np.abs(pw_full), axis=2)  # (T, n)
    if nb * k > t_full.size:
        mag_full = np.concatenate([mag_full, np.repeat(mag_full[-1:], nb * k - t_full.size, 0)])
    mag = mag_full.reshape(nb, k, n).max(axis=1).T  # (n, buckets): the bucket's peak
    im = axes[2].imshow(
        mag,
        aspect="auto",
        interpolation="nearest",
        origin="lower",
        cmap="magma",
        extent=(float(t_full[0]), max(float(t_full[-1]), float(t_full[0]) + 1e-3), 0.5, n + 0.5)
        if t_full.size
        else None,
        vmin=0.0,
    )
    axes[2].set_ylabel("robot (1..n)")
    axes[2].yaxis.set_major_locator(MaxNLocator(integer=True))
    axes[2].set_xlabel("time (s)")
    fig.colorbar(im, ax=axes[2], label="max |power| of the two wheels (%)")
    mark_time_axes(list(axes), log)
    fig.suptitle(f"Motor power over {n} robots (% of maximum)")
    save_figure(fig, path)


# -- formation error -------------------------------------------------------------------------


def _error_series(log: RunLog) -> tuple[np.ndarray, list[tuple[str, np.ndarray, str, str]]]:
    err = formation_error(log) * 100  # cm
    n = err.shape[1]
    if n <= DETAIL_MAX:
        t, env = envelope(log.t_s, err)
        series = [(rid, env[:, j], *robot_style(j)) for j, rid in enumerate(log.robot_ids)]
        return t, series
    stats = np.stack([*nan_percentiles(err, (50, 90)), nanmax(err, axis=1)], axis=1)
    t, env = envelope(log.t_s, stats)
    p50, p90, mx = env.T
    return t, [
        ("max over robots", mx, "tab:red", "-"),
        ("90th percentile", p90, "tab:orange", "-"),
        ("median", p50, "tab:blue", "-"),
    ]


def plot_error(log: RunLog, path: Path, settle_s: float | None = None) -> None:
    save_figure(error_figure(log, settle_s), path)


def error_figure(log: RunLog, settle_s: float | None = None) -> Figure:
    """The formation error figure (axes: linear from 0 above the peak, then log); unsaved."""
    if not log.t_s.size:
        return no_data_figure("Formation error")
    t, series = _error_series(log)
    n = len(log.robot_ids)
    fig = new_figure(10.0, 6.5)
    ax_lin, ax_log = fig.subplots(2, 1, sharex=True)
    finite = np.concatenate([np.zeros(0)] + [v[np.isfinite(v)] for _, v, _, _ in series])
    top = float(np.max(finite)) if finite.size else 1.0
    positive = finite[finite > 0]
    for label, v, c, ls in series:
        ax_lin.plot(t, v, ls, color=c, lw=1.0, label=label)
        ax_log.plot(t, np.where(v > 0, v, np.nan), ls, color=c, lw=1.0)
    if n > DETAIL_MAX and len(series) == 3:
        ax_lin.fill_between(t, series[2][1], series[1][1], color="tab:orange", alpha=0.2, lw=0)
    ax_lin.set_ylim(0.0, max(top, 1e-3) * 1.05)  # from 0 to above the largest value
    ax_lin.set_ylabel("error (cm)")
    ax_log.set_yscale("log")
    if positive.size:
        lo = max(float(np.min(positive)), top * 1e-5, 1e-4)
        ax_log.set_ylim(lo * 0.8, top * 1.3)
    else:  # nothing to draw (an empty run): positive limits all the same
        ax_log.set_ylim(1e-2, 1.0)
        ax_lin.text(0.5, 0.5, "no data", transform=ax_lin.transAxes, ha="center", color="0.4")
    ax_log.set_ylabel("error (cm), log")
    ax_log.set_xlabel("time (s)")
    for ax in (ax_lin, ax_log):
        ax.grid(True, alpha=0.3, which="both" if ax is ax_log else "major")
        if settle_s is not None:
            ax.axvline(settle_s, color="0.4", ls=":", lw=1)
    mark_time_axes([ax_lin, ax_log], log)  # faults and disturbances
    if settle_s is not None:
        ax_lin.text(settle_s, 1.0, " settle", transform=ax_lin.get_xaxis_transform(),
                    va="top", fontsize=8, color="0.3")  # fmt: skip
    fig.legend(loc="outside right upper", fontsize=8, title="robots" if n <= DETAIL_MAX else None)
    what = f"{n} robots, aggregated" if n > DETAIL_MAX else "per robot"
    fig.suptitle(f"Formation error: reference point to assigned slot ({what})")
    return fig


# -- roles -----------------------------------------------------------------------------------


def plot_roles(log: RunLog, path: Path) -> None:
    save_figure(roles_figure(log), path)


def roles_figure(log: RunLog) -> Figure:
    """The role figure (slot steps up to DETAIL_MAX robots, else role-change events); unsaved."""
    if not log.t_s.size:
        return no_data_figure("Roles")
    n = len(log.robot_ids)
    m = log.slot_xy.shape[1]
    changes = role_changes(log)
    if n <= DETAIL_MAX:
        fig = new_figure(10.0, min(0.45 * max(m, n) + 2.0, 8.0))
        ax = fig.add_subplot()
        for j, rid in enumerate(log.robot_ids):
            s = log.slot_of[:, j].astype(float)
            s[s < 0] = np.nan
            c, ls = robot_style(j)
            ax.plot(log.t_s, s, ls, drawstyle="steps-post", color=c, lw=2, label=rid)
        for ch in changes:
            if ch["to_slot"] is not None:
                ax.plot(ch["t_s"], ch["to_slot"], "|", color="k", ms=12, mew=1.2)
        ticks = sorted(set(log.slot_ids))
        if len(ticks) <= 2 * LEGEND_MAX:
            ax.set_yticks(ticks)
            ax.set_yticklabels([f"{s} leader" if s == 0 else str(s) for s in ticks])
        else:
            ax.yaxis.set_major_locator(MaxNLocator(integer=True))
        if ticks:
            ax.set_ylim(min(ticks) - 0.5, max(ticks) + 0.5)
        ax.set_ylabel("slot")
        ax.set_xlabel("time (s)")
        ax.grid(True, alpha=0.3)
        mark_time_axes([ax], log)
        fig.legend(loc="outside right upper", fontsize=8, title="robots", title_fontsize=8)
        ax.set_title(
            f"Slot of each robot; {len(changes)} role change(s) after the initial assignment (|)"
        )
        return fig
    fig = new_figure(11.0, 8.0)
    ax_n, ax_ev = fig.subplots(2, 1, sharex=True, height_ratios=[1, 3])
    held = (log.slot_of >= 0).sum(axis=1)
    leader = (log.slot_of == 0).any(axis=1)
    ax_n.plot(
        log.t_s, held, drawstyle="steps-post", color="tab:blue", lw=1.2,
        label="robots holding a slot",
    )  # fmt: skip
    ax_n.axhline(min(n, m), color="0.5", ls=":", lw=1, label=f"slots ({m})")
    if not leader.all():
        no_lead = log.t_s[~leader]
        ax_n.plot(no_lead, np.zeros_like(no_lead), "r|", ms=8, clip_on=False, label="no leader")
    ax_n.set_ylim(0, max(n, m) * 1.1 + 1)
    ax_n.yaxis.set_major_locator(MaxNLocator(integer=True))
    ax_n.set_ylabel("robots")
    ax_n.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=7)
    ax_n.grid(True, alpha=0.3)
    idx = {rid: j + 1 for j, rid in enumerate(log.robot_ids)}
    kinds = (
        ("becomes the leader", lambda c: c["to_slot"] == 0, "tab:red", "*", 40),
        ("loses its slot", lambda c: c["to_slot"] is None, "0.2", "x", 14),
        ("other slot change", lambda c: c["to_slot"] not in (0, None), "tab:blue", "o", 8),
    )
    for label, pred, c, mk, size in kinds:
        sel = [ch for ch in changes if pred(ch)]
        ax_ev.scatter(
            [ch["t_s"] for ch in sel], [idx[ch["robot"]] for ch in sel], s=size, c=c,
            marker=mk, label=f"{label} ({len(sel)})", zorder=3, clip_on=False,
        )  # fmt: skip
    if not changes:
        ax_ev.text(0.5, 0.5, "no role changes after the initial assignment",
                   transform=ax_ev.transAxes, ha="center", va="center", color="0.3")  # fmt: skip
    ax_ev.set_ylim(0.5, n + 0.5)
    if log.t_s.size > 1 and log.t_s[-1] > log.t_s[0]:
        ax_ev.set_xlim(float(log.t_s[0]), float(log.t_s[-1]))
    ax_ev.yaxis.set_major_locator(MaxNLocator(integer=True))
    ax_ev.set_ylabel("robot (1..n)")
    ax_ev.set_xlabel("time (s)")
    ax_ev.grid(True, alpha=0.3)
    ax_ev.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8)
    mark_time_axes([ax_n, ax_ev], log)
    fig.suptitle(f"Role changes of {n} robots over {m} slots (initial assignment not counted)")
    return fig


# -- index -----------------------------------------------------------------------------------


def _fmt(v: Any, scale: float, unit: str) -> str:
    return f"{float(v) * scale:.1f} {unit}" if isinstance(v, int | float) else "n/a"


def _summary_lines(metrics_path: Path) -> list[str]:
    try:
        m = json.loads(metrics_path.read_text())
        run = m["run"]
        robots = m["robots"]
    except (OSError, ValueError, KeyError, TypeError):
        return []
    rms = [r.get("formation_error_rms_m") for r in robots.values()]
    rms_f = [float(v) for v in rms if isinstance(v, int | float)]
    sep = run.get("min_separation_m")
    lines = [
        f"- {len(robots)} robots, {run.get('duration_s', 0.0):.1f} s, {run.get('ticks', 0)} ticks",
        f"- collisions {run.get('collisions')}, minimum separation {_fmt(sep, 100, 'cm')}",
        f"- role changes {run.get('role_change_count')} (initial assignment excluded), "
        f"final leader {run.get('final_leader')}",
    ]
    if rms_f:
        lines.append(
            f"- formation error RMS after settling: worst {max(rms_f) * 100:.2f} cm, "
            f"median {float(np.median(rms_f)) * 100:.2f} cm"
        )
    plan = m.get("plan")
    if isinstance(plan, dict):
        with contextlib.suppress(KeyError, TypeError, ValueError):
            lines.append(f"- {plan_summary(plan)}")
    return lines


def write_index(
    out_dir: Path, figures: Sequence[Path], title: str = "", n_robots: int | None = None
) -> Path:
    """Write ``out_dir/index.md``: links to ``metrics.json``, ``run.npz`` (when present) and
    every figure in ``figures`` with a one-line caption (for ``n_robots`` robots when given);
    return its path."""
    lines = [f"# {title or 'Run'}", ""]
    metrics = out_dir / "metrics.json"
    lines += _summary_lines(metrics)
    if lines[-1] != "":
        lines.append("")
    lines.append("## Files")
    lines.append("")
    if metrics.exists():
        lines.append("- [metrics.json](metrics.json): every metric of the run (JSON)")
    if (out_dir / "run.npz").exists():
        lines.append("- [run.npz](run.npz): the run's arrays (numpy `.npz`, a RunLog)")
    for p in figures:
        cap = caption(p.name, n_robots) if n_robots is not None else FIGURES.get(p.name, "")
        lines.append(f"- [{p.name}]({p.name}){': ' + cap if cap else ''}")
    lines.append("")
    for p in figures:
        lines.append(f"![{p.stem}]({p.name})")
        lines.append("")
    path = out_dir / "index.md"
    path.write_text("\n".join(lines))
    return path


def write_all(
    log: RunLog,
    out_dir: Path,
    title: str = "",
    settle_s: float | None = None,
    *,
    index: bool = True,
    events: Sequence[Event] = (),
    plan: PlanView | None = None,
) -> list[Path]:
    """Write the five figures (and ``index.md`` unless ``index=False``) to ``out_dir``; return
    the paths written, the figures first. Call it after ``metrics.json`` is written so the index
    links and summarises it. ``events``: labelled disturbances for ``formation.png``
    (:func:`formation.outputs.snapshots.events_of` a scenario's); ``plan``: the run's plan
    (:func:`formation.outputs.plan_view.plan_view`), drawn in ``trajectories.png``."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = [out_dir / name for name in FIGURES]
    plot_trajectories(log, paths[0], title, plan)
    plot_motor_power(log, paths[1])
    plot_error(log, paths[2], settle_s)
    plot_roles(log, paths[3])
    plot_snapshots(log, paths[4], events=events)
    if index:
        paths.append(write_index(out_dir, paths[:5], title, len(log.robot_ids)))
    return paths
