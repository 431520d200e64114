"""The camera calibration file (TOML): load, validate, write.

Format (docs/localization.md)::

    family = "tag36h11"          # or "patches" (the paper's two colour patches)
    tag_size_m = 0.06            # edge of the tag's black square
    detector = "auto"            # auto | apriltag | aruco  (auto: pupil-apriltags if installed)
    homography = [[h11, h12, h13], [h21, h22, h23], [h31, h32, h33]]  # image px -> floor m
    # optional lens model: pixels are undistorted before the homography
    camera_matrix = [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]
    dist_coeffs = [k1, k2, p1, p2, k3]
    reprojection_error_mm = 0.8  # written by `formation camera calibrate` (informative)

    [tags]                       # robot id -> tag id
    r1 = 0
    r2 = 1

    [offsets.r2]                 # optional: tag centre relative to the axle centre
    forward_m = 0.01
    left_m = 0.0
    yaw_rad = 0.0                # tag's top edge relative to the robot's front (CCW)

    [tracker]                    # optional, defaults below
    max_speed_mps = 1.0
    max_turn_radps = 12.0
    lost_after_s = 0.5

    [start]                      # patches mode: each robot's approximate start (x, y), metres
    r1 = [0.4, 0.0]

Image pixels have ``u`` right and ``v`` down with pixel centres at integer coordinates (OpenCV's
convention); the floor is right-handed seen from above, headings from +x counter-clockwise.
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from bus_schemas import keys

__all__ = [
    "FAMILIES",
    "Calibration",
    "CalibrationError",
    "TagOffset",
    "TrackerParams",
    "dumps",
    "load",
    "loads",
    "write",
]

FAMILIES = ("tag36h11", "patches")
DETECTORS = ("auto", "apriltag", "aruco")
TAG36H11_MAX_ID = 586


class CalibrationError(ValueError):
    """The calibration file is missing, unreadable or invalid (the message says where)."""


@dataclass(frozen=True)
class TagOffset:
    """Tag centre relative to the robot's axle centre (robot frame) and tag yaw vs the front."""

    forward_m: float = 0.0
    left_m: float = 0.0
    yaw_rad: float = 0.0


@dataclass(frozen=True)
class TrackerParams:
    """Plausibility limits of the tracker (localization.core.tracker)."""

    max_speed_mps: float = 1.0
    max_turn_radps: float = 12.0
    lost_after_s: float = 0.5
    reacquire_after: int = 3
    jump_slack_m: float = 0.03
    turn_slack_rad: float = 0.35


@dataclass(frozen=True)
class Calibration:
    """A validated calibration (see the module docstring for the meaning of each field)."""

    homography: tuple[tuple[float, float, float], ...]
    tags: Mapping[str, int]
    family: str = "tag36h11"
    tag_size_m: float = 0.06
    detector: str = "auto"
    camera_matrix: tuple[tuple[float, float, float], ...] | None = None
    dist_coeffs: tuple[float, ...] | None = None
    offsets: Mapping[str, TagOffset] = field(default_factory=dict)
    tracker: TrackerParams = field(default_factory=TrackerParams)
    start: Mapping[str, tuple[float, float]] = field(default_factory=dict)
    reprojection_error_mm: float | None = None

    def __post_init__(self) -> None:
        _validate(self)

    @property
    def robots(self) -> list[str]:
        """Robot ids this calibration tracks, sorted."""
        if self.family == "patches":
            return sorted(self.start)
        return sorted(self.tags)

    def robot_of_tag(self) -> dict[int, str]:
        return {tag: rid for rid, tag in self.tags.items()}


def _fail(where: str, what: str) -> CalibrationError:
    return CalibrationError(f"{where}: {what}")


def _finite(v: object, where: str) -> float:
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(float(v)):
        raise _fail(where, f"must be a finite number, got {v!r}")
    return float(v)


def _matrix(v: object, where: str) -> tuple[tuple[float, float, float], ...]:
    if not isinstance(v, list | tuple) or len(v) != 3:
        raise _fail(where, "must be a 3x3 array of numbers")
    rows = []
    for i, row in enumerate(v):
        if not isinstance(row, list | tuple) or len(row) != 3:
            raise _fail(where, "must be a 3x3 array of numbers")
        r = tuple(_finite(x, f"{where}[{i}]") for x in row)
        rows.append((r[0], r[1], r[2]))
    return tuple(rows)


def _det3(m: tuple[tuple[float, float, float], ...]) -> float:
    (a, b, c), (d, e, f), (g, h, i) = m
    return a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g)


