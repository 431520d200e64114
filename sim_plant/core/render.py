"""What an overhead camera sees: robots with their tags (or the paper's two colour patches).

A pinhole camera at a configurable pose above the floor (default: 1.14 m above the arena, as the
paper's camera) renders 8-bit BGR frames: the floor, each robot as a disc with its AprilTag
(tag36h11) or its two colour patches, then optional occluders, lighting gain/gradient, Gaussian
blur and sensor noise. The same camera gives the exact image->floor homography, so a tracker can
be checked against truth with the calibration error taken out.

Conventions (the tracker's, docs/localization.md):

* Image pixels: ``u`` right, ``v`` down, pixel centres at integer coordinates (OpenCV's).
* Floor: metres, ``x``/``y`` right-handed seen from above, heading from +x counter-clockwise.
* A tag lies face up on the robot, centred on the axle centre by default, its top edge toward the
  robot's front; ``tag_size_m`` is the edge of the black square (AprilTag's ``tag_size``).

Only numpy and OpenCV (the ``camera`` extra); nothing here touches the bus.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt

__all__ = [
    "MAX_SIDE_PX",
    "MIN_SIDE_PX",
    "PATCH_COLOURS_BGR",
    "CameraPose",
    "Occluder",
    "Renderer",
    "floor_to_image",
    "moving_scene",
    "write_video",
]

FloatArray = npt.NDArray[np.float64]
Frame = npt.NDArray[np.uint8]

PATCH_COLOURS_BGR: dict[str, tuple[int, int, int]] = {
    "front": (40, 40, 220),  # red
    "rear": (220, 120, 30),  # blue
}
"""Colours of the paper's two patches per robot (front, rear), BGR."""

MIN_SIDE_PX = 16
MAX_SIDE_PX = 8192
"""Bounds of a rendered image's width and height (pixels)."""

_TAG_CELLS = 8  # tag36h11: 6x6 data + a one-cell black border
_FLOOR_GREY = 150
_BODY_GREY = 70


