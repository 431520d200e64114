"""The physical world of tests/fleet/test_deploy_netns.py: motors, robot bodies, and what the
camera sees.

One RoboClaw emulator per robot (robot_agent/motors/emulator.py, a pty each: the agents open
them exactly as they would open /dev/roboclaw) and unicycle kinematics driven by the speeds the
agents command to those emulators (QPPS -> wheel rad/s with the robot config's encoder counts,
gear ratio, channel and inversion). The light between the robots and the overhead camera is the
truth: at every camera instant (30 Hz) the world publishes the robots' true poses as a
``truths`` batch, as ``formation plant --no-poses`` does for ``formation up --camera rendered``,
but on a plain Zenoh session of its own that listens on ``TRUTH_ENDPOINT`` (the hub's loopback),
not on the fleet's router: the shipped access control lets no fleet identity read truth, and a
real camera's light does not go through the router either. ``formation camera --source rendered
--truth-endpoint TRUTH_ENDPOINT`` renders and tracks those instants and publishes the poses the
fleet runs on, with the shipped localization certificate.

The world also checks the camera: with ``--observer ZENOH_CONFIG`` (the shipped
observer-mtls.json5) it reads the fleet's ``poses`` batches and compares each robot's pose with
the true pose of the instant it was rendered from (``PoseBatch.stamp`` is that instant's truth
stamp, exactly).

usage: python tests/support/deploy_world.py TRUTH_ENDPOINT ROBOT_TOML r1:x,y,theta r2:...
                                    [--observer ZENOH_CONFIG] [--fleet F]

Prints ``world ports r1=/dev/pts/N ...`` once the emulators exist, ``world ready`` once its
sessions are open; runs until SIGTERM/SIGINT, then prints ``world camera frames=N matched=M
misses=K median_mm=A p99_mm=B max_mm=C max_deg=D`` (the camera's poses against the truth) and
exits 0.
"""

from __future__ import annotations

import math
import signal
import sys
import threading
import time
import tomllib
from collections import OrderedDict
from pathlib import Path
from typing import Any

import runtime as rt
from bus_schemas import DecodeError, PoseBatch, TruthBatch, decode, encode, keys
from robot_agent.motors.emulator import RoboClawEmulator

STEP_S = 0.01
CAMERA_PERIOD_S = 1.0 / 30.0
HISTORY = 300  # truth instants kept for the comparison (10 s at 30 Hz)


def _option(argv: list[str], name: str, default: str | None) -> str | None:
    if name not in argv:
        return default
    i = argv.index(name)
    value = argv[i + 1]
    del argv[i : i + 2]
    return value


