"""``formation camera calibrate``: the image->floor homography from markers at known places.

Usage::

    formation camera calibrate --image FRAME.png --out calibration.toml
        --marker ID,X,Y[,YAW] ... [--marker-size M] [--point U,V,X,Y ...]
        --tags r1=0,r2=1,... [--tag-size 0.06] [--base OLD.toml] [--detector auto|apriltag|aruco]

Lay at least 4 floor markers (tag36h11 tags, ids not used by robots) flat at measured floor
coordinates, well spread over the arena, and take one frame (``--image``; a video file's first
frame also works). ``--marker ID,X,Y`` names a marker's centre on the floor (metres); with a
heading ``YAW`` (the direction its top edge faces, radians from +x CCW) and ``--marker-size``
(edge of its black square) its 4 corners are used too. ``--point U,V,X,Y`` adds a point clicked
by hand (pixel -> floor). The homography is fitted to every point (least squares, at least 4
points) and the reprojection error on the floor (mm) is printed and written to the file:
``reprojection_error_mm`` = RMS over the points. The robots' ``[tags]`` come from ``--tags`` or
from ``--base`` (an older calibration whose other settings are kept).
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt

from localization.core.calibration import Calibration, CalibrationError, load, write
from localization.core.detectors import TagDetection, make_detector
from localization.core.sources import SourceError, open_source

__all__ = ["Fit", "FloorMarker", "fit_homography", "main", "marker_points"]

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class FloorMarker:
    """A calibration marker on the floor: centre (m) and, optionally, its heading (rad)."""

    tag_id: int
    x: float
    y: float
    yaw: float | None = None


@dataclass(frozen=True)
class Fit:
    """A fitted homography and its per-point floor errors (mm)."""

    homography: FloatArray
    errors_mm: FloatArray
    n_points: int

    @property
    def rms_mm(self) -> float:
        return float(np.sqrt(np.mean(self.errors_mm**2)))

    @property
    def max_mm(self) -> float:
        return float(self.errors_mm.max())


def marker_points(
    detections: Sequence[TagDetection],
    markers: Mapping[int, FloorMarker],
    marker_size_m: float | None,
) -> tuple[FloatArray, FloatArray, list[int]]:
    """Matching (image px, floor m) point pairs from the detected markers; and the ids found."""
    img, floor, found = [], [], []
    for det in detections:
        mk = markers.get(det.tag_id)
        if mk is None:
            continue
        found.append(det.tag_id)
        img.append(det.corners.mean(axis=0))
        floor.append((mk.x, mk.y))
        if mk.yaw is not None and marker_size_m is not None:
            up = np.array([math.cos(mk.yaw), math.sin(mk.yaw)])
            right = np.array([math.sin(mk.yaw), -math.cos(mk.yaw)])
            h, c = marker_size_m / 2.0, np.array([mk.x, mk.y])
            for k, (a, b) in enumerate(((-1, 1), (1, 1), (1, -1), (-1, -1))):  # TL TR BR BL
                img.append(det.corners[k])
                floor.append(tuple(c + a * h * right + b * h * up))
    return (
        np.array(img, dtype=np.float64).reshape(-1, 2),
        np.array(floor, dtype=np.float64).reshape(-1, 2),
        sorted(found),
    )


def fit_homography(image_px: npt.ArrayLike, floor_m: npt.ArrayLike) -> Fit:
    """Least-squares image->floor homography over all points (>= 4, not collinear)."""
    src = np.asarray(image_px, dtype=np.float64).reshape(-1, 2)
    dst = np.asarray(floor_m, dtype=np.float64).reshape(-1, 2)
    if len(src) < 4 or len(src) != len(dst):
        raise ValueError(f"need at least 4 point pairs, got {len(src)}")
    h, _ = cv2.findHomography(src, dst, 0)
    if h is None or not np.all(np.isfinite(h)):
        raise ValueError("the points do not determine a homography (collinear?)")
    h = h / h[2, 2]
    hom = np.column_stack([src, np.ones(len(src))]) @ h.T
    err = np.linalg.norm(hom[:, :2] / hom[:, 2:3] - dst, axis=1) * 1e3
    return Fit(np.asarray(h, dtype=np.float64), err, len(src))


def _marker(text: str) -> FloorMarker:
    parts = text.split(",")
    try:
        if len(parts) not in (3, 4):
            raise ValueError
        vals = [float(p) for p in parts[1:]]
        if not all(math.isfinite(v) for v in vals):
            raise ValueError
        return FloorMarker(int(parts[0]), vals[0], vals[1], vals[2] if len(vals) == 3 else None)
    except ValueError:
        raise argparse.ArgumentTypeError(f"--marker ID,X,Y[,YAW], got {text!r}") from None


def _point(text: str) -> tuple[float, float, float, float]:
    try:
        u, v, x, y = (float(p) for p in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"--point U,V,X,Y, got {text!r}") from None
    return u, v, x, y


def _tags(text: str) -> dict[str, int]:
    out: dict[str, int] = {}
    try:
        for item in text.split(","):
            rid, tag = item.split("=")
            out[rid.strip()] = int(tag)
    except ValueError:
        raise argparse.ArgumentTypeError(f"--tags r1=0,r2=1,..., got {text!r}") from None
    return out


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="formation camera calibrate",
        description="Fit the image->floor homography from floor markers at known coordinates "
        "and write the calibration file (docs/localization.md).",
    )
    p.add_argument("--image", required=True, help="a frame (image file, video file or device)")
    p.add_argument("--out", required=True, help="calibration TOML to write")
    p.add_argument("--marker", type=_marker, action="append", default=[], metavar="ID,X,Y[,YAW]")
    p.add_argument("--marker-size", type=float, metavar="M", help="floor markers' black edge (m)")
    p.add_argument("--point", type=_point, action="append", default=[], metavar="U,V,X,Y")
    p.add_argument("--tags", type=_tags, help="robot tags: r1=0,r2=1,...")
    p.add_argument("--tag-size", type=float, default=0.06, help="robots' tag edge (m), 0.06")
    p.add_argument("--base", help="existing calibration whose tags and settings are kept")
    p.add_argument("--detector", choices=("auto", "apriltag", "aruco"), default="auto")
    return p


def _read_frame(path: str) -> npt.NDArray[np.uint8]:
    img = cv2.imread(path, cv2.IMREAD_COLOR)
    if img is not None:
        return np.asarray(img, dtype=np.uint8)
    src = open_source(path)
    try:
        frame = src.read()
    finally:
        src.close()
    if frame is None:
        raise SourceError(f"no frame in {path}")
    return frame


def main(argv: list[str]) -> int:
    """Entry point of ``formation camera calibrate``."""
    ns = build_parser().parse_args(argv)
    try:
        base = load(ns.base) if ns.base else None
        frame = _read_frame(ns.image)
    except (CalibrationError, SourceError) as exc:
        print(f"calibrate: {exc}", file=sys.stderr)
        return 2
    markers = {m.tag_id: m for m in ns.marker}
    img_pts, floor_pts = np.zeros((0, 2)), np.zeros((0, 2))
    found: list[int] = []
    if markers:
        detector = make_detector("tag36h11", ns.detector)
        print(f"calibrate: detector {detector.name}")
        img_pts, floor_pts, found = marker_points(detector.detect(frame), markers, ns.marker_size)
        missing = sorted(set(markers) - set(found))
        print(f"calibrate: markers found {found}" + (f", NOT found {missing}" if missing else ""))
    if ns.point:
        pts = np.array(ns.point, dtype=np.float64)
        img_pts = np.vstack([img_pts, pts[:, :2]])
        floor_pts = np.vstack([floor_pts, pts[:, 2:]])
    try:
        fit = fit_homography(img_pts, floor_pts)
    except ValueError as exc:
        print(f"calibrate: {exc}", file=sys.stderr)
        return 1
    tags = ns.tags if ns.tags is not None else (dict(base.tags) if base is not None else None)
    if not tags:
        print("calibrate: give the robots' tags (--tags r1=0,...) or --base", file=sys.stderr)
        return 2
    h = tuple((float(r[0]), float(r[1]), float(r[2])) for r in fit.homography.tolist())
    try:
        if base is not None:
            cal = dataclasses.replace(
                base, homography=h, tags=tags, reprojection_error_mm=fit.rms_mm
            )
        else:
            cal = Calibration(
                homography=h, tags=tags, tag_size_m=ns.tag_size, reprojection_error_mm=fit.rms_mm
            )
    except CalibrationError as exc:
        print(f"calibrate: {exc}", file=sys.stderr)
        return 1
    write(cal, ns.out)
    print(
        f"reprojection error: rms {fit.rms_mm:.2f} mm, max {fit.max_mm:.2f} mm "
        f"over {fit.n_points} points; wrote {ns.out}"
    )
    return 0