@dataclass(frozen=True)
class CameraPose:
    """A pinhole camera above the floor, looking at ``look_at`` from ``height_m``.

    ``tilt_deg`` tips the optical axis away from the vertical (the camera moves toward -y of the
    yawed frame and looks back at ``look_at``); ``yaw_deg`` turns the image about the vertical
    (0: image ``u`` along floor +x, image up along floor +y). Intrinsics in pixels; the principal
    point defaults to the image centre.
    """

    height_m: float = 1.14
    look_at: tuple[float, float] = (0.0, 0.0)
    tilt_deg: float = 0.0
    yaw_deg: float = 0.0
    width: int = 1280
    height: int = 720
    fx: float = 900.0
    fy: float = 900.0
    cx: float | None = None
    cy: float | None = None

    def __post_init__(self) -> None:
        if not (math.isfinite(self.height_m) and self.height_m > 0.05):
            raise ValueError(f"height_m must be > 0.05, got {self.height_m!r}")
        if not -60.0 <= self.tilt_deg <= 60.0:
            raise ValueError(f"tilt_deg must be in [-60, 60], got {self.tilt_deg!r}")
        if not (
            MIN_SIDE_PX <= self.width <= MAX_SIDE_PX and MIN_SIDE_PX <= self.height <= MAX_SIDE_PX
        ):
            raise ValueError(
                f"image must be {MIN_SIDE_PX}..{MAX_SIDE_PX} px on each side, "
                f"got {self.width}x{self.height}"
            )
        if not (self.fx > 0 and self.fy > 0):
            raise ValueError("fx and fy must be > 0")

    def with_resolution(self, width: int, height: int) -> CameraPose:
        """The same camera read out at ``width`` x ``height`` pixels: the lens and the field of
        view are kept (focal lengths and principal point scale with the image), as a camera's
        lower-resolution mode (binning) does; the pose is unchanged. Cheaper to render and to
        detect in (4x fewer pixels at half the size), at the cost of smaller tags in pixels."""
        sx, sy = width / self.width, height / self.height
        return dataclasses.replace(
            self,
            width=int(width),
            height=int(height),
            fx=self.fx * sx,
            fy=self.fy * sy,
            cx=None if self.cx is None else (self.cx + 0.5) * sx - 0.5,
            cy=None if self.cy is None else (self.cy + 0.5) * sy - 0.5,
        )

    @property
    def camera_matrix(self) -> FloatArray:
        cx = (self.width - 1) / 2.0 if self.cx is None else self.cx
        cy = (self.height - 1) / 2.0 if self.cy is None else self.cy
        return np.array([[self.fx, 0.0, cx], [0.0, self.fy, cy], [0.0, 0.0, 1.0]])

    def extrinsics(self) -> tuple[FloatArray, FloatArray]:
        """``(R, t)``: world -> camera rotation and translation (camera z along the view)."""
        yaw = math.radians(self.yaw_deg)
        tilt = math.radians(self.tilt_deg)
        lx, ly = self.look_at
        back = self.height_m * math.tan(tilt)  # horizontal offset of the camera from look_at
        # "forward" of the yawed floor frame is (-sin yaw, cos yaw): image up at yaw 0 is +y
        fwd = np.array([-math.sin(yaw), math.cos(yaw), 0.0])
        centre = np.array([lx, ly, 0.0]) - back * fwd + np.array([0.0, 0.0, self.height_m])
        z_c = np.array([lx, ly, 0.0]) - centre
        z_c /= np.linalg.norm(z_c)
        x_c = np.cross(z_c, fwd)
        x_c /= np.linalg.norm(x_c)
        y_c = np.cross(z_c, x_c)
        rot = np.stack([x_c, y_c, z_c])
        return rot, -rot @ centre

    def floor_to_image(self) -> FloatArray:
        """3x3 homography: floor (x, y, 1) in metres -> image (u, v, 1) in pixels."""
        rot, t = self.extrinsics()
        h = self.camera_matrix @ np.column_stack([rot[:, 0], rot[:, 1], t])
        return np.asarray(h / h[2, 2], dtype=np.float64)

    def image_to_floor(self) -> FloatArray:
        """3x3 homography: image (u, v, 1) -> floor (x, y, 1); what a calibration estimates."""
        h = np.linalg.inv(self.floor_to_image())
        return np.asarray(h / h[2, 2], dtype=np.float64)


def floor_to_image(h_floor_to_img: FloatArray, xy: npt.ArrayLike) -> FloatArray:
    """Apply a floor->image homography to ``(n, 2)`` floor points; returns ``(n, 2)`` pixels."""
    pts = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    hom = np.column_stack([pts, np.ones(len(pts))]) @ h_floor_to_img.T
    return np.asarray(hom[:, :2] / hom[:, 2:3], dtype=np.float64)


@dataclass(frozen=True)
class Occluder:
    """A dark image-plane rectangle (a person's arm, a cable) drawn over the scene, pixels."""

    u0: int
    v0: int
    u1: int
    v1: int
    grey: int = 30


