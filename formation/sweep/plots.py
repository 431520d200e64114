"""Plots of a study's table: each metric against each varied parameter, spread over seeds.

One PNG per metric (``<metric>.png``), one panel per numeric parameter. In a panel every case is
a dot; the line joins the median over seeds (and over the other parameters' values, when the
study varies more than one, unless the other parameter has few values: then one line each) and
the band spans the seeds' minimum to maximum. A text metric (``final_leader``) is drawn as the
share of cases for each of its values, per parameter value.
"""

from __future__ import annotations

import math
from collections import defaultdict
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Final

import matplotlib

matplotlib.use("Agg")
import numpy as np
from matplotlib.axes import Axes

from formation.outputs.figures_style import COLORS, new_figure, save_figure
from formation.sweep.case_metrics import METRICS
from formation.sweep.study import Study
from formation.sweep.table import TEXT_METRICS, Table

__all__ = ["plot_study"]

SPLIT_MAX: Final = 6
"""With two or more parameters, one line per value of another parameter up to this many."""


def _numeric(values: Sequence[Any]) -> bool:
    return all(isinstance(v, int | float) and not isinstance(v, bool) for v in values)


def _as_float(v: Any) -> float:
    return float(v) if isinstance(v, int | float) and not isinstance(v, bool) else math.nan


def _line(ax: Axes, xs: list[float], ys: list[float], color: str, label: str | None) -> None:
    groups: dict[float, list[float]] = defaultdict(list)
    for x, y in zip(xs, ys, strict=True):
        groups[x].append(y)
    gx = sorted(groups)
    stats = []
    for x in gx:
        ok = [y for y in groups[x] if math.isfinite(y)]
        stats.append(
            (float(np.median(ok)), min(ok), max(ok)) if ok else (math.nan, math.nan, math.nan)
        )
    arr = np.array(stats, dtype=float).reshape(len(stats), 3)
    med, lo, hi = arr[:, 0], arr[:, 1], arr[:, 2]
    ax.fill_between(gx, lo, hi, color=color, alpha=0.18, lw=0)
    ax.plot(gx, med, "-", color=color, lw=1.5, label=label)
    ax.plot(xs, ys, "o", color=color, ms=3, alpha=0.6)


def _panel(ax: Axes, study: Study, table: Table, metric: str, axis: str) -> None:
    columns, rows = table
    jm, jx = columns.index(metric), columns.index(axis)
    ok = [r for r in rows if r[columns.index("status")] == "ok"]
    others = [
        a.name
        for a in study.axes
        if a.name != axis and 1 < len(a.values) <= SPLIT_MAX and _numeric(a.values)
    ]
    split = others[0] if others else None
    if split is None:
        groups: dict[Any, list[list[Any]]] = {None: ok}
    else:
        js = columns.index(split)
        groups = defaultdict(list)
        for r in ok:
            groups[r[js]].append(r)
    for g, (value, rs) in enumerate(sorted(groups.items(), key=lambda kv: _as_float(kv[0]))):
        label = None if split is None else f"{split} = {value:g}"
        xs = [_as_float(r[jx]) for r in rs]
        ys = [_as_float(r[jm]) for r in rs]
        _line(ax, xs, ys, COLORS[g % len(COLORS)], label)
    if split is not None:
        ax.legend(fontsize=7)
    ax.set_xlabel(axis)
    ax.grid(True, alpha=0.3)


def _text_panel(ax: Axes, table: Table, metric: str, axis: str) -> None:
    columns, rows = table
    jm, jx = columns.index(metric), columns.index(axis)
    ok = [r for r in rows if r[columns.index("status")] == "ok"]
    xs = sorted({_as_float(r[jx]) for r in ok})
    labels = sorted({str(r[jm]) for r in ok})
    width = (float(np.min(np.diff(xs))) if len(xs) > 1 else 1.0) * 0.8
    bottom = np.zeros(len(xs))
    for g, lab in enumerate(labels):
        share = np.array(
            [
                np.mean([1.0 if str(r[jm]) == lab else 0.0 for r in ok if _as_float(r[jx]) == x])
                for x in xs
            ]
        )
        ax.bar(xs, share, width, bottom=bottom, color=COLORS[g % len(COLORS)], label=lab or "none")
        bottom += share
    ax.set_ylim(0, 1.05)
    ax.set_ylabel("share of cases")
    ax.set_xlabel(axis)
    ax.legend(fontsize=7, title=metric, title_fontsize=7)


def plot_study(study: Study, table: Table, out_dir: Path) -> list[Path]:
    """Write ``<metric>.png`` for each metric of ``study.metrics``; return the paths."""
    out_dir.mkdir(parents=True, exist_ok=True)
    columns, rows = table
    axes = [
        a.name
        for a in study.axes
        if _numeric([r[columns.index(a.name)] for r in rows]) and len(a.values) > 1
    ]
    if not axes:
        axes = [a.name for a in study.axes if _numeric(a.values)] or ["seed"]
    paths = []
    for metric in study.metrics:
        fig = new_figure(4.6 * len(axes) + 0.6, 3.8)
        panels = fig.subplots(1, len(axes), squeeze=False)[0]
        for ax, axis in zip(panels, axes, strict=True):
            if metric in TEXT_METRICS:
                _text_panel(ax, table, metric, axis)
            else:
                _panel(ax, study, table, metric, axis)
        panels[0].set_ylabel(metric)
        n_seeds = len(study.seeds)
        fig.suptitle(
            f"{study.name}: {METRICS[metric]}\n"
            f"{len(rows)} cases, {n_seeds} seed(s) each: median line, min-max band, dots = cases",
            fontsize=9,
        )
        path = out_dir / f"{metric}.png"
        save_figure(fig, path)
        paths.append(path)
    return paths
