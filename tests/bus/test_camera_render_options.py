"""The rendered source's speed and wiring options (docs/localization.md, "Running"):
``--render-size`` (a lower resolution with the same lens), ``--fps`` as the rendered source's
rate cap (on truth time, not the wall clock), ``--truth-endpoint`` (the truth from a separate
plain session, as tests/fleet/test_deploy_netns.py's world provides it), their validation, and
``camera_args`` reproducing a camera exactly (negative look-at points included)."""

from __future__ import annotations

import itertools
import math
import signal
import threading
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import zenoh
from support.bus_watch import Recorder, decoder_of
from support.routers import RouterHandle
from support.spawn import Spawner, free_port

pytest.importorskip("cv2")

import runtime as rt
from bus_schemas import PoseBatch, TruthBatch, encode, keys
from localization.core.calibration import write
from localization.core.rendered import (
    RenderedSource,
    RenderSettings,
    camera_args,
    camera_covering,
    rendered_calibration,
)
from localization.node.main import _open, _truth_settings, build_parser
from sim_plant.core.render import CameraPose, Renderer, floor_to_image

FLEET = "demo"
ROBOTS = ("r1", "r2", "r3")
TRUTH = np.array([[-0.4, 0.1, 0.3], [0.0, -0.1, -1.0], [0.3, 0.05, 2.5]])


# --- resolution ----------------------------------------------------------------------------


def test_with_resolution_keeps_the_view() -> None:
    """Half the pixels each way: every floor point lands at the same place of the image (in
    continuous coordinates), so the view and the calibration's floor frame are unchanged."""
    full = CameraPose(height_m=1.3, look_at=(-0.2, 0.1), tilt_deg=6.0)
    half = full.with_resolution(640, 360)
    assert (half.width, half.height, half.fx, half.fy) == (640, 360, 450.0, 450.0)
    pts = np.array([[-0.6, -0.3], [0.0, 0.0], [0.4, 0.35]])
    a = floor_to_image(full.floor_to_image(), pts)
    b = floor_to_image(half.floor_to_image(), pts)
    np.testing.assert_allclose((b + 0.5) * 2.0 - 0.5, a, atol=1e-9)
    off = CameraPose(cx=700.0, cy=300.0).with_resolution(640, 360)
    assert (off.cx, off.cy) == (349.75, 149.75)


@pytest.mark.parametrize("size", [(15, 100), (100, 15), (8193, 100), (100, 8193)])
def test_image_size_bounds(size: tuple[int, int]) -> None:
    with pytest.raises(ValueError, match="px on each side"):
        CameraPose(width=size[0], height=size[1])


@pytest.mark.parametrize(
    "kwargs",
    [
        {"blur_sigma_px": -1.0},
        {"blur_sigma_px": math.nan},
        {"noise_std": math.inf},
        {"noise_std": -0.1},
        {"max_fps": 0.0},
        {"max_fps": -5.0},
        {"max_fps": math.nan},
        {"max_fps": 1e6},
    ],
)
def test_render_settings_refuse_absurd_values(kwargs: dict[str, float]) -> None:
    with pytest.raises(ValueError):
        RenderSettings(**kwargs)  # type: ignore[arg-type]


