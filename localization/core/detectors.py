"""Marker detectors: image -> tag corners (or colour-patch centroids), in one pixel convention.

Every detector returns corners in **OpenCV's pixel convention** (pixel centres at integer
coordinates, ``u`` right, ``v`` down) and in the tag's **canonical order TL, TR, BR, BL**: the
corners of the tag image as printed (top-left first, clockwise on the image), whatever the tag's
rotation in the frame. The tag's top edge (TL -> TR) faces the robot's front.

* ``pupil-apriltags`` (AprilTag 3, tag36h11): the best detector measured here (0.30 mm /
  0.08 deg on rendered 720p frames). Its corners come as (TR, TL, BL, BR) of the canonical
  order and +0.5 px (pixel centres at .5): both are undone here (else a ~1.7 mm bias).
  No aarch64/armv7 wheel.
* OpenCV ``cv2.aruco.ArucoDetector`` with ``DICT_APRILTAG_36h11`` and sub-pixel corner refinement:
  the fallback (aarch64 has opencv-python-headless wheels); 0.59 mm / 0.49 deg measured.
* Colour patches (the paper's setup): two discs per robot, front red and rear blue, found by HSV
  thresholds and connected components; no identity (the tracker gives it, localization.core.pose).

:func:`make_detector` picks ``pupil-apriltags`` when importable, else OpenCV, and says which.
"""

from __future__ import annotations

import importlib.metadata
import threading
from dataclasses import dataclass
from typing import Any, Protocol

import cv2
import numpy as np
import numpy.typing as npt

__all__ = [
    "ArucoTagDetector",
    "PatchDetections",
    "PatchDetector",
    "PupilTagDetector",
    "RoiTagDetector",
    "TagDetection",
    "TagDetector",
    "make_detector",
    "pupil_available",
]

Frame = npt.NDArray[np.uint8]
FloatArray = npt.NDArray[np.float64]

# pupil-apriltags gives (TR, TL, BL, BR) of the canonical order (measured on rendered frames)
_PUPIL_TO_CANONICAL = [1, 0, 3, 2]  # canonical TL,TR,BR,BL = pupil[1], pupil[0], pupil[3], pupil[2]


@dataclass(frozen=True, slots=True)
class TagDetection:
    """One tag: its id and its 4 corners ``(4, 2)`` in pixels, canonical order TL, TR, BR, BL."""

    tag_id: int
    corners: FloatArray


class TagDetector(Protocol):
    name: str

    def detect(self, gray: Frame) -> list[TagDetection]: ...


def _gray(frame: Frame) -> Frame:
    if frame.ndim == 3:
        return np.asarray(cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY), dtype=np.uint8)
    return frame


def pupil_available() -> bool:
    """True if ``pupil_apriltags`` imports (x86_64 wheels; built from source elsewhere)."""
    try:
        import pupil_apriltags  # noqa: F401
    except ImportError:
        return False
    return True


def _version(dist: str) -> str:
    try:
        return importlib.metadata.version(dist)
    except importlib.metadata.PackageNotFoundError:
        return "?"


_PUPIL_SHARED: dict[tuple[float, int], tuple[Any, threading.Lock]] = {}
_PUPIL_SHARED_LOCK = threading.Lock()


def _shared_pupil(quad_decimate: float, nthreads: int) -> tuple[Any, threading.Lock]:
    """One pupil-apriltags detector per configuration and process, never destroyed.

    Measured here (pupil-apriltags 1.0.4.post11): with ``nthreads=1``, destroying a detector
    after whole-frame detections crashed in ``apriltag_detector_destroy`` (segfault / heap
    corruption; upstream pupil-labs/apriltags issue 39 reports the same corruption) within a few
    dozen create/detect/destroy cycles; one long-lived detector ran 600 detections cleanly. So
    detectors are shared and kept (their ``__del__`` does nothing); the lock serialises callers.
    """
    key = (quad_decimate, nthreads)
    with _PUPIL_SHARED_LOCK:
        shared = _PUPIL_SHARED.get(key)
        if shared is None:
            import pupil_apriltags

            class _Kept(pupil_apriltags.Detector):  # type: ignore[misc]
                def __del__(self) -> None:  # never call apriltag_detector_destroy (see above)
                    pass

            det = _Kept(
                families="tag36h11",
                nthreads=nthreads,
                quad_decimate=quad_decimate,
                quad_sigma=0.0,
                refine_edges=1,
                decode_sharpening=0.25,
            )
            shared = (det, threading.Lock())
            _PUPIL_SHARED[key] = shared
        return shared


