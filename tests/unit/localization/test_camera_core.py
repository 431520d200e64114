"""Localization cores on rendered frames (no Zenoh): corner conventions of both detectors, floor
poses against truth, tag offsets, the calibration file, the tracker's rejections and misses,
unknown and duplicated tags, occlusion, the paper's colour patches, calibration fitting."""

from __future__ import annotations

import math

import numpy as np
import pytest

pytest.importorskip("cv2")

from localization.core import calibration as calmod
from localization.core.calibration import Calibration, CalibrationError, TagOffset, TrackerParams
from localization.core.detectors import ArucoTagDetector, make_detector, pupil_available
from localization.core.pipeline import CameraPipeline
from localization.core.pose import Measurement, PoseEstimator, true_corner_pixels
from localization.core.tracker import Tracker
from localization.node.calibrate import FloorMarker, fit_homography, marker_points
from robot_agent.core.kinematics import wrap_angle
from sim_plant.core.render import CameraPose, Occluder, Renderer, moving_scene

CAM = CameraPose(tilt_deg=8.0)
DETECTORS = ["aruco"] + (["apriltag"] if pupil_available() else [])


def _cal(renderer: Renderer, n: int, **kw: object) -> Calibration:
    return Calibration(
        homography=renderer.h_image_to_floor.tolist(),
        tags={f"r{i + 1}": i for i in range(n)},
        tag_size_m=renderer.tag_size_m,
        **kw,  # type: ignore[arg-type]
    )


def _errors(ms: list[Measurement], truth: np.ndarray) -> tuple[list[float], list[float]]:
    pos, head = [], []
    for m in ms:
        i = int(m.robot[1:]) - 1
        pos.append(math.hypot(m.x - truth[i, 0], m.y - truth[i, 1]) * 1e3)
        head.append(abs(wrap_angle(m.theta - truth[i, 2])) * 180.0 / math.pi)
    return pos, head


def test_auto_detector_says_which() -> None:
    det = make_detector("tag36h11", "auto")
    assert det.name.startswith("pupil-apriltags" if pupil_available() else "opencv-aruco")
    assert make_detector("tag36h11", "aruco").name.startswith("opencv-aruco")


@pytest.mark.parametrize("detector", DETECTORS)
def test_headings_all_quadrants_and_accuracy(detector: str) -> None:
    """Every heading, including +-pi: both detectors' corner orders map to the same pose."""
    r = Renderer(CAM)
    headings = np.linspace(-math.pi, math.pi, 8, endpoint=False) + 0.1
    truth = np.array([[-0.6 + 0.17 * i, 0.05 * (i % 2), th] for i, th in enumerate(headings)])
    truth = np.vstack([truth, [[0.0, -0.3, math.pi]]])
    pipe = CameraPipeline(_cal(r, len(truth)), detector)
    rng = np.random.default_rng(4)
    frame = r.render(truth, list(range(len(truth))), blur_sigma_px=0.8, noise_std=3.0, rng=rng)
    ms = pipe.measure(frame)
    assert [m.robot for m in ms] == sorted(f"r{i + 1}" for i in range(len(truth)))
    pos, head = _errors(ms, truth)
    assert np.median(pos) < 2.0 and max(pos) < 5.0, pos
    assert np.median(head) < 0.5 and max(head) < 1.5, head


def test_pose_from_exact_corners_and_offsets() -> None:
    """Corners projected exactly give the pose to 1e-9; offsets move tag -> axle centre."""
    h_f2i = CAM.floor_to_image()
    off = TagOffset(forward_m=0.02, left_m=-0.01, yaw_rad=math.pi / 2)
    cal = Calibration(homography=CAM.image_to_floor().tolist(), tags={"r1": 3}, offsets={"r1": off})
    est = PoseEstimator(cal)
    x, y, th = 0.31, -0.12, 2.9
    psi = th + off.yaw_rad
    tx = x + math.cos(th) * off.forward_m - math.sin(th) * off.left_m
    ty = y + math.sin(th) * off.forward_m + math.cos(th) * off.left_m
    from localization.core.detectors import TagDetection

    corners = true_corner_pixels(h_f2i, tx, ty, psi, 0.06)
    (m,) = est.from_tags([TagDetection(3, corners)])
    assert m.robot == "r1"
    assert math.isclose(m.x, x, abs_tol=1e-9) and math.isclose(m.y, y, abs_tol=1e-9)
    assert abs(wrap_angle(m.theta - th)) < 1e-9
    assert math.isclose(m.size_m, 0.06, rel_tol=1e-6)


def test_rendered_offsets_recovered() -> None:
    off = (0.015, 0.01, -0.3)
    r = Renderer(CAM, tag_offsets={0: off})
    cal = _cal(r, 1, offsets={"r1": TagOffset(*off)})
    truth = np.array([[0.1, 0.1, 1.0]])
    (m,) = CameraPipeline(cal, "aruco").measure(r.render(truth, [0]))
    pos, head = _errors([m], truth)
    assert pos[0] < 2.0 and head[0] < 0.5


