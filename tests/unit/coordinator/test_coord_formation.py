"""Formation geometry: staged slot trees, eqs 3-5 (corrected) and the feed-forward velocity."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from coordinator.core.formation import (
    FormationSpec,
    SlotSpec,
    SlotState,
    slot_arrays,
    slot_states,
)
from coordinator.core.trajectory import Circle, FigureEight, LeaderState, Trajectory, Waypoints

B = 0.4


def _xy(states: list[SlotState]) -> np.ndarray:
    return np.array([(s.x, s.y) for s in states])


def _min_separation(xy: np.ndarray) -> float:
    d = np.hypot(*(xy[:, None, :] - xy[None, :, :]).transpose(2, 0, 1))
    np.fill_diagonal(d, np.inf)
    return float(d.min()) if len(xy) > 1 else math.inf


def test_triangle_matches_paper_fig_2a() -> None:
    """theta = 0: phi = pi/3 behind-left, 2 pi/3 behind-right, equilateral of side b."""
    spec = FormationSpec.triangle(b_m=B)
    states = slot_states(spec, LeaderState(0.0, 1.0, 2.0, 0.0, 0.1, 0.0))
    assert [s.slot for s in states] == [0, 1, 2]
    assert [(s.role, s.stage, s.parent) for s in states] == [
        ("leader", 0, None),
        ("follower", 1, 0),
        ("follower", 1, 0),
    ]
    h = B * math.sqrt(3) / 2
    assert (states[1].x, states[1].y) == pytest.approx((1.0 - h, 2.0 + B / 2))
    assert (states[2].x, states[2].y) == pytest.approx((1.0 - h, 2.0 - B / 2))
    xy = _xy(states)
    assert _min_separation(xy) == pytest.approx(B)
    assert np.hypot(*(xy[0] - xy[2])) == pytest.approx(B)


@pytest.mark.parametrize("theta", [0.3, 1.9, -2.5, math.pi])
def test_triangle_turns_with_the_leader(theta: float) -> None:
    """The followers stay behind the leader and the same side of its heading, whatever theta."""
    leader = LeaderState(0.0, -0.5, 0.7, theta, 0.1, 0.0)
    states = slot_states(FormationSpec.triangle(), leader)
    hx, hy = math.cos(theta), math.sin(theta)
    for s, side in ((states[1], 1.0), (states[2], -1.0)):
        dx, dy = s.x - leader.x, s.y - leader.y
        assert dx * hx + dy * hy == pytest.approx(-B * math.sqrt(3) / 2)  # behind
        assert hx * dy - hy * dx == pytest.approx(side * B / 2)  # left (+) / right (-)
        assert s.theta == pytest.approx(leader.theta)


def test_eqs_3_to_5_applied_recursively_from_the_sub_leader() -> None:
    spec = FormationSpec.from_tree(
        [(0, None, 0.0, 0.0), (1, 0, 0.5, 1.0), (2, 1, 0.3, 2.2), (3, 2, 0.7, 0.4)]
    )
    leader = LeaderState(3.0, 0.2, -0.4, 0.8, 0.12, 0.05)
    states = {s.slot: s for s in slot_states(spec, leader)}
    for sid, b, phi in ((1, 0.5, 1.0), (2, 0.3, 2.2), (3, 0.7, 0.4)):
        p = states[spec[sid].parent]  # type: ignore[index]
        gamma = phi + leader.theta - math.pi / 2  # eq 3
        assert states[sid].x == pytest.approx(p.x - b * math.cos(gamma))  # eq 4
        assert states[sid].y == pytest.approx(p.y - b * math.sin(gamma))  # eq 5
        assert states[sid].vx == pytest.approx(p.vx + b * leader.omega_radps * math.sin(gamma))
        assert states[sid].vy == pytest.approx(p.vy - b * leader.omega_radps * math.cos(gamma))
    assert [states[k].role for k in range(4)] == ["leader", "subleader", "subleader", "follower"]
    assert [states[k].stage for k in range(4)] == [0, 1, 2, 3]
    assert (states[0].vx, states[0].vy) == pytest.approx(
        (0.12 * math.cos(0.8), 0.12 * math.sin(0.8))
    )


def test_chevron_of_seven_is_two_stages_with_two_children_per_sub_leader() -> None:
    spec = FormationSpec.chevron(7, b_m=B)
    assert [s.stage for s in spec] == [0, 1, 1, 2, 2, 2, 2]
    assert [s.role for s in spec] == ["leader"] + ["subleader"] * 2 + ["follower"] * 4
    assert sorted(spec.children(1) + spec.children(2)) == [3, 4, 5, 6]
    assert len(spec.children(1)) == len(spec.children(2)) == 2
    assert spec.children(0) == (1, 2)
    xy = _xy(slot_states(spec, LeaderState(0.0, 0.0, 0.0, 0.0, 0.1, 0.0)))
    # Stage 1 is the paper's triangle; slot 1's children on the left, slot 2's on the right.
    assert xy[1] == pytest.approx((-B * math.sqrt(3) / 2, B / 2))
    assert all(xy[c, 1] > 0 for c in spec.children(1))
    assert all(xy[c, 1] < 0 for c in spec.children(2))
    assert all(xy[c, 0] < xy[1, 0] - 0.9 * B for c in (3, 4, 5, 6))
    assert _min_separation(xy) >= 0.9 * B


@pytest.mark.parametrize("builder", ["chevron", "lattice"])
@pytest.mark.parametrize("n", [*range(1, 40), 100, 250])
def test_builders_give_valid_well_separated_trees(builder: str, n: int) -> None:
    spec: FormationSpec = getattr(FormationSpec, builder)(n, b_m=B)
    assert len(spec) == n
    assert spec.slot_ids == tuple(range(n))
    stages = [s.stage for s in spec]
    assert stages == sorted(stages)  # stage by stage
    assert set(stages) == set(range(spec.n_stages))
    for s in spec:
        kids = spec.children(s.slot)
        expected = "leader" if s.slot == 0 else ("subleader" if kids else "follower")
        assert s.role == expected
    xy, _ = slot_arrays(spec, LeaderState(0.0, 0.0, 0.0, 0.4, 0.1, 0.0))
    assert _min_separation(xy) >= 0.9 * B
    # The formation trails the leader: nobody ahead of it.
    heading = np.array([math.cos(0.4), math.sin(0.4)])
    assert np.all(xy[1:] @ heading < 0.0)


def test_lattice_rows_have_stage_plus_one_slots() -> None:
    spec = FormationSpec.lattice(13, b_m=B)  # 1 + 2 + 3 + 4 + 3 (partial)
    counts = np.bincount([s.stage for s in spec])
    assert counts.tolist() == [1, 2, 3, 4, 3]
    xy, _ = slot_arrays(spec, LeaderState(0.0, 0.0, 0.0, 0.0, 0.0, 0.0))
    for s in spec:
        assert xy[s.slot, 0] == pytest.approx(-s.stage * B * math.sqrt(3) / 2)
    # The partial last stage is centred (filled centre out).
    last = [s.slot for s in spec if s.stage == 4]
    assert abs(float(np.sum(xy[last, 1]))) <= B / 2 + 1e-12
    # Each slot's nearest neighbours in the lattice are exactly b apart.
    assert _min_separation(xy) == pytest.approx(B)


def test_small_builders_reduce_to_the_triangle() -> None:
    assert FormationSpec.chevron(3, b_m=0.5) == FormationSpec.triangle(b_m=0.5)
    assert FormationSpec.lattice(3, b_m=0.5) == FormationSpec.triangle(b_m=0.5)
    one = FormationSpec.chevron(1)
    assert len(one) == 1 and one[0].role == "leader"


def test_priority_order_leader_then_stage_then_slot() -> None:
    spec = FormationSpec(
        [
            SlotSpec(0, None, 0.0, 0.0, 0, "leader"),
            SlotSpec(5, 0, 0.4, 1.0, 1, "subleader"),
            SlotSpec(2, 5, 0.4, 1.0, 2, "follower"),
            SlotSpec(3, 0, 0.4, 2.0, 1, "follower"),
        ]
    )
    assert spec.priority_order() == [0, 3, 5, 2]
    assert FormationSpec.chevron(7).priority_order() == list(range(7))


def _leaf(slot: int, parent: int | None, stage: int, role: str, b: float = 0.4) -> SlotSpec:
    return SlotSpec(slot, parent, b, 1.0, stage, role)


ROOT = SlotSpec(0, None, 0.0, 0.0, 0, "leader")


@pytest.mark.parametrize(
    ("slots", "match"),
    [
        ([], "at least the leader"),
        ([_leaf(1, 0, 1, "follower")], "first slot must be the leader slot 0"),
        ([SlotSpec(0, None, 0.4, 0.0, 0, "leader")], "b_m 0"),
        ([ROOT, _leaf(1, 0, 1, "follower"), _leaf(1, 0, 1, "follower")], "duplicate slot id 1"),
        ([ROOT, _leaf(1, 2, 1, "follower")], "parent 2, which is defined nowhere"),
        (
            [ROOT, _leaf(1, 2, 2, "subleader"), _leaf(2, 1, 2, "subleader")],
            "defined later; parents must come before",
        ),
        ([ROOT, _leaf(1, 1, 1, "follower")], "its own parent"),
        ([ROOT, _leaf(1, None, 1, "follower")], "only slot 0 may be the root"),
        ([ROOT, _leaf(1, 0, 1, "follower", b=0.0)], "needs b_m > 0"),
        ([ROOT, _leaf(1, 0, 2, "follower")], "expected 1"),
        ([ROOT, _leaf(1, 0, 1, "subleader")], "must have role 'follower'"),
        (
            [ROOT, _leaf(1, 0, 1, "follower"), _leaf(2, 1, 2, "follower")],
            "slot 1 must have role 'subleader'",
        ),
        (["not a slot"], "must be SlotSpec"),
    ],
)
def test_spec_validation(slots: list[Any], match: str) -> None:
    with pytest.raises(ValueError, match=match):
        FormationSpec(slots)


@pytest.mark.parametrize(
    ("make", "match"),
    [
        (lambda: SlotSpec(-1, None, 0.0, 0.0, 0, "leader"), "slot must be an int >= 0"),
        (lambda: SlotSpec(1, 0, 0.4, 0.0, 1, "boss"), "role must be one of"),
        (lambda: SlotSpec(1, 0, math.nan, 0.0, 1, "follower"), "b_m must be finite"),
        (lambda: SlotSpec(1, "0", 0.4, 0.0, 1, "follower"), "parent must be None or an int"),  # type: ignore[arg-type]
        (lambda: FormationSpec.chevron(0), "n .* must be an int >= 1"),
        (lambda: FormationSpec.lattice(2.5), "n .* must be an int >= 1"),  # type: ignore[arg-type]
        (lambda: FormationSpec.triangle(b_m=-0.4), "needs b_m > 0"),
        (lambda: FormationSpec.triangle(phi=(1.0,)), "phi must be a pair"),  # type: ignore[arg-type]
    ],
)
def test_slot_and_builder_validation(make: Any, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        make()


def test_from_dict_builders_and_explicit_round_trip() -> None:
    assert FormationSpec.from_dict({"kind": "triangle"}) == FormationSpec.triangle()
    assert FormationSpec.from_dict(
        {"kind": "triangle", "b_m": 0.5, "phi": [1.0, 2.0]}
    ) == FormationSpec.triangle(0.5, (1.0, 2.0))
    assert FormationSpec.from_dict(
        {"kind": "chevron", "params": {"n": 7, "b_m": 0.3}}
    ) == FormationSpec.chevron(7, 0.3)
    assert FormationSpec.from_dict({"kind": "lattice", "n": 12}) == FormationSpec.lattice(12)
    spec = FormationSpec.chevron(9)
    assert FormationSpec.from_dict(spec.to_dict()) == spec
    explicit = {
        "slots": [
            {"slot": 0},
            {"slot": 1, "parent": 0, "b_m": 0.4, "phi_rad": math.pi / 2},
            {"slot": 2, "parent": 1, "b_m": 0.4, "phi_rad": math.pi / 2, "role": "follower"},
        ]
    }
    col = FormationSpec.from_dict(explicit)
    assert [s.role for s in col] == ["leader", "subleader", "follower"]
    assert [s.stage for s in col] == [0, 1, 2]


@pytest.mark.parametrize(
    ("d", "match"),
    [
        ({}, "missing 'kind'"),
        ({"kind": "hexagon"}, "unknown kind 'hexagon'"),
        ({"kind": "chevron"}, "missing required parameter n"),
        ({"kind": "chevron", "n": 5, "spacing": 1}, r"unknown parameter\(s\) spacing"),
        ({"kind": "lattice", "params": {"n": 3}, "n": 4}, "unexpected key"),
        ({"kind": "triangle", "phi": 1.0}, "phi must be a pair"),
        ({"kind": "triangle", "phi": [1.0, "x"]}, r"phi\[1\] must be a number"),
        ({"kind": "explicit", "slots": []}, "non-empty list"),
        ({"slots": [{"slot": 0}, {"slot": 1, "parent": 0, "b_m": 0.4}]}, "missing 'phi_rad'"),
        ({"slots": [{"slot": 0}, {"parent": 0}]}, r"slots\[1\] is missing 'slot'"),
        ({"slots": [{"slot": 0, "colour": "red"}]}, "unknown key.*colour"),
        (
            {
                "slots": [
                    {"slot": 0},
                    {"slot": 1, "parent": 0, "b_m": 0.4, "phi_rad": 1, "stage": 2},
                ]
            },
            "slot 1 has stage 2 but the tree gives 1",
        ),
        ({"slots": [{"slot": 0}, {"slot": 1, "parent": 3, "b_m": 0.4, "phi_rad": 1}]}, "parent 3"),
        ("triangle", "expected a table"),
    ],
)
def test_from_dict_errors(d: Any, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        FormationSpec.from_dict(d)


@pytest.mark.parametrize(
    "traj",
    [
        Circle(0.5, -0.3, 1.2, 0.15, start_angle_rad=0.4),
        Circle(0.0, 0.0, 0.6, 0.1, ccw=False),
        FigureEight(0.0, 0.0, 1.5, 60.0, rotation_rad=0.7),
        Waypoints([(0, 0), (2, 0), (2, 2), (0, 2)], 0.1, 0.4, loop=True),
    ],
    ids=["circle-ccw", "circle-cw", "figure8", "waypoints"],
)
def test_feed_forward_equals_numerical_derivative_of_slot_positions(traj: Trajectory) -> None:
    spec = FormationSpec.chevron(7, b_m=B)
    h = 1e-4
    knots = np.array(getattr(traj, "knot_times_s", ()))
    for t in np.linspace(5.0, 70.0, 37):
        if knots.size and np.min(np.abs(knots - t)) < 3 * h:
            continue
        before = slot_states(spec, traj.sample(t - h))
        after = slot_states(spec, traj.sample(t + h))
        now = slot_states(spec, traj.sample(t))
        for a, b, s in zip(before, after, now, strict=True):
            assert (b.x - a.x) / (2 * h) == pytest.approx(s.vx, abs=1e-6)
            assert (b.y - a.y) / (2 * h) == pytest.approx(s.vy, abs=1e-6)


@settings(max_examples=200, deadline=None)
@given(
    x=st.floats(-50, 50),
    y=st.floats(-50, 50),
    theta=st.floats(-math.pi, math.pi),
    v=st.floats(-0.5, 0.5),
    omega=st.floats(-2.0, 2.0),
    n=st.integers(1, 40),
    kind=st.sampled_from(["chevron", "lattice"]),
)
def test_vectorised_path_matches_recursive_equations(
    x: float, y: float, theta: float, v: float, omega: float, n: int, kind: str
) -> None:
    spec: FormationSpec = getattr(FormationSpec, kind)(n, b_m=0.35)
    leader = LeaderState(1.0, x, y, theta, v, omega)
    states = slot_states(spec, leader)
    xy, vxy = slot_arrays(spec, leader)
    np.testing.assert_allclose(xy, _xy(states), atol=1e-9)
    np.testing.assert_allclose(vxy, [(s.vx, s.vy) for s in states], atol=1e-9)
    # Rigid formation: same heading everywhere, shape independent of the leader pose.
    assert all(s.theta == states[0].theta for s in states)
    ref, _ = slot_arrays(spec, LeaderState(0.0, 0.0, 0.0, 0.0, 0.0, 0.0))
    d_now = np.hypot(*(xy[:, None] - xy[None]).transpose(2, 0, 1))
    d_ref = np.hypot(*(ref[:, None] - ref[None]).transpose(2, 0, 1))
    np.testing.assert_allclose(d_now, d_ref, atol=1e-9)


def test_thousand_slots() -> None:
    spec = FormationSpec.lattice(1000, b_m=B)
    leader = LeaderState(0.0, 2.0, 1.0, 0.3, 0.1, 0.02)
    states = slot_states(spec, leader)
    xy, vxy = slot_arrays(spec, leader)
    assert len(states) == 1000 and xy.shape == vxy.shape == (1000, 2)
    np.testing.assert_allclose(xy, _xy(states), atol=1e-9)
    assert spec.n_stages == 45  # 1 + 2 + ... + 44 = 990 slots in full rows, then 10 more
    assert _min_separation(xy) == pytest.approx(B)
