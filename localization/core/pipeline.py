"""The tracker's per-frame pipeline: detector -> floor poses -> tracker (no Zenoh, no clock).

``CameraPipeline(calibration).process(frame, stamp_s, clock, media_s)`` is what
``formation camera`` runs on every frame (localization.node.camera is its shell); tests, benches and
any other runtime can call it directly.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from localization.core.calibration import Calibration
from localization.core.detectors import PatchDetections, make_detector
from localization.core.pose import Measurement, PoseEstimator
from localization.core.tracker import Tracker

__all__ = ["CameraPipeline", "FrameResult"]

Frame = npt.NDArray[np.uint8]


@dataclass(frozen=True, slots=True)
class FrameResult:
    """One processed frame: capture time, what to publish, detection time (s)."""

    stamp_s: float
    measurements: list[Measurement]
    detect_s: float


class CameraPipeline:
    """Frame -> published measurements: detector, floor mapping, tracker. No Zenoh, no clock
    reads (the capture time is passed in)."""

    def __init__(
        self,
        calibration: Calibration,
        detector_choice: str | None = None,
        *,
        windows: bool = True,
    ) -> None:
        self.cal = calibration
        self.detector = make_detector(
            calibration.family,
            detector_choice or calibration.detector,
            windows=windows,
            expected=set(calibration.tags.values()),
        )
        self.estimator = PoseEstimator(calibration)
        self.tracker = Tracker(
            calibration.robots,
            calibration.tracker,
            tag_size_m=calibration.tag_size_m if calibration.family == "tag36h11" else None,
        )
        for rid, (x, y) in calibration.start.items():
            self.tracker.seed(rid, x, y, -math.inf)

    def measure(self, frame: Frame) -> list[Measurement]:
        """Detections of one frame as floor measurements (before the tracker)."""
        if self.cal.family == "patches":
            det = self.detector.detect(frame)
            assert isinstance(det, PatchDetections)
            return self.estimator.from_patches(det, self.tracker.positions())
        return self.estimator.from_tags(self.detector.detect(frame))

    def process(
        self,
        frame: Frame,
        stamp_s: float,
        clock: Callable[[], float],
        media_s: float | None = None,
    ) -> FrameResult:
        """One frame captured at ``stamp_s``. ``media_s``: the frame's time in a recording
        (frame index / fps): the tracker's motion limits then use it, so a file read faster or
        slower than real time (``--fast``, a loaded machine) is judged at the speed it was
        recorded; default: the capture time (live sources)."""
        start = clock()
        meas = self.measure(frame)
        detect_s = clock() - start
        t_track = stamp_s if media_s is None else media_s
        return FrameResult(stamp_s, self.tracker.update(t_track, meas), detect_s)

    def rejects(self) -> dict[str, int]:
        st = self.tracker.stats()
        return {
            "jump": st["jumps"],
            "bad_size": st["bad_size"],
            "unknown": self.estimator.unknown_tags,
            "duplicate": self.estimator.duplicates,
        }
