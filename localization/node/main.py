"""``formation camera``: the command line and the bootstrap of the overhead-camera tracker
(localization.node.camera has the frame thread and the loop side; its docstring is the theory of
operation). ``main`` parses the options, loads the calibration, opens the source and runs the
node: one Zenoh session (and a second plain one for ``--truth-endpoint``), the grabber thread,
the status every ``STATUS_PERIOD_S`` and the systemd watchdog; exits 0 within a second of
SIGINT/SIGTERM, closing its sessions.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import dataclasses
import math
import sys
import time
from typing import Any, Final

import runtime as rt
from bus_schemas import DecodeError, Truth, TruthBatch, decode, keys
from localization.core.calibration import Calibration, CalibrationError, load
from localization.core.pipeline import CameraPipeline, FrameResult
from localization.core.sources import FrameSource, SourceError, open_source
from localization.node.camera import STATUS_PERIOD_S, CameraNode, Grabber
from runtime.sdnotify import Notifier

__all__ = ["build_parser", "main", "with_tags"]

LIVE_QUEUE: Final = 4
RENDERED: Final = "rendered"
JOIN_S: Final = 0.15
"""At stop, how long the grabber gets to finish its frame and release the source (s). Not
longer: a rendered frame costs ~50 ms of CPU, several times that next to CPU hogs, and the stop
has a second in all (bench/bench_exit.py: the camera was the slowest process to exit, its wait
here the largest part). A grabber still in ``read()`` when the process leaves is no harm: the
process ends with ``os._exit`` (no destructor runs, the kernel closes the device)."""
FAST_QUEUE: Final = 256


def with_tags(cal: Calibration, tags: dict[str, int]) -> Calibration:
    """``cal`` tracking the fleet file's robots and tags (``--fleet-file``) instead of its own
    ``[tags]``; tag offsets of robots no longer tracked are dropped."""
    if cal.family != "tag36h11":
        raise CalibrationError(
            f"--fleet-file gives tag ids, but the calibration's family is {cal.family!r}"
        )
    offsets = {rid: off for rid, off in cal.offsets.items() if rid in tags}
    return dataclasses.replace(cal, tags=dict(tags), offsets=offsets)


def _size(text: str) -> tuple[int, int]:
    from sim_plant.core.render import MAX_SIDE_PX, MIN_SIDE_PX

    w, sep, h = text.lower().partition("x")
    if not (sep and w.isdigit() and h.isdigit()):
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT in pixels, got {text!r}")
    size = int(w), int(h)
    if not all(MIN_SIDE_PX <= v <= MAX_SIDE_PX for v in size):
        raise argparse.ArgumentTypeError(
            f"each side must be {MIN_SIDE_PX}..{MAX_SIDE_PX} px, got {text}"
        )
    return size


def build_parser() -> argparse.ArgumentParser:
    """The ``formation camera`` argument parser."""
    p = argparse.ArgumentParser(
        prog="formation camera",
        description="Overhead-camera tracker: publishes robot poses from a camera, a video file, "
        "a folder of images or a stream (docs/localization.md). "
        "`formation camera calibrate --help` for the calibration tool.",
    )
    p.add_argument(
        "--source",
        required=True,
        metavar="SRC",
        help="device index or /dev/videoN, video file, image folder, stream URL, or `rendered` "
        "(simulation: frames rendered from the plant's truth)",
    )
    p.add_argument("--calibration", required=True, metavar="FILE", help="calibration TOML")
    p.add_argument("--fleet", default=None, help="fleet name (demo, or the fleet file's)")
    p.add_argument(
        "--fleet-file",
        metavar="FLEET.toml",
        help="real robots: take the fleet name and the robot -> tag ids from the fleet file "
        "(they replace the calibration's [tags])",
    )
    p.add_argument("--name", default="camera", help="this tracker's name in its status key")
    p.add_argument(
        "--detector",
        choices=("auto", "apriltag", "aruco"),
        help="override the calibration's detector choice",
    )
    p.add_argument(
        "--fps",
        type=rt.positive_float,
        metavar="HZ",
        help="rate of a folder / file (default: the file's own, 30 for a folder); with "
        "--source rendered: at most HZ frames per second (default: every truth instant)",
    )
    p.add_argument(
        "--fast",
        action="store_true",
        help="a recording: every frame as fast as possible (not at its own rate)",
    )
    p.add_argument("--loop", action="store_true", help="a recording: start again at its end")
    p.add_argument("--no-batch", action="store_true", help="no `poses` batch, per-robot keys only")
    p.add_argument(
        "--duration", type=rt.positive_float, metavar="S", help="stop after S s and exit 0"
    )
    g = p.add_argument_group(
        "--source rendered (simulation: frames rendered from the plant's truth)"
    )
    g.add_argument("--render-height", type=rt.positive_float, default=1.14, metavar="M",
                   help="camera height above the floor (1.14 m, the paper's)")  # fmt: skip
    g.add_argument("--render-tilt", type=float, default=0.0, metavar="DEG", help="camera tilt")
    g.add_argument("--render-look-at", default="0,0", metavar="X,Y",
                   help="floor point at the image centre (0,0)")  # fmt: skip
    g.add_argument("--render-noise", type=float, default=2.0, metavar="STD",
                   help="pixel noise std (grey levels, 2)")  # fmt: skip
    g.add_argument("--render-blur", type=float, default=0.8, metavar="PX",
                   help="blur sigma (px, 0.8)")  # fmt: skip
    g.add_argument("--render-size", type=_size, default=(1280, 720), metavar="WxH",
                   help="image size in pixels (1280x720); the lens is kept (the focal length "
                   "scales with the width: 900 px at 1280), so a smaller size sees the same "
                   "floor in fewer pixels (cheaper to render and detect, smaller tags)",
                   )  # fmt: skip
    g.add_argument("--truth-endpoint", metavar="EP",
                   help="read the truth from a separate plain Zenoh session connected to EP "
                   "(the simulated world's own, e.g. tcp/127.0.0.1:7600) instead of the fleet "
                   "session, whose identity (the localization certificate) may only publish "
                   "poses")  # fmt: skip
    rt.add_zenoh_arguments(p)
    return p


def main(argv: list[str]) -> int:
    """Entry point of ``formation camera``; returns the exit status."""
    if argv and argv[0] == "calibrate":
        from localization.node import calibrate

        return calibrate.main(argv[1:])
    ns = build_parser().parse_args(argv)
    try:
        pipeline, settings, truth_settings = _checked(ns)
        source = _open_checked(ns, pipeline.cal)
    except rt.UsageError as exc:
        rt.NodeLog("camera").info(str(exc))
        return rt.USAGE_EXIT
    started: list[Grabber] = []
    try:
        return rt.run_node(
            lambda stop: _node(stop, ns, pipeline, source, settings, truth_settings, started)
        )
    finally:
        if not started:  # else the grabber thread closes it (see Grabber._run)
            source.close()


def _truth_settings(ns: argparse.Namespace) -> rt.ZenohSettings | None:
    """``--truth-endpoint``: the plain client session the truth comes through (else None)."""
    if ns.truth_endpoint is None:
        return None
    if ns.source != RENDERED:
        raise ValueError("--truth-endpoint needs --source rendered")
    return rt.ZenohSettings(connect=(ns.truth_endpoint,), mode="client", open_timeout_s=10.0)


def _checked(
    ns: argparse.Namespace,
) -> tuple[CameraPipeline, rt.ZenohSettings, rt.ZenohSettings | None]:
    """The fleet and names (``ns.fleet`` filled in), the calibration's pipeline and the Zenoh
    settings; a mistake as :class:`runtime.UsageError`, before any device is opened."""
    tags: dict[str, int] | None = None
    if ns.fleet_file is not None:
        fleet_file = rt.load_fleet_file(ns.fleet_file)
        ns.fleet = ns.fleet or fleet_file.fleet
        tags = fleet_file.tags
    ns.fleet = ns.fleet or keys.DEFAULT_FLEET
    rt.check_names(("--fleet", ns.fleet), ("--name", ns.name))
    try:
        cal = load(ns.calibration)
        if tags is not None:
            cal = with_tags(cal, tags)
        pipeline = CameraPipeline(cal, ns.detector)
    except (CalibrationError, ImportError, ValueError) as exc:
        raise rt.UsageError(str(exc)) from None
    settings = rt.zenoh_settings(ns)
    try:
        truth_settings = _truth_settings(ns)
    except (TypeError, ValueError) as exc:
        raise rt.UsageError(f"zenoh settings: {exc}") from None
    return pipeline, settings, truth_settings


def _open_checked(ns: argparse.Namespace, cal: Calibration) -> FrameSource:
    """:func:`_open`, a source that cannot be opened as :class:`runtime.UsageError`."""
    try:
        return _open(ns, cal)
    except (SourceError, ValueError) as exc:
        raise rt.UsageError(str(exc)) from None


def _open(ns: argparse.Namespace, cal: Calibration) -> FrameSource:
    if ns.source != RENDERED:
        return open_source(ns.source, fps=ns.fps)
    from localization.core.rendered import RenderedSource, RenderSettings
    from sim_plant.core.render import CameraPose

    lx, ly = (float(v) for v in ns.render_look_at.split(","))
    camera = CameraPose(
        height_m=ns.render_height, tilt_deg=ns.render_tilt, look_at=(lx, ly)
    ).with_resolution(*ns.render_size)
    settings = RenderSettings(
        camera, blur_sigma_px=ns.render_blur, noise_std=ns.render_noise, max_fps=ns.fps
    )
    return RenderedSource(cal, settings)


def _feed_truth(
    session: Any, loop: asyncio.AbstractEventLoop, fleet: str, source: Any, node: CameraNode
) -> None:
    """``--source rendered``: the plant's truth (per robot and batched) into the source."""
    feed = source.feed

    def on_truth(rx: rt.Received) -> None:
        msg = decode(rx.payload, Truth)
        parsed = keys.parse_robot_key(rx.key)
        if isinstance(msg, DecodeError) or parsed is None:
            node.truth_rejected += 1
            return
        feed.push(parsed[1], msg.t, msg.x, msg.y, msg.theta)

    def on_truths(rx: rt.Received) -> None:
        msg = decode(rx.payload, TruthBatch)
        if isinstance(msg, DecodeError):
            node.truth_rejected += 1
            return
        for rid, x, y, th in zip(msg.robots, msg.x, msg.y, msg.theta, strict=True):
            feed.push(rid, msg.stamp, x, y, th)

    rt.subscribe(session, keys.all_truth_pattern(fleet), loop, on_truth)
    rt.subscribe(session, keys.truths_key(fleet), loop, on_truths)