def test_unknown_and_duplicated_tags_counted_not_published() -> None:
    r = Renderer(CAM)
    truth = np.array([[-0.4, 0.0, 0.0], [0.0, 0.0, 0.0], [0.4, 0.0, 0.0], [0.0, 0.3, 0.0]])
    cal = Calibration(homography=r.h_image_to_floor.tolist(), tags={"r1": 1, "r2": 2})
    pipe = CameraPipeline(cal, "aruco")
    # tag 1 twice (a forged / misprinted tag), tag 2 once, tag 9 unknown
    ms = pipe.measure(r.render(truth, [1, 2, 1, 9]))
    assert [m.robot for m in ms] == ["r2"]
    assert pipe.estimator.duplicates == 2
    assert pipe.estimator.unknown_tags == 1


def test_occluded_robot_is_missed_not_published() -> None:
    r = Renderer(CAM)
    truth = moving_scene(3, 0.0)
    pipe = CameraPipeline(_cal(r, 3), "aruco")
    x1, y1, th1 = truth[1]
    pix = true_corner_pixels(r.h_floor_to_image, x1, y1, th1, 0.06)
    u0, v0 = (pix.min(axis=0) - 15).astype(int)
    u1, v1 = (pix.max(axis=0) + 15).astype(int)
    frame = r.render(truth, [0, 1, 2], occluders=[Occluder(u0, v0, u1, v1)])
    res = pipe.process(frame, 1.0, lambda: 0.0)
    assert [m.robot for m in res.measurements] == ["r1", "r3"]
    st = pipe.tracker.stats()
    assert st["misses"] == {"r1": 0, "r2": 1, "r3": 0}


def test_lighting_change_blur_noise_still_tracked() -> None:
    r = Renderer(CAM)
    truth = moving_scene(6, 0.3)
    pipe = CameraPipeline(_cal(r, 6), "aruco")
    rng = np.random.default_rng(2)
    for gain, grad in ((0.55, 0.3), (1.3, -0.2)):
        frame = r.render(
            truth, list(range(6)), blur_sigma_px=1.2, noise_std=5.0, gain=gain, gradient=grad,
            rng=rng,
        )  # fmt: skip
        ms = pipe.measure(frame)
        assert len(ms) == 6
        pos, head = _errors(ms, truth)
        assert np.median(pos) < 2.0 and np.median(head) < 0.5


def test_tracker_jump_rejection_reacquire_and_staleness() -> None:
    p = TrackerParams(max_speed_mps=1.0, lost_after_s=0.5, reacquire_after=3, jump_slack_m=0.03)
    tr = Tracker(["r1", "r2"], p, tag_size_m=0.06)
    m = lambda x, t=0.0, s=0.06: Measurement("r1", x, 0.0, t, s)  # noqa: E731
    assert tr.update(0.0, [m(0.0)]) == [m(0.0)]
    assert tr.update(1 / 30, [m(0.01)]) == [m(0.01)]  # 0.3 m/s: plausible
    assert tr.update(2 / 30, [m(0.5)]) == []  # a 0.49 m jump in 33 ms: rejected
    assert tr.update(3 / 30, [m(0.02)]) == [m(0.02)]  # the flicker is over
    assert tr.update(4 / 30, [m(0.02, t=2.0)]) == []  # a 2 rad turn in 33 ms: rejected
    # picked up and put down 1 m away: consistent rejections, then the new place is accepted
    assert tr.update(5 / 30, [m(1.0)]) == []
    assert tr.update(6 / 30, [m(1.0)]) == []
    assert tr.update(7 / 30, [m(1.0)]) == [m(1.0)]
    # lost for longer than lost_after_s: the next measurement starts a new track anywhere
    assert tr.update(2.0, [m(-1.0)]) == [m(-1.0)]
    # a tag seen at the wrong scale (a tag lying elsewhere, a print at another size)
    assert tr.update(2.0 + 1 / 30, [m(-1.0, s=0.09)]) == []
    st = tr.stats()
    assert st["jumps"] == 4 and st["reacquired"] == 2 and st["bad_size"] == 1
    assert st["misses"] == {"r1": 0, "r2": 10}
    assert st["published"]["r1"] == 5


def test_patches_mode_identity_from_start_positions() -> None:
    r = Renderer(CAM, mode="patches")
    truth = moving_scene(4, 0.0)
    start = {f"r{i + 1}": (truth[i, 0] + 0.02, truth[i, 1] - 0.02) for i in range(4)}
    cal = Calibration(
        homography=r.h_image_to_floor.tolist(), tags={}, family="patches", start=start
    )
    pipe = CameraPipeline(cal)
    for k in range(3):
        t = k / 30.0
        truth = moving_scene(4, t)
        res = pipe.process(r.render(truth), t, lambda: 0.0)
        assert [m.robot for m in res.measurements] == ["r1", "r2", "r3", "r4"]
        pos, head = _errors(res.measurements, truth)
        assert max(pos) < 3.0 and max(head) < 1.0, (pos, head)


