"""The 3D scene (``formation.live.scene.SceneModel``, live Foxglove and a recording's ``/scene``)
from batched frames: a lockstep run and agent hosts read truth and poses as batches (a lockstep
plant puts each robot's own keys only while someone subscribes to them), and the robots must be
drawn from the batches as from the per-robot keys."""

from __future__ import annotations

from bus_schemas import Pose, PoseBatch, Truth, TruthBatch, keys
from formation.live.scene import SceneModel

FLEET = "demo"


Rows = dict[str, tuple[float, float, float]]


def _frame(
    cls: type[PoseBatch] | type[TruthBatch], stamp: float, rows: Rows
) -> PoseBatch | TruthBatch:
    """A batch of ``cls`` (the two share their fields) of ``rows`` at ``stamp``."""
    return cls(
        t=stamp, seq=1, robots=tuple(rows), x=tuple(r[0] for r in rows.values()),
        y=tuple(r[1] for r in rows.values()), theta=tuple(r[2] for r in rows.values()),
        stamp=stamp,
    )  # fmt: skip


def test_batched_frames_place_the_robots_as_their_per_robot_keys_do() -> None:
    batched, keyed = SceneModel(), SceneModel()
    rows = {"r1": (0.5, -0.25, 0.1), "r2": (1.0, 0.75, -0.3)}
    batched.update(keys.truths_key(FLEET), _frame(TruthBatch, 0.02, rows))
    for rid, (x, y, th) in rows.items():
        keyed.update(keys.truth_key(FLEET, rid), Truth(t=0.02, seq=1, x=x, y=y, theta=th))
    got = {rid: r.xytheta for rid, r in batched.robots.items()}
    assert got == {rid: r.xytheta for rid, r in keyed.robots.items()} == rows
    assert batched.ref_point("r1") == keyed.ref_point("r1") is not None

    # a measured pose wins over truth from then on, batched or per robot
    seen = {"r1": (0.55, -0.2, 0.12), "r2": (1.05, 0.7, -0.28)}
    batched.update(keys.poses_key(FLEET), _frame(PoseBatch, 0.04, seen))
    for rid, (x, y, th) in seen.items():
        keyed.update(keys.pose_key(FLEET, rid), Pose(t=0.04, seq=1, x=x, y=y, theta=th))
    batched.update(keys.truths_key(FLEET), _frame(TruthBatch, 0.06, rows))
    for rid, (x, y, th) in rows.items():
        keyed.update(keys.truth_key(FLEET, rid), Truth(t=0.06, seq=2, x=x, y=y, theta=th))
    assert {rid: r.xytheta for rid, r in batched.robots.items()} == seen
    assert {rid: r.xytheta for rid, r in keyed.robots.items()} == seen
    assert all(r.from_pose for r in batched.robots.values())