async def _node(  # noqa: PLR0915 (the camera node: setup, then its frame loop)
    stop: asyncio.Event,
    ns: argparse.Namespace,
    pipeline: CameraPipeline,
    source: FrameSource,
    settings: rt.ZenohSettings,
    truth_settings: rt.ZenohSettings | None,
    started: list[Grabber],
) -> int:
    loop = asyncio.get_running_loop()
    try:
        session = await rt.open_session_async(settings)
    except (rt.TransportError, ValueError) as exc:
        print(f"camera: {exc}", file=sys.stderr)
        return 1
    truth_session = None
    if truth_settings is not None:
        try:
            truth_session = await rt.open_session_async(truth_settings)
        except (rt.TransportError, ValueError) as exc:
            print(f"camera: truth: {exc}", file=sys.stderr)
            session.close()
            return 1
    grabber: Grabber | None = None
    notifier = Notifier()
    try:
        pubs = rt.Publishers(session)
        node = CameraNode(
            ns.fleet, ns.name, pipeline, source.description, pubs.put, batch=not ns.no_batch
        )
        if node.batch:
            pubs.get(node.poses_key, rt.QOS_CONTROL)
        for key in node.pose_keys.values():
            pubs.get(key, rt.QOS_CONTROL)
        # A live or paced source: the newest frames win (a backlog is stale). --fast on a
        # recording: every frame is published (the grabber is the slow side; bounded anyway).
        results: asyncio.Queue[tuple[FrameResult, float] | None] = asyncio.Queue(
            maxsize=FAST_QUEUE if ns.fast else LIVE_QUEUE
        )

        def deliver(res: tuple[FrameResult, float] | None) -> None:  # grabber thread
            def put() -> None:
                if res is not None and results.full():  # the loop is behind: newest wins
                    results.get_nowait()
                    if node.grabber is not None:
                        node.grabber.dropped += 1
                results.put_nowait(res)

            with contextlib.suppress(RuntimeError):  # loop closed: exiting
                loop.call_soon_threadsafe(put)

        if ns.source == RENDERED:
            truth_from = session if truth_session is None else truth_session
            _feed_truth(truth_from, loop, ns.fleet, source, node)
        grabber = Grabber(source, pipeline, deliver, fast=ns.fast, loop_file=ns.loop)
        node.grabber = grabber
        print(
            f"camera ready: detector {pipeline.detector.name}; source {source.description}; "
            f"{len(pipeline.cal.robots)} robots",
            flush=True,
        )
        started.append(grabber)
        grabber.start()
        # Type=notify under systemd (deploy/systemd/formation-camera.service): READY now, and
        # WATCHDOG from the loop below (it turns at least every STATUS_PERIOD_S).
        notifier.ready(f"camera {ns.name}: {source.description}")
        wd_period = notifier.watchdog_interval_s()
        next_wd = time.monotonic()
        end = math.inf if ns.duration is None else time.monotonic() + ns.duration
        next_status = time.monotonic()
        stopping: asyncio.Future[Any] = asyncio.ensure_future(stop.wait())
        getting: asyncio.Future[Any] | None = None
        try:
            while not stop.is_set():
                now = time.monotonic()
                if now >= end:
                    break
                if now >= next_status:
                    node.publish_status()
                    next_status = now + STATUS_PERIOD_S
                if wd_period is not None and now >= next_wd:
                    notifier.watchdog()
                    next_wd = now + wd_period
                if getting is None:
                    getting = asyncio.ensure_future(results.get())
                await asyncio.wait(
                    (getting, stopping),
                    timeout=max(0.0, min(next_status, end) - now),
                    return_when=asyncio.FIRST_COMPLETED,
                )
                if not getting.done():
                    continue
                res, getting = getting.result(), None
                if res is None:
                    break
                node.on_frame(*res)
        finally:
            stopping.cancel()
            if getting is not None:
                getting.cancel()
        node.state = "done"
        node.publish_status()
        return 0
    finally:
        if grabber is not None:
            grabber.stop.set()
            if ns.source == RENDERED:
                source.close()  # wakes a grabber waiting for truth (only closes the feed)
            # let the frame in progress finish, so the thread releases the source itself
            grabber.thread.join(JOIN_S)
        notifier.stopping()
        notifier.close()
        for s in (truth_session, session):  # each waited for at most rt.SESSION_CLOSE_S
            if s is not None and not rt.close_session(s):
                print(
                    f"camera: Zenoh session close still blocked after {rt.SESSION_CLOSE_S:g} s "
                    "(router not reading?): exiting without it",
                    file=sys.stderr,
                )


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main(sys.argv[1:]))
