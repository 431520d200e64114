"""Outsider fuzz of a running fleet: seeded hostile payloads on every key its nodes subscribe to.

Used by ``tests/fleet/test_outsider_fuzz.py`` (short) and ``bench/bench_fuzz.py`` (long). A plain
Zenoh client (no project node) publishes, on each subscribed key of a realtime ``formation up``
fleet, payloads derived from a valid message of the key's type by seeded mutations: random
bytes, truncation, bit flips, a field deleted, a field of another type, NaN/inf, values beyond
the plausibility bounds, a non-string map key, a duplicate map key, a wrong version, nested
garbage. Every payload is kept only if the strict decoder refuses it (``decode`` returns a
DecodeError), so each node must reject and count *exactly* the payloads it received, and no
robot may move because of one (schema-valid forgeries are the election's and the ACL's
business, not a fuzzer's).

:func:`fuzz_plan` says which nodes receive each key (the expected count per node);
:func:`payloads_for` generates the payloads of one key.
"""

from __future__ import annotations

import math
import random
import struct
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import msgpack

from bus_schemas import (
    DecodeError,
    Disturbance,
    Estop,
    Heartbeat,
    Message,
    Pose,
    PoseBatch,
    Setpoint,
    Wheels,
    decode,
    encode,
    keys,
    to_map,
)

__all__ = ["FuzzKey", "fuzz_plan", "payloads_for"]


@dataclass(frozen=True)
class FuzzKey:
    """One subscribed key: its message type, a valid sample, and the nodes that decode it."""

    key: str
    kind: type[Any]
    sample: Message
    receivers: tuple[str, ...]
    """Node names (``agent-r1``, ``coordinator``, ``plant``) whose ``rejected`` must grow by one
    per payload."""


def fuzz_plan(fleet: str, robots: tuple[str, ...], coordinator: str = "main") -> list[FuzzKey]:
    """Every key a realtime fleet's agents, active coordinator and plant subscribe to (except
    liveliness and the lockstep clock/leader, which a realtime fleet does not subscribe to),
    with the nodes that count a rejected payload on it."""
    agents = tuple(f"agent-{r}" for r in robots)
    out: list[FuzzKey] = []
    for r in robots:
        sp = Setpoint(
            t=1.0, seq=1, robot=r, slot=0, role="leader", stage=0, parent=None,
            x=0.0, y=0.0, theta=0.0, vx=0.0, vy=0.0,
        )  # fmt: skip
        out.append(FuzzKey(keys.setpoint_key(fleet, r), Setpoint, sp, (f"agent-{r}",)))
        pose = Pose(t=1.0, seq=1, x=0.0, y=0.0, theta=0.0, robot=r)
        out.append(FuzzKey(keys.pose_key(fleet, r), Pose, pose, (f"agent-{r}", "coordinator")))
        wh = Wheels(
            t=1.0, seq=1, omega_r=0.0, omega_l=0.0, power_r=0.0, power_l=0.0, pose_t=1.0,
        )  # fmt: skip
        out.append(FuzzKey(keys.wheels_key(fleet, r), Wheels, wh, ("plant",)))
    batch = PoseBatch(t=1.0, seq=1, stamp=1.0, robots=robots, x=(0.0,) * len(robots),
                      y=(0.0,) * len(robots), theta=(0.0,) * len(robots))  # fmt: skip
    out.append(FuzzKey(keys.poses_key(fleet), PoseBatch, batch, agents))
    estop = Estop(t=1.0, engage=False, robot=None)
    out.append(FuzzKey(keys.estop_key(fleet), Estop, estop, (*agents, "coordinator")))
    hb = Heartbeat(t=1.0, seq=1, name="fuzz", active=False, epoch=0, leader_t0=0.0)
    out.append(FuzzKey(keys.heartbeat_key(fleet, "fuzz"), Heartbeat, hb, ("coordinator",)))
    dist = Disturbance(t=1.0, robot=robots[0], kind="drag", dx=0.0, dy=0.0, duration_s=0.1)
    out.append(FuzzKey(keys.disturbance_key(fleet), Disturbance, dist, ("plant",)))
    del coordinator
    return out


def _pack(obj: Any) -> bytes:
    data: bytes = msgpack.packb(obj, use_bin_type=True)
    return data


def _map_with_duplicate(base: dict[str, Any], key: str) -> bytes:
    """A msgpack map with ``key`` twice (msgpack-python cannot build one from a dict)."""
    items = [*base.items(), (key, base[key])]
    n = len(items)
    head = bytes([0x80 | n]) if n < 16 else b"\xde" + struct.pack(">H", n)
    return head + b"".join(_pack(k) + _pack(v) for k, v in items)


def _mutations(rnd: random.Random, valid: bytes, base: dict[str, Any]) -> Iterator[bytes]:
    fields = sorted(base)
    while True:
        f = rnd.choice(fields)
        choice = rnd.randrange(14)
        if choice == 0:
            yield bytes(rnd.getrandbits(8) for _ in range(rnd.randrange(0, 200)))
        elif choice == 1:
            yield valid[: rnd.randrange(0, len(valid))]
        elif choice == 2:
            b = bytearray(valid)
            for _ in range(rnd.randrange(1, 4)):
                b[rnd.randrange(len(b))] ^= 1 << rnd.randrange(8)
            yield bytes(b)
        elif choice == 3:
            yield _pack({k: v for k, v in base.items() if k != f})
        elif choice == 4:
            yield _pack({**base, f: rnd.choice(["x", [1, 2], {"a": 1}, b"\x00", None, True])})
        elif choice == 5:
            yield _pack({**base, f: rnd.choice([math.nan, math.inf, -math.inf])})
        elif choice == 6:
            yield _pack({**base, f: rnd.choice([1e300, -1e300, 2**64 - 1, -(2**63)])})
        elif choice == 7:
            yield _pack({**base, rnd.randrange(-5, 5): 1})  # a non-string key
        elif choice == 8:
            yield _map_with_duplicate(base, f)
        elif choice == 9:
            yield _pack({**base, "v": rnd.choice([0, 2, 99, "1", True])})
        elif choice == 10:
            yield _pack({**base, f: {"nested": [{1: 2}, [b"x"] * 5]}})
        elif choice == 11:
            yield _pack([base])
        elif choice == 12:
            yield _pack({**base, "t": rnd.choice([-1.0, 1e12, "now"])})
        else:  # (no oversized payload: a capped transport may drop it before any node counts)
            yield _pack(rnd.choice(["garbage", 3.5, None, b"\xff" * 40]))


def payloads_for(fk: FuzzKey, seed: int, n: int) -> list[bytes]:
    """``n`` payloads for ``fk`` (deterministic in ``seed`` and the key), each refused by the
    strict decoder of the key's type."""
    rnd = random.Random(f"{seed}/{fk.key}")
    valid = encode(fk.sample)
    base = dict(to_map(fk.sample))
    out: list[bytes] = []
    for payload in _mutations(rnd, valid, base):
        if isinstance(decode(payload, fk.kind), DecodeError):
            out.append(payload)
            if len(out) == n:
                return out
    raise AssertionError("unreachable")  # pragma: no cover
