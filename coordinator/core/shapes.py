"""The shapes of a formation as slot trees: the chevron and lattice builders and the paper's
staged growth (Fig 2b), each a list of rows ``(slot, parent, b_m, phi_rad)`` (slot 0 the
leader, parent None) that :meth:`coordinator.core.formation.FormationSpec.from_tree` turns into a
formation. Geometry of a row: paper eqs 3-5 (coordinator/core/formation.py). Inputs are checked by
the callers (FormationSpec's builders, ``grow_staged``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any, Final

import numpy as np
import numpy.typing as npt

from coordinator.core.slots import LEADER_SLOT

__all__ = ["GROW_TOL", "Row", "chevron_rows", "grow_rows", "lattice_rows"]

Row = tuple[int, int | None, float, float]
"""One slot of a tree: ``(slot, parent, b_m, phi_rad)``."""
GROW_TOL: Final = 1e-6
"""Relative tolerance on the spacing when growing (float noise of summed offsets)."""


def chevron_rows(n: int, b: float) -> list[Row]:
    """The rows of ``FormationSpec.chevron(n, b)`` (see its docstring for the shape)."""
    rows: list[Row] = [(0, None, 0.0, 0.0)]
    ids: dict[tuple[int, int, int], int] = {}  # (stage, side +1 left / -1 right, k) -> slot
    stage = 1
    while len(rows) < n:
        for k in range(1, stage + 1):
            for side in (1, -1):
                if len(rows) >= n:
                    break
                slot = len(rows)
                if stage == 1:
                    parent, bb = LEADER_SLOT, b
                    phi = math.pi / 3.0 if side > 0 else 2.0 * math.pi / 3.0
                elif k < stage:
                    parent, bb, phi = ids[(stage - 1, side, k)], b, math.pi / 2.0
                else:
                    parent, bb = ids[(stage - 1, side, k - 1)], math.sqrt(2.0) * b
                    phi = math.pi / 4.0 if side > 0 else 3.0 * math.pi / 4.0
                ids[(stage, side, k)] = slot
                rows.append((slot, parent, bb, phi))
        stage += 1
    return rows


def lattice_rows(n: int, b: float) -> list[Row]:
    """The rows of ``FormationSpec.lattice(n, b)`` (see its docstring for the shape)."""
    rows: list[Row] = [(0, None, 0.0, 0.0)]
    ids: dict[tuple[int, int], int] = {(0, 0): LEADER_SLOT}  # (stage, 2 y / b) -> slot
    stage = 1
    while len(rows) < n:
        # 2 y / b for the s + 1 slots of the row, ordered centre out, left (+y) first.
        keys = sorted(range(-stage, stage + 1, 2), key=lambda q: (abs(q), -q))
        for q in keys:
            if len(rows) >= n:
                break
            slot = len(rows)
            if q > 0:  # left half: behind-left of the neighbour ahead on the centre side
                parent, phi = ids[(stage - 1, q - 1)], math.pi / 3.0
            else:  # right half and centre: behind-right of the neighbour ahead on its left
                parent, phi = ids[(stage - 1, q + 1)], 2.0 * math.pi / 3.0
            ids[(stage, q)] = slot
            rows.append((slot, parent, b, phi))
        stage += 1
    return rows


def grow_rows(
    rows: Sequence[Row],
    stages: Sequence[int],
    offsets: npt.NDArray[np.float64],
    pattern: Sequence[tuple[float, float]],
    n: int,
    spacing: float,
    owner: str,
) -> list[Row]:
    """``rows`` (with their ``stages`` and body-frame ``offsets``) grown to ``n`` rows by
    repeating the first-stage ``pattern`` of ``(b_m, phi_rad)`` (the rule of
    ``coordinator.core.formation.grow_staged``, which documents it); new slots keep no closer than
    ``spacing`` (m) to any other. Raises ValueError (naming ``owner``) if the pattern cannot
    place another slot."""
    min_d = spacing * (1.0 - GROW_TOL)
    merge_d = spacing * GROW_TOL
    q = spacing * GROW_TOL  # quantum for ordering keys (float noise must not reorder)
    rows = list(rows)
    pts: list[tuple[float, float]] = [(float(x), float(y)) for x, y in offsets]
    stage_of: dict[int, int] = {r[0]: st for r, st in zip(rows, stages, strict=True)}
    off_of: dict[int, tuple[float, float]] = {r[0]: pts[i] for i, r in enumerate(rows)}
    last_spec_stage = max(stages)
    next_id = max(stage_of) + 1
    placed = np.array(pts, dtype=np.float64)
    stage = 1
    while len(rows) < n:
        parents = [r[0] for r in rows if stage_of[r[0]] == stage - 1]
        # candidates: [x, y, parent, b, phi, (parent |y|, -parent y, generation index)]
        cands: list[list[Any]] = []
        gen = 0
        for p in parents:
            px, py = off_of[p]
            for b, phi in pattern:
                x, y = px - b * math.sin(phi), py + b * math.cos(phi)
                pref = (round(abs(py) / q), -round(py / q), gen)
                for c in cands:
                    if math.hypot(c[0] - x, c[1] - y) <= merge_d:
                        if pref < c[5]:  # a parent nearer the centre line takes the shared slot
                            c[2:6] = [p, b, phi, pref]
                        break
                else:
                    cands.append([x, y, p, b, phi, pref])
                gen += 1

        added = 0
        # centre out, left (+y) before right, front to back, then generation order
        cands.sort(key=lambda c: (round(abs(c[1]) / q), -round(c[1] / q), -round(c[0] / q), c[5]))
        for c in cands:
            if len(rows) >= n:
                break
            x, y = c[0], c[1]
            if float(np.min(np.hypot(placed[:, 0] - x, placed[:, 1] - y))) < min_d:
                continue
            rows.append((next_id, c[2], c[3], c[4]))
            stage_of[next_id] = stage
            off_of[next_id] = (x, y)
            placed = np.vstack([placed, [[x, y]]])
            next_id += 1
            added += 1
        if added == 0 and stage > last_spec_stage:
            raise ValueError(
                f"{owner}: the first-stage pattern cannot place slot {len(rows)} at stage {stage} "
                f"without coming closer than {spacing:.3g} m to another slot"
            )
        stage += 1
    return rows
