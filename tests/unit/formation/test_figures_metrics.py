"""Figures readable at any fleet size (bounded images, aggregate views, correct axes, an index
page) and role-change counts that leave out the initial assignment."""

from __future__ import annotations

import json
import re
import warnings
from pathlib import Path

import matplotlib.image as mpimg
import matplotlib.pyplot as plt
import numpy as np
import pytest
from support.synthetic_logs import synthetic_log

import scenario
from formation.outputs import figures, figures_style, metrics
from formation.outputs.runlog import RunLog
from formation.sim import simulate


@pytest.mark.parametrize("n", [3, 12, 300])
def test_figures_have_bounded_size_and_an_index(n: int, tmp_path: Path) -> None:
    log = synthetic_log(n)
    m = metrics.compute(log, 5.0, 0.02)
    (tmp_path / "metrics.json").write_text(json.dumps(m))
    paths = figures.write_all(log, tmp_path, "synthetic", 5.0)
    assert [p.name for p in paths] == [*figures.FIGURES, "index.md"]
    for p in paths[:4]:
        h, w = mpimg.imread(p).shape[:2]
        assert 300 <= w <= figures_style.MAX_PX and 200 <= h <= figures_style.MAX_PX, (p.name, w, h)
    index = (tmp_path / "index.md").read_text()
    links = re.findall(r"\]\(([^)]+)\)", index)
    assert "metrics.json" in links
    for name in figures.FIGURES:
        assert name in links
    for link in links:
        assert (tmp_path / link).exists(), link
    assert f"- {n} robots" in index
    assert "role changes 4 (initial assignment excluded)" in index  # swap 2, lose 1, back 1
    assert plt.get_fignums() == []  # every figure closed


def test_index_without_metrics_links_only_what_exists(tmp_path: Path) -> None:
    paths = figures.write_all(synthetic_log(3, ticks=50), tmp_path)
    index = paths[-1].read_text()
    assert "metrics.json" not in index and "run.npz" not in index
    assert (
        figures.write_all(synthetic_log(3, ticks=50), tmp_path / "x", index=False)[-1].suffix
        == ".png"
    )


@pytest.mark.parametrize("n", [3, 40])
def test_error_axes_never_negative_and_never_clip_the_peak(n: int) -> None:
    log = synthetic_log(n)
    peak_cm = float(np.nanmax(metrics.formation_error(log))) * 100
    fig = figures.error_figure(log, settle_s=5.0)
    try:
        ax_lin, ax_log = fig.axes[:2]
        assert ax_lin.get_yscale() == "linear" and ax_log.get_yscale() == "log"
        lo, hi = ax_lin.get_ylim()
        assert lo == 0.0 and hi >= peak_cm
        lo, hi = ax_log.get_ylim()
        assert 0.0 < lo < hi and hi >= peak_cm
    finally:
        plt.close(fig)


@pytest.mark.parametrize("n", [3, 40])
def test_roles_ticks_are_integers(n: int) -> None:
    fig = figures.roles_figure(synthetic_log(n))
    try:
        ax = fig.axes[-1]
        fig.canvas.draw()
        ticks = [t for t in ax.get_yticks() if ax.get_ylim()[0] <= t <= ax.get_ylim()[1]]
        assert ticks and all(float(t).is_integer() for t in ticks), ticks
    finally:
        plt.close(fig)


def test_robot_styles_are_distinct_up_to_forty() -> None:
    styles = [figures_style.robot_style(i) for i in range(40)]
    assert len(set(styles)) == 40
    assert len({c for c, _ in styles[:20]}) == 20  # 20 distinct colours, all solid
    assert figures_style.robot_style(0)[0] == "#d62728"  # the paper's r1 was red


def test_role_changes_leave_out_the_initial_assignment() -> None:
    clean = metrics.compute(synthetic_log(3, events=False), 5.0, 0.02)["run"]
    assert clean["role_change_count"] == 0 and clean["role_changes"] == []
    assert [(a["robot"], a["slot"]) for a in clean["initial_assignments"]] == [
        ("r1", 0),
        ("r2", 1),
        ("r3", 2),
    ]
    assert all(a["t_s"] == pytest.approx(0.05) for a in clean["initial_assignments"])
    run = metrics.compute(synthetic_log(5), 5.0, 0.02)["run"]
    got = [(c["robot"], c["from_slot"], c["to_slot"]) for c in run["role_changes"]]
    assert got == [("r1", 0, 1), ("r2", 1, 0), ("r5", 4, None), ("r5", None, 4)]
    assert run["role_change_count"] == 4


def test_clean_simulated_three_robot_run_reports_no_role_change() -> None:
    scn = scenario.load("paper-exp1")
    res = simulate.run(scn, duration_s=5.0)
    run = metrics.compute(res.log, 2.5, scn.settle_tol_m)["run"]
    assert run["role_change_count"] == 0
    assert len(run["initial_assignments"]) == 3


@pytest.mark.parametrize("n", [3, 40])
@pytest.mark.parametrize("ticks", [0, 1, 2])
def test_figures_of_empty_and_tiny_runs(n: int, ticks: int, tmp_path: Path) -> None:
    """An interrupted run may have recorded nothing or one tick: figures are still written."""
    if ticks:
        log = synthetic_log(n, ticks=ticks)
    else:
        log = RunLog.allocate([f"r{j + 1}" for j in range(n)], list(range(n)), 0)
    with warnings.catch_warnings():
        warnings.simplefilter("error", UserWarning)  # no singular axis limits
        paths = figures.write_all(log, tmp_path)
    for p in paths[:4]:
        h, w = mpimg.imread(p).shape[:2]
        assert w <= figures_style.MAX_PX and h <= figures_style.MAX_PX