@dataclass
class Renderer:
    """Renders frames of robots seen by ``camera``.

    Args:
        camera: the camera's pose and intrinsics.
        tag_size_m: edge of the tag's black square (m).
        body_radius_m: radius of the robot's disc (m).
        mode: ``"tag"`` (AprilTag tag36h11 per robot) or ``"patches"`` (the paper's two colour
            patches, front red and rear blue).
        patch_radius_m, patch_offset_m: size of each patch and its distance from the axle centre
            along the heading (front +, rear -).
        tag_offsets: per tag id ``(forward_m, left_m, yaw_rad)`` of the tag centre relative to
            the axle centre (default: centred, top edge forward).
    """

    camera: CameraPose = field(default_factory=CameraPose)
    tag_size_m: float = 0.06
    body_radius_m: float = 0.075
    mode: str = "tag"
    patch_radius_m: float = 0.022
    patch_offset_m: float = 0.04
    tag_offsets: dict[int, tuple[float, float, float]] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.mode not in ("tag", "patches"):
            raise ValueError(f"mode must be 'tag' or 'patches', got {self.mode!r}")
        if not 0.0 < self.tag_size_m < 2.0 * self.body_radius_m:
            raise ValueError("tag_size_m must be > 0 and fit on the robot")
        self._h = self.camera.floor_to_image()
        self._dict = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_APRILTAG_36h11)
        self._tags: dict[tuple[int, int], Frame] = {}
        self._noise_bank: dict[float, list[npt.NDArray[np.float32]]] = {}
        # pixels per metre near the image centre: sets the source resolution of the tags
        lx, ly = self.camera.look_at
        c = floor_to_image(self._h, [(lx, ly), (lx + 0.01, ly)])
        self._px_per_m = float(np.linalg.norm(c[1] - c[0])) / 0.01

    @property
    def h_floor_to_image(self) -> FloatArray:
        return self._h.copy()

    @property
    def h_image_to_floor(self) -> FloatArray:
        """The true image->floor homography of this camera (what calibration estimates)."""
        return self.camera.image_to_floor()

    def _tag_image(self, tag_id: int, ppc: int) -> Frame:
        """Tag ``tag_id`` with a one-cell white quiet zone, ``ppc`` source pixels per cell."""
        key = (tag_id, ppc)
        cached = self._tags.get(key)
        if cached is not None:
            return cached
        marker = cv2.aruco.generateImageMarker(self._dict, tag_id, _TAG_CELLS * ppc)
        img = np.asarray(
            cv2.copyMakeBorder(marker, ppc, ppc, ppc, ppc, cv2.BORDER_CONSTANT, value=255),
            dtype=np.uint8,
        )
        self._tags[key] = img
        return img

    def _disc(self, frame: Frame, cx: float, cy: float, r: float, colour: Any) -> None:
        a = np.linspace(0.0, 2.0 * math.pi, 48, endpoint=False)
        pts = floor_to_image(self._h, np.column_stack([cx + r * np.cos(a), cy + r * np.sin(a)]))
        shift = 4  # sub-pixel polygon vertices (1/16 px)
        poly = np.round(pts * (1 << shift)).astype(np.int32).reshape(-1, 1, 2)
        cv2.fillPoly(frame, [poly], colour, lineType=cv2.LINE_AA, shift=shift)

    def _draw_tag(self, frame: Frame, tag_id: int, x: float, y: float, theta: float) -> None:
        fwd_m, left_m, yaw = self.tag_offsets.get(tag_id, (0.0, 0.0, 0.0))
        c, s = math.cos(theta), math.sin(theta)
        tx, ty = x + c * fwd_m - s * left_m, y + s * fwd_m + c * left_m
        psi = theta + yaw
        up = np.array([math.cos(psi), math.sin(psi)])  # tag's top edge direction (robot front)
        right = np.array([math.sin(psi), -math.cos(psi)])
        side_px = self.tag_size_m * self._px_per_m
        ppc = max(2, round(side_px / _TAG_CELLS))
        src = self._tag_image(tag_id, ppc)
        m_per_src = self.tag_size_m / (_TAG_CELLS * ppc)
        centre_src = (src.shape[1] - 1) / 2.0  # continuous coordinate of the tag's centre
        # source pixel (us, vs) -> floor: centre + (us - c) * m * right - (vs - c) * m * up
        a = np.array(
            [
                [m_per_src * right[0], -m_per_src * up[0], 0.0],
                [m_per_src * right[1], -m_per_src * up[1], 0.0],
                [0.0, 0.0, 1.0],
            ]
        )
        a[0, 2] = tx - centre_src * (a[0, 0] + a[0, 1])
        a[1, 2] = ty - centre_src * (a[1, 0] + a[1, 1])
        m = self._h @ a
        n = src.shape[0]
        corners = np.array([[-0.5, -0.5], [n - 0.5, -0.5], [n - 0.5, n - 0.5], [-0.5, n - 0.5]])
        hc = np.column_stack([corners, np.ones(4)]) @ m.T
        pix = hc[:, :2] / hc[:, 2:3]
        hgt, wid = frame.shape[:2]
        u0 = max(0, math.floor(pix[:, 0].min()) - 1)
        v0 = max(0, math.floor(pix[:, 1].min()) - 1)
        u1 = min(wid, math.ceil(pix[:, 0].max()) + 2)
        v1 = min(hgt, math.ceil(pix[:, 1].max()) + 2)
        if u1 <= u0 or v1 <= v0:
            return
        shift = np.array([[1.0, 0.0, -u0], [0.0, 1.0, -v0], [0.0, 0.0, 1.0]])
        roi = np.ascontiguousarray(
            frame[v0:v1, u0:u1] if frame.ndim == 2 else frame[v0:v1, u0:u1, 0]
        )
        cv2.warpPerspective(
            src,
            shift @ m,
            (u1 - u0, v1 - v0),
            dst=roi,
            flags=cv2.INTER_LINEAR,
            borderMode=cv2.BORDER_TRANSPARENT,
        )
        frame[v0:v1, u0:u1] = roi if frame.ndim == 2 else roi[:, :, None]

    def render(
        self,
        poses: npt.ArrayLike,
        tag_ids: Sequence[int] | None = None,
        *,
        blur_sigma_px: float = 0.0,
        noise_std: float = 0.0,
        gain: float = 1.0,
        gradient: float = 0.0,
        occluders: Iterable[Occluder] = (),
        rng: np.random.Generator | None = None,
        gray: bool = False,
    ) -> Frame:
        """One BGR frame of robots at ``poses`` (``(n, 3)``: x_m, y_m, theta_rad).

        ``tag_ids[i]`` is robot i's tag (tag mode). ``gain`` scales the brightness, ``gradient``
        adds a left-to-right lighting ramp (fraction of the brightness), ``noise_std`` is the
        standard deviation of additive Gaussian noise in grey levels (needs ``rng``; drawn from a
        bank of 4 noise images shifted at random, so a frame costs no new normal draws).
        ``gray``: a single-channel frame (tag mode; 3x cheaper, what a tag detector reads).
        """
        p = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
        if self.mode == "tag" and (tag_ids is None or len(tag_ids) != len(p)):
            raise ValueError("tag mode needs one tag id per robot")
        if gray and self.mode != "tag":
            raise ValueError("colour patches need a colour frame")
        cam = self.camera
        shape = (cam.height, cam.width) if gray else (cam.height, cam.width, 3)
        frame = np.full(shape, _FLOOR_GREY, dtype=np.uint8)
        for i, (x, y, theta) in enumerate(p.tolist()):
            self._disc(frame, x, y, self.body_radius_m, (_BODY_GREY,) * 3)
            if self.mode == "tag":
                assert tag_ids is not None
                self._draw_tag(frame, int(tag_ids[i]), x, y, theta)
            else:
                c, s = math.cos(theta), math.sin(theta)
                d = self.patch_offset_m
                self._disc(frame, x + c * d, y + s * d, self.patch_radius_m,
                           PATCH_COLOURS_BGR["front"])  # fmt: skip
                self._disc(frame, x - c * d, y - s * d, self.patch_radius_m,
                           PATCH_COLOURS_BGR["rear"])  # fmt: skip
        for occ in occluders:
            cv2.rectangle(frame, (occ.u0, occ.v0), (occ.u1, occ.v1), (occ.grey,) * 3, -1)
        if blur_sigma_px > 0.0:
            frame = np.asarray(cv2.GaussianBlur(frame, (0, 0), blur_sigma_px), dtype=np.uint8)
        if gain != 1.0 or gradient != 0.0 or noise_std > 0.0:
            img = frame.astype(np.float32)
            if gain != 1.0 or gradient != 0.0:
                ramp = gain * (1.0 + gradient * (np.arange(cam.width, dtype=np.float32)
                                                 / (cam.width - 1) - 0.5))  # fmt: skip
                img *= ramp[None, :, None] if img.ndim == 3 else ramp[None, :]
            if noise_std > 0.0:
                if rng is None:
                    raise ValueError("noise needs an rng")
                noise = self._noise(noise_std, rng)
                img += noise[:, :, None] if img.ndim == 3 else noise
            frame = np.clip(img + 0.5, 0, 255).astype(np.uint8)
        return frame

    def _noise(self, std: float, rng: np.random.Generator) -> npt.NDArray[np.float32]:
        """A (height, width) Gaussian noise image: one of a bank of 4, rolled at random."""
        cam = self.camera
        bank = self._noise_bank.get(std)
        if bank is None:
            shape = (cam.height, cam.width)
            bank = [rng.normal(0.0, std, shape).astype(np.float32) for _ in range(4)]
            self._noise_bank[std] = bank
        k, dv, du = (int(v) for v in rng.integers(0, (4, cam.height, cam.width)))
        return np.roll(bank[k], (dv, du), axis=(0, 1))