def test_calibration_file_round_trip_and_validation(tmp_path: object) -> None:
    cal = Calibration(
        homography=CAM.image_to_floor().tolist(),
        tags={"r1": 0, "r2": 7},
        tag_size_m=0.05,
        detector="aruco",
        camera_matrix=CAM.camera_matrix.tolist(),
        dist_coeffs=(0.01, -0.02, 0.0, 0.0, 0.001),
        offsets={"r2": TagOffset(0.01, 0.0, 0.1)},
        tracker=TrackerParams(max_speed_mps=0.5),
        reprojection_error_mm=0.7,
    )
    again = calmod.loads(calmod.dumps(cal))
    assert again == cal
    base = calmod.dumps(Calibration(homography=CAM.image_to_floor().tolist(), tags={"r1": 0}))
    bad = {
        "singular": base.replace("homography = [", "homography = [[0,0,0],[0,0,0],[0,0,1]]\nx=["),
        "dup tag": base.replace("r1 = 0", "r1 = 0\nr2 = 0"),
        "bad robot id": base.replace("r1 = 0", '"R 1" = 0'),
        "tag out of range": base.replace("r1 = 0", "r1 = 9999"),
        "unknown key": "bogus = 1\n" + base,
        "not toml": "homography = [",
        "no tags": base.replace("r1 = 0", ""),
        "nan": base.replace("tag_size_m = 0.06", "tag_size_m = nan"),
    }
    for what, text in bad.items():
        with pytest.raises(CalibrationError):
            calmod.loads(text)
            pytest.fail(what)


def test_fit_homography_from_rendered_floor_markers() -> None:
    """Markers at known floor places -> a homography within ~1 mm of the true one."""
    r = Renderer(CAM, tag_size_m=0.08, body_radius_m=0.06)
    places = [(-0.7, -0.3), (0.0, -0.33), (0.7, -0.3), (-0.7, 0.3), (0.0, 0.0), (0.7, 0.33)]
    markers = {100 + i: FloorMarker(100 + i, x, y, 0.0) for i, (x, y) in enumerate(places)}
    truth = np.array([[x, y, 0.0] for x, y in places])
    frame = r.render(truth, list(markers), blur_sigma_px=0.7, noise_std=2.0,
                     rng=np.random.default_rng(0))  # fmt: skip
    img, floor, found = marker_points(ArucoTagDetector().detect(frame), markers, 0.08)
    assert found == sorted(markers) and len(img) == 5 * len(markers)
    fit = fit_homography(img, floor)
    assert fit.rms_mm < 1.5
    # compare with the true homography over the whole view
    us, vs = np.meshgrid(np.linspace(100, 1180, 7), np.linspace(60, 660, 5))
    pix = np.column_stack([us.ravel(), vs.ravel(), np.ones(us.size)])
    a = pix @ fit.homography.T
    b = pix @ r.h_image_to_floor.T
    err = np.linalg.norm(a[:, :2] / a[:, 2:] - b[:, :2] / b[:, 2:], axis=1) * 1e3
    assert err.max() < 3.0, err
    with pytest.raises(ValueError):
        fit_homography(img[:3], floor[:3])


@pytest.mark.skipif(not pupil_available(), reason="windows wrap pupil-apriltags only")
def test_windows_find_what_the_full_frame_finds() -> None:
    """Window detection (pupil-apriltags): same poses as the full frame; a robot that leaves its
    window (teleported) is found in the same frame; a new tag shows up at the next full frame."""
    from localization.core.detectors import PupilTagDetector, RoiTagDetector

    r = Renderer(CAM)
    roi = RoiTagDetector(PupilTagDetector(), expected={0, 1, 2}, full_every=8)
    full = PupilTagDetector()
    truth = moving_scene(3, 0.0)
    ids = [0, 1, 2]
    for k in range(4):
        truth = moving_scene(3, k / 30.0)
        frame = r.render(truth, ids)
        a = sorted((d.tag_id, d.corners.round(3).tolist()) for d in roi.detect(frame))
        b = sorted((d.tag_id, d.corners.round(3).tolist()) for d in full.detect(frame))
        assert [x[0] for x in a] == [0, 1, 2]
        assert np.allclose([x[1] for x in a], [x[1] for x in b], atol=0.2)  # px; ~0.25 mm
    assert roi.window_frames == 3 and roi.full_frames == 1
    jumped = truth.copy()
    jumped[1, :2] = (0.5, 0.3)  # far outside its window
    found = {d.tag_id: d for d in roi.detect(r.render(jumped, ids))}
    assert set(found) == {0, 1, 2} and roi.full_frames == 2  # fell back in the same frame
    # an unknown tag appears: not looked for in windows, found at the next full frame (k = 8)
    extra = np.vstack([jumped, [[-0.5, -0.3, 0.0]]])
    seen = [{d.tag_id for d in roi.detect(r.render(extra, [*ids, 40]))} for _ in range(3)]
    assert seen == [{0, 1, 2}, {0, 1, 2}, {0, 1, 2, 40}]
    assert roi.full_frames == 3


