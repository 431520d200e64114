"""Paper-style figures from a RunLog: trajectories with the virtual trajectories (Figs 6, 9, 11),
motor power per wheel (Figs 7, 10, 12), formation error over time and a role timeline."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from formation.metrics import formation_error
from formation.runlog import RunLog

COLORS = ["tab:red", "tab:green", "tab:blue", "tab:orange", "tab:purple", "tab:brown",
          "tab:pink", "tab:gray", "tab:olive", "tab:cyan"]  # fmt: skip


def _color(i: int) -> str:
    return COLORS[i % len(COLORS)]


def plot_trajectories(log: RunLog, path: Path, title: str = "") -> None:
    fig, ax = plt.subplots(figsize=(8, 6))
    n_slots = log.slot_xy.shape[1]
    for k in range(n_slots):
        xy = log.slot_xy[:, k, :]
        ax.plot(xy[:, 0] * 100, xy[:, 1] * 100, "--", color="0.55", lw=1.0,
                label="virtual trajectories" if k == 0 else None)  # fmt: skip
        ax.annotate(f"v{log.slot_ids[k] + 1}", xy[-1] * 100, color="0.4", fontsize=8)
    for j, rid in enumerate(log.robot_ids):
        ref = log.ref[:, j, :]
        c = _color(j)
        ax.plot(ref[:, 0] * 100, ref[:, 1] * 100, "-", color=c, lw=1.5, label=rid)
        ax.plot(ref[0, 0] * 100, ref[0, 1] * 100, "o", color=c, ms=6)
        ax.plot(ref[-1, 0] * 100, ref[-1, 1] * 100, "s", color=c, ms=6)
    ax.set_xlabel("x (cm)")
    ax.set_ylabel("y (cm)")
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(True, alpha=0.3)
    ax.legend(loc="best", fontsize=8)
    ax.set_title(title or "Robots' reference points (solid) and virtual trajectories (dashed)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_motor_power(log: RunLog, path: Path) -> None:
    n = len(log.robot_ids)
    fig, axes = plt.subplots(n, 1, figsize=(8, 1.9 * n + 0.6), sharex=True, squeeze=False)
    for j, rid in enumerate(log.robot_ids):
        ax = axes[j, 0]
        ax.plot(log.t_s, log.power[:, j, 0] * 100, color="tab:red", lw=0.8, label="right")
        ax.plot(log.t_s, log.power[:, j, 1] * 100, color="tab:blue", lw=0.8, label="left")
        ax.set_ylabel(f"{rid} power (%)")
        ax.grid(True, alpha=0.3)
        ax.legend(loc="upper right", fontsize=7)
    axes[-1, 0].set_xlabel("time (s)")
    fig.suptitle("Motor power per wheel (fraction of maximum)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_error(log: RunLog, path: Path, settle_s: float | None = None) -> None:
    err = formation_error(log)
    fig, ax = plt.subplots(figsize=(8, 3.5))
    for j, rid in enumerate(log.robot_ids):
        ax.plot(log.t_s, err[:, j] * 100, color=_color(j), lw=1.0, label=rid)
    if settle_s is not None:
        ax.axvline(settle_s, color="0.5", ls=":", lw=1)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("formation error (cm)")
    ax.set_yscale("symlog", linthresh=1.0)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_roles(log: RunLog, path: Path) -> None:
    fig, ax = plt.subplots(figsize=(8, 0.5 * len(log.robot_ids) + 1.2))
    for j, rid in enumerate(log.robot_ids):
        s = log.slot_of[:, j].astype(float)
        s[s < 0] = np.nan
        ax.plot(log.t_s, s, drawstyle="steps-post", color=_color(j), lw=2, label=rid)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("slot (0 = leader)")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8, loc="upper right")
    ax.set_title("Role timeline")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def write_all(
    log: RunLog, out_dir: Path, title: str = "", settle_s: float | None = None
) -> list[Path]:
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = [
        out_dir / "trajectories.png",
        out_dir / "motor_power.png",
        out_dir / "formation_error.png",
        out_dir / "roles.png",
    ]
    plot_trajectories(log, paths[0], title)
    plot_motor_power(log, paths[1])
    plot_error(log, paths[2], settle_s)
    plot_roles(log, paths[3])
    return paths