def write_video(path: str | Path, frames: Iterable[Frame], fps: float) -> int:
    """Write BGR ``frames`` to ``path`` as Motion-JPEG in an AVI (the opencv wheel's encoder);
    returns the number of frames written. Raises OSError if the writer cannot open."""
    it = iter(frames)
    first = next(it, None)
    if first is None:
        raise ValueError("no frames to write")
    h, w = first.shape[:2]
    if first.ndim == 2:  # the MJPG writer takes BGR
        first, it = _bgr(first), (_bgr(f) for f in it)
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter.fourcc(*"MJPG"), float(fps), (w, h))
    if not writer.isOpened():
        raise OSError(f"cannot open a video writer for {path}")
    writer.set(cv2.VIDEOWRITER_PROP_QUALITY, 100)
    n = 0
    try:
        for frame in _chain(first, it):
            writer.write(frame)
            n += 1
    finally:
        writer.release()
    return n


def _bgr(frame: Frame) -> Frame:
    return frame if frame.ndim == 3 else np.asarray(cv2.cvtColor(frame, cv2.COLOR_GRAY2BGR))


def _chain(first: Frame, rest: Iterable[Frame]) -> Iterable[Frame]:
    yield first
    yield from rest


def moving_scene(
    n: int,
    t_s: float,
    *,
    spacing_m: float = 0.19,
    centre: tuple[float, float] = (0.0, 0.0),
    radius_m: float = 0.03,
    speed_mps: float = 0.15,
) -> FloatArray:
    """``(n, 3)`` poses of ``n`` robots at time ``t_s`` for tests and benches: a grid (up to 8
    per row, ``spacing_m`` apart around ``centre``), each driving a circle of ``radius_m`` at
    ``speed_mps`` counter-clockwise (heading tangent), with a per-robot phase."""
    cols = min(n, 8)
    rows = (n + cols - 1) // cols
    out = np.empty((n, 3))
    omega = speed_mps / radius_m
    for i in range(n):
        r, c = divmod(i, cols)
        cx = centre[0] + (c - (cols - 1) / 2.0) * spacing_m
        cy = centre[1] + ((rows - 1) / 2.0 - r) * spacing_m
        phase = omega * t_s + 2.399963 * i  # golden angle: robots out of step
        out[i] = (
            cx + radius_m * math.cos(phase),
            cy + radius_m * math.sin(phase),
            math.remainder(phase + math.pi / 2.0, 2.0 * math.pi),
        )
    return out
