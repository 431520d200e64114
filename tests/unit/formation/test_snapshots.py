"""``formation.png`` (formation.outputs.snapshots): the instants drawn (start of the formation,
end, evenly between, one just before each disturbance), tight axes around what is drawn, and a
bounded image at 3 and at 30 robots."""

from __future__ import annotations

from pathlib import Path

import matplotlib.image as mpimg
import numpy as np
import pytest
from support.synthetic_logs import synthetic_log

from formation.outputs import snapshots
from formation.outputs.figures_style import MAX_PX
from scenario.load import Disturbance


def test_instants_start_at_the_first_assignment_and_include_each_disturbance() -> None:
    log = synthetic_log(3, ticks=400, dt_s=0.05)  # unassigned at tick 0
    plain = snapshots.snapshot_ticks(log, [])
    assert plain[0] == 1 and plain[-1] == 399 and len(plain) == snapshots.SNAPSHOTS
    events = snapshots.events_of([Disturbance(t_s=7.0, robot="r1", kind="drag", dx=-0.6)])
    assert events == [(7.0, 1.0, "r1", "r1 dragged 60 cm")]
    with_event = snapshots.snapshot_ticks(log, events)
    assert int(np.searchsorted(log.t_s, 7.0)) - 1 in with_event
    assert len(with_event) == snapshots.SNAPSHOTS and with_event == sorted(with_event)


@pytest.mark.parametrize("n", [3, 30])
def test_the_figure_is_bounded_and_its_axes_tight(n: int, tmp_path: Path) -> None:
    import matplotlib.pyplot as plt

    log = synthetic_log(n, ticks=300, dt_s=0.05)
    path = tmp_path / "formation.png"
    captured = {}
    real_save = snapshots.save_figure

    def keep(fig: object, p: Path) -> None:
        captured["axes"] = [(ax.get_xlim(), ax.get_ylim()) for ax in fig.axes]  # type: ignore[attr-defined]
        real_save(fig, p)  # type: ignore[arg-type]

    snapshots.save_figure = keep  # type: ignore[assignment]
    try:
        snapshots.plot_snapshots(log, path, events=[(7.0, 1.0, "r1", "r1 dragged 60 cm")])
    finally:
        snapshots.save_figure = real_save  # type: ignore[assignment]
    img = mpimg.imread(path)
    assert max(img.shape[:2]) <= MAX_PX
    pts = np.concatenate([log.truth[:, :, :2].reshape(-1, 2), log.slot_xy.reshape(-1, 2)]) * 100
    span = pts.max(axis=0) - pts.min(axis=0)
    (xlim, ylim) = captured["axes"][0]
    # no more than the margins (and the time labels' room) around the data
    assert xlim[1] - xlim[0] <= span[0] + 2 * (snapshots.MARGIN_CM + 8.0) + 1e-6
    assert ylim[1] - ylim[0] <= span[1] + 2 * (snapshots.MARGIN_CM + 8.0) + 8.0 + 1e-6
    if n > snapshots.FEW:
        assert len(captured["axes"]) == snapshots.PANELS
    plt.close("all")