def test_lens_distortion_is_undone_before_the_homography() -> None:
    """With ``camera_matrix`` and ``dist_coeffs``, distorted pixels map to the floor through the
    homography of undistorted pixels (floor points projected with OpenCV's lens model)."""
    import cv2

    rot, t = CAM.extrinsics()
    k = CAM.camera_matrix
    dist = np.array([-0.25, 0.08, 0.001, -0.0005, -0.01])
    floor = np.array([[x, y, 0.0] for x in np.linspace(-0.6, 0.6, 5) for y in (-0.3, 0.0, 0.3)])
    rvec, _ = cv2.Rodrigues(rot)
    pix, _ = cv2.projectPoints(floor, rvec, t, k, dist)
    pix = pix.reshape(-1, 2)
    cal = Calibration(
        homography=CAM.image_to_floor().tolist(),
        tags={"r1": 0},
        camera_matrix=k.tolist(),
        dist_coeffs=tuple(dist.tolist()),
    )
    got = PoseEstimator(cal).to_floor(pix)
    assert np.abs(got - floor[:, :2]).max() < 1e-4  # 0.1 mm
    # without the lens model the same pixels are centimetres off near the edges
    plain = PoseEstimator(Calibration(homography=CAM.image_to_floor().tolist(), tags={"r1": 0}))
    assert np.abs(plain.to_floor(pix) - floor[:, :2]).max() > 0.01


def test_tracker_never_publishes_an_unconfirmed_jump() -> None:
    """Property (hypothesis): whatever the measurements, a published pose is within the motion
    limits of the previous published one, unless the track was lost (lost_after_s) or the jump
    was confirmed by ``reacquire_after`` consistent measurements in a row."""
    from hypothesis import given, settings
    from hypothesis import strategies as st

    p = TrackerParams(max_speed_mps=1.0, lost_after_s=0.5, reacquire_after=3)
    step = st.tuples(
        st.floats(0.005, 0.6),  # dt
        st.booleans(),  # seen
        st.floats(-2.0, 2.0),
        st.floats(-2.0, 2.0),
        st.floats(-math.pi, math.pi),
    )

    @settings(max_examples=200, deadline=None)
    @given(st.lists(step, min_size=1, max_size=60))
    def check(steps: list[tuple[float, bool, float, float, float]]) -> None:
        tr = Tracker(["r1"], p)
        t = 0.0
        last: tuple[float, Measurement] | None = None
        history: list[Measurement] = []
        for dt, seen, x, y, th in steps:
            t += dt
            m = Measurement("r1", x, y, th)
            out = tr.update(t, [m] if seen else [])
            if seen:
                history.append(m)
            if not out:
                continue
            assert out == [m]
            if last is not None and t - last[0] <= p.lost_after_s:
                t0, prev = last
                ok_move = math.hypot(x - prev.x, y - prev.y) <= (
                    p.max_speed_mps * (t - t0) + p.jump_slack_m
                )
                ok_turn = abs(wrap_angle(th - prev.theta)) <= (
                    p.max_turn_radps * (t - t0) + p.turn_slack_rad
                )
                if not (ok_move and ok_turn):  # must be a confirmed relocation
                    recent = history[-p.reacquire_after :]
                    assert len(recent) == p.reacquire_after
                    assert all(math.hypot(r.x - x, r.y - y) <= 2 * p.jump_slack_m for r in recent)
            last = (t, m)

    check()


def test_auto_falls_back_to_opencv_without_pupil(monkeypatch: pytest.MonkeyPatch) -> None:
    """aarch64 has no pupil-apriltags wheel: ``auto`` then uses OpenCV's ArucoDetector (and no
    windows), and still measures within the goals."""
    import localization.core.detectors as det_mod

    monkeypatch.setattr(det_mod, "pupil_available", lambda: False)
    r = Renderer(CAM)
    pipe = CameraPipeline(_cal(r, 3), "auto")
    assert pipe.detector.name.startswith("opencv-aruco")
    truth = moving_scene(3, 0.2)
    pos, head = _errors(pipe.measure(r.render(truth, [0, 1, 2])), truth)
    assert len(pos) == 3 and max(pos) < 2.0 and max(head) < 0.5
