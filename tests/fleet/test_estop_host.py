"""Agent hosts and the latched e-stop (issue 13 item 4): a host asks for it at start.

A coordinator (the durable source of the latched state) runs on a real router; the test session,
as the operator, engages a fleet e-stop; an agent host (``formation agent-host``, three robots)
started afterwards must report every robot in ESTOP in *every* status batch it publishes (it
asked before it subscribed to anything that moves them); SIGKILLed and started again (a respawn)
the same. After the fleet's release and an e-stop of r2 alone, a new host comes up with r2 in
ESTOP and the other two not.
"""

from __future__ import annotations

import signal
import time
from collections.abc import Callable

import msgpack
import pytest
import zenoh
from support.bus_watch import Recorder, decoder_of
from support.routers import RouterHandle
from support.spawn import Spawner

import runtime as rt
from bus_schemas import Estop, StatusBatch, encode, keys, new_estop_id

pytestmark = [pytest.mark.zenoh]

FLEET = "hostestop"
IDS = ("r1", "r2", "r3")


def modes_of(batch: StatusBatch) -> dict[str, str]:
    return dict(zip(batch.robots, batch.mode, strict=True))


def test_agent_hosts_come_up_in_the_latched_estop(
    spawn: Spawner, router: RouterHandle, session: Callable[..., zenoh.Session]
) -> None:
    client = session()
    pubs = rt.Publishers(client)
    coords = Recorder(client, f"formation/{FLEET}/coordinator/*/status", msgpack.unpackb)
    hosts = Recorder(client, keys.all_host_status_pattern(FLEET), decoder_of(StatusBatch))
    spawn(
        "coordinator", "--scenario", "paper-exp1", "--fleet", FLEET,
        "--endpoint", router.endpoint, ready="coord",
    )  # fmt: skip

    def estop(engage: bool, robot: str | None, want: Callable[[dict[str, object]], bool]) -> None:
        """Publish until the coordinator's status shows the latched state ``want``."""
        deadline = time.monotonic() + 10.0
        eid = new_estop_id() if engage else None  # one engagement, however many copies
        while True:
            msg = Estop(t=time.monotonic(), engage=engage, robot=robot, id=eid)
            pubs.put(keys.estop_key(FLEET), encode(msg), rt.QOS_CONTROL)
            t_sent = time.monotonic()

            def latched(r: float, _k: str, s: dict[str, object], t_sent: float = t_sent) -> bool:
                # CoordinatorStatus: estop_fleet, estop_robots (the status map's old "estop")
                state = {"fleet": s["estop_fleet"], "robots": s["estop_robots"]}
                return r > t_sent and want(state)

            try:
                coords.wait_for(latched, timeout_s=0.5)
                return
            except AssertionError:
                assert time.monotonic() < deadline, "the coordinator never latched it"

    def host_batches(name: str, since: float, n: int) -> list[dict[str, str]]:
        """The first ``n`` status batches of host ``name`` received after ``since``."""
        got: list[dict[str, str]] = []

        def enough(r: float, k: str, b: StatusBatch) -> bool:
            if r > since and k.endswith(f"/host/{name}/status"):
                got.append(modes_of(b))
            return len(got) >= n

        hosts.wait_for(enough, timeout_s=20.0)
        return got

    estop(True, None, lambda e: e["fleet"] is True)
    for attempt in ("start", "respawn"):
        t_start = time.monotonic()
        host = spawn(
            "agent-host", "--ids", "r1..r3", "--name", "h1", "--fleet", FLEET,
            "--scenario", "paper-exp1", "--endpoint", router.endpoint,
            ready="agent-host h1 ready",
        )  # fmt: skip
        for batch in host_batches("h1", t_start, 3):
            assert batch == {r: "estop" for r in IDS}, (attempt, batch)
        host.stop(signal.SIGKILL)

    estop(False, None, lambda e: e["fleet"] is False)
    estop(True, "r2", lambda e: e["robots"] == ["r2"])
    t_start = time.monotonic()
    spawn(
        "agent-host", "--ids", "r1..r3", "--name", "h2", "--fleet", FLEET,
        "--scenario", "paper-exp1", "--endpoint", router.endpoint, ready="agent-host h2 ready",
    )  # fmt: skip
    for batch in host_batches("h2", t_start, 3):
        assert batch["r2"] == "estop" and batch["r1"] != "estop" and batch["r3"] != "estop", batch
