"""``formation up --camera rendered``: the real tracker (``formation camera --source rendered``)
in the closed loop in place of the plant's camera emulation (the plant runs ``--no-poses``):
paper-exp1 converges with no collision on poses measured from rendered images, in an
authenticated run (``--secure``: the generated ACL lets the localization identity read truth)."""

from __future__ import annotations

from pathlib import Path

import pytest
from support.spawn import Spawner
from support.up_runs import finish, up

pytest.importorskip("cv2")


@pytest.mark.zenoh
@pytest.mark.slow
def test_paper_exp1_converges_with_the_rendered_camera(spawn: Spawner, tmp_path: Path) -> None:
    import numpy as np

    from formation.outputs import metrics
    from formation.outputs.runlog import RunLog

    out = tmp_path / "exp1-camera"
    m = finish(
        up(
            spawn, out, "--scenario", "paper-exp1", "--duration", "11", "--camera", "rendered",
            "--secure",  # the ACL must let the tracker read the truth it renders
        ),
        out,
    )  # fmt: skip
    children = m["meta"]["children"]
    assert children["camera"]["returncode"] == 0 and not children["camera"]["killed"]
    assert (out / "camera.toml").exists()
    assert m["meta"]["mode"] == "realtime"
    assert m["run"]["collisions"] == 0
    assert m["run"]["final_leader"] == "r1"
    z = np.load(out / "run.npz")
    arrays = ("t_s", "truth", "ref", "target", "slot_of", "slot_xy", "leader", "power", "mode")
    log = RunLog(
        robot_ids=[str(r) for r in z["robot_ids"]],
        slot_ids=[int(s) for s in z["slot_ids"]],
        **{k: z[k] for k in arrays},
    )
    err = metrics.formation_error(log)
    t = log.t_s
    early = np.nanmean(err[(t >= 1.0) & (t <= 3.0)], axis=0)
    late = np.nanmean(err[t >= t[-1] - 2.0], axis=0)
    # 11 s, not 15 s (as test_up.py's realtime exp1): at 11 s the late errors were 5.1-5.3,
    # 9.3-9.5 and 8.2-8.4 mm against early ones of 33-35, 63-65 and 55-57 mm (three runs, load ~5)
    assert np.all(late < 0.5 * early), (early, late)
    assert np.all(late < 0.03), late


def test_rendered_camera_needs_realtime(spawn: Spawner, tmp_path: Path) -> None:
    child = up(spawn, tmp_path / "x", "--lockstep", "--camera", "rendered")
    child.proc.wait(timeout=30)
    assert child.proc.returncode == 2
    assert "realtime only" in child.stderr()
