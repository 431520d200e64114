"""Staged growth of any formation to N slots (paper Fig 2b): grow_staged / FormationSpec.grown."""

from __future__ import annotations

import math
import tomllib
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from coordinator.formation import (
    FormationSpec,
    first_stage_pattern,
    formation_spacing_m,
    grow_staged,
    resized_formation_table,
)

SCENARIOS = Path(__file__).resolve().parents[1] / "formation" / "scenarios"


def _scenario_formations() -> dict[str, dict[str, Any]]:
    out = {}
    for path in sorted(SCENARIOS.glob("*.toml")):
        out[path.stem] = tomllib.loads(path.read_text())["formation"]
    return out


FORMATIONS: dict[str, FormationSpec] = {
    **{f"scenario:{k}": FormationSpec.from_dict(v) for k, v in _scenario_formations().items()},
    "triangle": FormationSpec.triangle(),
    "triangle-wide": FormationSpec.triangle(b_m=0.5, phi=(math.pi / 4, 3 * math.pi / 4)),
    "chevron5": FormationSpec.chevron(5),
    "chevron7": FormationSpec.chevron(7),
    "lattice5": FormationSpec.lattice(5),
    "lattice10": FormationSpec.lattice(10, b_m=0.3),
    "explicit-column": FormationSpec.from_tree([(0, None, 0.0, 0.0), (4, 0, 0.35, math.pi / 2)]),
}


def _min_pairwise(d: np.ndarray) -> float:
    if len(d) < 2:
        return math.inf
    diff = d[:, None, :] - d[None, :, :]
    dist = np.hypot(diff[..., 0], diff[..., 1])
    np.fill_diagonal(dist, np.inf)
    return float(dist.min())


@pytest.mark.parametrize("name", sorted(FORMATIONS))
def test_grown_to_every_n_up_to_100_is_a_valid_staged_tree(name: str) -> None:
    base = FORMATIONS[name]
    spacing = formation_spacing_m(base)
    big = base.grown(100)
    assert len(big) == 100
    for n in range(1, 101):
        spec = grow_staged(base, n)
        assert len(spec) == n
        assert spec.slots[0].slot == 0 and spec.slots[0].role == "leader"
        assert spec.slots[0].parent is None
        seen: dict[int, int] = {spec.slots[0].slot: 0}
        for s in spec.slots[1:]:
            assert s.parent in seen, f"n={n}: slot {s.slot}'s parent {s.parent} is not earlier"
            assert s.stage == seen[s.parent] + 1
            seen[s.slot] = s.stage
        assert len(set(spec.slot_ids)) == n
        # no two slots closer than the formation's spacing (the spacing of the paper's
        # triangle is b, so this also checks >= 0.9 b)
        assert _min_pairwise(spec.body_offsets_m) >= 0.9 * spacing
        # existing slots unchanged: the base's slots (up to n), then a prefix of the n = 100 tree
        for s, t in zip(spec.slots, big.slots, strict=False):
            assert (s.slot, s.parent, s.b_m, s.phi_rad, s.stage) == (
                t.slot,
                t.parent,
                t.b_m,
                t.phi_rad,
                t.stage,
            )
        for s, t in zip(spec.slots, base.slots, strict=False):
            assert (s.slot, s.parent, s.b_m, s.phi_rad, s.stage) == (
                t.slot,
                t.parent,
                t.b_m,
                t.phi_rad,
                t.stage,
            )
        np.testing.assert_allclose(spec.body_offsets_m, big.body_offsets_m[:n], atol=1e-12)


@pytest.mark.parametrize("name", sorted(FORMATIONS))
def test_new_slots_use_the_first_stage_pattern_and_fill_stage_by_stage(name: str) -> None:
    base = FORMATIONS[name]
    pattern = set(first_stage_pattern(base))
    big = base.grown(80)
    stages = [s.stage for s in big.slots[len(base) :]]
    assert stages == sorted(stages)  # stage by stage, never back
    assert stages[0] >= max(1, base.n_stages - 1)  # at most completes the base's last stage
    for s in big.slots[len(base) :]:
        assert (s.b_m, s.phi_rad) in pattern
    # every slot's parent that has children is a sub-leader
    for s in big.slots[1:]:
        assert s.role == ("subleader" if big.children(s.slot) else "follower")


def test_grown_triangle_is_the_lattice_the_paper_fig_2b_tree_merged() -> None:
    """The triangle's pi/3, 2 pi/3 sub-trees overlap (the paper's trajectory 5 hangs off 2 or
    3): the naive tree puts 2^s slots on s + 1 points of stage s; growth merges them."""
    for n in range(1, 60):
        assert grow_staged(FormationSpec.triangle(), n) == FormationSpec.lattice(n)
    spec = FormationSpec.triangle(b_m=0.4).grown(10)
    per_stage = [sum(1 for s in spec.slots if s.stage == k) for k in range(spec.n_stages)]
    assert per_stage == [1, 2, 3, 4]
    # Fig 2b: the centre second-stage slot (5 in the paper's numbering) hangs off the left
    # sub-leader (slot 1) as its right follower, and the wings off their own side.
    s = spec.slots
    assert (s[3].parent, s[4].parent, s[5].parent) == (1, 1, 2)
    xy = spec.body_offsets_m
    assert xy[3] == pytest.approx([-2 * 0.4 * math.sqrt(3) / 2, 0.0])


def test_a_partial_last_stage_is_completed_before_a_new_one() -> None:
    spec = FormationSpec.lattice(5).grown(6)  # lattice(5) lacks the right wing of stage 2
    assert spec == FormationSpec.lattice(6)


def test_chevron_grows_behind_its_last_row_without_overlap() -> None:
    spec = FormationSpec.chevron(7, b_m=0.4).grown(12)
    assert [s.stage for s in spec.slots[7:]] == [3, 3, 3, 3, 3]
    ys = sorted(round(float(y) / 0.4, 6) for y in spec.body_offsets_m[7:, 1])
    assert ys == [-2.0, -1.0, 0.0, 1.0, 2.0]
    assert formation_spacing_m(spec) == pytest.approx(0.4)


def test_cutting_keeps_the_first_slots_and_rederives_roles() -> None:
    spec = FormationSpec.chevron(7).grown(2)
    assert [(s.slot, s.parent, s.role) for s in spec.slots] == [
        (0, None, "leader"),
        (1, 0, "follower"),
    ]


def test_growth_refuses_what_it_cannot_do() -> None:
    with pytest.raises(ValueError, match="no first stage"):
        FormationSpec.lattice(1).grown(2)
    assert FormationSpec.lattice(1).grown(1) == FormationSpec.lattice(1)
    for bad in (0, -3, 2.5, True, "4"):
        with pytest.raises(ValueError, match="n"):
            grow_staged(FormationSpec.triangle(), bad)  # type: ignore[arg-type]


def test_resized_formation_table_for_every_scenario() -> None:
    for name, table in _scenario_formations().items():
        for n in (1, 3, 5, 40):
            out = resized_formation_table(table, n)
            spec = FormationSpec.from_dict(out)
            assert len(spec) == n, name
            if table["kind"] in ("chevron", "lattice"):
                assert out["kind"] == table["kind"] and out["n"] == n
            else:
                assert out["kind"] == "explicit"
                assert spec == FormationSpec.from_dict(table).grown(n)
    with pytest.raises(ValueError):
        resized_formation_table({"kind": "triangle"}, 0)
