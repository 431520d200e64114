"""The neighbour entries that can matter to one firmware tick: a long list's far entries dropped
once, before repulsion and the safety filter walk it.

Stdlib only, pure. A shell passes every robot it knows (the in-process simulator: all the others,
29 entries a tick at 30 robots, as a ``neighbour_index.NeighbourView``, whose near entries are
this function's answer computed from the entries of the cells near the robot only), and both
per-neighbour loops of a tick (``repulsion._pushes``,
``safety_neighbours.NeighbourBarriers.append``) read each entry in full, only to skip most of
them with a box test. :func:`near_entries` reads an entry's position (and the three fields that
widen the filter's box) and drops it only when BOTH loops would skip it without a trace:

* repulsion (at the axle centre ``(x, y)``): ``not (-d0 < dx < d0 and -d0 < dy < d0)`` with a
  finite ``dx + dy`` (a non-finite one is counted there: kept);
* the safety filter (at the reference point ``(rx, ry)``): an eight-field entry (a
  ``Neighbour`` without motion claims) with no radius and no velocity
  (``not (rad > 0 or vx != 0 or vy != 0)``: its quick-reject bound is ``box_m`` itself), outside
  the box ``-box_m < dx < box_m`` ... with a finite ``dx + dy``. ``box_m`` is
  :meth:`robot_agent.core.safety_filter.SafetyFilter.reach_box_m`, the same floats as the
  filter's own bound (one formula, ``NeighbourBarriers.quick_m``).

The differences are the same float operations as in those loops (``x - qx``, ``rx - qx``), and
"outside" is written with the comparisons that are False for a NaN, so a NaN anywhere (a field,
a bound) keeps the entry. Every other entry (two fields, a motion claim's view, a radius or a
velocity, not a tuple, anything odd) is kept. A kept entry is the same object, in the same
order: the loops add the same terms in the same order, count the same rejections and bind the
same constraints, bit for bit (``tests/unit/robot_agent/test_neighbour_select.py``). Any
exception while reading (a field that is not a number) returns the list unchanged: the loops
then raise as they always did, and the firmware counts it.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Final

from robot_agent.core import _accel

__all__ = ["SELECT_MIN_ENTRIES", "near_entries", "select_min_entries"]

#: The compiled core selects the neighbours that can matter from lists of at least this many
#: entries: below, the walks it saves cost less than the selection (a small fleet's neighbours
#: are mostly near anyway). Pure Python never does: there the selection costs more than it
#: saves (chevron30: ~5 % more per tick; docs/benchmarks.md). The outputs are the same bit for
#: bit either way.
SELECT_MIN_ENTRIES: Final = 8
_NEVER: Final = 1 << 62  # (no list is this long)


def select_min_entries() -> int:
    """The shortest neighbour list a firmware of this process selects from
    (:data:`SELECT_MIN_ENTRIES` with the compiled core; pure Python: none, a huge number)."""
    return SELECT_MIN_ENTRIES if _accel.ACTIVE else _NEVER


def near_entries(
    neighbours: Sequence[Any],
    x: float,
    y: float,
    d0: float,
    rx: float,
    ry: float,
    box_m: float,
) -> Sequence[Any]:
    """``neighbours`` without the entries that neither repulsion (influence ``d0`` at the axle
    centre ``(x, y)``; ``-inf``: repulsion off) nor the safety filter (quick-reject half-width
    ``box_m`` at the reference point ``(rx, ry)``; ``-inf``: filter off) can use (module
    docstring); the same list when it is not a list or on a malformed entry."""
    if not isinstance(neighbours, list):
        return neighbours
    try:
        return _near(neighbours, x, y, d0, rx, ry, box_m)
    except Exception:  # a malformed entry: the loops raise on it themselves (counted)
        return neighbours


def _near(
    neighbours: list[Any],
    x: float,
    y: float,
    d0: float,
    rx: float,
    ry: float,
    box_m: float,
) -> list[Any]:
    """:func:`near_entries` on a list (raises on a field that is not a number)."""
    out: list[Any] = []
    for nb in neighbours:
        if not _drops(nb, x, y, d0, rx, ry, box_m):
            out.append(nb)
    return out


def _near_of(
    entries: list[Any],
    mask: int,
    tail: list[Any],
    x: float,
    y: float,
    d0: float,
    rx: float,
    ry: float,
    box_m: float,
) -> list[Any]:
    """:func:`_near` of the list of ``entries[j]`` for each bit ``j`` of ``mask`` (lowest
    first), then ``tail``, without building that list (``neighbour_index.NeighbourView.near``'s
    candidates)."""
    out: list[Any] = []
    while mask:  # (lowest bit first: the entries in list order)
        low = mask & -mask
        nb = entries[low.bit_length() - 1]
        mask ^= low
        if not _drops(nb, x, y, d0, rx, ry, box_m):
            out.append(nb)
    for nb in tail:
        if not _drops(nb, x, y, d0, rx, ry, box_m):
            out.append(nb)
    return out


def _drops(nb: Any, x: float, y: float, d0: float, rx: float, ry: float, box_m: float) -> bool:
    """Neither loop can use entry ``nb`` (module docstring; raises on a field that is not a
    number)."""
    if not isinstance(nb, tuple):
        return False
    ent: tuple[Any, ...] = nb
    n = len(ent)  # (compared as a name: "len(ent) == 8" would make ent a fixed tuple,
    if n != 8:  # compiled, unboxed whole at each item read)
        return False
    # (float-typed locals: compiled, each field is unboxed once and compared natively; the
    # fields are read by index, the position first: a near entry's other fields are not read)
    qx: float = ent[0]
    qy: float = ent[1]
    dx = x - qx
    dy = y - qy
    fx = rx - qx
    fy = ry - qy
    if (
        (dx >= d0 or dx <= -d0 or dy >= d0 or dy <= -d0)
        and (fx >= box_m or fx <= -box_m or fy >= box_m or fy <= -box_m)
        and (s := dx + dy) - s == 0.0  # finite (x - x is 0.0 for those only)
        and (f := fx + fy) - f == 0.0
    ):
        rad: float = ent[7]
        vx: float = ent[4]
        vy: float = ent[5]
        return not (rad > 0.0 or vx != 0.0 or vy != 0.0)  # far from both: read no more
    return False