class PupilTagDetector:
    """tag36h11 with pupil-apriltags (``quad_decimate`` 2: ~33 ms per 720p frame, one thread)."""

    def __init__(self, *, quad_decimate: float = 2.0, nthreads: int = 1) -> None:
        self._det, self._lock = _shared_pupil(quad_decimate, nthreads)
        version = _version("pupil-apriltags")
        self.name = f"pupil-apriltags {version} tag36h11 (quad_decimate {quad_decimate:g})"

    def detect(self, frame: Frame) -> list[TagDetection]:
        gray = np.ascontiguousarray(_gray(frame))
        out = []
        with self._lock:
            found = self._det.detect(gray)
        for d in found:
            if d.hamming > 1:  # more than one corrected bit: not trusted
                continue
            corners = np.asarray(d.corners, dtype=np.float64)[_PUPIL_TO_CANONICAL] - 0.5
            out.append(TagDetection(int(d.tag_id), corners))
        return out


class ArucoTagDetector:
    """tag36h11 with OpenCV's ArucoDetector (``DICT_APRILTAG_36h11``, sub-pixel corners)."""

    def __init__(self) -> None:
        params = cv2.aruco.DetectorParameters()
        params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
        dictionary = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_APRILTAG_36h11)
        self._det = cv2.aruco.ArucoDetector(dictionary, params)
        self.name = f"opencv-aruco {cv2.__version__} DICT_APRILTAG_36h11 (CORNER_REFINE_SUBPIX)"

    def detect(self, frame: Frame) -> list[TagDetection]:
        corners, ids, _ = self._det.detectMarkers(_gray(frame))
        if ids is None:
            return []
        return [
            TagDetection(int(i), np.asarray(c, dtype=np.float64).reshape(4, 2))
            for c, i in zip(corners, ids.ravel().tolist(), strict=True)
        ]


@dataclass(frozen=True, slots=True)
class PatchDetections:
    """Centroids ``(n, 2)`` pixels of the front (red) and rear (blue) patches of one frame."""

    front: FloatArray
    rear: FloatArray


class PatchDetector:
    """The paper's two colour patches: HSV thresholds + connected components (no identity)."""

    name = "colour patches (HSV + connected components)"

    def __init__(self, *, min_area_px: int = 12, max_area_px: int = 20000) -> None:
        self.min_area_px = min_area_px
        self.max_area_px = max_area_px

    def _centroids(self, mask: Frame) -> FloatArray:
        n, _, stats, cents = cv2.connectedComponentsWithStats(mask, connectivity=8)
        keep = [
            i
            for i in range(1, n)
            if self.min_area_px <= stats[i, cv2.CC_STAT_AREA] <= self.max_area_px
        ]
        return np.asarray(cents[keep], dtype=np.float64).reshape(-1, 2)

    def detect(self, frame: Frame) -> PatchDetections:
        if frame.ndim != 3:
            raise ValueError("colour patches need a colour (BGR) frame")
        hsv = cv2.cvtColor(frame, cv2.COLOR_BGR2HSV)
        red = np.asarray(cv2.inRange(hsv, (0, 110, 60), (10, 255, 255)), dtype=np.uint8)
        red |= np.asarray(cv2.inRange(hsv, (170, 110, 60), (180, 255, 255)), dtype=np.uint8)
        blue = np.asarray(cv2.inRange(hsv, (95, 110, 60), (130, 255, 255)), dtype=np.uint8)
        return PatchDetections(self._centroids(red), self._centroids(blue))


