"""Benchmark: the overhead-camera tracker on rendered 1280x720 frames.

Part 1 (in-process, one core: the process is pinned to one CPU, OpenCV and pupil-apriltags
single-threaded): for 3, 10 and 30 robots (sim_plant.core.render.moving_scene, camera 1.14 m above
the
floor tilted 8 deg, 6 cm tags ~47 px) and two image conditions (``mild``: blur 0.8 px + noise 3;
``heavy``: blur 1.5 px + noise 8 + a 0.6 lighting gain with a 30 % gradient), each detector's
detection rate, position / heading error against truth with the true homography (median, p95,
max) and detection + floor-mapping time per frame (median, mean, p95; frames per second =
1 / mean). ``+ windows``: pupil-apriltags run only in windows around the previous frame's tags,
the whole frame every 15th frame or when a robot was not found again (localization.core.detectors).

Part 2 (processes): ``formation camera`` on a rendered 10-robot 720p MJPG video played at its own
30 fps against a ``formation router``; its status key gives the achieved frame rate and the
capture -> published latency (p50/p99/max) as the tracker measures it (the grabber's stamp right
after the frame was read, to just after the last put of the frame).

The machine's load average is printed before and after: other engineers share these 2 cores, so
times are upper bounds. Measures only; asserts nothing.

Run: .venv/bin/python bench/bench_camera.py [--frames 40] [--no-pin] [--skip-process]
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import cv2
import numpy as np

from bus_schemas import CameraStatus, DecodeError, decode, keys
from localization.core.calibration import Calibration, write
from localization.core.detectors import pupil_available
from localization.core.pipeline import CameraPipeline
from sim_plant.core.render import CameraPose, Renderer, moving_scene, write_video

CONDITIONS = {
    "mild": {"blur_sigma_px": 0.8, "noise_std": 3.0},
    "heavy": {"blur_sigma_px": 1.5, "noise_std": 8.0, "gain": 0.6, "gradient": 0.3},
}


def _load() -> str:
    a, b, c = os.getloadavg()
    return f"load average {a:.2f} {b:.2f} {c:.2f} on {os.cpu_count()} cores"


def _cal(r: Renderer, n: int, family: str = "tag36h11", start: dict | None = None) -> Calibration:
    return Calibration(
        homography=r.h_image_to_floor.tolist(),
        tags={} if family == "patches" else {f"r{i + 1}": i for i in range(n)},
        tag_size_m=r.tag_size_m,
        family=family,
        start=start or {},
    )


def bench_detection(frames: int) -> None:
    print(f"\n## detection on rendered 1280x720 frames ({frames} frames each, one core)\n")
    print(
        "| robots | image | detector | found | pos median / p95 / max mm "
        "| heading median / p95 / max deg | ms/frame median / mean / p95 | fps (1/mean) |"
    )
    print("|---|---|---|---|---|---|---|---|")
    cam = CameraPose(tilt_deg=8.0)
    for n in (3, 10, 30):
        for cond, kw in CONDITIONS.items():
            modes = [("tag36h11", "aruco", False)]
            if pupil_available():
                modes[:0] = [("tag36h11", "apriltag", False), ("tag36h11", "apriltag", True)]
            if n <= 10:
                modes.append(("patches", "auto", False))
            for family, det, windows in modes:
                r = Renderer(cam, mode="patches" if family == "patches" else "tag")
                truth0 = moving_scene(n, 0.0)
                start = {f"r{i + 1}": (float(p[0]), float(p[1])) for i, p in enumerate(truth0)}
                pipe = CameraPipeline(_cal(r, n, family, start), det, windows=windows)
                rng = np.random.default_rng(n)
                pos, head, times = [], [], []
                found = 0
                for k in range(frames):
                    t = k / 30.0
                    truth = moving_scene(n, t)
                    img = r.render(truth, list(range(n)), rng=rng, **kw)  # type: ignore[arg-type]
                    t0 = time.perf_counter()
                    res = pipe.process(img, t, time.perf_counter)
                    times.append(time.perf_counter() - t0)
                    found += len(res.measurements)
                    for m in res.measurements:
                        i = int(m.robot[1:]) - 1
                        pos.append(math.hypot(m.x - truth[i, 0], m.y - truth[i, 1]) * 1e3)
                        head.append(abs(math.remainder(m.theta - truth[i, 2], 2 * math.pi)))
                pa = np.array(pos) if pos else np.array([math.nan])
                ha = np.degrees(np.array(head)) if head else np.array([math.nan])
                ta = np.array(times) * 1e3
                name = pipe.detector.name.split(" (")[0] + (" + windows" if windows else "")
                print(
                    f"| {n} | {cond} | {name} | {found}/{n * frames} "
                    f"| {np.median(pa):.2f} / {np.percentile(pa, 95):.2f} / {pa.max():.2f} "
                    f"| {np.median(ha):.3f} / {np.percentile(ha, 95):.3f} / {ha.max():.3f} "
                    f"| {np.median(ta):.1f} / {ta.mean():.1f} / {np.percentile(ta, 95):.1f} "
                    f"| {1e3 / ta.mean():.0f} |",
                    flush=True,
                )


def bench_process(seconds: float) -> None:
    from common import router, running

    n, fps = 10, 30.0
    r = Renderer(CameraPose(tilt_deg=8.0))
    with tempfile.TemporaryDirectory() as d:
        video = Path(d) / "scene.avi"
        rng = np.random.default_rng(1)
        count = int(fps * 4)
        write_video(
            video,
            (
                r.render(
                    moving_scene(n, k / fps),
                    list(range(n)),
                    blur_sigma_px=0.8,
                    noise_std=3.0,
                    rng=rng,
                )
                for k in range(count)
            ),
            fps,
        )
        cal = Path(d) / "cal.toml"
        write(_cal(r, n), cal)
        import zenoh

        import runtime as tp

        with router() as ep:
            session = tp.open_session(tp.ZenohSettings(connect=(ep,)))
            statuses: list[CameraStatus] = []

            def on_status(s: Any) -> None:  # a zenoh.Sample
                msg = decode(s.payload.to_bytes(), CameraStatus)
                if not isinstance(msg, DecodeError):
                    statuses.append(msg)

            sub = session.declare_subscriber(keys.all_camera_status_pattern("demo"), on_status)
            argv = [
                sys.executable, "-m", "formation", "camera", "--source", str(video),
                "--calibration", str(cal), "--endpoint", ep, "--loop",
            ]  # fmt: skip
            with running(argv, ready="camera ready") as proc:
                time.sleep(seconds)
                from common import cpu_s

                cpu = cpu_s(proc.pid)
            sub.undeclare()
            session.close()
            del zenoh
    last = [s for s in statuses if s.latency_p50_ms is not None][-1]
    print(f"\n## formation camera process: {n} robots, 720p MJPG file at its own {fps:g} fps\n")
    print(f"detector: {last.detector}")
    print(
        f"frames {last.frames} in ~{seconds:g} s, dropped {last.dropped}, "
        f"fps (last status period) {last.fps:.1f}, process CPU {cpu:.1f} s"
    )
    print(
        f"detect ms p50 {last.detect_p50_ms:.1f} p99 {last.detect_p99_ms:.1f} "
        f"max {last.detect_max_ms:.1f}"
    )
    print(
        f"capture -> published latency ms p50 {last.latency_p50_ms:.1f} "
        f"p99 {last.latency_p99_ms:.1f} max {last.latency_max_ms:.1f}"
    )


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--frames", type=int, default=40)
    ap.add_argument("--seconds", type=float, default=6.0, help="process part duration")
    ap.add_argument("--no-pin", action="store_true", help="do not pin to one CPU")
    ap.add_argument("--skip-process", action="store_true")
    ns = ap.parse_args()
    print(f"# bench_camera ({_load()})")
    print(f"opencv {cv2.__version__}, pupil-apriltags available: {pupil_available()}")
    if not ns.no_pin and hasattr(os, "sched_setaffinity"):
        cpu = sorted(os.sched_getaffinity(0))[-1]
        os.sched_setaffinity(0, {cpu})
        print(f"pinned to CPU {cpu}")
    cv2.setNumThreads(1)
    bench_detection(ns.frames)
    if not ns.skip_process:
        if not ns.no_pin and hasattr(os, "sched_setaffinity"):
            os.sched_setaffinity(0, set(range(os.cpu_count() or 1)))
        bench_process(ns.seconds)
    print(f"\n({_load()} at the end)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
