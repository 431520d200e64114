"""An agent still paused (``formation fault pause``) when a ``formation up`` run ends (issue 30).

Before, the stopped agent could not handle its SIGTERM, was SIGABRTed and SIGKILLed after 2 s and
the run exited 1 as if a node had hung. A paused process is not hung: it is an injected fault
whose effect on the run is already measured. Now the launcher resumes a stopped child right
after its SIGTERM (the signal waits for it to run), the child exits cleanly, the run exits 0 and
``meta.events`` says the agent was paused at the end. A child that does not exit while running
is still a failure (tests/fleet/test_up.py, tests/fleet/test_up_hardening.py).
"""

from __future__ import annotations

import json
import time
import uuid
from pathlib import Path

import pytest
from support.fault_fleet import fault
from support.spawn import Spawner, free_port

import runtime as rt
from bus_schemas import keys
from formation.operate.fault import FaultError

pytestmark = [pytest.mark.slow, pytest.mark.zenoh]

# The run's length: long enough for the pause to land first (about 0.2 s after the first truth,
# the fault tool's code running in this process over the test's session; a ``formation fault``
# process costs 1-2 s to start, and the CLI is tested in tests/fleet/test_up_hardening.py).
DURATION_S = 5.0


def test_an_agent_paused_at_the_end_is_an_event_not_a_failure(
    spawn: Spawner, tmp_path: Path
) -> None:
    out = tmp_path / "out"
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    fleet = f"t{uuid.uuid4().hex[:8]}"
    up = spawn(
        "up", "--scenario", "paper-exp1", "--duration", f"{DURATION_S:g}", "--no-figures",
        "--quiet", "--endpoint", endpoint, "--fleet", fleet, "--out", str(out),
    )  # fmt: skip
    deadline = time.monotonic() + 60.0
    session = None
    while session is None:
        assert up.proc.poll() is None and time.monotonic() < deadline, up.describe()
        try:
            session = rt.open_session(rt.ZenohSettings(connect=(endpoint,), open_timeout_s=2.0))
        except rt.TransportError:
            time.sleep(0.2)
    try:
        truth: list[object] = []
        sub = session.declare_subscriber(keys.truth_key(fleet, "r1"), truth.append)
        while not truth:  # the plant runs (it waits for every agent's token before it starts)
            assert up.proc.poll() is None and time.monotonic() < deadline, up.describe()
            time.sleep(0.05)
        sub.undeclare()
        while True:  # then pause r2's agent (the fault tool's code, in this process)
            try:
                fault(endpoint, fleet, "--timeout", "1", "pause", "r2", session=session)
                break
            except FaultError as e:
                assert up.proc.poll() is None, up.describe()
                assert time.monotonic() < deadline, e
                time.sleep(0.2)
    finally:
        session.close()
    assert up.proc.wait(timeout=120) == 0, up.describe()
    m = json.loads((out / "metrics.json").read_text())
    events = [e["event"] for e in m["meta"]["events"]]
    assert any("agent-r2" in e and "paused at the end" in e for e in events), events
    assert m["meta"]["failures"] == []
    r2 = m["meta"]["children"]["agent-r2"]
    assert not r2["killed"] and r2["returncode"] in (0, -15), r2
