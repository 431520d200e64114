"""The ``rendered`` frame source: the real tracker in the simulated loop, no images on the bus.

``formation camera --source rendered`` subscribes to the plant's truth (``robot/<id>/truth`` or
the ``truths`` batches), and for every truth instant the plant publishes (in realtime the plant
publishes truth at each camera capture, so at the scenario's camera rate) renders what an
overhead camera sees with :mod:`sim_plant.core.render` and hands the frame to the normal pipeline
(detector, homography, tracker). The frame's capture time is the truth's ``t`` (the plant's
``time.monotonic()``, the same clock on one host), so the published pose's ``t`` and the
capture -> published latency include rendering and detection, as a real camera's would include
exposure and transfer.

Realtime only: in lockstep the plant's clock would have to wait for the tracker's poses (not
built; see docs/localization.md).
"""

from __future__ import annotations

import math
import threading
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Final

import numpy as np
import numpy.typing as npt

from localization.core.calibration import Calibration
from sim_plant.core.render import CameraPose, Renderer

__all__ = [
    "RenderSettings",
    "RenderedSource",
    "TruthFeed",
    "camera_args",
    "camera_covering",
    "rendered_calibration",
]

Frame = npt.NDArray[np.uint8]


MAX_FPS: Final = 240.0
"""Upper bound of the rendered source's frame-rate cap (frames per second)."""
MAX_BLUR_PX: Final = 20.0
MAX_NOISE_STD: Final = 100.0


@dataclass(frozen=True)
class RenderSettings:
    """Camera pose and image conditions of the rendered source.

    ``max_fps``: at most this many frames per second of truth time are rendered (truth instants
    closer than ``0.9 / max_fps`` to the last rendered one are skipped, as a slower camera would
    miss them; the 10 % slack keeps every instant of a plant publishing at exactly ``max_fps``);
    ``None`` renders every truth instant the plant publishes. With the camera's
    resolution (``camera.with_resolution``), the knob that makes the rendered loop light.
    """

    camera: CameraPose = field(default_factory=CameraPose)
    blur_sigma_px: float = 0.8
    noise_std: float = 2.0
    seed: int = 0
    max_fps: float | None = None

    def __post_init__(self) -> None:
        if not (math.isfinite(self.blur_sigma_px) and 0.0 <= self.blur_sigma_px <= MAX_BLUR_PX):
            raise ValueError(f"blur must be in [0, {MAX_BLUR_PX:g}] px, got {self.blur_sigma_px}")
        if not (math.isfinite(self.noise_std) and 0.0 <= self.noise_std <= MAX_NOISE_STD):
            raise ValueError(f"noise must be in [0, {MAX_NOISE_STD:g}], got {self.noise_std}")
        if self.max_fps is not None and not (
            math.isfinite(self.max_fps) and 0.0 < self.max_fps <= MAX_FPS
        ):
            raise ValueError(f"max_fps must be in (0, {MAX_FPS:g}], got {self.max_fps}")


def rendered_calibration(
    settings: RenderSettings, tags: Mapping[str, int], tag_size_m: float = 0.06
) -> Calibration:
    """The calibration of a rendered camera: its true homography (no calibration error)."""
    return Calibration(
        homography=settings.camera.image_to_floor().tolist(), tags=dict(tags), tag_size_m=tag_size_m
    )


class TruthFeed:
    """Latest true poses per robot, grouped into frames by their stamp; thread-safe.

    A frame is complete when every expected robot reported the same stamp, or when a newer
    stamp starts (the older one is then emitted with the robots it has).
    """

    def __init__(self, robots: Sequence[str]) -> None:
        self.robots = list(robots)
        self._cond = threading.Condition()
        self._collect_t = -math.inf
        self._collect: dict[str, tuple[float, float, float]] = {}
        self._ready: tuple[float, dict[str, tuple[float, float, float]]] | None = None
        self._closed = False
        self.frames = 0

    def push(self, robot: str, t: float, x: float, y: float, theta: float) -> None:
        with self._cond:
            if t < self._collect_t:
                return  # late sample of an older instant
            if t > self._collect_t:
                if self._collect:
                    self._emit()
                self._collect_t = t
                self._collect = {}
            self._collect[robot] = (x, y, theta)
            if all(r in self._collect for r in self.robots):
                self._emit()
                self._collect = {}

    def _emit(self) -> None:
        self._ready = (self._collect_t, dict(self._collect))
        self.frames += 1
        self._cond.notify_all()

    def take(self, timeout_s: float) -> tuple[float, dict[str, tuple[float, float, float]]] | None:
        """The newest complete frame not taken yet (waits up to ``timeout_s``); None if none."""
        with self._cond:
            if self._ready is None and not self._closed:
                self._cond.wait(timeout_s)
            ready, self._ready = self._ready, None
            return ready

    def close(self) -> None:
        with self._cond:
            self._closed = True
            self._cond.notify_all()

    @property
    def closed(self) -> bool:
        return self._closed


