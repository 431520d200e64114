"""``formation camera``: the overhead-camera tracker as a process: its frame thread
(:class:`Grabber`) and its loop side (:class:`CameraNode`, Zenoh only via ``publish``); the
command line and the bootstrap are in localization.node.main.

Usage::

    formation camera --source SRC --calibration FILE [--fleet demo] [--name camera]
                     [--fast] [--loop] [--fps HZ] [--detector auto|apriltag|aruco]
                     [--no-batch] [--duration S] [zenoh options: --endpoint EP ...]
    formation camera --source rendered ... [--render-size WxH] [--render-height M]
                     [--render-look-at=X,Y] [--render-tilt DEG] [--render-blur PX]
                     [--render-noise STD] [--fps HZ (a cap)] [--truth-endpoint EP]
    formation camera calibrate ...        (localization.node.calibrate)

Theory of operation
-------------------
A grabber thread reads frames from the source (localization.core.sources), stamps each with
``time.monotonic()`` right after the frame was read (the *capture time*; a device's exposure
started up to one frame period earlier), detects the markers, maps them to the floor and runs the
tracker (:class:`CameraPipeline`, no Zenoh). It hands each frame's result to the event loop,
which publishes, per frame: one ``poses`` batch (``PoseBatch``, ``stamp`` = capture time) then
``robot/<id>/pose`` for each robot seen (``t`` = capture time, ``robot`` set, ``pub_t`` = its
publication time on the clock of ``t``), the same keys and order as the plant's camera emulation,
so agents and the coordinator cannot tell the difference. ``pub_t`` (and the batch's ``t``) is
the capture time plus the time elapsed on this host since the frame was read: receivers estimate
the clock offset from it and so compensate the pipeline's latency (docs/clocks.md).
A robot not seen is not published (the firmware's staleness rule stops it).

``--source rendered`` (localization.core.rendered) renders the plant's truth instants instead of
reading a camera: at most ``--fps`` of them a second of truth time, at ``--render-size``; the
truth comes over the fleet session, or with ``--truth-endpoint`` over a second plain session
(a simulated world's own), so the fleet identity needs no grant to read truth.

A recording (file, folder) is read at its own frame rate, frames dropped when processing falls
behind (counted), unless ``--fast`` (every frame, as fast as possible); at its end the process
exits 0 (``--loop``: start again). A live source (device, stream) is read as fast as it delivers.

Status: ``formation/<fleet>/camera/<name>/status`` at 2 Hz, ``CameraStatus`` of the bus contract
(bus_schemas.messages_status; every field in docs/bus.md): ``state`` (``running``/``done``),
``detector``, ``source``, ``frames``, ``dropped``, ``fps`` (frames processed per second over the
last period), ``detect_{p50,p99,max}_ms`` and ``latency_{p50,p99,max}_ms`` (capture -> published,
over the last 1000 frames; absent before the first), ``detections``/``published``/``misses`` (per
robot), ``rejects`` (``jump``, ``bad_size``, ``unknown``, ``duplicate``), ``reacquired``,
``internal_errors``, ``truth_rejected``.

Exits 0 within a second of SIGINT/SIGTERM, closing its Zenoh session (runtime).
"""

from __future__ import annotations

import sys
import threading
import time
from collections import deque
from collections.abc import Callable
from typing import Final

import numpy as np
import numpy.typing as npt

import runtime as rt
from bus_schemas import (
    CAMERA_MS_MAX,
    MAX_STR_LEN,
    CameraStatus,
    Pose,
    PoseBatch,
    encode,
    keys,
)
from localization.core.pipeline import CameraPipeline, FrameResult
from localization.core.sources import FrameSource

__all__ = ["CameraNode", "Grabber"]

STATUS_PERIOD_S: Final = 0.5
LATENCY_SAMPLES: Final = 1000

Frame = npt.NDArray[np.uint8]


class Grabber:
    """The frame thread: read (paced for recordings), stamp, process, hand over to the loop."""

    def __init__(
        self,
        source: FrameSource,
        pipeline: CameraPipeline,
        deliver: Callable[[tuple[FrameResult, float] | None], None],
        *,
        fast: bool,
        loop_file: bool,
    ) -> None:
        self.source = source
        self.pipeline = pipeline
        self.deliver = deliver
        self.paced = not source.live and not fast
        self.loop_file = loop_file
        self.stop = threading.Event()
        self.frames = 0
        self.dropped = 0
        self.errors = 0
        self.last_error = ""
        self.thread = threading.Thread(target=self._run, name="camera-grabber", daemon=True)

    def start(self) -> None:
        self.thread.start()

    def _run(self) -> None:
        period = 1.0 / self.source.fps
        t0 = time.monotonic()
        k = 0  # index of the next frame of the recording
        base = 0.0  # media time of the recording's start (grows at each --loop)
        try:
            while not self.stop.is_set():
                if self.paced:
                    now = time.monotonic()
                    due = t0 + k * period
                    if due > now and self.stop.wait(due - now):
                        break
                    # late by more than a frame: drop frames as a live camera would
                    while time.monotonic() > t0 + (k + 1) * period and self.source.skip():
                        k += 1
                        self.dropped += 1
                frame = self.source.read()
                # capture time: right after the read, or the source's own (rendered: the truth's)
                own = getattr(self.source, "frame_stamp_s", None)
                read_s = time.monotonic()  # this host's clock, for the publication time
                stamp = read_s if own is None else float(own)
                k += 1
                if frame is None:
                    if self.loop_file and not self.source.live and self.source.rewind():
                        t0, k, base = time.monotonic(), 0, base + (k - 1) * period
                        continue
                    break
                media = None if self.source.live else base + (k - 1) * period
                try:
                    result = self.pipeline.process(frame, stamp, time.perf_counter, media)
                except Exception as exc:  # a bug or a corrupt frame: count, go on
                    self.errors += 1
                    self.last_error = repr(exc)
                    continue
                self.frames += 1
                self.deliver((result, read_s))
        finally:
            # The source is released by the thread that reads it: releasing a VideoCapture
            # while another thread is inside read() aborts the process (std::terminate).
            self.source.close()
            self.deliver(None)  # end of stream (or stop)


