"""Staged growth of any formation to N slots (paper Fig 2b): grow_staged / FormationSpec.grown."""

from __future__ import annotations

import math
import tomllib
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from coordinator.core.formation import (
    FormationSpec,
    SlotSpec,
    first_stage_pattern,
    formation_spacing_m,
    grow_staged,
    resized_formation_table,
)

SCENARIOS = Path(__file__).resolve().parents[3] / "scenario" / "builtin"


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


def test_builtin_spacing_is_b() -> None:
    """For the built-in kinds the growth spacing is b, so ">= spacing" is ">= b"."""
    for spec, b in (
        (FormationSpec.triangle(b_m=0.4), 0.4),
        (FormationSpec.chevron(7, b_m=0.35), 0.35),
        (FormationSpec.lattice(6, b_m=0.5), 0.5),
    ):
        assert formation_spacing_m(spec) == pytest.approx(b)
        assert formation_spacing_m(spec.grown(60)) >= 0.9 * b


_angle = st.floats(0.15, math.pi - 0.15)  # behind the parent (phi in (0, pi))
_b = st.floats(0.2, 1.0)


@settings(max_examples=60, deadline=None)
@given(
    first=st.lists(st.tuples(_b, _angle), min_size=1, max_size=3),
    n=st.integers(1, 60),
)
def test_any_first_stage_pattern_grows_or_refuses_cleanly(
    first: list[tuple[float, float]], n: int
) -> None:
    rows: list[tuple[int, int | None, float, float]] = [(0, None, 0.0, 0.0)]
    rows += [(i + 1, 0, b, phi) for i, (b, phi) in enumerate(first)]
    base = FormationSpec.from_tree(rows)
    spacing = formation_spacing_m(base)
    if spacing < 1e-9:  # coincident first-stage slots: growth refuses with a reason
        with pytest.raises(ValueError, match="coincide"):
            grow_staged(base, len(base) + 1)
        return
    spec = grow_staged(base, n)
    assert len(spec) == n
    assert _min_pairwise(spec.body_offsets_m) >= spacing * (1 - 1e-6)

    def key(s: SlotSpec) -> tuple[int, int | None, float, float, int]:
        return (s.slot, s.parent, s.b_m, s.phi_rad, s.stage)

    assert [key(s) for s in spec.slots[: len(base)]] == [key(s) for s in base.slots[:n]]
    big = grow_staged(base, n + 5)
    assert [s.slot for s in big.slots[:n]] == [s.slot for s in spec.slots]


def test_grown_paper_triangle_flies_in_the_simulator() -> None:
    """paper-sim's triangle grown to 10 slots, 10 robots started on their slots: the closed
    loop holds it (no collision, every robot keeps its first slot)."""
    import scenario
    from coordinator.core.formation import slot_states
    from coordinator.core.trajectory import make_trajectory
    from formation.outputs import metrics
    from formation.sim import simulate

    data = tomllib.loads((SCENARIOS / "paper-sim.toml").read_text())
    data["formation"] = resized_formation_table(data["formation"], 10)
    traj = dict(data["trajectory"])
    leader = make_trajectory(str(traj.pop("kind")), traj).sample(0.0)
    spec = FormationSpec.from_dict(data["formation"])
    l_m = 0.05
    data["robots"] = {
        "ids": [f"r{i + 1}" for i in range(10)],
        "initial": [
            [s.x - l_m * math.cos(s.theta), s.y - l_m * math.sin(s.theta), s.theta]
            for s in slot_states(spec, leader)
        ],
    }
    scn = scenario.parse(data)
    res = simulate.run(scn, duration_s=6.0)
    run = metrics.compute(res.log, 3.0, scn.settle_tol_m)["run"]
    assert run["collisions"] == 0 and run["min_separation_m"] > 0.3
    assert run["role_change_count"] == 0
    assert [a["slot"] for a in run["initial_assignments"]] == list(range(10))
