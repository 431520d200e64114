"""An in-process run as the bus would carry it, for the run collector (:func:`bus_messages`: truth,
slots, assignment, leader and wheels of each tick on fleet :data:`FLEET`; :func:`scramble`:
another arrival order a bus may give)."""

from __future__ import annotations

import random

from bus_schemas import (
    Assignment,
    Leader,
    Slot,
    Truth,
    Wheels,
    encode,
    keys,
)
from formation.outputs.runlog import RunLog

FLEET = "unit"


def bus_messages(
    log: RunLog, dt_s: float | None, t_offset_s: float = 0.0
) -> list[tuple[str, bytes]]:
    """The quantities of ``log`` as the bus carries them (truth per tick, the coordinator's
    slots, assignment on change and leader, the agents' wheels), in the order of a tick."""
    out: list[tuple[str, bytes]] = []
    prev: dict[str, int] | None = None
    for k in range(log.t_s.size):
        t = float(log.t_s[k]) + t_offset_s
        for i, rid in enumerate(log.robot_ids):
            x, y, th = (float(v) for v in log.truth[k, i])
            out.append((keys.truth_key(FLEET, rid), encode(Truth(t=t, seq=k, x=x, y=y, theta=th))))
        for m, s in enumerate(log.slot_ids):
            sx, sy = (float(v) for v in log.slot_xy[k, m])
            slot = Slot(
                t=t, seq=k, slot=s, role="leader" if s == 0 else "follower",
                stage=0 if s == 0 else 1, parent=None if s == 0 else 0,
                x=sx, y=sy, theta=0.0, vx=0.0, vy=0.0,
            )  # fmt: skip
            out.append((keys.slot_key(FLEET, s), encode(slot)))
        robots = {rid: int(log.slot_of[k, i]) for i, rid in enumerate(log.robot_ids)}
        robots = {r: s for r, s in robots.items() if s >= 0}
        if robots != prev:
            leader = next((r for r, s in robots.items() if s == 0), None)
            msg = Assignment(t=t, seq=k, leader=leader, robots=robots)
            out.append((keys.assignment_key(FLEET), encode(msg)))
            prev = robots
        lx, ly, lth = (float(v) for v in log.leader[k])
        leader_msg = Leader(t=t, seq=k, x=lx, y=ly, theta=lth, v_mps=0.02, omega_radps=0.0)
        out.append((keys.leader_key(FLEET), encode(leader_msg)))
        for i, rid in enumerate(log.robot_ids):
            pr, pl = (float(v) for v in log.power[k, i])
            wheels = Wheels(
                t=t, seq=k, omega_r=pr * 10.0, omega_l=pl * 10.0, power_r=pr, power_l=pl,
                pose_t=None, tick=k if dt_s is not None else None,
            )  # fmt: skip
            out.append((keys.wheels_key(FLEET, rid), encode(wheels)))
    return out


def scramble(msgs: list[tuple[str, bytes]], seed: int) -> list[tuple[str, bytes]]:
    """Shuffle messages of different keys (a bus keeps only each key's own order)."""
    rng = random.Random(seed)
    by_key: dict[str, list[tuple[str, bytes]]] = {}
    for m in msgs:
        by_key.setdefault(m[0], []).append(m)
    queues = list(by_key.values())
    out = []
    while queues:
        q = rng.choice(queues)
        out.append(q.pop(0))
        if not q:
            queues.remove(q)
    return out