@pytest.mark.parametrize("text", ["640", "640x", "x360", "0x360", "640x9000", "axb", "-640x360"])
def test_render_size_option_is_validated(text: str, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        build_parser().parse_args(["--source", "rendered", "--calibration", "c.toml",
                                   f"--render-size={text}"])  # fmt: skip
    assert exc.value.code == 2
    assert "--render-size" in capsys.readouterr().err


def test_camera_args_round_trip(tmp_path: Path) -> None:
    """``camera_args`` -> the parser -> the source renders from exactly the same camera (a look-at
    point with negative coordinates is one ``--render-look-at=X,Y`` word, not an option)."""
    base = CameraPose().with_resolution(640, 360)
    camera = camera_covering([(-1.1, -0.3), (0.5, 0.3)], margin_m=0.0, base=base)
    assert camera.look_at[0] < 0
    args = camera_args(camera, max_fps=15.0)
    cal = rendered_calibration(RenderSettings(camera), {"r1": 1}, 0.1)
    ns = build_parser().parse_args([*args, "--calibration", "unused.toml"])
    source = _open(ns, cal)
    assert isinstance(source, RenderedSource)
    try:
        assert source.settings.camera == camera
        assert source.settings.max_fps == 15.0
        assert "640x360" in source.description and "<= 15 fps" in source.description
    finally:
        source.close()
    with pytest.raises(ValueError):  # a camera the options cannot express
        camera_args(CameraPose(yaw_deg=10.0))


def test_truth_endpoint_is_validated() -> None:
    p = build_parser()
    ns = p.parse_args(["--source", "0", "--calibration", "c.toml", "--truth-endpoint",
                       "tcp/127.0.0.1:7600"])  # fmt: skip
    with pytest.raises(ValueError, match="needs --source rendered"):
        _truth_settings(ns)
    ns = p.parse_args(["--source", "rendered", "--calibration", "c.toml", "--truth-endpoint",
                       "nonsense"])  # fmt: skip
    with pytest.raises(ValueError, match="not a Zenoh endpoint"):
        _truth_settings(ns)
    ns = p.parse_args(["--source", "rendered", "--calibration", "c.toml"])
    assert _truth_settings(ns) is None


# --- rate cap --------------------------------------------------------------------------------


def test_rate_cap_skips_truth_instants_by_their_stamps() -> None:
    """``max_fps`` 15 on 30 Hz truth: every other instant is rendered, judged on the truth's
    stamps (what a slower camera would have exposed), whenever the frames are read."""
    camera = CameraPose().with_resolution(320, 180)
    settings = RenderSettings(camera, max_fps=15.0, noise_std=0.0, blur_sigma_px=0.0)
    cal = rendered_calibration(settings, {"r1": 1}, 0.1)
    source = RenderedSource(cal, settings)
    rendered: list[float] = []

    def reader() -> None:
        while (frame := source.read()) is not None:
            assert frame.shape == (180, 320)
            assert source.frame_stamp_s is not None
            rendered.append(source.frame_stamp_s)

    thread = threading.Thread(target=reader, daemon=True)
    thread.start()
    try:
        for k in range(12):
            handled = len(rendered) + source.skipped
            source.feed.push("r1", 100.0 + k / 30.0, 0.0, 0.0, 0.0)
            deadline = time.monotonic() + 10.0  # the reader takes each instant before the next
            while len(rendered) + source.skipped == handled and time.monotonic() < deadline:
                time.sleep(0.002)
    finally:
        source.close()
        thread.join(2.0)
    assert rendered == [100.0 + k / 30.0 for k in range(0, 12, 2)]
    assert source.skipped == 6


# --- the truth from a separate session (the deployment test's world) ---------------------------


def test_truth_from_a_separate_session(
    spawn: Spawner, router: RouterHandle, session: Callable[..., zenoh.Session], tmp_path: Path
) -> None:
    """``--truth-endpoint``: the camera renders the truth of a separate plain session (a peer
    listening on its own port, here this test) at 640x360 and at most 15 fps, and publishes the
    poses on its fleet session. Decoy truth on the fleet router is never rendered."""
    camera = CameraPose().with_resolution(640, 360)
    cal_path = tmp_path / "camera.toml"
    write(rendered_calibration(RenderSettings(camera), {r: i for i, r in enumerate(ROBOTS)}, 0.1),
          cal_path)  # fmt: skip
    truth_ep = f"tcp/127.0.0.1:{free_port()}"
    light = rt.open_session(rt.ZenohSettings(connect=(), listen=(truth_ep,), mode="peer"))
    client = session()
    try:
        batches = Recorder(client, keys.poses_key(FLEET), decoder_of(PoseBatch))
        cam = spawn(
            "camera", *camera_args(camera, max_fps=15.0), "--truth-endpoint", truth_ep,
            "--calibration", str(cal_path), "--endpoint", router.endpoint, ready="camera ready",
        )  # fmt: skip
        truths = light.declare_publisher(keys.truths_key(FLEET))
        decoy = client.declare_publisher(keys.truths_key(FLEET))
        sent: dict[float, np.ndarray] = {}
        k = 0
        deadline = time.monotonic() + 30.0
        while len(batches.snapshot()) < 15 and time.monotonic() < deadline:
            t = time.monotonic()
            truth = TRUTH + np.array([0.001 * k, 0.0, 0.0])
            sent[t] = truth
            for pub, xs in ((truths, truth), (decoy, truth + np.array([0.3, 0.3, 0.0]))):
                pub.put(encode(TruthBatch(
                    t=t, seq=k + 1, robots=ROBOTS, x=tuple(xs[:, 0]), y=tuple(xs[:, 1]),
                    theta=tuple(xs[:, 2]), stamp=t,
                )))  # fmt: skip
            k += 1
            time.sleep(1.0 / 30.0)
        got = [m for _, _, m in batches.snapshot()]
        assert len(got) >= 15, cam.describe()
        stamps = [m.stamp for m in got]
        assert all(b - a >= 0.9 / 15.0 for a, b in itertools.pairwise(stamps)), stamps
        for m in got:
            truth = sent[m.stamp]  # a truth instant of the separate session, never a decoy's
            for rid, x, y in zip(m.robots, m.x, m.y, strict=True):
                tx, ty, _ = truth[ROBOTS.index(rid)]
                assert math.hypot(x - tx, y - ty) < 0.005, (rid, x, y, tx, ty)
        assert cam.stop(signal.SIGTERM, timeout_s=5.0) < 1.5
        assert cam.proc.returncode == 0, cam.describe()
    finally:
        light.close()


def test_small_frames_are_detected() -> None:
    """The deployment test's camera: 640x360, 10 cm tags over a 2.1 m wide view (~30 px): every
    robot found in every frame, sub-millimetre, with the blur and noise of the default source."""
    from localization.core.pipeline import CameraPipeline

    base = CameraPose().with_resolution(640, 360)
    camera = camera_covering([(-1.1, -0.3), (1.0, 0.3)], margin_m=0.0, base=base)
    cal = rendered_calibration(RenderSettings(camera), {r: i + 1 for i, r in enumerate(ROBOTS)},
                               0.1)  # fmt: skip
    renderer = Renderer(camera, tag_size_m=0.1)
    pipeline = CameraPipeline(cal)
    rng = np.random.default_rng(1)
    errs = []
    for k in range(30):
        truth = TRUTH + np.array([0.02 * k, 0.0, 0.05 * k])
        frame = renderer.render(truth, [1, 2, 3], blur_sigma_px=0.8, noise_std=2.0, rng=rng,
                                gray=True)  # fmt: skip
        res = pipeline.process(frame, k / 15.0, time.perf_counter)
        assert sorted(m.robot for m in res.measurements) == list(ROBOTS), k
        for m in res.measurements:
            tx, ty, _ = truth[ROBOTS.index(m.robot)]
            errs.append(math.hypot(m.x - tx, m.y - ty))
    assert float(np.median(errs)) < 0.002 and max(errs) < 0.005