def _validate(cal: Calibration) -> None:
    h = _matrix(cal.homography, "homography")
    scale = max(abs(x) for row in h for x in row)
    if scale == 0.0 or abs(_det3(h)) <= 1e-15 * scale**3:
        raise _fail("homography", "is singular")
    object.__setattr__(cal, "homography", h)
    if cal.family not in FAMILIES:
        raise _fail("family", f"must be one of {FAMILIES}, got {cal.family!r}")
    if cal.detector not in DETECTORS:
        raise _fail("detector", f"must be one of {DETECTORS}, got {cal.detector!r}")
    size = _finite(cal.tag_size_m, "tag_size_m")
    if not 0.005 <= size <= 1.0:
        raise _fail("tag_size_m", f"must be in [0.005, 1] m, got {size}")
    seen: dict[int, str] = {}
    for rid, tag in cal.tags.items():
        if not keys.is_robot_id(rid):
            raise _fail(f"tags.{rid}", f"robot id must match {keys.ROBOT_ID_PATTERN}")
        if isinstance(tag, bool) or not isinstance(tag, int) or not 0 <= tag <= TAG36H11_MAX_ID:
            raise _fail(f"tags.{rid}", f"tag id must be an int in [0, {TAG36H11_MAX_ID}]")
        if tag in seen:
            raise _fail(f"tags.{rid}", f"tag {tag} is already robot {seen[tag]}'s")
        seen[tag] = rid
    if cal.family == "tag36h11" and not cal.tags:
        raise _fail("tags", "needs at least one robot id = tag id")
    if cal.family == "patches" and not cal.start:
        raise _fail("start", "patches mode needs each robot's start (x, y)")
    for rid in cal.offsets:
        if rid not in cal.tags:
            raise _fail(f"offsets.{rid}", "robot is not in [tags]")
    for rid, xy in cal.start.items():
        if not keys.is_robot_id(rid):
            raise _fail(f"start.{rid}", f"robot id must match {keys.ROBOT_ID_PATTERN}")
        if len(xy) != 2:
            raise _fail(f"start.{rid}", "must be [x, y]")
    if cal.camera_matrix is not None:
        k = _matrix(cal.camera_matrix, "camera_matrix")
        if not (k[0][0] > 0 and k[1][1] > 0 and k[2] == (0.0, 0.0, 1.0)):
            raise _fail("camera_matrix", "must be [[fx,0,cx],[0,fy,cy],[0,0,1]] with fx, fy > 0")
        object.__setattr__(cal, "camera_matrix", k)
    if cal.dist_coeffs is not None:
        d = tuple(_finite(x, "dist_coeffs") for x in cal.dist_coeffs)
        if len(d) not in (4, 5, 8, 12, 14):
            raise _fail("dist_coeffs", "must have 4, 5, 8, 12 or 14 coefficients")
        if cal.camera_matrix is None:
            raise _fail("dist_coeffs", "needs camera_matrix")
        object.__setattr__(cal, "dist_coeffs", d)
    t = cal.tracker
    for name in ("max_speed_mps", "max_turn_radps", "lost_after_s", "jump_slack_m"):
        if not _finite(getattr(t, name), f"tracker.{name}") > 0.0:
            raise _fail(f"tracker.{name}", "must be > 0")


_TOP_KEYS = {
    "family", "tag_size_m", "detector", "homography", "camera_matrix", "dist_coeffs",
    "reprojection_error_mm", "tags", "offsets", "tracker", "start", "image_size",
}  # fmt: skip


def _table(data: Mapping[str, Any], name: str) -> Mapping[str, Any]:
    v = data.get(name, {})
    if not isinstance(v, dict):
        raise _fail(name, "must be a table")
    return v


