"""The physical world of tests/test_deploy_netns.py: motors, robot bodies and the overhead camera.

One RoboClaw emulator per robot (robot_agent/motors/emulator.py, a pty each: the agents open
them exactly as they would open /dev/roboclaw), unicycle kinematics driven by the speeds the
agents command to those emulators (QPPS -> wheel rad/s with the robot config's encoder counts,
gear ratio, channel and inversion), and a camera publishing what it sees as the
``localization`` identity: ``robot/<id>/pose`` and the ``poses`` batch, at 30 Hz, through the
router with the localization certificate (the shipped localization-mtls.json5). This is the
plant's emulated camera, not rendered frames (docs/deploy.md, "Tested as shipped").

usage: python tests/deploy_world.py ZENOH_CONFIG ROBOT_TOML r1:x,y,theta r2:... [--fleet F]

Prints ``world ports r1=/dev/pts/N ...`` once the emulators exist, ``world ready`` once the
Zenoh session is open; runs until SIGTERM/SIGINT.
"""

from __future__ import annotations

import math
import signal
import sys
import threading
import time
import tomllib
from pathlib import Path

import runtime as rt
from bus_schemas import Pose, PoseBatch, encode, keys
from robot_agent.motors.emulator import RoboClawEmulator

STEP_S = 0.01
CAMERA_PERIOD_S = 1.0 / 30.0


def main(argv: list[str]) -> int:
    fleet = "demo"
    if "--fleet" in argv:
        i = argv.index("--fleet")
        fleet = argv[i + 1]
        del argv[i : i + 2]
    zconf, robot_toml, *specs = argv
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
    session = rt.open_session(rt.ZenohSettings(connect=(), mode=None, config_file=zconf))
    try:
        pubs = rt.Publishers(session)
        for rid in robots:
            pubs.get(keys.pose_key(fleet, rid), rt.QOS_CONTROL)
        pubs.get(keys.poses_key(fleet), rt.QOS_CONTROL)
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
                for rid, (x, y, th) in robots.items():
                    msg = Pose(t=now, seq=seq, x=x, y=y, theta=th, robot=rid)
                    pubs.put(keys.pose_key(fleet, rid), encode(msg), rt.QOS_CONTROL)
                batch = PoseBatch(
                    t=now,
                    seq=seq,
                    robots=ids,
                    x=tuple(robots[r][0] for r in ids),
                    y=tuple(robots[r][1] for r in ids),
                    theta=tuple(robots[r][2] for r in ids),
                    stamp=now,
                )
                pubs.put(keys.poses_key(fleet), encode(batch), rt.QOS_CONTROL)
    finally:
        session.close()
        for emu in emus.values():
            emu.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
