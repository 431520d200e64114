"""A burst of vanished robot tokens is re-assigned once, right after the burst.

An agent host's tokens vanish together (the host died, or `formation up` stopped it): with 300
robots one re-assignment per vanished token held the coordinator's loop ~0.75 s (bench/
bench_exit.py). The coordinator queues one re-assignment behind the burst instead; it still runs
in the same turn of the loop (issue 4: the robots left learn their slots within 50 ms; the real
process and router: tests/fleet/test_faults.py, tests/bus/test_node_coordinator.py).
"""

from __future__ import annotations

import asyncio
import time
from typing import Any

import runtime as rt
from bus_schemas import Pose, encode, keys
from coordinator.node.coordinator import CoordinatorNode
from scenario import load

FLEET = "demo"
ROBOTS = [f"r{k}" for k in range(1, 13)]  # the scenario's 3 slots and 9 spares


def _node() -> tuple[CoordinatorNode, list[tuple[str, bytes]]]:
    out: list[tuple[str, bytes]] = []

    def publish(key: str, payload: bytes, _qos: Any) -> None:
        out.append((key, payload))

    node = CoordinatorNode(load("paper-exp2"), "main", FLEET, publish)
    now = time.monotonic()
    for k, rid in enumerate(ROBOTS):
        node.on_alive(keys.alive_robot_key(FLEET, rid), True)
        pose = Pose(t=now, seq=1, x=0.4 - 0.3 * k, y=0.02, theta=0.0, robot=rid)
        node.on_pose(rt.Received(keys.pose_key(FLEET, rid), encode(pose), now))
    node.tick(now)
    assert node.last is not None and len(node.last.assignment) == 3
    return node, out


def test_a_burst_of_lost_tokens_is_reassigned_once_in_the_same_loop_turn() -> None:
    async def run() -> None:
        node, _ = _node()
        assert node.last is not None
        gone = [*node.last.assignment, *ROBOTS[3:9]]  # every assigned robot and 6 spares
        ticks = node.ticks
        for rid in gone:  # back to back, as the loop runs the queued liveliness callbacks
            node.on_alive(keys.alive_robot_key(FLEET, rid), False)
        assert node.ticks == ticks  # nothing re-assigned per token
        assert node.reassign_coalesced == len(gone) - 1
        await asyncio.sleep(0)  # the queued re-assignment runs in the loop's next turn
        assert node.ticks == ticks + 1
        out = node.last
        assert out is not None and not set(out.assignment) & set(gone)
        assert sorted(out.assignment) == sorted(set(ROBOTS) - set(gone))
        # a later loss queues a new one
        node.on_alive(keys.alive_robot_key(FLEET, ROBOTS[9]), False)
        await asyncio.sleep(0)
        assert node.ticks == ticks + 2 and ROBOTS[9] not in node.last.assignment

    asyncio.run(run())


def test_a_lost_token_without_a_running_loop_is_reassigned_at_once() -> None:
    node, _ = _node()
    assert node.last is not None
    leader = next(r for r, s in node.last.assignment.items() if s == 0)
    ticks = node.ticks
    node.on_alive(keys.alive_robot_key(FLEET, leader), False)
    assert node.ticks == ticks + 1 and leader not in node.last.assignment
    assert node.last.assignment and 0 in node.last.assignment.values()


def test_a_stepped_down_coordinator_does_not_reassign_from_a_queued_burst() -> None:
    async def run() -> None:
        node, _ = _node()
        ticks = node.ticks
        node.on_alive(keys.alive_robot_key(FLEET, "r1"), False)
        node.election_io.step_down("a test")  # between the burst and the queued re-assignment
        await asyncio.sleep(0)
        assert node.ticks == ticks and not node.active

    asyncio.run(run())
