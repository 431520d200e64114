"""Marks on the time axes of the figures: every fault a run sent and every scheduled
disturbance (``log.meta["faults"]`` and ``log.meta["disturbances"]``, in the log's time base),
so a recovery reads against its cause. A fault is a solid red line, the end of its
``duration_s`` (resume, release, ...) a dotted one, a disturbance an orange dashed line; the
top axis names them."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from formation.outputs.runlog import RunLog

__all__ = ["event_marks", "mark_time_axes"]

MAX_LABELS = 12
"""Name at most this many marks (a long list of faults would cover the axis)."""


def event_marks(log: RunLog) -> list[tuple[float, str, str, str]]:
    """``(t_s, label, colour, line style)`` of each fault and disturbance inside the log."""
    if not log.t_s.size:
        return []
    t0, t1 = float(log.t_s[0]), float(log.t_s[-1])
    out: list[tuple[float, str, str, str]] = []
    for f in log.meta.get("faults", []):
        t = f.get("t_s")
        if not isinstance(t, int | float) or not t0 <= t <= t1:
            continue
        who = f" {f['robot']}" if f.get("robot") else ""
        if f.get("undo"):
            out.append((float(t), f"{f.get('kind')}{who}", "tab:red", ":"))
        else:
            out.append((float(t), f"{f.get('kind')}{who}", "tab:red", "-"))
    for d in log.meta.get("disturbances", []):
        t = d.get("t_s")
        if isinstance(t, int | float) and t0 <= t <= t1:
            out.append((float(t), f"{d.get('kind')} {d.get('robot')}", "tab:orange", "--"))
    return sorted(out)


def mark_time_axes(axes: Sequence[Any], log: RunLog) -> int:
    """Draw :func:`event_marks` on every axis of ``axes`` (time on x), labels on the first;
    returns how many marks were drawn."""
    marks = event_marks(log)
    for ax in axes:
        for t, _, colour, ls in marks:
            ax.axvline(t, color=colour, ls=ls, lw=0.9, alpha=0.8, zorder=1)
    if marks and axes:
        top = axes[0]
        for t, label, colour, _ in marks[:MAX_LABELS]:
            top.text(
                t, 1.0, f" {label}", transform=top.get_xaxis_transform(), rotation=90,
                va="top", ha="right", fontsize=7, color=colour,
            )  # fmt: skip
    return len(marks)
