"""A lockstep agent whose liveliness lease expires is a fault event, never a change of result.

Issue 13 item 7: under extreme load a lockstep agent can be descheduled longer than its
wall-clock lease; its token vanishes although it will answer the tick it owes. The plant and
the coordinator must treat that as an event only (the plant keeps waiting for the agent up to
its lockstep timeout, the coordinator keeps its slot), so the result equals the unpaused run.
Reproduced deterministically: r2's agent is SIGSTOPped mid-run until its token is seen gone
(lease 300 ms here), then resumed; the metrics must equal those of the same run without pause.
"""

from __future__ import annotations

import json
import os
import signal
import threading
from pathlib import Path
from typing import Any

import msgpack
import pytest
import zenoh
from support.spawn import free_port
from support.up_runs import finish_process, lockstep_result, up_process

import runtime as rt
from formation.record import report as report_mod

pytestmark = [pytest.mark.slow, pytest.mark.zenoh, pytest.mark.shares_cpu]

ARGS = ("--lockstep", "--duration", "12", "--lease-ms", "300")


class Watch:
    """r2's status pid, the lockstep clock's tick and r2's token events of a running fleet."""

    def __init__(self, endpoint: str, fleet: str) -> None:
        self.lock = threading.Lock()
        self.cond = threading.Condition(self.lock)
        self.pid: int | None = None
        self.tick = -1
        self.token: list[str] = []  # "put" / "delete" in arrival order
        self.session = rt.open_session(rt.ZenohSettings(connect=(endpoint,)), timeout_s=60.0)
        s = self.session
        self._subs = [
            s.declare_subscriber(f"formation/{fleet}/robot/r2/status", self._on_status),
            s.declare_subscriber(f"formation/{fleet}/clock", self._on_clock),
            s.liveliness().declare_subscriber(
                f"formation/{fleet}/alive/robot/r2", self._on_token, history=True
            ),
        ]

    def _on_status(self, sample: Any) -> None:
        st = msgpack.unpackb(bytes(sample.payload.to_bytes()))
        with self.cond:
            self.pid = int(st["pid"])
            self.cond.notify_all()

    def _on_clock(self, sample: Any) -> None:
        st = msgpack.unpackb(bytes(sample.payload.to_bytes()))
        with self.cond:
            self.tick = max(self.tick, int(st["tick"]))
            self.cond.notify_all()

    def _on_token(self, sample: Any) -> None:
        kind = "delete" if sample.kind == zenoh.SampleKind.DELETE else "put"
        with self.cond:
            self.token.append(kind)
            self.cond.notify_all()

    def wait(self, what: str, pred: Any, timeout_s: float = 60.0) -> None:
        with self.cond:
            if not self.cond.wait_for(pred, timeout_s):
                raise AssertionError(f"{what} not within {timeout_s} s")

    def stop_r2(self, fleet: str, tick: int) -> tuple[int, int]:
        """Once r2's status and ``tick`` were seen: SIGSTOP r2's agent (checked to be this
        fleet's); its pid and the tick it was stopped at."""
        self.wait(f"r2's status and tick {tick}", lambda: self.pid and self.tick >= tick)
        pid = self.pid
        assert pid is not None
        cmd = agent_cmdline(pid)
        assert "agent" in cmd and "r2" in cmd and fleet in cmd, cmd  # ours, r2's agent
        os.kill(pid, signal.SIGSTOP)
        return pid, self.tick

    def close(self) -> None:
        self.session.close()


def agent_cmdline(pid: int) -> str:
    return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()


def test_a_lease_expiry_in_lockstep_does_not_change_the_result(tmp_path: Path) -> None:
    base = up_process(tmp_path / "pause0", *ARGS)
    base_m = finish_process(base, tmp_path / "pause0")
    unpaused = lockstep_result(base_m)

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    run = up_process(tmp_path / "pause1", *ARGS, endpoint=endpoint)
    watch = Watch(endpoint, "pause1")
    pid: int | None = None
    try:
        tokens_before = len(watch.token)
        pid, stopped_at = watch.stop_r2("pause1", 150)
        # the lease expires: r2's token vanishes while the plant waits for r2's answer
        watch.wait("r2's token gone", lambda: "delete" in watch.token[tokens_before:], 10.0)
        assert watch.tick <= stopped_at + 1  # the plant waits: no tick went on without r2
        os.kill(pid, signal.SIGCONT)
        pid = None
        watch.wait("r2's token back", lambda: watch.token[-1] == "put", 30.0)
        watch.wait("the run goes on", lambda: watch.tick > stopped_at + 20, 60.0)
    finally:
        if pid is not None:
            os.kill(pid, signal.SIGCONT)
        watch.close()
    paused_m = finish_process(run, tmp_path / "pause1")
    assert lockstep_result(paused_m) == unpaused
    # the plant's own account, in the record: it waited for every answer of both runs
    for m in (base_m, paused_m):
        assert m["meta"]["plant"]["timeouts"] == 0 and m["meta"]["plant"]["state"] == "done"


def test_a_pause_past_the_lockstep_timeout_is_said_in_the_result(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """r2's agent stopped for longer than the plant's lockstep timeout (``formation up
    --lockstep-timeout 1``): the plant goes on without r2's answer, so the run is no longer the
    simulator's, and the run says so: the plant's timeouts in ``metrics.json``'s ``meta.plant``
    and one warning line, and so does ``formation report`` of the run's recording."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    mcap = tmp_path / "pause2.mcap"
    args = ("--lockstep", "--lockstep-timeout", "1", "--duration", "8", "--record", str(mcap))
    run = up_process(tmp_path / "pause2", *args, endpoint=endpoint)
    watch = Watch(endpoint, "pause2")
    pid: int | None = None
    try:
        pid, stopped_at = watch.stop_r2("pause2", 100)
        # after its timeout the plant steps on without r2's answer
        watch.wait("a tick without r2", lambda: watch.tick > stopped_at + 1, 30.0)
        os.kill(pid, signal.SIGCONT)
        pid = None
    finally:
        if pid is not None:
            os.kill(pid, signal.SIGCONT)
        watch.close()
    _, stderr = run.communicate(timeout=200)
    assert run.returncode == 0, stderr[-2000:]
    m = json.loads((tmp_path / "pause2" / "metrics.json").read_text())
    assert m["meta"]["plant"]["timeouts"] >= 1, m["meta"]["plant"]
    assert m["meta"]["plant"]["state"] == "done"
    said = [line for line in stderr.splitlines() if "without every answer" in line]
    assert len(said) == 1 and "not formation sim's" in said[0], stderr[-2000:]
    plant_log = (tmp_path / "pause2" / "logs" / "plant.log").read_text()
    assert "no answer from r2 within 1 s" in plant_log  # the launcher's option reached it

    capsys.readouterr()
    out = tmp_path / "report"
    assert report_mod.main([str(mcap), "--out", str(out), "--no-figures", "--quiet"]) == 0
    said = [line for line in capsys.readouterr().err.splitlines() if "without every answer" in line]
    assert len(said) == 1 and said[0].startswith("formation report: lockstep: the plant went on")
    rep = json.loads((out / "metrics.json").read_text())
    assert rep["meta"]["plant"]["timeouts"] >= 1 and rep["meta"]["plant"]["source"] == "status"