def make_detector(
    family: str = "tag36h11",
    choice: str = "auto",
    *,
    windows: bool = False,
    expected: set[int] | None = None,
) -> Any:
    """The detector for ``family`` (``tag36h11`` or ``patches``).

    ``choice``: ``auto`` (pupil-apriltags if it imports, else OpenCV), ``apriltag`` (require
    pupil-apriltags), ``aruco`` (OpenCV). ``windows``: wrap it in :class:`RoiTagDetector`
    (``expected``: the tag ids of the robots). The returned object has a ``name`` saying which.
    """
    if family == "patches":
        return PatchDetector()
    if family != "tag36h11":
        raise ValueError(f"unknown family {family!r}")
    inner: TagDetector
    if choice == "aruco" or (choice == "auto" and not pupil_available()):
        inner = ArucoTagDetector()
    elif choice in ("auto", "apriltag"):
        inner = PupilTagDetector()
    else:
        raise ValueError(f"unknown detector {choice!r}")
    # Windows only for pupil-apriltags: OpenCV's ArucoDetector on small crops was measured
    # ~50x slower per pixel than on the whole frame (3 windows: ~200 ms).
    if windows and isinstance(inner, PupilTagDetector):
        return RoiTagDetector(inner, expected=expected)
    return inner


class RoiTagDetector:
    """Speeds a tag detector up by looking only around where tags were in the previous frame.

    A full-frame detection runs on the first frame, every ``full_every`` frames (new tags,
    forged duplicates, robots that entered the view), whenever a tag of ``expected`` seen
    in the previous frame is not found again in its window (so a robot lost by the windows is
    looked for in the whole frame of the same image), and every ``search_every`` frames while a
    robot of ``expected`` is missing (covered, or out of view: it is found again within
    ``search_every`` frames of reappearing, at the cost of a whole-frame detection that often).
    Windows are the previous corners' bounding box grown by ``margin`` tag edges (motion between
    frames) plus ``min_margin_px``.
    The same tag found in two overlapping windows at the same place is kept once; found at two
    different places it is kept twice (the pose estimator then drops both as duplicates).

    Stateful (the previous frame's corners and a frame counter), no clock.
    """

    def __init__(
        self,
        inner: TagDetector,
        *,
        expected: set[int] | None = None,
        full_every: int = 15,
        search_every: int = 3,
        margin: float = 0.6,
        min_margin_px: int = 12,
    ) -> None:
        self.inner = inner
        self.expected = expected
        self.full_every = max(1, full_every)
        self.search_every = max(1, search_every)
        self._last_full = 0
        self.margin = margin
        self.min_margin_px = min_margin_px
        self.name = f"{inner.name} + windows (full frame every {self.full_every})"
        self._prev: list[TagDetection] = []
        self._k = 0
        self.full_frames = 0
        self.window_frames = 0

    def _windows(self, shape: tuple[int, ...]) -> list[tuple[int, int, int, int]]:
        h, w = shape[:2]
        boxes = []
        for det in self._prev:
            lo, hi = det.corners.min(axis=0), det.corners.max(axis=0)
            edge = float(np.max(hi - lo))
            m = edge * self.margin + self.min_margin_px
            # even origins: the detector's 2x decimation grid stays that of the full frame
            u0, v0 = max(0, int(lo[0] - m) & ~1), max(0, int(lo[1] - m) & ~1)
            u1, v1 = min(w, int(hi[0] + m) + 1), min(h, int(hi[1] + m) + 1)
            if u1 - u0 >= 8 and v1 - v0 >= 8:
                boxes.append((u0, v0, u1, v1))
        return boxes

    def detect(self, frame: Frame) -> list[TagDetection]:
        gray = _gray(frame)
        self._k += 1
        full = self._k == 1 or self._k % self.full_every == 0 or not self._prev
        out: list[TagDetection] = []
        if not full:
            self.window_frames += 1
            for u0, v0, u1, v1 in self._windows(gray.shape):
                crop = np.ascontiguousarray(gray[v0:v1, u0:u1])
                for d in self.inner.detect(crop):
                    corners = d.corners + np.array([u0, v0], dtype=np.float64)
                    if any(
                        o.tag_id == d.tag_id and float(np.abs(o.corners - corners).max()) < 2.0
                        for o in out
                    ):
                        continue  # the same tag seen through two overlapping windows
                    out.append(TagDetection(d.tag_id, corners))
            found = {d.tag_id for d in out}
            wanted = {d.tag_id for d in self._prev}
            if self.expected is not None:
                wanted &= self.expected
            if not wanted <= found:
                full = True  # a robot slipped out of its window: look everywhere
            elif (
                self.expected is not None
                and not self.expected <= found
                and self._k - self._last_full >= self.search_every
            ):
                full = True  # a robot is missing: look for it now and then
        if full:
            self._last_full = self._k
            self.full_frames += 1
            out = self.inner.detect(gray)
        self._prev = out
        return out
