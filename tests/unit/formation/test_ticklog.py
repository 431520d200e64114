"""The loop's flat per-tick record (formation/sim/ticklog.py) gives the RunLog that the per-tick
objects gave (RunLog.from_ticks, and the slots put on one axis of slot ids after a reshape, as
the loop did before): the same arrays bit for bit, for any fleet, any slots and any reshapes,
converted in chunks of any size."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from formation.outputs.runlog import RunLog, floats_of, ints_of
from formation.sim.ticklog import TickLog
from robot_agent.core.firmware import Mode, WheelCommand

ARRAYS = ("t_s", "truth", "ref", "target", "slot_of", "slot_xy", "leader", "power", "mode")
floats = st.floats(allow_nan=True, allow_infinity=False, width=64)
MODES = (Mode.IDLE, Mode.TRACKING, Mode.HOLD, Mode.ESTOP)
ODD_MODES = ("hold", "no such mode", None)  # a mode's name is coded as the mode, anything else 0


def by_slot_id(
    first: list[int], slot_ids: list[tuple[int, ...]], rows: list[list[tuple[float, ...]]]
) -> tuple[list[int], list[list[tuple[float, ...]]]]:
    """The loop's former regrouping of per-tick rows by slot id (NaN where a tick lacked one)."""
    order = list(first)
    for ids in dict.fromkeys(slot_ids):
        order += [s for s in ids if s not in order]
    if all(ids == tuple(order) for ids in dict.fromkeys(slot_ids)):
        return order, rows
    nan_row = (math.nan, math.nan, math.nan, math.nan)
    out = []
    for ids, tick_rows in zip(slot_ids, rows, strict=True):
        by_id = dict(zip(ids, tick_rows, strict=True))
        out.append([by_id.get(s, nan_row) for s in order])
    return order, out


@st.composite
def runs(draw: st.DrawFn) -> tuple[int, int, list[tuple[int, ...]], bool]:
    n = draw(st.integers(1, 4))
    ticks = draw(st.integers(1, 12))
    shapes = draw(
        st.lists(
            st.lists(st.integers(0, 6), unique=True, max_size=5).map(tuple),
            min_size=1,
            max_size=3,
        )
    )
    keyed = draw(st.booleans())
    if not keyed:
        shapes = shapes[:1]
    switch = sorted(draw(st.lists(st.integers(0, ticks - 1), max_size=len(shapes) - 1)))
    per_tick = [shapes[sum(k >= s for s in switch)] for k in range(ticks)]
    return n, ticks, per_tick, keyed


@settings(max_examples=60, deadline=None)
@given(runs(), st.data())
def test_the_flat_record_gives_the_arrays_of_the_per_tick_objects(
    run: tuple[int, int, list[tuple[int, ...]], bool], data: st.DataObject
) -> None:
    n, ticks, per_tick, keyed = run
    ids = [f"r{i}" for i in range(n)]
    log = TickLog(keyed=keyed, chunk_ticks=data.draw(st.integers(1, 5)))
    truth: list[tuple[tuple[float, ...], ...]] = []
    leader: list[tuple[float, float, float]] = []
    slots: list[list[tuple[float, ...]]] = []
    cmds: list[list[WheelCommand]] = []
    for k in range(ticks):
        tr = tuple(tuple(data.draw(floats) for _ in range(3)) for _ in range(n))
        ld = (data.draw(floats), data.draw(floats), data.draw(floats))
        rows = [tuple(data.draw(floats) for _ in range(4)) for _ in per_tick[k]]
        cm = [
            WheelCommand(0.1, 0.2, data.draw(floats), data.draw(floats),
                         data.draw(st.sampled_from(MODES + ODD_MODES)), None, False)
            for _ in range(n)
        ]  # fmt: skip
        log.record(tr, ld[0], ld[1], ld[2], rows, per_tick[k], cm)
        truth.append(tr)
        leader.append(ld)
        slots.append(rows)
        cmds.append(cm)
    changes = [(0, [-1] * n)]
    first = list(per_tick[0])
    if first and ticks > 1:
        changes.append((ticks - 1, [first[i % len(first)] for i in range(n)]))
    flat = log.runlog(ids, first, 0.02, changes, 0.05)
    order, rows_by_id = by_slot_id(first, per_tick, slots) if keyed else (first, slots)
    if not order:  # no slot at all: from_ticks' rows are empty per tick
        rows_by_id = [[] for _ in range(ticks)]
    ref = RunLog.from_ticks(ids, order, 0.02, truth, leader, rows_by_id, changes, cmds, 0.05)
    assert flat.slot_ids == ref.slot_ids
    for name in ARRAYS:
        a, b = getattr(flat, name), getattr(ref, name)
        assert a.shape == b.shape and a.dtype == b.dtype, name
        assert a.tobytes() == b.tobytes(), name
        assert a.flags.writeable, name


@given(st.lists(st.floats(width=64) | st.integers(-(2**53), 2**53), max_size=300))
def test_floats_of_packs_each_number_s_double(values: list[float]) -> None:
    """``floats_of`` (the chunks' conversion): the doubles ``np.fromiter`` gives, bit for bit
    (NaN payloads, signed zeros, infinities, ints as their floats), in a writable array."""
    got = floats_of(values)
    want = np.fromiter(values, np.float64, len(values))
    assert got.dtype == np.float64 and got.shape == (len(values),) and got.flags.writeable
    assert got.tobytes() == want.tobytes()


@given(st.lists(st.integers(-(2**63), 2**63 - 1), max_size=300))
def test_ints_of_packs_each_int64(values: list[int]) -> None:
    """``ints_of`` (the chunks' mode codes): the int64 array ``np.array`` gives, writable."""
    got = ints_of(values)
    assert got.dtype == np.int64 and got.shape == (len(values),) and got.flags.writeable
    assert got.tolist() == values
