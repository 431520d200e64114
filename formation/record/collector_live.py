"""The live snapshot of a run being collected: what
:meth:`formation.record.collector.RunCollector.live`
returns (a :class:`~formation.outputs.live_table.LiveView`, for ``formation up``'s display), from
the
latest sample of each series the collector keeps. Cheap enough to call at a few Hz."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np

from bus_schemas import Status
from formation.outputs.live_table import LiveRobot, LiveView
from formation.record.collector_series import Series
from robot_agent.core.kinematics import reference_point

__all__ = ["live_view"]


def live_view(
    robot_ids: Sequence[str],
    latest: Sequence[tuple[float, float, float] | None],
    statuses: Sequence[Status | None],
    alive: Mapping[str, bool],
    assignment_series: Series,
    slots: Mapping[int, Series],
    wheels: Sequence[Series],
    *,
    ref_offset_m: float,
    t_s: float | None,
    tick: int | None,
    rejected: int,
) -> LiveView:
    """The run now: per robot (index ``i`` of ``robot_ids``) its latest truth pose ``latest[i]``,
    status ``statuses[i]``, liveliness (``alive["robot/<id>"]``), assigned slot (the latest of
    ``assignment_series``), tracking error (its reference point, eqs 10-11 with
    ``ref_offset_m``, to the latest position of that slot in ``slots``) and latest wheel command
    (``wheels[i]``); the smallest centre distance between the latest poses and the leader (the
    robot assigned slot 0). ``t_s``, ``tick`` and ``rejected`` are passed through."""
    assignment: dict[str, int] = assignment_series.latest() or {}
    slot_xy = {s: series.latest() for s, series in slots.items()}
    l_m = ref_offset_m
    robots: list[LiveRobot] = []
    for i, rid in enumerate(robot_ids):
        st = statuses[i]
        slot = assignment.get(rid)
        err: float | None = None
        pose = latest[i]
        target = slot_xy.get(slot) if slot is not None else None
        if pose is not None and target is not None:
            xr, yr = reference_point(pose[0], pose[1], pose[2], l_m)
            err = math.hypot(target[0] - xr, target[1] - yr)
        robots.append(
            LiveRobot(
                robot=rid,
                alive=alive.get(f"robot/{rid}"),
                slot=slot,
                role=st.role if st is not None else None,
                mode=st.mode if st is not None else None,
                error_m=err,
                rejected=st.rejected if st is not None else None,
                power=wheels[i].latest(),
            )
        )
    min_d: float | None = None
    known = [p for p in latest if p is not None]
    if len(known) >= 2:
        xy = np.array([p[:2] for p in known])
        diff = xy[:, None, :] - xy[None, :, :]
        d = np.hypot(diff[..., 0], diff[..., 1])
        d[np.diag_indices_from(d)] = np.inf
        min_d = float(d.min())
    leader = next((rid for rid, s in assignment.items() if s == 0), None)
    return LiveView(
        t_s=t_s,
        tick=tick,
        leader=leader,
        min_distance_m=min_d,
        robots=robots,
        rejected=rejected,
    )
