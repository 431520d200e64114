"""``formation camera`` as a real process on a real router, fed a rendered video file: every
robot's pose on the bus within the goals (median < 2 mm, < 0.5 deg with the true homography),
``t`` = capture time, the batch and the status key; a file at its own frame rate; clean SIGTERM
exit; ``formation camera calibrate`` round trip through the CLI."""

from __future__ import annotations

import itertools
import math
import signal
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import zenoh
from support.bus_watch import Recorder, decoder_of
from support.routers import RouterHandle
from support.spawn import Spawner

pytest.importorskip("cv2")

from bus_schemas import CameraStatus, Pose, PoseBatch, keys
from localization.core.calibration import Calibration, TrackerParams, load, write
from sim_plant.core.render import CameraPose, Renderer, moving_scene, write_video

FLEET = "demo"
FPS = 30.0
N_ROBOTS = 6
N_FRAMES = 36
EXIT_BOUND_S = 1.5  # requirement: 1 s after SIGTERM; 0.5 s margin for a loaded 2-core box
RENDERER = Renderer(CameraPose(tilt_deg=8.0))


def scene(k: int) -> np.ndarray:
    return moving_scene(N_ROBOTS, k / FPS)


@pytest.fixture(scope="module")
def video(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """A rendered MJPG video of N_ROBOTS moving robots (blur + noise) and its true calibration."""
    d = tmp_path_factory.mktemp("camera")
    rng = np.random.default_rng(7)
    frames = (
        RENDERER.render(scene(k), list(range(N_ROBOTS)), blur_sigma_px=0.8, noise_std=2.0, rng=rng)
        for k in range(N_FRAMES)
    )
    path = d / "scene.avi"
    assert write_video(path, frames, FPS) == N_FRAMES
    cal = Calibration(
        homography=RENDERER.h_image_to_floor.tolist(),
        tags={f"r{i + 1}": i for i in range(N_ROBOTS)},
        tag_size_m=RENDERER.tag_size_m,
        tracker=TrackerParams(lost_after_s=60.0),
    )
    cal_path = d / "calibration.toml"
    write(cal, cal_path)
    return path, cal_path


@pytest.fixture
def client(session: Callable[..., zenoh.Session]) -> zenoh.Session:
    return session()


def _status(rec: Recorder) -> list[CameraStatus]:
    return [m for _, _, m in rec.snapshot()]


def test_rendered_video_poses_on_the_bus_within_goals(
    spawn: Spawner, router: RouterHandle, client: zenoh.Session, video: tuple[Path, Path]
) -> None:
    path, cal_path = video
    poses = Recorder(client, keys.all_poses_pattern(FLEET), decoder_of(Pose))
    batches = Recorder(client, keys.poses_key(FLEET), decoder_of(PoseBatch))
    status = Recorder(client, keys.all_camera_status_pattern(FLEET), decoder_of(CameraStatus))
    cam = spawn(
        "camera", "--source", str(path), "--calibration", str(cal_path),
        "--endpoint", router.endpoint, "--fast", ready="camera ready",
    )  # fmt: skip
    cam.proc.wait(timeout=60)  # a recording ends: exit 0
    assert cam.proc.returncode == 0, cam.describe()
    assert "detector " in cam.stdout()
    time.sleep(0.2)
    final = _status(status)[-1]
    assert final.state == "done" and final.frames == N_FRAMES, final
    assert final.dropped == 0 and final.internal_errors == 0, final
    assert final.misses == {f"r{i + 1}": 0 for i in range(N_ROBOTS)}, final
    assert final.rejects == {"jump": 0, "bad_size": 0, "unknown": 0, "duplicate": 0}
    assert final.latency_p50_ms is not None and final.detect_max_ms is not None
    # Every frame published every robot: the n-th pose of a robot (seq n) is frame n-1.
    pos_err, head_err = [], []
    by_robot: dict[str, list[Pose]] = {}
    for _, key, msg in poses.snapshot():
        assert key == keys.pose_key(FLEET, msg.robot)
        by_robot.setdefault(msg.robot, []).append(msg)
    assert sorted(by_robot) == [f"r{i + 1}" for i in range(N_ROBOTS)]
    for rid, msgs in by_robot.items():
        assert [m.seq for m in msgs] == list(range(1, N_FRAMES + 1)), rid
        ts = [m.t for m in msgs]
        assert all(b > a for a, b in itertools.pairwise(ts)), "t = capture time, increasing"
        i = int(rid[1:]) - 1
        for k, m in enumerate(msgs):
            x, y, th = scene(k)[i]
            pos_err.append(math.hypot(m.x - x, m.y - y) * 1e3)
            head_err.append(abs(math.remainder(m.theta - th, 2 * math.pi)) * 180 / math.pi)
    assert np.median(pos_err) < 2.0 and np.median(head_err) < 0.5, (
        np.median(pos_err), np.median(head_err),
    )  # fmt: skip
    assert max(pos_err) < 6.0 and max(head_err) < 2.0
    # one batch per frame, published before the frame's poses, stamp = the poses' t
    b = [m for _, _, m in batches.snapshot()]
    assert len(b) == N_FRAMES
    assert all(len(m.robots) == N_ROBOTS for m in b)
    stamps = {m.t for ms in by_robot.values() for m in ms}
    assert {m.stamp for m in b} == stamps


def test_file_at_its_own_rate_and_clean_sigterm(
    spawn: Spawner, router: RouterHandle, client: zenoh.Session, video: tuple[Path, Path]
) -> None:
    path, cal_path = video
    poses = Recorder(client, keys.pose_key(FLEET, "r1"), decoder_of(Pose))
    cam = spawn(
        "camera", "--source", str(path), "--calibration", str(cal_path),
        "--endpoint", router.endpoint, "--loop", ready="camera ready",
    )  # fmt: skip
    poses.wait_for(lambda *_: True, timeout_s=10.0)
    time.sleep(1.5)
    msgs = [m for _, _, m in poses.snapshot()]
    span = msgs[-1].t - msgs[0].t
    # never faster than the file's 30 fps (frames may be dropped on a loaded machine)
    assert len(msgs) - 1 <= FPS * span * 1.1 + 1, (len(msgs), span)
    assert span > 1.0
    dt = time.monotonic()
    assert cam.stop(signal.SIGTERM, timeout_s=5.0) < EXIT_BOUND_S
    assert cam.proc.returncode == 0, cam.describe()
    assert time.monotonic() - dt < 5.0


def test_bad_inputs_exit_2(spawn: Spawner, tmp_path: Path, video: tuple[Path, Path]) -> None:
    path, cal_path = video
    bad = tmp_path / "bad.toml"
    bad.write_text("homography = [[0,0,0],[0,0,0],[0,0,0]]\n[tags]\nr1 = 0\n")
    for argv in (
        ["--source", str(path), "--calibration", str(bad)],
        ["--source", str(tmp_path / "missing.avi"), "--calibration", str(cal_path)],
    ):
        child = spawn("camera", *argv)
        child.proc.wait(timeout=20)
        assert child.proc.returncode == 2, child.describe()
        assert "camera:" in child.stderr()


def test_calibrate_cli_round_trip(spawn: Spawner, tmp_path: Path) -> None:
    """Floor markers at known places in a rendered frame -> the calibration file, the error
    reported in mm, and a homography within a few mm of the true one over the whole view."""
    import cv2

    r = Renderer(CameraPose(tilt_deg=8.0), tag_size_m=0.08, body_radius_m=0.06)
    places = [(-0.7, -0.3), (0.0, -0.33), (0.7, -0.3), (-0.7, 0.3), (0.0, 0.0), (0.7, 0.33)]
    truth = np.array([[x, y, 0.0] for x, y in places])
    img = tmp_path / "floor.png"
    frame = r.render(truth, [200 + i for i in range(len(places))], blur_sigma_px=0.7)
    cv2.imwrite(str(img), frame)
    out = tmp_path / "cal.toml"
    args = ["camera", "calibrate", "--image", str(img), "--out", str(out), "--marker-size", "0.08"]
    for i, (x, y) in enumerate(places):
        args += ["--marker", f"{200 + i},{x},{y},0"]
    args += ["--tags", "r1=0,r2=1"]
    child = spawn(*args)
    child.proc.wait(timeout=30)
    assert child.proc.returncode == 0, child.describe()
    line = [s for s in child.stdout().splitlines() if s.startswith("reprojection error")]
    assert line and " mm" in line[0], child.stdout()
    rms = float(line[0].split("rms ")[1].split(" mm")[0])
    cal = load(out)
    assert cal.tags == {"r1": 0, "r2": 1}
    assert cal.reprojection_error_mm is not None and abs(cal.reprojection_error_mm - rms) < 0.01
    h = np.array(cal.homography)
    us, vs = np.meshgrid(np.linspace(100, 1180, 7), np.linspace(60, 660, 5))
    pix = np.column_stack([us.ravel(), vs.ravel(), np.ones(us.size)])
    a, b = pix @ h.T, pix @ r.h_image_to_floor.T
    err = np.linalg.norm(a[:, :2] / a[:, 2:] - b[:, :2] / b[:, 2:], axis=1) * 1e3
    assert err.max() < 3.0, err


def test_systemd_unit_verifies(tmp_path: Path) -> None:
    """deploy/systemd/formation-camera.service passes ``systemd-analyze verify`` (no warnings)."""
    import os
    import subprocess

    from support.spawn import REPO_ROOT

    analyze = "/usr/bin/systemd-analyze"
    if not os.access(analyze, os.X_OK):
        pytest.skip(f"{analyze} is not installed")
    fake = tmp_path / "formation"
    fake.write_text("#!/bin/sh\nexit 0\n")
    fake.chmod(0o755)
    text = (REPO_ROOT / "deploy" / "systemd" / "formation-camera.service").read_text()
    assert "ExecStart=/opt/formation/venv/bin/formation camera " in text
    unit = tmp_path / "formation-camera.service"
    unit.write_text(text.replace("/opt/formation/venv/bin/formation ", f"{fake} "))
    result = subprocess.run(
        [analyze, "verify", "--man=no", str(unit)], capture_output=True, text=True, timeout=60
    )
    output = result.stdout + result.stderr
    assert result.returncode == 0, output
    assert [s for s in output.splitlines() if "formation-camera" in s] == [], output


def test_rendered_source_tracks_the_truth_on_the_bus(
    spawn: Spawner, router: RouterHandle, client: zenoh.Session, tmp_path: Path
) -> None:
    """``--source rendered``: truth published on the bus (here by the test, as the plant does in
    realtime, one instant per camera frame) is rendered and tracked; each pose's ``t`` is the
    truth instant it was rendered from, and it matches that truth within the goals."""
    import threading

    import runtime as tp
    from bus_schemas import Truth, TruthBatch, encode
    from localization.core.rendered import RenderSettings, rendered_calibration

    settings = RenderSettings(CameraPose(tilt_deg=8.0))
    cal_path = tmp_path / "rendered.toml"
    write(rendered_calibration(settings, {f"r{i + 1}": i for i in range(N_ROBOTS)}), cal_path)
    poses = Recorder(client, keys.all_poses_pattern(FLEET), decoder_of(Pose))
    status = Recorder(client, keys.all_camera_status_pattern(FLEET), decoder_of(CameraStatus))
    cam = spawn(
        "camera", "--source", "rendered", "--calibration", str(cal_path), "--render-tilt", "8",
        "--endpoint", router.endpoint, ready="camera ready",
    )  # fmt: skip
    pubs = tp.Publishers(client)
    sent: dict[float, np.ndarray] = {}
    stop = threading.Event()

    def publish_truth() -> None:  # 30 Hz; half the instants per robot, half as a batch
        k = 0
        t0 = time.monotonic()
        while not stop.is_set():
            t = time.monotonic()
            truth = moving_scene(N_ROBOTS, t - t0)
            sent[t] = truth
            if k % 2:
                for i, (x, y, th) in enumerate(truth.tolist()):
                    rid = f"r{i + 1}"
                    msg = Truth(t=t, seq=k + 1, x=x, y=y, theta=th, robot=rid)
                    pubs.put(keys.truth_key(FLEET, rid), encode(msg))
            else:
                batch = TruthBatch(
                    t=t, seq=k + 1, robots=tuple(f"r{i + 1}" for i in range(N_ROBOTS)),
                    x=tuple(truth[:, 0]), y=tuple(truth[:, 1]), theta=tuple(truth[:, 2]), stamp=t,
                )  # fmt: skip
                pubs.put(keys.truths_key(FLEET), encode(batch))
            k += 1
            stop.wait(max(0.0, t0 + k / FPS - time.monotonic()))

    feeder = threading.Thread(target=publish_truth, daemon=True)
    feeder.start()
    try:
        # hostile input: garbage on the truth keys is counted, never rendered. Sent once a pose
        # proves the camera's truth subscription has reached the router (earlier puts are dropped).
        poses.wait_for(lambda *_: True, timeout_s=20.0)
        block = zenoh.CongestionControl.BLOCK
        client.put(keys.truth_key(FLEET, "r1"), b"\xc1garbage", congestion_control=block)
        client.put(keys.truths_key(FLEET), b"\x93\x01\x02\x03", congestion_control=block)
        deadline = time.monotonic() + 20.0
        while len(poses.snapshot()) < 20 * N_ROBOTS and time.monotonic() < deadline:
            time.sleep(0.05)
    finally:
        stop.set()
        feeder.join(2.0)
    got = [m for _, _, m in poses.snapshot()]
    assert len(got) >= 20 * N_ROBOTS, cam.describe()
    pos_err, head_err = [], []
    for m in got:
        truth = sent[m.t]  # t is exactly the truth instant the frame was rendered from
        x, y, th = truth[int(m.robot[1:]) - 1]
        pos_err.append(math.hypot(m.x - x, m.y - y) * 1e3)
        head_err.append(abs(math.remainder(m.theta - th, 2 * math.pi)) * 180 / math.pi)
    assert np.median(pos_err) < 2.0 and np.median(head_err) < 0.5
    assert {m.robot for m in got} == {f"r{i + 1}" for i in range(N_ROBOTS)}
    status.wait_for(lambda _r, _k, s: s.truth_rejected == 2, timeout_s=3.0)
    assert cam.stop(signal.SIGTERM, timeout_s=5.0) < EXIT_BOUND_S
    assert cam.proc.returncode == 0, cam.describe()


def test_plant_no_poses_publishes_truth_only(
    spawn: Spawner, router: RouterHandle, client: zenoh.Session
) -> None:
    """``formation plant --no-poses`` (used by ``formation up --camera rendered``): the camera
    emulation is off, truth still flows at the camera rate for the rendered source."""
    from bus_schemas import Truth

    poses = Recorder(client, keys.all_poses_pattern(FLEET), decoder_of(Pose))
    batches = Recorder(client, keys.poses_key(FLEET), decoder_of(PoseBatch))
    truth = Recorder(client, keys.all_truth_pattern(FLEET), decoder_of(Truth))
    spawn(
        "plant", "--scenario", "paper-exp1", "--no-poses", "--endpoint", router.endpoint,
        ready="plant ready",
    )  # fmt: skip
    truth.wait_for(lambda *_: True, timeout_s=10.0)
    time.sleep(0.5)
    assert len(truth.snapshot()) >= 3 * 5
    assert poses.snapshot() == [] and batches.snapshot() == []


def test_folder_of_images_source(
    spawn: Spawner, router: RouterHandle, client: zenoh.Session, tmp_path: Path,
    video: tuple[Path, Path],
) -> None:  # fmt: skip
    """A folder of PNGs is read in name order (non-images ignored) and published."""
    import cv2

    _, cal_path = video
    folder = tmp_path / "frames"
    folder.mkdir()
    for k in range(5):
        cv2.imwrite(str(folder / f"f{k:03d}.png"), RENDERER.render(scene(k), list(range(N_ROBOTS))))
    (folder / "notes.txt").write_text("not an image")
    poses = Recorder(client, keys.pose_key(FLEET, "r2"), decoder_of(Pose))
    cam = spawn(
        "camera", "--source", str(folder), "--calibration", str(cal_path), "--fps", "50",
        "--fast", "--endpoint", router.endpoint, ready="camera ready",
    )  # fmt: skip
    assert "folder " in cam.stdout() and "5 images @ 50 fps" in cam.stdout()
    cam.proc.wait(timeout=20)
    assert cam.proc.returncode == 0, cam.describe()
    got = [m for _, _, m in poses.snapshot()]
    assert [m.seq for m in got] == [1, 2, 3, 4, 5]
    for k, m in enumerate(got):
        x, y, _ = scene(k)[1]
        assert math.hypot(m.x - x, m.y - y) < 0.002


def test_misses_jumps_and_unknown_tags_on_the_bus(
    spawn: Spawner, router: RouterHandle, client: zenoh.Session, tmp_path: Path,
    video: tuple[Path, Path],
) -> None:  # fmt: skip
    """A video where r2 is covered for 4 frames, r3 flickers 0.25 m away for one frame and an
    unknown tag lies on the floor: r2 is not published while covered (misses), the flicker is
    rejected (a jump, never published), the unknown tag is counted; the status says so."""
    from sim_plant.core.render import Occluder

    _, cal_path = video
    n_frames = 20
    unknown = np.array([[0.0, -0.33, 0.0]])

    def frame(k: int) -> np.ndarray:
        truth = scene(k).copy()
        if k == 10:
            truth[2, 1] += 0.25  # an empty part of the floor
        occ = []
        if 5 <= k <= 8:
            from localization.core.pose import true_corner_pixels

            x, y, th = scene(k)[1]
            pix = true_corner_pixels(RENDERER.h_floor_to_image, x, y, th, 0.06)
            (u0, v0), (u1, v1) = pix.min(axis=0) - 12, pix.max(axis=0) + 12
            occ = [Occluder(int(u0), int(v0), int(u1), int(v1))]
        poses = np.vstack([truth, unknown])
        return RENDERER.render(poses, [*range(N_ROBOTS), 40], occluders=occ)

    path = tmp_path / "events.avi"
    write_video(path, (frame(k) for k in range(n_frames)), FPS)
    poses = Recorder(client, keys.all_poses_pattern(FLEET), decoder_of(Pose))
    status = Recorder(client, keys.all_camera_status_pattern(FLEET), decoder_of(CameraStatus))
    cam = spawn(
        "camera", "--source", str(path), "--calibration", str(cal_path), "--fast",
        "--endpoint", router.endpoint, ready="camera ready",
    )  # fmt: skip
    cam.proc.wait(timeout=30)
    assert cam.proc.returncode == 0, cam.describe()
    time.sleep(0.2)
    final = _status(status)[-1]
    assert final.frames == n_frames and final.state == "done"
    # covered in frames 5-8; found again within search_every (3) frames of reappearing
    missed = final.misses["r2"]
    assert 4 <= missed <= 6 and final.misses["r1"] == 0
    assert final.rejects["jump"] == 1
    assert final.rejects["unknown"] >= 1
    got: dict[str, list[Pose]] = {}
    for _, _, m in poses.snapshot():
        got.setdefault(m.robot, []).append(m)
    assert len(got["r1"]) == n_frames
    assert len(got["r2"]) == n_frames - missed
    assert len(got["r3"]) == n_frames - 1
    for m in got["r3"]:  # the flicker never reached the bus
        assert (
            min(math.hypot(m.x - scene(k)[2][0], m.y - scene(k)[2][1]) for k in range(20)) < 0.003
        )