class RenderedSource:
    """Frames rendered from the truth feed (a live source: one frame per truth instant)."""

    live = True

    def __init__(self, calibration: Calibration, settings: RenderSettings) -> None:
        self.tag_of = dict(calibration.tags)
        self.feed = TruthFeed(sorted(self.tag_of))
        self.renderer = Renderer(settings.camera, tag_size_m=calibration.tag_size_m)
        self.settings = settings
        self.rng = np.random.default_rng(settings.seed)
        self.fps = 30.0 if settings.max_fps is None else settings.max_fps  # nominal (live)
        # a truth instant this close after the last rendered one is skipped (rate cap): a
        # tenth of a period of slack, so a plant publishing at exactly max_fps loses nothing
        self._min_gap_s = 0.0 if settings.max_fps is None else 0.9 / settings.max_fps
        self._last_stamp = -math.inf
        self.skipped = 0
        self.frame_stamp_s: float | None = None
        cam = settings.camera
        rate = "every truth instant" if settings.max_fps is None else f"<= {settings.max_fps:g} fps"
        self.description = (
            f"rendered {cam.width}x{cam.height} from the plant's truth (camera {cam.height_m:g} m "
            f"above {cam.look_at}, tilt {cam.tilt_deg:g} deg, {rate})"
        )

    def read(self) -> Frame | None:
        while not self.feed.closed:
            got = self.feed.take(0.2)
            if got is None:
                continue
            stamp, poses = got
            if stamp - self._last_stamp < self._min_gap_s:
                self.skipped += 1  # faster than the camera's rate cap
                continue
            self._last_stamp = stamp
            known = [r for r in sorted(poses) if r in self.tag_of]
            truth = np.array([poses[r] for r in known], dtype=np.float64).reshape(-1, 3)
            s = self.settings
            frame = self.renderer.render(
                truth,
                [self.tag_of[r] for r in known],
                blur_sigma_px=s.blur_sigma_px,
                noise_std=s.noise_std,
                rng=self.rng,
                gray=True,
            )
            self.frame_stamp_s = stamp
            return frame
        return None

    def skip(self) -> bool:
        return False

    def rewind(self) -> bool:
        return False

    def close(self) -> None:
        self.feed.close()


def camera_covering(
    points: Sequence[tuple[float, float]],
    *,
    margin_m: float = 0.3,
    min_height_m: float = 1.14,
    base: CameraPose | None = None,
) -> CameraPose:
    """A straight-down camera (``base``'s intrinsics) whose view covers ``points`` (floor, m)
    with ``margin_m`` around them: centred on their bounding box, no lower than
    ``min_height_m`` (the paper's 1.14 m), higher if the box needs it."""
    cam = base if base is not None else CameraPose()
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    if len(pts) == 0:
        raise ValueError("no points to cover")
    lo, hi = pts.min(axis=0) - margin_m, pts.max(axis=0) + margin_m
    centre = (float(lo[0] + hi[0]) / 2.0, float(lo[1] + hi[1]) / 2.0)
    # the view at height h spans width * h / fx metres across and height * h / fy along
    need = max(
        float(hi[0] - lo[0]) * cam.fx / cam.width, float(hi[1] - lo[1]) * cam.fy / cam.height
    )
    return CameraPose(
        height_m=max(min_height_m, need),
        look_at=centre,
        tilt_deg=0.0,
        yaw_deg=0.0,
        width=cam.width,
        height=cam.height,
        fx=cam.fx,
        fy=cam.fy,
    )


def camera_args(camera: CameraPose, *, max_fps: float | None = None) -> list[str]:
    """``formation camera`` options rendering from ``camera`` (its pose, and its resolution with
    the default lens scaled to it: ``CameraPose().with_resolution``), at most ``max_fps``."""
    x, y = camera.look_at
    lens = CameraPose(height_m=camera.height_m, look_at=camera.look_at, tilt_deg=camera.tilt_deg)
    if camera != lens.with_resolution(camera.width, camera.height):
        raise ValueError("the options give only yaw 0 and the default lens scaled to the size")
    out = [
        "--source", "rendered", "--render-height", repr(camera.height_m),
        # one word with `=`: a value starting with '-' would be taken for an option
        f"--render-look-at={x!r},{y!r}", "--render-tilt", repr(camera.tilt_deg),
    ]  # fmt: skip
    if (camera.width, camera.height) != (CameraPose.width, CameraPose.height):
        out += ["--render-size", f"{camera.width}x{camera.height}"]
    if max_fps is not None:
        out += ["--fps", repr(max_fps)]
    return out


def scenario_camera_args(
    robot_ids: Sequence[str],
    initial: Sequence[Sequence[float]],
    trajectory: Mapping[str, object],
    formation_size_m: float,
    duration_s: float,
    calibration_path: str,
) -> list[str]:
    """For ``formation up --camera rendered``: a straight-down camera covering the robots' start
    and the virtual leader's path over ``duration_s`` (plus ``formation_size_m``), its true
    calibration written to ``calibration_path`` (robot k -> tag k-1 in ``robot_ids`` order);
    returns the ``formation camera`` options (without the Zenoh ones)."""
    from coordinator.core.trajectory import make_trajectory

    params = {k: v for k, v in trajectory.items() if k != "kind"}
    traj = make_trajectory(str(trajectory["kind"]), params)
    pts = [(float(p[0]), float(p[1])) for p in initial]
    steps = max(2, int(duration_s) + 1)
    for k in range(steps):
        s = traj.sample(duration_s * k / (steps - 1))
        pts.append((s.x, s.y))
    camera = camera_covering(pts, margin_m=formation_size_m + 0.3)
    settings = RenderSettings(camera)
    from localization.core.calibration import write

    write(rendered_calibration(settings, {r: i for i, r in enumerate(robot_ids)}), calibration_path)
    return [*camera_args(camera), "--calibration", calibration_path]