class CameraCheck:
    """The camera's poses (fleet ``poses`` batches) against the truth instants they came from."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.truth: OrderedDict[float, dict[str, tuple[float, float, float]]] = OrderedDict()
        self.frames = 0
        self.unmatched = 0  # a batch whose stamp is no truth instant of this world
        self.misses = 0  # a robot of the instant absent from the batch
        self.err_m: list[float] = []
        self.err_rad: list[float] = []

    def add_truth(self, stamp: float, poses: dict[str, tuple[float, float, float]]) -> None:
        with self.lock:
            self.truth[stamp] = poses
            while len(self.truth) > HISTORY:
                self.truth.popitem(last=False)

    def on_poses(self, sample: Any) -> None:
        msg = decode(sample.payload.to_bytes(), PoseBatch)
        if isinstance(msg, DecodeError):
            return
        with self.lock:
            self.frames += 1
            true = self.truth.get(msg.stamp)
            if true is None:
                self.unmatched += 1
                return
            self.misses += len(set(true) - set(msg.robots))
            for rid, x, y, th in zip(msg.robots, msg.x, msg.y, msg.theta, strict=True):
                tx, ty, tth = true[rid]
                self.err_m.append(math.hypot(x - tx, y - ty))
                self.err_rad.append(abs(math.remainder(th - tth, 2.0 * math.pi)))

    def summary(self) -> str:
        with self.lock:
            errs = sorted(self.err_m)

            def q(f: float) -> float:
                return errs[min(len(errs) - 1, int(f * len(errs)))] * 1e3 if errs else math.nan

            return (
                f"world camera frames={self.frames} matched={len(errs)} "
                f"unmatched={self.unmatched} misses={self.misses} median_mm={q(0.5):.3f} "
                f"p99_mm={q(0.99):.3f} max_mm={(errs[-1] * 1e3 if errs else math.nan):.3f} "
                f"max_deg={math.degrees(max(self.err_rad, default=math.nan)):.3f}"
            )


def main(argv: list[str]) -> int:
    fleet = _option(argv, "--fleet", "demo") or "demo"
    observer = _option(argv, "--observer", None)
    truth_ep, robot_toml, *specs = argv
    cfg = tomllib.loads(Path(robot_toml).read_text())
    geom, motor = cfg["geometry"], cfg["motor"]
    wheel_r, half_track = float(geom["wheel_radius_m"]), float(geom["half_track_m"])
    qpps_per_radps = motor["encoder_counts_per_rev"] * motor["gear_ratio"] / (2.0 * math.pi)
    right_m1 = motor.get("right_channel", "m1") == "m1"
    sign_r = -1.0 if motor.get("invert_right", False) else 1.0
    sign_l = -1.0 if motor.get("invert_left", False) else 1.0

    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    signal.signal(signal.SIGINT, lambda *_: stop.set())

    robots: dict[str, list[float]] = {}
    emus: dict[str, RoboClawEmulator] = {}
    for spec in specs:
        rid, _, pose = spec.partition(":")
        robots[rid] = [float(v) for v in pose.split(",")]
        emus[rid] = RoboClawEmulator()
    print("world ports " + " ".join(f"{r}={e.port}" for r, e in emus.items()), flush=True)
    check = CameraCheck()
    light = rt.open_session(rt.ZenohSettings(connect=(), listen=(truth_ep,), mode="peer"))
    fleet_session = None
    try:
        truths = light.declare_publisher(keys.truths_key(fleet))
        if observer is not None:
            fleet_session = rt.open_session(
                rt.ZenohSettings(connect=(), mode=None, config_file=observer), timeout_s=15.0
            )
            fleet_session.declare_subscriber(keys.poses_key(fleet), check.on_poses)
        print("world ready", flush=True)
        seq = 0
        last = time.monotonic()
        next_cam = last
        while not stop.wait(STEP_S):
            now = time.monotonic()
            dt, last = now - last, now
            for rid, st in robots.items():
                m1, m2 = emus[rid].speeds()
                if emus[rid].mode != "speed":
                    m1 = m2 = 0
                qr, ql = (m1, m2) if right_m1 else (m2, m1)
                w_r, w_l = sign_r * qr / qpps_per_radps, sign_l * ql / qpps_per_radps
                v = wheel_r * (w_r + w_l) / 2.0
                w = wheel_r * (w_r - w_l) / (2.0 * half_track)
                st[0] += v * math.cos(st[2]) * dt
                st[1] += v * math.sin(st[2]) * dt
                st[2] = math.atan2(math.sin(st[2] + w * dt), math.cos(st[2] + w * dt))
            if now >= next_cam:
                next_cam = now + CAMERA_PERIOD_S
                seq += 1
                ids = tuple(robots)
                check.add_truth(now, {r: (p[0], p[1], p[2]) for r, p in robots.items()})
                batch = TruthBatch(
                    t=now,
                    seq=seq,
                    robots=ids,
                    x=tuple(robots[r][0] for r in ids),
                    y=tuple(robots[r][1] for r in ids),
                    theta=tuple(robots[r][2] for r in ids),
                    stamp=now,
                )
                truths.put(encode(batch))
    finally:
        if fleet_session is not None:
            fleet_session.close()
        light.close()
        for emu in emus.values():
            emu.close()
    print(check.summary(), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