def from_mapping(data: Mapping[str, Any]) -> Calibration:
    """A Calibration from a parsed TOML document; CalibrationError on anything invalid."""
    unknown = set(data) - _TOP_KEYS
    if unknown:
        raise _fail("file", f"unknown keys {sorted(unknown)}")
    if "homography" not in data:
        raise _fail("homography", "is required")
    tags: dict[str, int] = {}
    for rid, tag in _table(data, "tags").items():
        if isinstance(tag, bool) or not isinstance(tag, int):
            raise _fail(f"tags.{rid}", f"tag id must be an int, got {tag!r}")
        tags[rid] = tag
    offsets: dict[str, TagOffset] = {}
    for rid, off in _table(data, "offsets").items():
        if not isinstance(off, dict) or set(off) - {"forward_m", "left_m", "yaw_rad"}:
            raise _fail(f"offsets.{rid}", "keys: forward_m, left_m, yaw_rad")
        offsets[rid] = TagOffset(**{k: _finite(v, f"offsets.{rid}.{k}") for k, v in off.items()})
    tr = _table(data, "tracker")
    fields = TrackerParams.__dataclass_fields__
    if set(tr) - set(fields):
        raise _fail("tracker", f"unknown keys {sorted(set(tr) - set(fields))}")
    tracker_kw: dict[str, Any] = {}
    for k, v in tr.items():
        tracker_kw[k] = int(v) if k == "reacquire_after" else _finite(v, f"tracker.{k}")
    start: dict[str, tuple[float, float]] = {}
    for rid, xy in _table(data, "start").items():
        if not isinstance(xy, list) or len(xy) != 2:
            raise _fail(f"start.{rid}", "must be [x, y]")
        start[rid] = (_finite(xy[0], f"start.{rid}"), _finite(xy[1], f"start.{rid}"))
    err = data.get("reprojection_error_mm")
    return Calibration(
        homography=data["homography"],
        tags=tags,
        family=data.get("family", "tag36h11"),
        tag_size_m=data.get("tag_size_m", 0.06),
        detector=data.get("detector", "auto"),
        camera_matrix=data.get("camera_matrix"),
        dist_coeffs=tuple(data["dist_coeffs"]) if "dist_coeffs" in data else None,
        offsets=offsets,
        tracker=TrackerParams(**tracker_kw),
        start=start,
        reprojection_error_mm=None if err is None else _finite(err, "reprojection_error_mm"),
    )


def loads(text: str) -> Calibration:
    """Parse and validate calibration TOML text."""
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise CalibrationError(f"not valid TOML: {exc}") from None
    return from_mapping(data)


def load(path: str | Path) -> Calibration:
    """Read and validate a calibration file; CalibrationError (a ValueError) if invalid."""
    try:
        text = Path(path).read_text(encoding="utf-8")
    except OSError as exc:
        raise CalibrationError(f"{path}: {exc}") from None
    try:
        return loads(text)
    except CalibrationError as exc:
        raise CalibrationError(f"{path}: {exc}") from None


def _num(x: float) -> str:
    return repr(float(x))


def _rows(m: tuple[tuple[float, float, float], ...]) -> str:
    return "[\n" + "".join(f"  [{', '.join(_num(x) for x in row)}],\n" for row in m) + "]"


def dumps(cal: Calibration) -> str:
    """The calibration as TOML text (``loads(dumps(c)) == c``)."""
    out = [
        "# Camera calibration for `formation camera` (docs/localization.md).",
        f'family = "{cal.family}"',
        f"tag_size_m = {_num(cal.tag_size_m)}",
        f'detector = "{cal.detector}"',
        "# image pixels (u right, v down, pixel centres at integers) -> floor metres",
        f"homography = {_rows(cal.homography)}",
    ]
    if cal.camera_matrix is not None:
        out.append(f"camera_matrix = {_rows(cal.camera_matrix)}")
    if cal.dist_coeffs is not None:
        out.append(f"dist_coeffs = [{', '.join(_num(x) for x in cal.dist_coeffs)}]")
    if cal.reprojection_error_mm is not None:
        out.append(f"reprojection_error_mm = {_num(cal.reprojection_error_mm)}")
    out.append("\n[tags]")
    out.extend(f"{rid} = {tag}" for rid, tag in sorted(cal.tags.items()))
    for rid, off in sorted(cal.offsets.items()):
        out.append(f"\n[offsets.{rid}]")
        out.append(f"forward_m = {_num(off.forward_m)}")
        out.append(f"left_m = {_num(off.left_m)}")
        out.append(f"yaw_rad = {_num(off.yaw_rad)}")
    if cal.tracker != TrackerParams():
        out.append("\n[tracker]")
        for name in TrackerParams.__dataclass_fields__:
            v = getattr(cal.tracker, name)
            out.append(f"{name} = {v if isinstance(v, int) else _num(v)}")
    if cal.start:
        out.append("\n[start]")
        out.extend(f"{rid} = [{_num(x)}, {_num(y)}]" for rid, (x, y) in sorted(cal.start.items()))
    return "\n".join(out) + "\n"


def write(cal: Calibration, path: str | Path) -> None:
    """Write ``cal`` to ``path`` (atomically: a temporary file then a rename)."""
    p = Path(path)
    tmp = p.with_name(p.name + ".tmp")
    tmp.write_text(dumps(cal), encoding="utf-8")
    tmp.replace(p)
