"""Detections -> robot poses on the floor, through the calibrated image->floor homography.

The floor is a plane, so the 4 tag corners are mapped to the floor by the homography (after lens
undistortion when the calibration has intrinsics) and the pose is read there: the tag centre is
the mean of the 4 floor corners, the tag's heading is the direction from the bottom edge's
midpoint to the top edge's midpoint (top edge toward the robot's front), measured from +x
counter-clockwise. A per-marker 3-D pose (solvePnP) was measured ~9 mm off at these marker sizes
(docs/localization.md); the homography is what the calibration pins down.

Per-tag offsets turn the tag's pose into the axle centre's: robot heading = tag heading - yaw,
axle = tag centre - R(heading) (forward, left).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt

from localization.core.calibration import Calibration, TagOffset
from localization.core.detectors import PatchDetections, TagDetection
from robot_agent.core.kinematics import wrap_angle

__all__ = ["Measurement", "PoseEstimator"]

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True, slots=True)
class Measurement:
    """One robot's measured pose (axle centre, heading) in a frame; ``size_m`` = mean tag edge
    length on the floor (a plausibility check: a tag seen at the wrong scale is rejected)."""

    robot: str
    x: float
    y: float
    theta: float
    size_m: float = math.nan


_ZERO = TagOffset()


class PoseEstimator:
    """Maps detections of one frame to measurements, with ``calibration``'s homography."""

    def __init__(self, calibration: Calibration) -> None:
        self.cal = calibration
        self.h = np.array(calibration.homography, dtype=np.float64)
        self.k = (
            None
            if calibration.camera_matrix is None
            else np.array(calibration.camera_matrix, dtype=np.float64)
        )
        self.d = (
            None
            if calibration.dist_coeffs is None
            else np.array(calibration.dist_coeffs, dtype=np.float64)
        )
        self.robot_of_tag = calibration.robot_of_tag()
        self.unknown_tags = 0
        self.duplicates = 0

    def to_floor(self, pixels: npt.ArrayLike) -> FloatArray:
        """``(n, 2)`` image pixels -> ``(n, 2)`` floor metres (undistorted first if calibrated)."""
        pts = np.asarray(pixels, dtype=np.float64).reshape(-1, 2)
        if len(pts) == 0:
            return pts
        if self.k is not None:
            und = cv2.undistortPoints(pts.reshape(-1, 1, 2), self.k, self.d, P=self.k)
            pts = np.asarray(und, dtype=np.float64).reshape(-1, 2)
        hom = np.column_stack([pts, np.ones(len(pts))]) @ self.h.T
        return np.asarray(hom[:, :2] / hom[:, 2:3], dtype=np.float64)

    def tag_pose(self, corners_px: npt.ArrayLike) -> tuple[float, float, float, float]:
        """Floor pose of a tag from its canonical corners: ``(x, y, heading, edge_m)``."""
        tl, tr, br, bl = self.to_floor(corners_px).tolist()
        cx = (tl[0] + tr[0] + br[0] + bl[0]) / 4.0
        cy = (tl[1] + tr[1] + br[1] + bl[1]) / 4.0
        # top-edge midpoint minus bottom-edge midpoint, plus right edge minus left edge turned
        # +90 deg: both point along the tag's "up"; their sum averages the two directions.
        ux = (tl[0] + tr[0] - bl[0] - br[0]) - (tr[1] + br[1] - tl[1] - bl[1])
        uy = (tl[1] + tr[1] - bl[1] - br[1]) + (tr[0] + br[0] - tl[0] - bl[0])
        edge = (math.dist(tl, tr) + math.dist(tr, br) + math.dist(br, bl) + math.dist(bl, tl)) / 4.0
        return cx, cy, math.atan2(uy, ux), edge

    def from_tags(self, detections: Iterable[TagDetection]) -> list[Measurement]:
        """Measurements of the known robots; unknown tag ids and duplicated ids are counted and
        dropped (two tags with one id in a frame: neither can be trusted)."""
        by_tag: dict[int, list[TagDetection]] = {}
        for det in detections:
            if det.tag_id not in self.robot_of_tag:
                self.unknown_tags += 1
                continue
            by_tag.setdefault(det.tag_id, []).append(det)
        out = []
        for tag, dets in by_tag.items():
            if len(dets) > 1:
                self.duplicates += len(dets)
                continue
            rid = self.robot_of_tag[tag]
            tx, ty, psi, edge = self.tag_pose(dets[0].corners)
            out.append(self._axle(rid, tx, ty, psi, edge, self.cal.offsets.get(rid, _ZERO)))
        out.sort(key=lambda m: m.robot)
        return out

    @staticmethod
    def _axle(
        rid: str, tx: float, ty: float, psi: float, edge: float, off: TagOffset
    ) -> Measurement:
        theta = wrap_angle(psi - off.yaw_rad)
        c, s = math.cos(theta), math.sin(theta)
        x = tx - (c * off.forward_m - s * off.left_m)
        y = ty - (s * off.forward_m + c * off.left_m)
        return Measurement(rid, x, y, theta, edge)

    def from_patches(
        self,
        patches: PatchDetections,
        previous: Mapping[str, tuple[float, float]],
        *,
        pair_m: tuple[float, float] = (0.04, 0.14),
        gate_m: float = 0.15,
    ) -> list[Measurement]:
        """The paper's mode: pair each front patch with its nearest rear patch (centres
        ``pair_m`` apart on the floor), pose = midpoint, heading = rear -> front; identity by the
        nearest previous position of each robot (``previous``: robot -> (x, y)) within
        ``gate_m``, robots taken greedily by distance. Unmatched pairs are counted unknown."""
        front = self.to_floor(patches.front)
        rear = self.to_floor(patches.rear)
        pairs: list[tuple[float, float, float]] = []
        used: set[int] = set()
        for f in front.tolist():
            best, best_d = -1, math.inf
            for j, r in enumerate(rear.tolist()):
                d = math.dist(f, r)
                if j not in used and pair_m[0] <= d <= pair_m[1] and d < best_d:
                    best, best_d = j, d
            if best >= 0:
                used.add(best)
                r = rear[best]
                pairs.append(
                    ((f[0] + r[0]) / 2.0, (f[1] + r[1]) / 2.0, math.atan2(f[1] - r[1], f[0] - r[0]))
                )
        cand = sorted(
            (math.hypot(px - qx, py - qy), i, rid)
            for i, (px, py, _) in enumerate(pairs)
            for rid, (qx, qy) in previous.items()
        )
        taken_pair: set[int] = set()
        taken_robot: set[str] = set()
        out = []
        for d, i, rid in cand:
            if d > gate_m:
                break
            if i in taken_pair or rid in taken_robot:
                continue
            taken_pair.add(i)
            taken_robot.add(rid)
            x, y, th = pairs[i]
            out.append(Measurement(rid, x, y, th))
        self.unknown_tags += len(pairs) - len(out)
        out.sort(key=lambda m: m.robot)
        return out


def true_corner_pixels(
    h_floor_to_img: FloatArray, x: float, y: float, theta: float, size_m: float
) -> FloatArray:
    """Pixels of a tag's canonical corners for a tag centred at (x, y) facing ``theta`` (tests)."""
    up = np.array([math.cos(theta), math.sin(theta)])
    right = np.array([math.sin(theta), -math.cos(theta)])
    h = size_m / 2.0
    c = np.array([x, y])
    pts: Sequence[FloatArray] = [
        c - h * right + h * up, c + h * right + h * up, c + h * right - h * up,
        c - h * right - h * up,
    ]  # fmt: skip
    hom = np.column_stack([np.array(pts), np.ones(4)]) @ h_floor_to_img.T
    return np.asarray(hom[:, :2] / hom[:, 2:3], dtype=np.float64)
