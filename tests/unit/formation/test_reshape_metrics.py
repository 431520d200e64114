"""metrics.json's ``reshapes`` (issue 28): the reshapes the leader messages reported, with their
transition time and the least distance between two robots' truth during each."""

from __future__ import annotations

import math

import numpy as np
import pytest

from formation.outputs.metrics import reshape_metrics
from formation.outputs.runlog import RunLog
from formation.record.collector_build import reshape_intervals


def test_intervals_split_where_the_fraction_falls_back_or_the_shape_changes() -> None:
    marks = [
        (10.0, "column", 0.0),
        (10.5, "column", 0.5),
        (11.0, "column", 1.0),
        (20.0, "triangle", 0.1),
        (22.0, "triangle", 1.0),
        (30.0, "triangle", 0.0),  # the same shape again: a new reshape
        (31.0, "triangle", 1.0),
    ]
    got = reshape_intervals(marks[::-1], origin_s=10.0)  # order of arrival does not matter
    assert got == [
        {"kind": "column", "start_s": 0.0, "end_s": 1.0, "complete": True},
        {"kind": "triangle", "start_s": 10.0, "end_s": 12.0, "complete": True},
        {"kind": "triangle", "start_s": 20.0, "end_s": 21.0, "complete": True},
    ]
    assert reshape_intervals([(1.0, "line", 0.2), (2.0, "line", 0.6)], 0.0)[0]["complete"] is False
    assert reshape_intervals([], 0.0) == []
    # the slot count a reshape ends with, when the leader messages carry it
    grown = reshape_intervals([(1.0, "chevron", 0.1, 5), (4.0, "chevron", 1.0, 5)], 0.0)
    assert grown == [
        {"kind": "chevron", "start_s": 1.0, "end_s": 4.0, "complete": True, "slots": 5}
    ]


def test_reshape_metrics_measure_the_truth_during_each_reshape() -> None:
    log = RunLog.allocate(["r1", "r2", "r3"], [0, 1, 2], 5)
    log.t_s[:] = np.arange(5.0)
    # r1 and r2 come within 0.25 m at t = 2 (inside), 0.1 m at t = 4 (outside)
    gaps = [0.5, 0.4, 0.25, 0.5, 0.1]
    for k, g in enumerate(gaps):
        log.truth[k] = [[0.0, 0.0, 0.0], [g, 0.0, 0.0], [0.0, 3.0, 0.0]]
    log.reshapes = [{"kind": "column", "start_s": 1.0, "end_s": 3.0}]
    (m,) = reshape_metrics(log)
    assert m["kind"] == "column" and m["transition_s"] == 2.0 and m["start_s"] == 1.0
    assert m["complete"] is True
    assert m["least_separation_m"] == pytest.approx(0.25)
    log.truth[:] = math.nan  # no truth during it: unknown, not 0 nor inf
    assert reshape_metrics(log)[0]["least_separation_m"] is None
