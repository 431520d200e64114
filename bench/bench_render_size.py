"""Benchmark: what the rendered camera costs per frame at each image size (``--render-size``).

For each size (1280x720, 960x540, 800x450, 640x360: the default lens scaled, so the same floor
in fewer pixels) and tag edge (6 and 10 cm), a straight-down camera covering a 2.1 m x 0.6 m
strip (x -1.1..1.0, the robots' path in tests/fleet/test_deploy_netns.py), three robots moving
across
it: render time of a gray frame (blur 0.8 px, noise 2: the rendered source's defaults), the
tracker's time (pupil-apriltags with windows when installed, else OpenCV, + floor mapping +
tracker), the fraction of robot-frames detected and the median position error against truth.
Pinned to one CPU (``--no-pin`` to leave it); the load average is printed: other engineers
share these 2 cores, so times are upper bounds. Measures only; asserts nothing.

Run: .venv/bin/python bench/bench_render_size.py [--frames 120] [--no-pin]
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np

from localization.core.pipeline import CameraPipeline
from localization.core.rendered import RenderSettings, camera_covering, rendered_calibration
from sim_plant.core.render import CameraPose, Renderer

SIZES = ((1280, 720), (960, 540), (800, 450), (640, 360))
TAGS_M = (0.06, 0.10)
VIEW = ((-1.1, -0.3), (1.0, 0.3))


def _load() -> str:
    a, b, c = os.getloadavg()
    return f"load average {a:.2f} {b:.2f} {c:.2f} on {os.cpu_count()} cores"


def scene(k: int, fps: float) -> np.ndarray:
    """Three robots in a triangle crossing the view at 0.05 m/s, turning slowly."""
    t = k / fps
    x = -0.6 + 0.05 * t
    return np.array(
        [[x + 0.05, 0.0, 0.1 * t], [x - 0.35, 0.22, 0.2 - 0.1 * t], [x - 0.35, -0.22, 0.05 * t]]
    )


def run(size: tuple[int, int], tag_m: float, frames: int, fps: float) -> str:
    camera = camera_covering(VIEW, margin_m=0.0, base=CameraPose().with_resolution(*size))
    tags = {"r1": 1, "r2": 2, "r3": 3}
    cal = rendered_calibration(RenderSettings(camera), tags, tag_m)
    renderer = Renderer(camera, tag_size_m=tag_m)
    pipeline = CameraPipeline(cal)
    rng = np.random.default_rng(0)
    renderer.render(scene(0, fps), [1, 2, 3], noise_std=2.0, rng=rng, gray=True)  # noise bank
    t_render, t_track, errs, seen = [], [], [], 0
    for k in range(frames):
        truth = scene(k, fps)
        a = time.perf_counter()
        frame = renderer.render(truth, [1, 2, 3], blur_sigma_px=0.8, noise_std=2.0, rng=rng,
                                gray=True)  # fmt: skip
        b = time.perf_counter()
        res = pipeline.process(frame, k / fps, time.perf_counter)
        c = time.perf_counter()
        t_render.append(b - a)
        t_track.append(c - b)
        for m in res.measurements:
            tx, ty, _ = truth[int(m.robot[1:]) - 1]
            errs.append(float(np.hypot(m.x - tx, m.y - ty)))
            seen += 1
    px = tag_m * camera.fx / camera.height_m
    med = f"{np.median(errs) * 1e3:.2f} mm" if errs else "-"
    return (
        f"{size[0]}x{size[1]:<4d} tag {tag_m * 100:.0f} cm ({px:4.0f} px)  "
        f"render {np.median(t_render) * 1e3:5.2f} ms  track {np.median(t_track) * 1e3:5.2f} ms "
        f"(mean {np.mean(t_track) * 1e3:5.2f})  detected {seen / (3 * frames):6.1%}  "
        f"median error {med}"
    )


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--frames", type=int, default=120)
    p.add_argument("--fps", type=float, default=15.0)
    p.add_argument("--no-pin", action="store_true")
    ns = p.parse_args()
    if not ns.no_pin and hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
    print(_load())
    for size in SIZES:
        for tag_m in TAGS_M:
            print(run(size, tag_m, ns.frames, ns.fps), flush=True)
    print(_load())


if __name__ == "__main__":
    main()
