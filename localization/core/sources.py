"""Frame sources for ``formation camera``: a V4L2 device, a video file, a folder of images, a
stream URL (all through OpenCV's VideoCapture but the folder).

``open_source(spec)`` picks the kind from ``spec``:

* ``0``, ``1``, ... or ``/dev/videoN``: a camera device (V4L2 backend on Linux), live;
* a directory: its ``*.png``/``*.jpg``/``*.jpeg``/``*.bmp`` files in name order, at ``fps``;
* ``scheme://...`` (rtsp, http, udp, ...): a network stream, live;
* any other path: a video file (MJPG/XVID .avi, mp4v .mp4 with the opencv wheel) at its own
  frame rate.

A source only reads; pacing (a file at its own rate unless ``--fast``), capture timestamps and
frame dropping are the node's (localization.node.camera). ``read()`` blocks until the next frame and
returns None at the end of the stream (or when a live device stops delivering).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Protocol

import cv2
import numpy as np
import numpy.typing as npt

__all__ = ["FolderSource", "FrameSource", "SourceError", "VideoSource", "open_source"]

Frame = npt.NDArray[np.uint8]
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp")
DEFAULT_FPS = 30.0


class SourceError(OSError):
    """The source cannot be opened."""


class FrameSource(Protocol):
    description: str
    live: bool
    """True: frames arrive at the device's pace (no pacing); False: a recording (paced)."""
    fps: float

    def read(self) -> Frame | None: ...

    def skip(self) -> bool: ...

    def rewind(self) -> bool: ...

    def close(self) -> None: ...


class VideoSource:
    """cv2.VideoCapture on a device index, a device path, a file or a URL."""

    def __init__(self, spec: str, *, live: bool, fps: float | None = None) -> None:
        target: int | str = int(spec) if spec.isdigit() else spec
        if isinstance(target, int) or spec.startswith("/dev/video"):
            cap = cv2.VideoCapture(target, cv2.CAP_V4L2)
        else:
            cap = cv2.VideoCapture(target)
        if not cap.isOpened():
            raise SourceError(f"cannot open video source {spec!r}")
        self._cap = cap
        self.live = live
        native = float(cap.get(cv2.CAP_PROP_FPS) or 0.0)
        self.fps = fps if fps is not None else (native if 0.0 < native <= 1000.0 else DEFAULT_FPS)
        w = int(cap.get(cv2.CAP_PROP_FRAME_WIDTH))
        h = int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT))
        kind = (
            "device"
            if isinstance(target, int) or spec.startswith("/dev/")
            else ("stream" if "://" in spec else "file")
        )
        self.description = f"{kind} {spec} ({w}x{h} @ {self.fps:g} fps, {cap.getBackendName()})"

    def read(self) -> Frame | None:
        ok, frame = self._cap.read()
        return np.asarray(frame, dtype=np.uint8) if ok else None

    def skip(self) -> bool:
        """Drop the next frame without decoding it (a paced file running late)."""
        return bool(self._cap.grab())

    def rewind(self) -> bool:
        return bool(self._cap.set(cv2.CAP_PROP_POS_FRAMES, 0))

    def close(self) -> None:
        self._cap.release()


class FolderSource:
    """The images of a directory, in name order, at ``fps``."""

    def __init__(self, path: str, fps: float | None = None) -> None:
        files = sorted(
            p for p in Path(path).iterdir() if p.suffix.lower() in IMAGE_SUFFIXES and p.is_file()
        )
        if not files:
            raise SourceError(f"no {'/'.join(IMAGE_SUFFIXES)} images in {path}")
        self._files = files
        self._i = 0
        self.live = False
        self.fps = fps if fps is not None else DEFAULT_FPS
        self.description = f"folder {path} ({len(files)} images @ {self.fps:g} fps)"

    def read(self) -> Frame | None:
        while self._i < len(self._files):
            f = self._files[self._i]
            self._i += 1
            img = cv2.imread(str(f), cv2.IMREAD_COLOR)
            if img is not None:
                return np.asarray(img, dtype=np.uint8)
        return None

    def skip(self) -> bool:
        self._i += 1
        return self._i <= len(self._files)

    def rewind(self) -> bool:
        self._i = 0
        return True

    def close(self) -> None:
        self._files = []


def open_source(spec: str, *, fps: float | None = None) -> FrameSource:
    """Open the source named by ``spec`` (see the module docstring); SourceError if it fails.

    ``fps`` overrides the rate of a folder or a file (a device keeps its own).
    """
    if spec.isdigit() or spec.startswith("/dev/video"):
        return VideoSource(spec, live=True)
    if "://" in spec:
        return VideoSource(spec, live=True)
    if os.path.isdir(spec):
        return FolderSource(spec, fps)
    if not os.path.exists(spec):
        raise SourceError(f"no such file, directory or device: {spec!r}")
    return VideoSource(spec, live=False, fps=fps)