class CameraNode:
    """The loop side: publishes each frame's poses and the status; Zenoh only via ``publish``."""

    def __init__(
        self,
        fleet: str,
        name: str,
        pipeline: CameraPipeline,
        source_desc: str,
        publish: Callable[[str, bytes, rt.QoS], None],
        *,
        batch: bool = True,
    ) -> None:
        self.fleet = fleet
        self.pipeline = pipeline
        self.source_desc = source_desc
        self.publish = publish
        self.batch = batch
        self.poses_key = keys.poses_key(fleet)
        self.pose_keys = {r: keys.pose_key(fleet, r) for r in pipeline.cal.robots}
        self.status_key = keys.camera_status_key(fleet, name)
        self.seq: dict[str, int] = {}
        self.latency_s: deque[float] = deque(maxlen=LATENCY_SAMPLES)
        self.detect_s: deque[float] = deque(maxlen=LATENCY_SAMPLES)
        self.frames = 0
        self.internal_errors = 0
        self.truth_rejected = 0
        self.state = "running"
        self._fps_mark = (time.monotonic(), 0)
        self.fps = 0.0
        self.grabber: Grabber | None = None

    def _next(self, key: str) -> int:
        n = self.seq.get(key, 0) + 1
        self.seq[key] = n
        return n

    def on_frame(self, res: FrameResult, read_s: float | None = None) -> None:
        """Publish one frame: the batch first, then each robot's pose (t = capture time).

        ``read_s``: this host's ``time.monotonic()`` when the frame was read (the capture time
        for a camera; a rendered frame's capture time is the truth's, another clock). The
        publication time on the clock of ``t`` is ``stamp + (now - read_s)``; None: now.
        """
        try:
            stamp = max(res.stamp_s, 0.0)
            now = time.monotonic()
            pub_t = max(now if read_s is None else stamp + (now - read_s), stamp)
            ms = res.measurements
            if ms and self.batch:
                batch = PoseBatch(
                    t=pub_t,
                    seq=self._next(self.poses_key),
                    robots=tuple(m.robot for m in ms),
                    x=tuple(m.x for m in ms),
                    y=tuple(m.y for m in ms),
                    theta=tuple(m.theta for m in ms),
                    stamp=stamp,
                )
                self.publish(self.poses_key, encode(batch), rt.QOS_CONTROL)
            for m in ms:
                key = self.pose_keys[m.robot]
                msg = Pose(t=stamp, seq=self._next(key), x=m.x, y=m.y, theta=m.theta, robot=m.robot,
                           pub_t=pub_t)  # fmt: skip
                self.publish(key, encode(msg), rt.QOS_CONTROL)
            self.frames += 1
            self.detect_s.append(res.detect_s)
            self.latency_s.append(time.monotonic() - res.stamp_s)
        except Exception as exc:
            self.internal_errors += 1
            print(f"camera: internal error publishing a frame: {exc!r}", file=sys.stderr)

    @staticmethod
    def _percentiles(samples: deque[float]) -> tuple[float, float, float] | tuple[None, None, None]:
        """(p50, p99, max) in ms of ``samples`` (s); Nones when there are none."""
        if not samples:
            return None, None, None
        arr = np.fromiter(samples, dtype=float) * 1e3
        p50, p99 = np.percentile(arr, [50.0, 99.0])
        out = float(p50), float(p99), float(arr.max())
        if not all(-CAMERA_MS_MAX <= v <= CAMERA_MS_MAX for v in out):
            return None, None, None  # clocks 11 days apart (rendered source): not a latency
        return out

    def status_msg(self) -> CameraStatus:
        """The tracker's status now (``CameraStatus``); advances the status ``seq``."""
        now = time.monotonic()
        t_mark, n_mark = self._fps_mark
        if now - t_mark >= 0.2:
            self.fps = (self.frames - n_mark) / (now - t_mark)
            self._fps_mark = (now, self.frames)
        st = self.pipeline.tracker.stats()
        g = self.grabber
        d50, d99, dmax = self._percentiles(self.detect_s)
        l50, l99, lmax = self._percentiles(self.latency_s)
        return CameraStatus(
            t=now,
            seq=self._next(self.status_key),
            state=self.state,
            detector=self.pipeline.detector.name[:MAX_STR_LEN],
            source=self.source_desc[:MAX_STR_LEN],
            frames=self.frames,
            dropped=g.dropped if g is not None else 0,
            fps=self.fps,
            detect_p50_ms=d50,
            detect_p99_ms=d99,
            detect_max_ms=dmax,
            latency_p50_ms=l50,
            latency_p99_ms=l99,
            latency_max_ms=lmax,
            detections=st["detections"],
            published=st["published"],
            misses=st["misses"],
            rejects=self.pipeline.rejects(),
            reacquired=st["reacquired"],
            internal_errors=self.internal_errors + (g.errors if g is not None else 0),
            truth_rejected=self.truth_rejected,
        )

    def publish_status(self) -> None:
        try:
            self.publish(self.status_key, encode(self.status_msg()), rt.QOS_TELEMETRY)
        except Exception as exc:
            self.internal_errors += 1
            print(f"camera: internal error in status: {exc!r}", file=sys.stderr)
