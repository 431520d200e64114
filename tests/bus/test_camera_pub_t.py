"""``formation camera`` sets ``Pose.pub_t`` (issue 16): the publication time on the clock of the
capture time ``t``, so a receiver's clock-offset estimate (robot_agent/core/clocksync.py) sees the
camera pipeline's latency as age and the estimator compensates it. Without ``pub_t`` the agent
falls back to ``t`` and takes a pose as fresh as the fastest one ever seen (docs/clocks.md).

Real parts: a rendered frame through the real detection pipeline, the node's publish path, the
strict decoder, and the agent's ``ClockOffsets``; no Zenoh is needed (the node publishes through
a callable; tests/fleet/test_camera_node.py runs the process on a router)."""

from __future__ import annotations

import time

import numpy as np
import pytest

pytest.importorskip("cv2")

import runtime as rt
from bus_schemas import DecodeError, Pose, PoseBatch, decode, keys
from localization.core.calibration import Calibration
from localization.core.pipeline import CameraPipeline
from localization.node.camera import CameraNode
from robot_agent.core.clocksync import ClockOffsets
from sim_plant.core.render import CameraPose, Renderer

FLEET = "demo"


def _frame_and_pipeline() -> tuple[np.ndarray, CameraPipeline]:
    r = Renderer(CameraPose(tilt_deg=8.0))
    truth = np.array([[-0.3, 0.1, 0.4], [0.35, -0.2, -2.0]])
    cal = Calibration(
        homography=r.h_image_to_floor.tolist(),
        tags={"r1": 0, "r2": 1},
        tag_size_m=r.tag_size_m,
    )
    return r.render(truth, [0, 1]), CameraPipeline(cal, "aruco")


def _published(
    camera_clock_s: float | None,
) -> tuple[list[tuple[str, bytes]], float, float, float]:
    """One frame processed and published. The capture ``stamp`` is read on the camera's clock:
    ``camera_clock_s`` is what that clock says at the read (a rendered frame carries the plant's
    stamp, a camera host has its own uptime), None = a camera on this host (its stamp is this
    host's ``time.monotonic()``). A fixed reading, never this host's clock minus an offset: the
    test must not depend on how long this machine has been up (a clock minus 3600 s was
    negative on a machine booted less than an hour ago). Returns (messages, stamp, read_s, the
    host's clock just before publishing)."""
    frame, pipe = _frame_and_pipeline()
    out: list[tuple[str, bytes]] = []

    def publish(key: str, payload: bytes, qos: rt.QoS) -> None:
        out.append((key, payload))

    node = CameraNode(FLEET, "cam", pipe, "rendered", publish)
    read_s = time.monotonic()
    stamp = read_s if camera_clock_s is None else camera_clock_s
    res = pipe.process(frame, stamp, time.perf_counter)
    assert {m.robot for m in res.measurements} == {"r1", "r2"}
    before = time.monotonic()
    node.on_frame(res, read_s)
    return out, stamp, read_s, before


CAMERA_CLOCKS_S = [None, 0.5, 2.5e6]
"""This host's clock; a camera host booted half a second ago (far behind this host's clock,
whatever this host's uptime); one up for a month (far ahead)."""


@pytest.mark.parametrize("camera_clock_s", CAMERA_CLOCKS_S)
def test_pose_carries_its_publication_time_on_the_capture_clock(
    camera_clock_s: float | None,
) -> None:
    out, stamp, read_s, before = _published(camera_clock_s)
    poses = [decode(p, Pose) for k, p in out if k != keys.poses_key(FLEET)]
    (batch,) = [decode(p, PoseBatch) for k, p in out if k == keys.poses_key(FLEET)]
    assert not isinstance(batch, DecodeError)
    assert len(poses) == 2
    for msg in poses:
        assert not isinstance(msg, DecodeError)
        assert msg.t == stamp
        assert msg.pub_t is not None
        # the time elapsed on this host since the read, on the capture clock
        assert msg.pub_t - msg.t >= before - read_s - 1e-9
        assert msg.pub_t - msg.t < 60.0
        assert msg.pub_t == batch.t  # the batch's publication time: the same instant
    assert batch.stamp == stamp


def test_agent_sees_the_pipeline_latency_as_age_whatever_the_clock_offset() -> None:
    """The agent's conversion of the capture time (robot_agent.core.clocksync): with ``pub_t`` the
    age it computes is the pipeline's latency (publication - capture) plus the link, for a
    camera on another clock too; with ``pub_t`` dropped it would be 0 (the old behaviour)."""
    for camera_clock_s in CAMERA_CLOCKS_S:
        out, _, _, _ = _published(camera_clock_s)
        key = keys.pose_key(FLEET, "r1")
        (payload,) = [p for k, p in out if k == key]
        msg = decode(payload, Pose)
        assert not isinstance(msg, DecodeError) and msg.pub_t is not None
        latency = msg.pub_t - msg.t
        assert latency > 0.0
        rx = time.monotonic()  # the agent's clock (this host)
        clocks = ClockOffsets()
        capture_local = clocks.capture_to_local(key, msg.pub_t, msg.t, rx)
        assert rx - capture_local == pytest.approx(latency, abs=1e-6)
        # without pub_t the shell passes t for both: the capture is taken as received now
        old = ClockOffsets().capture_to_local(key, msg.t, msg.t, rx)
        # (to float precision: a camera clock 2.5e6 s away leaves ~1e-10 s of rounding)
        assert rx - old == pytest.approx(0.0, abs=1e-6)
