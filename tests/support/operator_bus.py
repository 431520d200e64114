"""The robots of a coordinator under test as bus inputs (issue 28's operator tests): perfect
followers whose poses sit on the setpoints the coordinator sends, and the check that consecutive
leader messages never jump farther than the speed limit allows."""

from __future__ import annotations

import itertools
import math
import threading
import time

import zenoh

import runtime as rt
from bus_schemas import Leader, Pose, Setpoint, encode, keys
from coordinator.core.leader import LeaderConfig
from scenario import load
from support.bus_watch import decoder_of

FLEET = "demo"
SCENARIO = load("paper-exp2")
START = dict(zip(SCENARIO.robot_ids, SCENARIO.initial, strict=True))
L_M = SCENARIO.agent.geometry.ref_offset_m
CFG = LeaderConfig()


class Followers:
    """Poses on the setpoints: each robot's reference point is where its last setpoint put
    it (a perfect follower), published every ``period_s`` from a thread."""

    def __init__(self, session: zenoh.Session, period_s: float = 0.02) -> None:
        self.pubs = rt.Publishers(session)
        self.period_s = period_s
        self.at: dict[str, tuple[float, float, float]] = dict(START)
        self._lock = threading.Lock()
        self._sub = session.declare_subscriber(
            keys.all_setpoints_pattern(FLEET),
            zenoh.handlers.Callback(self._on_setpoint, indirect=False),
        )
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _on_setpoint(self, sample: zenoh.Sample) -> None:
        sp = decoder_of(Setpoint)(sample.payload.to_bytes())
        if sp is None:
            return
        x, y = sp.x - L_M * math.cos(sp.theta), sp.y - L_M * math.sin(sp.theta)
        with self._lock:
            self.at[sp.robot] = (x, y, sp.theta)

    def __enter__(self) -> Followers:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(2.0)
        self._sub.undeclare()

    def _run(self) -> None:
        for seq in itertools.count(1):
            if self._stop.is_set():
                return
            with self._lock:
                at = dict(self.at)
            for rid, (x, y, th) in sorted(at.items()):
                msg = Pose(t=time.monotonic(), seq=seq, x=x, y=y, theta=th, robot=rid)
                self.pubs.put(keys.pose_key(FLEET, rid), encode(msg), rt.QOS_CRITICAL)
            self._stop.wait(self.period_s)


def leader_jumps(leaders: list[tuple[float, str, Leader]]) -> list[tuple[float, float]]:
    """(distance, allowed) of consecutive leader messages farther apart than the speed limit
    allows over their stamps (the same publisher's clock)."""
    bad = []
    for (_, _, a), (_, _, b) in itertools.pairwise(leaders):
        allowed = CFG.max_speed_mps * max(b.t - a.t, 0.0) + 1e-6
        d = math.hypot(b.x - a.x, b.y - a.y)
        if d > allowed:
            bad.append((d, allowed))
    return bad
