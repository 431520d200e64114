"""One tick's neighbour entries of a whole fleet, bucketed once by position, so each robot's
:func:`~robot_agent.core.neighbour_select.near_entries` reads only the entries near it.

Stdlib only, pure. The in-process simulator gives every robot the same entries (the others'
:class:`~robot_agent.core.safety_types.Neighbour`), and each robot's selection walks all of them
(29 entries a robot a tick at 30 robots, most of them far). :class:`NeighbourIndex` takes the
fleet's entries once a tick (``entries[j]``: robot ``j``'s, or None) and puts each *plain* entry
in a square cell of a uniform grid (``cell_m``, or larger); :meth:`NeighbourIndex.view` is
robot ``i``'s list (every entry but its own and the Nones, in order, then ``tail``) as a
:class:`NeighbourView`, a read-only sequence equal to that list.

:meth:`NeighbourView.near` answers exactly what ``near_entries`` answers on that list: the same
entries, the same objects, in the same order (``tests/unit/robot_agent/test_neighbour_index.py``
compares them on random fleets). It walks ``near_entries``'s own test (``neighbour_select._drops``,
through ``_near_of``) over fewer entries, the *candidates* in list order (read from the bit mask
below, without building their list), and leaves out only entries that walk would drop:

* a plain entry is a tuple of eight fields whose position ``(x, y)``, velocity ``(vx, vy)`` and
  radius are floats (the type itself), the position finite and within :data:`COORD_LIMIT_M`,
  with no radius and no velocity (``not (rad > 0 or vx != 0 or vy != 0)``). It is a candidate
  when its cell meets the box around the two boxes the walk tests (repulsion's ``d0`` at
  ``(x, y)``, the filter's ``box_m`` at ``(rx, ry)``), widened by :data:`PAD_M`, far more than
  the rounding of a difference of two coordinates within the limit (~1e-10 m). A cell number
  is ``floor(c * (1 / cell_m))``, the same float operations for an entry and a bound
  (monotone: an entry inside the widened box is in a cell the query meets). Outside: the walk
  would find it outside both boxes, with finite differences, and drop it without reading more;
* every other entry (a motion claim's view, a radius, a velocity, a list, anything odd or
  far away) and every ``tail`` entry is a candidate; a malformed one raises in the walk as it
  would in ``near_entries``, and then the whole list is the answer, as there.

A query the grid cannot answer exactly (a non-finite or far centre, a non-finite or infinite
half-width) walks the whole list. The grid is two lists of strips over the plain entries'
bounding box, one per axis (the cells' columns and rows), each strip a bit mask of its entries
(bit ``j``: ``entries[j]``), the cell doubled until there are at most 64 + 8 strips a plain
entry (a sparse fleet). A query's cells hold the entries of its x strips AND of its y strips:
it ORs the masks of the strips it meets on each axis (clipped to the grid), ANDs the two, adds
the special entries' mask and walks the bits in order: no sort, no dictionary, one read a
strip, native integers up to 62 robots.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any, Final

from .neighbour_select import _near_of, near_entries

__all__ = [
    "COORD_LIMIT_M",
    "NEIGHBOUR_CELL_M",
    "PAD_M",
    "NeighbourIndex",
    "NeighbourView",
]

NEIGHBOUR_CELL_M: Final = 0.3
"""The in-process simulator's cell (m): with the default parameters a firmware's boxes (the
filter's +-0.54 m) meet about 5 strips an axis. Any positive size gives the same answers; at
chevron30 0.2 and 0.3 m give the same candidates (6.8 a robot, 5.7 kept), 0.6 m more (9.4);
0.3 m reads fewer strips (docs/benchmarks.md)."""

COORD_LIMIT_M: Final = 1.0e6
"""A plain entry's coordinates and a query's centres lie within +-this (m): a difference of two
is then exact to ~1e-10 m, far below :data:`PAD_M`."""
PAD_M: Final = 1.0e-6
"""How far (m) the grid's query box reaches beyond the walk's boxes."""
_NEG_INF: Final = -math.inf
_MAX_CELLS_BASE: Final = 64  # (the grid: at most this many cells plus ...
_MAX_CELLS_PER_ENTRY: Final = 8  # ... this many a plain entry, its cell doubled until so)


def _cell(c: float, inv_cell: float) -> int:
    """``floor(c * inv_cell)``: the cell number of coordinate ``c`` (finite, within the limit)."""
    v = c * inv_cell
    k = int(v)
    if float(k) > v:
        k -= 1
    return k


def _or_of(strips: list[int], a: int, b: int) -> int:
    """The OR of ``strips[a]`` to ``strips[b]`` (0 for none)."""
    out = 0
    for c in range(a, b + 1):
        out |= strips[c]
    return out


def _span(cells: list[int]) -> tuple[int, int]:
    """The least and the greatest of ``cells`` ((0, 0) for none)."""
    if not cells:
        return 0, 0
    lo = cells[0]
    hi = lo
    for c in cells:
        if c < lo:
            lo = c
        elif c > hi:
            hi = c
    return lo, hi


def _x_of(ent: tuple[Any, ...]) -> float:
    """A plain entry's x."""
    x: float = ent[0]
    return x


def _y_of(ent: tuple[Any, ...]) -> float:
    """A plain entry's y."""
    y: float = ent[1]
    return y


def _is_plain(nb: object, lim: float) -> bool:
    """``nb`` is a plain entry (module docstring): a tuple of eight fields, position, velocity
    and radius floats, the position within ``+-lim``, no radius and no velocity."""
    if not isinstance(nb, tuple):
        return False
    ent: tuple[Any, ...] = nb
    n = len(ent)
    if n != 8:
        return False
    qx_o = ent[0]
    qy_o = ent[1]
    vx_o = ent[4]
    vy_o = ent[5]
    rad_o = ent[7]
    if not (
        type(qx_o) is float
        and type(qy_o) is float
        and type(vx_o) is float
        and type(vy_o) is float
        and type(rad_o) is float
    ):
        return False
    qx: float = qx_o
    qy: float = qy_o
    vx: float = vx_o
    vy: float = vy_o
    rad: float = rad_o
    return -lim <= qx <= lim and -lim <= qy <= lim and not (rad > 0.0 or vx != 0.0 or vy != 0.0)


class NeighbourIndex:
    """The fleet's entries of one tick (``entries[j]``: robot ``j``'s entry or None) in a grid
    of cells of at least ``cell_m`` (module docstring). Read-only once built."""

    __slots__ = (
        "_cell_m",
        "_count",
        "_entries",
        "_inv_cell",
        "_kx0",
        "_ky0",
        "_nx",
        "_ny",
        "_special",
        "_strips_x",
        "_strips_y",
    )

    def __init__(self, entries: list[Any], cell_m: float) -> None:
        if not cell_m > 0.0 or cell_m - cell_m != 0.0:
            raise ValueError(f"cell_m must be positive and finite, got {cell_m!r}")
        self._entries = entries
        special = 0  # (bit j: entry j is a candidate of every query)
        count = 0  # entries that are not None
        plain_j: list[int] = []
        cx: list[int] = []  # (the plain entries' cells)
        cy: list[int] = []
        lim = COORD_LIMIT_M
        inv = 1.0 / cell_m
        for j in range(len(entries)):
            nb = entries[j]
            if nb is None:
                continue
            count += 1
            if _is_plain(nb, lim):
                ent: tuple[Any, ...] = nb
                qx: float = ent[0]
                qy: float = ent[1]
                plain_j.append(j)
                cx.append(_cell(qx, inv))
                cy.append(_cell(qy, inv))
            else:
                special |= 1 << j
        self._special = special
        self._count = count
        # the strips over the plain entries' cells, the cell doubled until there are at most
        # _MAX_CELLS_PER_ENTRY strips a plain entry (a sparse fleet; any cell: the same answers)
        cap = _MAX_CELLS_BASE + _MAX_CELLS_PER_ENTRY * len(plain_j)
        while True:
            kx0, kx1 = _span(cx)
            ky0, ky1 = _span(cy)
            nx = kx1 - kx0 + 1
            ny = ky1 - ky0 + 1
            if nx + ny <= cap:
                break
            cell_m *= 2.0
            inv = 1.0 / cell_m
            cx = [_cell(_x_of(entries[j]), inv) for j in plain_j]
            cy = [_cell(_y_of(entries[j]), inv) for j in plain_j]
        strips_x = [0] * nx
        strips_y = [0] * ny
        for k in range(len(plain_j)):
            bit = 1 << plain_j[k]
            c = cx[k] - kx0
            strips_x[c] = strips_x[c] | bit
            c = cy[k] - ky0
            strips_y[c] = strips_y[c] | bit
        self._cell_m = cell_m
        self._inv_cell = inv
        self._kx0 = kx0
        self._ky0 = ky0
        self._nx = nx
        self._ny = ny
        self._strips_x = strips_x
        self._strips_y = strips_y

    @property
    def entries(self) -> list[Any]:
        """The fleet's entries, as given (not copied)."""
        return self._entries

    @property
    def cell_m(self) -> float:
        """The grid's cell (m): ``cell_m`` as given, or doubled for a sparse fleet."""
        return self._cell_m

    def view(self, i: int, tail: list[Any] | None = None) -> NeighbourView:
        """Robot ``i``'s neighbour list: every entry but ``entries[i]`` and the Nones, in order,
        then ``tail`` (entries of no robot, such as the scenario's bodies)."""
        return NeighbourView(self, i, [] if tail is None else tail)

    def views(self, tail: list[Any] | None = None) -> list[NeighbourView]:
        """Every robot's :meth:`view` (``entries[i]``'s at ``i``), in one call."""
        t: list[Any] = [] if tail is None else tail
        return [NeighbourView(self, i, t) for i in range(len(self._entries))]

    def candidates(
        self, i: int, x: float, y: float, d0: float, rx: float, ry: float, box_m: float
    ) -> int:
        """The entries that :func:`near_entries` may keep for a robot at ``(x, y)`` /
        ``(rx, ry)`` with half-widths ``d0`` and ``box_m`` (its arguments), as a bit mask (bit
        ``j``: ``entries[j]``), without ``i``: every special entry and every plain one whose cell
        meets the query box; -1 when the grid cannot answer exactly (module docstring)."""
        lim = COORD_LIMIT_M
        if not (-lim <= x <= lim and -lim <= y <= lim and -lim <= rx <= lim and -lim <= ry <= lim):
            return -1
        # each half-width: finite (an infinite or NaN one keeps everything), or -inf (the loop
        # is off); one at most 0.0 has an empty box
        if not (d0 - d0 == 0.0 or d0 == _NEG_INF):
            return -1
        if not (box_m - box_m == 0.0 or box_m == _NEG_INF):
            return -1
        have = False
        lo_x = 0.0
        hi_x = 0.0
        lo_y = 0.0
        hi_y = 0.0
        if d0 > 0.0:
            have = True
            lo_x = x - d0
            hi_x = x + d0
            lo_y = y - d0
            hi_y = y + d0
        if box_m > 0.0:
            bx0 = rx - box_m
            bx1 = rx + box_m
            by0 = ry - box_m
            by1 = ry + box_m
            if have:
                lo_x = min(lo_x, bx0)
                hi_x = max(hi_x, bx1)
                lo_y = min(lo_y, by0)
                hi_y = max(hi_y, by1)
            else:
                have = True
                lo_x = bx0
                hi_x = bx1
                lo_y = by0
                hi_y = by1
        mask = self._special
        if have:
            inv = self._inv_cell
            pad = PAD_M
            kx0 = self._kx0
            ky0 = self._ky0
            nx = self._nx
            ny = self._ny
            # the query's cells, relative to the grid's first one and clipped to the grid
            ax = _cell(lo_x - pad, inv) - kx0
            bx = _cell(hi_x + pad, inv) - kx0
            ay = _cell(lo_y - pad, inv) - ky0
            by = _cell(hi_y + pad, inv) - ky0
            if ax < 0:
                ax = 0
            if bx >= nx:
                bx = nx - 1
            if ay < 0:
                ay = 0
            if by >= ny:
                by = ny - 1
            # (the entries of the cells (cx, cy) in range: those of the x strips in range AND
            # of the y strips in range)
            mask |= _or_of(self._strips_x, ax, bx) & _or_of(self._strips_y, ay, by)
        if mask >> i & 1:
            mask ^= 1 << i
        return mask

    def count_without(self, i: int) -> int:
        """How many entries are not None, without ``entries[i]``."""
        return self._count - (0 if self._entries[i] is None else 1)


class NeighbourView:
    """Robot ``i``'s neighbour list of a :class:`NeighbourIndex` (its :meth:`~NeighbourIndex.view`):
    a read-only sequence of the entries, and :meth:`near`, its :func:`near_entries`."""

    __slots__ = ("_full", "_i", "_index", "_len", "_tail")

    def __init__(self, index: NeighbourIndex, i: int, tail: list[Any]) -> None:
        self._index = index
        self._i = i
        self._tail = tail
        self._len = index.count_without(i) + len(tail)
        self._full: list[Any] | None = None

    def full(self) -> list[Any]:
        """The whole list (built once; the same list every call: do not change it)."""
        got = self._full
        if got is None:
            i = self._i
            ents = self._index.entries
            got = [ents[j] for j in range(len(ents)) if j != i and ents[j] is not None]
            got.extend(self._tail)
            self._full = got
        return got

    def near(
        self, x: float, y: float, d0: float, rx: float, ry: float, box_m: float
    ) -> Sequence[Any]:
        """``near_entries(self.full(), x, y, d0, rx, ry, box_m)``, from the candidates only (the
        same entries in the same order; the whole list on a malformed entry, as there)."""
        index = self._index
        mask = index.candidates(self._i, x, y, d0, rx, ry, box_m)
        if mask < 0:
            return near_entries(self.full(), x, y, d0, rx, ry, box_m)
        try:  # (the candidates, in list order, walked without building their list)
            return _near_of(index.entries, mask, self._tail, x, y, d0, rx, ry, box_m)
        except Exception:  # a malformed entry: near_entries answers the whole list
            return self.full()

    def __len__(self) -> int:
        return self._len

    def __bool__(self) -> bool:
        return self._len > 0

    def __iter__(self) -> Any:
        return iter(self.full())

    def __getitem__(self, k: Any) -> Any:
        return self.full()[k]
