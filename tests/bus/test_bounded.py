"""Bounded memory (issue 13, item 6): the message size cap of every session and the launcher's
collector memory bound; the fault tool's command-line parsing and verification helpers."""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from support.routers import RouterHandle

import runtime as rt
from bus_schemas import Truth, Wheels, encode, keys
from formation.operate import fault
from formation.record.collector import RunCollector

pytestmark = pytest.mark.shares_cpu

FLEET = "bounded"
IDS = ["r1", "r2", "r3"]


def collector(max_entries: int | None, dt_s: float | None = None) -> RunCollector:
    return RunCollector(
        IDS, fleet=FLEET, dt_s=dt_s, ref_offset_m=0.05, body_radius_m=0.075,
        max_entries=max_entries,
    )  # fmt: skip


def feed_run(c: RunCollector, frames: int, dt: float = 0.02) -> None:
    for k in range(frames):
        t = 100.0 + k * dt
        for i, rid in enumerate(IDS):
            truth = Truth(t=t, seq=k, x=0.01 * k, y=0.5 * i, theta=0.0)
            c.feed(keys.truth_key(FLEET, rid), encode(truth))
            wheels = Wheels(
                t=t, seq=k, omega_r=1.0, omega_l=1.0, power_r=0.1, power_l=0.1, pose_t=None,
                tick=None, saturated=None,
            )  # fmt: skip
            c.feed(keys.wheels_key(FLEET, rid), encode(wheels))


def test_realtime_collector_thins_its_history_within_the_bound() -> None:
    bounded, full = collector(2000), collector(None)
    feed_run(bounded, 5000)
    feed_run(full, 5000)
    assert full.stats()["decimation"] == 1
    st = bounded.stats()
    assert st["decimation"] >= 8  # 30000 values into 2000
    assert bounded.history.entries <= 2000
    stored = sum(len(r) for r in bounded.history.truth.values()) + sum(
        len(s.keys) for s in bounded.history.thinned_series()
    )
    assert stored == bounded.history.entries
    log, ref = bounded.build(), full.build()
    # the whole run is still covered, at a lower time resolution, with the same poses
    stride_s = 0.02 * st["decimation"]
    assert log.t_s[0] == 0.0 and log.t_s[-1] >= ref.t_s[-1] - stride_s
    assert log.t_s.size < ref.t_s.size / 4
    for row in (0, log.t_s.size // 2, -1):
        k = round(float(log.t_s[row]) / 0.02)
        assert log.t_s[row] == pytest.approx(ref.t_s[k])  # the same time axis
        assert log.truth[row] == pytest.approx(ref.truth[k])


def test_lockstep_collector_is_never_thinned() -> None:
    c = collector(1000, dt_s=0.02)
    assert c.max_entries is None
    feed_run(c, 600)
    assert c.stats()["decimation"] == 1


def test_every_session_caps_the_message_size(
    router: RouterHandle, session: Callable[..., Any]
) -> None:
    assert rt.MAX_MESSAGE_BYTES == 128 * 1024
    conf = rt.make_config(rt.ZenohSettings())
    assert int(conf.get_json("transport/link/rx/max_message_size")) == rt.MAX_MESSAGE_BYTES
    pub, sub = session(), session()
    got: list[int] = []
    s = sub.declare_subscriber("cap/test", lambda sample: got.append(len(sample.payload)))
    try:
        time.sleep(0.3)
        for size in (32 * 1024, 1024 * 1024, 16 * 1024):
            pub.put("cap/test", b"x" * size)
        deadline = time.monotonic() + 3.0
        while len(got) < 2 and time.monotonic() < deadline:
            time.sleep(0.02)
        time.sleep(0.3)
    finally:
        s.undeclare()
    assert got == [32 * 1024, 16 * 1024]  # the 1 MiB message is never delivered


# ---------------------------------------------------------------------------------------------
# formation fault: parsing and verification helpers (no bus)
# ---------------------------------------------------------------------------------------------


def parse(*argv: str) -> argparse.Namespace:
    return fault.build_parser().parse_args(list(argv))


def test_fault_options_before_or_after_the_command() -> None:
    for argv in (
        ("--fleet", "f", "--endpoint", "tcp/127.0.0.1:9", "--timeout", "2", "kill", "r1"),
        ("kill", "r1", "--fleet", "f", "--endpoint", "tcp/127.0.0.1:9", "--timeout", "2"),
        ("--fleet", "f", "kill", "r1", "--endpoint", "tcp/127.0.0.1:9", "--timeout", "2"),
    ):
        ns = parse(*argv)
        assert (ns.command, ns.robot, ns.fleet, ns.timeout) == ("kill", "r1", "f", 2.0)
        assert ns.zenoh_connect == ["tcp/127.0.0.1:9"]
    ns = parse("kill-leader")  # the fleet is found later: $FORMATION_FLEET, the run file, demo
    assert (ns.fleet, ns.timeout, ns.zenoh_connect) == (None, 3.0, None)
    text = " ".join(fault.build_parser().format_help().split())
    assert "examples:" in text and "default 3 s" in text and "else demo" in text


def test_fault_bad_arguments_exit_2(capsys: pytest.CaptureFixture[str]) -> None:
    assert fault.main(["kill", "r1", "--timeout", "-1"]) == 2
    assert fault.main(["--fleet", "bad fleet!", "kill", "r1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and all(line.startswith("formation fault: ") for line in err)


def test_verify_process_reads_the_command_line(tmp_path: Path) -> None:
    where = fault.Where("demo", frozenset({fault.norm_endpoint("tcp/127.0.0.1:7500")}))
    assert fault.norm_endpoint("tls/localhost:7500") == fault.norm_endpoint("tcp/127.0.0.1:7500")
    # a process with an agent's command line: a stand-in `formation` package that sleeps
    (tmp_path / "formation").mkdir()
    (tmp_path / "formation" / "__init__.py").write_text("")
    (tmp_path / "formation" / "__main__.py").write_text("import time\ntime.sleep(60)\n")
    proc = subprocess.Popen(
        [
            sys.executable, "-m", "formation", "agent", "--id", "r2", "--endpoint",
            "tcp/127.0.0.1:7500", "--fleet", "demo",
        ],
        cwd=tmp_path,
        env={"PATH": os.environ.get("PATH", "")},
    )  # fmt: skip
    try:
        pid = proc.pid
        deadline = time.monotonic() + 5
        while fault.cmdline(pid) is None or "agent" not in (fault.cmdline(pid) or []):
            assert time.monotonic() < deadline
            time.sleep(0.01)
        assert fault.verify_process(pid, "agent", "r2", where) is None
        assert "not the agent of r3" in str(fault.verify_process(pid, "agent", "r3", where))
        other_fleet = fault.Where("other", where.endpoints)
        assert "fleet 'demo'" in str(fault.verify_process(pid, "agent", "r2", other_fleet))
        other_ep = fault.Where("demo", frozenset({fault.norm_endpoint("tcp/127.0.0.1:7501")}))
        assert "connected to" in str(fault.verify_process(pid, "agent", "r2", other_ep))
        assert "not `formation coordinator`" in str(
            fault.verify_process(pid, "coordinator", "main", where)
        )
        assert fault.find_processes("agent", "r2", where) == [pid]
        assert fault.find_processes("agent", "r2", where, stopped=True) == []
        assert fault.verify_process(os.getpid(), "agent", "r2", where) is not None
        assert fault.verify_process(1, "agent", "r2", where) is not None
    finally:
        proc.kill()
        proc.wait()
