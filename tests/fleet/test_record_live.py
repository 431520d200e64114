"""formation.record.command on a real bus: the bus tap, the ``formation record`` command on a real
router (ready line, SIGINT, finalized file), and recordings of real ``formation up --lockstep``
runs whose own live collector's metrics.json the report must reproduce exactly (and, with
``--record``, the in-process simulator's).

The recorder fed directly with a synthetic stream is in tests/unit/formation/test_record_report.py.
"""

from __future__ import annotations

import json
import signal
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
import zenoh
from mcap.reader import make_reader
from support.json_schema import schema_errors
from support.routers import RouterHandle
from support.spawn import Spawner, free_port

import runtime as rt
from bus_schemas import Pose, encode, keys, message_type_for_key
from formation.record import report as report_mod
from formation.record.command import READY_PREFIX, start_recorder
from runtime.tap import BusItem, BusTap

pytestmark = pytest.mark.shares_cpu

FLEET = "demo"
DT = 0.02
BLOCK = zenoh.CongestionControl.BLOCK

EXIT_BOUND_S = 1.5  # requirement: exit within 1 s of SIGINT; 0.5 s margin for a loaded CI box


# ---------------------------------------------------------------------------------------------
# The bus tap (the recorder's worker thread) on a real session
# ---------------------------------------------------------------------------------------------


@pytest.mark.alone
def test_bus_tap_survives_handler_errors_and_bounds_its_close(
    session: Callable[..., zenoh.Session],
) -> None:
    handled: list[str] = []

    def slow_and_fragile(item: BusItem) -> None:
        if item.key.endswith("/bad"):
            raise ValueError("boom")
        time.sleep(0.02)
        handled.append(item.key)

    tap = BusTap(session(), FLEET, slow_and_fragile, name="test-tap")
    tap.feed(BusItem("put", f"formation/{FLEET}/bad", b"", 0))
    for k in range(100):  # 2 s of work queued
        tap.feed(BusItem("put", f"formation/{FLEET}/k{k}", b"", k))
    start = time.monotonic()
    tap.close(timeout_s=0.3)
    took = time.monotonic() - start
    assert took < 1.0, f"close took {took:.2f} s"
    assert tap.errors == 1 and 0 < len(handled) < 100
    assert tap.received == 101 and tap.dropped == 100 - len(handled)
    n = len(handled)
    time.sleep(0.05)
    assert len(handled) == n  # the worker has stopped


@pytest.mark.alone
def test_bus_tap_keeps_a_backlog_its_router_had_when_the_router_exits(spawn: Spawner) -> None:
    """A tap whose worker is slower than the bus (1 ms of Python per sample: a recorder on a
    starved machine) and whose router exits right after the last put: every sample published
    before is handled, and the router exits at once with status 0. With the samples taken on
    Zenoh's network thread (a callback that needs the GIL the worker holds), the session read
    its link slowly, the router held the backlog and, trying to flush it at its exit, overran
    its exit bound and was forced out (status 70) with it: 2816 and 3115 of 4000 handled next to
    CPU hogs; a recording of a finished `formation up --lockstep` run missed its last ticks
    (runtime.bridge.subscribe_buffered). On an idle machine the old way may pass too."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    router = spawn("router", "--listen", endpoint, ready="router listening on ")
    settings = rt.ZenohSettings(connect=(endpoint,), open_timeout_s=10.0)
    handled: list[int] = []

    def slow(item: BusItem) -> None:
        start = time.perf_counter()
        while time.perf_counter() - start < 0.001:
            pass
        handled.append(int(item.payload))

    sub, pub = rt.open_session(settings), rt.open_session(settings)
    try:
        tap = BusTap(sub, FLEET, slow, name="slow-tap")
        time.sleep(0.5)  # the subscription reaches the router
        n = 4000
        for k in range(n):  # 8 MB: more than the socket buffers hold
            pub.put(f"formation/{FLEET}/k", str(k).encode().ljust(2000), congestion_control=BLOCK)
        pub.close()
        exit_s = router.stop(signal.SIGINT, timeout_s=10.0)
        assert router.proc.returncode == 0, router.describe()
        assert exit_s < EXIT_BOUND_S, f"the router took {exit_s:.2f} s to exit"
        deadline = time.monotonic() + 60.0
        while len(handled) < n and time.monotonic() < deadline:
            time.sleep(0.05)
        tap.close()
    finally:
        sub.close()
    assert handled == list(range(n)) and tap.dropped == 0


# ---------------------------------------------------------------------------------------------
# formation record on a real router
# ---------------------------------------------------------------------------------------------


@pytest.mark.alone
def test_record_command_finalizes_the_file_within_a_second_of_sigint(
    spawn: Spawner, router: RouterHandle, session: Callable[..., zenoh.Session], tmp_path: Path
) -> None:
    out = tmp_path / "rec.mcap"
    child = spawn("record", "--out", str(out), "--endpoint", router.endpoint, ready=READY_PREFIX)
    assert f"formation/{FLEET}/**" in child.stdout()
    pub = session()
    token = rt.declare_token(pub, keys.alive_robot_key(FLEET, "r1"))
    t0 = 100.0
    for k in range(20):
        pub.put(
            keys.pose_key(FLEET, "r1"), encode(Pose(t=t0 + k * 0.1, seq=k, x=0.1, y=0.2, theta=0.0))
        )
    pub.put(keys.pose_key(FLEET, "r1"), b"\x92\x01\x02")  # valid msgpack, not a map
    time.sleep(0.3)
    token.undeclare()
    time.sleep(0.3)
    exit_s = child.stop(signal.SIGINT, timeout_s=5.0)
    assert child.proc.returncode == 0, child.describe()
    assert exit_s < EXIT_BOUND_S, f"exit took {exit_s:.2f} s"
    assert "recorded 20 samples (1 rejected, 2 liveliness changes)" in child.stdout()
    with open(out, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()  # present only in a finalized file
        assert summary is not None and summary.statistics is not None
        poses = [
            m for _, _, m in reader.iter_messages(topics=[f"/formation/{FLEET}/robot/r1/pose"])
        ]
        assert [m.publish_time for m in poses] == [round((t0 + k * 0.1) * 1e9) for k in range(20)]
        assert abs(poses[0].log_time - time.time_ns()) < 60e9  # wall clock
        rejected = [
            json.loads(m.data) for _, _, m in reader.iter_messages(topics=["/recorder/rejected"])
        ]
        assert [r["reason"] for r in rejected] == ["not_a_map"]
        alive = [
            json.loads(m.data)["alive"]
            for _, _, m in reader.iter_messages(topics=[f"/formation/{FLEET}/alive/robot/r1"])
        ]
        assert alive == [True, False]


def test_record_command_rejects_bad_arguments(tmp_path: Path) -> None:
    from formation.record import command as record

    assert record.main(["--out", str(tmp_path / "x.mcap"), "--fleet", "a/b"]) == 2
    assert record.main(["--out", str(tmp_path / "x.mcap"), "--duration", "0"]) == 2
    assert record.main(["--out", str(tmp_path / "x.mcap"), "--scenario", "nope"]) == 2


# ---------------------------------------------------------------------------------------------
# Round trip on a real distributed run
# ---------------------------------------------------------------------------------------------


def test_lockstep_end_of_run_waits_for_the_final_ticks_answers_not_a_time() -> None:
    """What `formation up --lockstep` waits for after the plant ran its duration
    (``RunCollector.tick_complete``): the last tick's truth of every robot, the coordinator's
    leader of that tick and every live robot's wheels answering it, however late they come (on
    a starved machine the answers trail the truth); a robot whose token is gone is not waited
    for (the plant went on without it)."""
    from support.run_traffic import FLEET as UP_FLEET
    from support.run_traffic import bus_messages

    import scenario
    from formation.record.collector import RunCollector
    from formation.sim import simulate

    scn = scenario.load("paper-exp1")
    log = simulate.run(scn, duration_s=0.1).log
    final = log.t_s.size - 1
    msgs = bus_messages(log, scn.dt_s)
    col = RunCollector.for_scenario(scn, fleet=UP_FLEET, lockstep=True)
    # the last tick's answers (leader, wheels) held back: the truth alone is not the end
    last_t = float(log.t_s[-1])
    answers = [m for m in msgs if m[0].endswith(("/leader", "/wheels"))]
    tail = [m for m in answers if _msg_t(m[1]) == last_t]
    col.feed_all([m for m in msgs if m not in tail])
    assert col.last_truth_tick == final and not col.tick_complete(final)
    leader = [m for m in tail if m[0].endswith("/leader")]
    wheels = [m for m in tail if m[0].endswith("/wheels")]
    assert len(leader) == 1 and len(wheels) == len(scn.robot_ids)
    col.feed_all(leader + wheels[:-1])
    assert not col.tick_complete(final)  # one robot's answer still missing
    gone = keys.parse_robot_key(wheels[-1][0])
    assert gone is not None
    col.feed_alive(keys.alive_robot_key(UP_FLEET, gone[1]), False)
    assert col.tick_complete(final)  # its agent is gone: the plant did not wait for it either
    col.feed_alive(keys.alive_robot_key(UP_FLEET, gone[1]), True)
    assert not col.tick_complete(final)
    col.feed_all(wheels[-1:])
    assert col.tick_complete(final) and not col.tick_complete(final + 1)
    assert col.build().t_s.size == final + 1


def _msg_t(payload: bytes) -> float:
    import msgpack

    return float(msgpack.unpackb(payload)["t"])


@pytest.mark.slow
def test_report_of_a_recorded_lockstep_run_equals_the_live_collectors_metrics(
    spawn: Spawner, tmp_path: Path
) -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    up_out = tmp_path / "up"
    duration = 4.0
    up = spawn(
        "up",
        "--lockstep",
        "--scenario",
        "paper-exp1",
        "--duration",
        str(duration),
        "--endpoint",
        endpoint,
        "--out",
        str(up_out),
        "--no-figures",
        "--quiet",
    )
    # The recorder joins as soon as up's router listens, before the plant starts its clock
    # (the plant waits for every agent's token; each agent takes a Python start).
    handle = start_recorder(
        rt.ZenohSettings(connect=(endpoint,), open_timeout_s=30.0), FLEET, tmp_path / "run.mcap"
    )
    try:
        assert up.proc.wait(timeout=120) == 0, up.describe()
        live = json.loads((up_out / "metrics.json").read_text())
        # Samples still queued in the recorder's process when `up` exits (a starved machine):
        # wait until it has written every clock tick the live collector saw before closing it.
        # (They must be in this process by then: up's router exits with up, and what it still
        # held for a slow subscriber was lost with it; runtime.bridge.subscribe_buffered.)
        clocks = live["meta"]["collector"]["received"]["clock"]
        deadline = time.monotonic() + 60.0
        while (
            recorded := handle.recorder.stats.per_key.get(keys.clock_key(FLEET), 0)
        ) < clocks and time.monotonic() < deadline:
            time.sleep(0.05)
    finally:
        stats = handle.close()
    assert recorded >= clocks, f"the recording has {recorded} of the run's {clocks} clock ticks"
    assert stats.dropped == 0 and stats.handler_errors == 0 and stats.rejected == 0

    rep_out = tmp_path / "report"
    settle = live["run"]["settle_s"]
    code = report_mod.main(
        [
            str(tmp_path / "run.mcap"),
            "--out",
            str(rep_out),
            "--scenario",
            "paper-exp1",
            "--settle",
            str(settle),
            "--quiet",
        ]
    )
    assert code == 0
    for name in ("trajectories", "motor_power", "formation_error", "roles"):
        assert (rep_out / f"{name}.png").stat().st_size > 10_000
    rep = json.loads((rep_out / "metrics.json").read_text())
    assert rep["meta"]["collector"]["first_tick"] == 0, "the recorder joined late"
    assert rep["robots"] == live["robots"]
    assert rep["run"] == live["run"]
    assert rep["run"]["ticks"] > 0 and rep["run"]["collisions"] == 0
    assert rep["latency"]["rx_latency_ms"]["n"] > 0
    assert 0.0 < rep["latency"]["rx_latency_ms"]["p50"] < 100.0
    assert rep["leader_loss"] == []  # the run was not disturbed
    # the plant waited for every answer: its own file says so live, its status in the recording
    assert live["meta"]["plant"]["timeouts"] == 0 and rep["meta"]["plant"]["timeouts"] == 0
    assert live["meta"]["plant"]["source"] == "plant_stats.json"
    assert rep["meta"]["plant"]["source"] == "status"

    # The file itself: a channel per key, schemas present, counts > 0, JSON decodes.
    with open(tmp_path / "run.mcap", "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None and summary.statistics is not None
        counts = {
            summary.channels[c].topic: n
            for c, n in summary.statistics.channel_message_counts.items()
        }
        for rid in ("r1", "r2", "r3"):
            for leaf in ("truth", "pose", "wheels", "setpoint", "status"):
                assert counts[f"/formation/{FLEET}/robot/{rid}/{leaf}"] > 0
        for key in ("clock", "leader", "assignment", "slot/0", "slot/1", "slot/2"):
            assert counts[f"/formation/{FLEET}/{key}"] > 0
        assert counts[f"/formation/{FLEET}/alive/plant"] >= 1
        for ch in summary.channels.values():
            if ch.topic.startswith("/formation/") and ch.schema_id:
                assert summary.schemas[ch.schema_id].encoding == "jsonschema"
        for _, _, msg in reader.iter_messages(topics=[f"/formation/{FLEET}/robot/r2/wheels"]):
            body = json.loads(msg.data)
            assert set(body) >= {"v", "t", "seq", "omega_r", "power_r", "pose_t"}


# ---------------------------------------------------------------------------------------------
# formation up --record, then formation report: the file, the figures, the simulator's metrics
# ---------------------------------------------------------------------------------------------


@pytest.mark.zenoh
@pytest.mark.slow
def test_up_record_then_report_reproduces_the_in_process_simulator(
    spawn: Spawner, tmp_path: Path
) -> None:
    """``formation up --lockstep --record`` on 4 s of paper-exp2: the MCAP file read back by the
    mcap library (one channel per key, JSON Schemas, the run's metadata), ``formation report
    --compare-sim`` on it (metrics.json, the four figures), and the metrics computed from truth,
    commands and assignment (``robots`` and ``run``: error RMS, settling, separation, collisions,
    role changes with their times, motor power peaks) of the live run's metrics.json, of the
    report's and of ``formation sim``'s metrics.json for the same scenario, seed and duration are
    equal, exactly: the lockstep plant publishes truth at every tick, so all three are computed
    on the same 201 ticks."""
    import scenario
    from formation.sim import command as sim_cli
    from formation.sim import simulate

    fleet, seed, duration = "rec1", 3, 4.0
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    up_out, mcap_path, rep_out = tmp_path / "up", tmp_path / "run.mcap", tmp_path / "report"
    up = spawn(
        "up", "--lockstep", "--scenario", "paper-exp2", "--duration", str(duration),
        "--seed", str(seed), "--endpoint", endpoint, "--fleet", fleet, "--out", str(up_out),
        "--no-figures", "--quiet", "--record", str(mcap_path),
    )  # fmt: skip
    assert up.proc.wait(timeout=120) == 0, up.describe()
    live = json.loads((up_out / "metrics.json").read_text())
    assert live["meta"]["record"] == str(mcap_path)

    # The file, read back by the mcap library.
    with open(mcap_path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None and summary.statistics is not None
        topics = [ch.topic for ch in summary.channels.values()]
        assert len(topics) == len(set(topics)), "one channel per key"
        counts = {
            summary.channels[c].topic: n
            for c, n in summary.statistics.channel_message_counts.items()
        }
        expected = [f"robot/{r}/{leaf}" for r in ("r1", "r2", "r3")
                    for leaf in ("truth", "pose", "wheels", "setpoint", "status")]  # fmt: skip
        expected += ["clock", "leader", "assignment", "slot/0", "slot/1", "slot/2"]
        expected += ["alive/plant", "alive/coordinator/main", "alive/robot/r1"]
        for key in expected:
            assert counts.get(f"/formation/{fleet}/{key}", 0) > 0, key
        ticks = round(duration / DT) + 1
        assert counts[f"/formation/{fleet}/clock"] == ticks
        assert counts[f"/formation/{fleet}/robot/r2/wheels"] == ticks
        schemas: dict[str, dict[str, Any]] = {}
        for ch in summary.channels.values():
            if ch.topic.startswith(f"/formation/{fleet}/"):
                assert ch.message_encoding == "json", ch.topic
                if "/alive/" not in ch.topic and message_type_for_key(ch.topic[1:]) is None:
                    continue  # a node's extra key outside the bus contract: schemaless JSON
                assert ch.schema_id != 0, ch.topic
                schema = summary.schemas[ch.schema_id]
                assert schema.encoding == "jsonschema" and schema.name.startswith("formation.")
                schemas[ch.topic] = json.loads(schema.data)
        assert (
            summary.schemas[
                next(
                    c.schema_id for c in summary.channels.values() if c.topic.endswith("r1/wheels")
                )
            ].name
            == "formation.Wheels"
        )
        assert {"/scene", "/tf", "/derived/robot/r1/tracking_error"} <= set(topics)
        meta = {m.name: m.metadata for m in reader.iter_metadata()}
        assert meta["formation.run"]["lockstep"] == "true"
        assert meta["formation.run"]["seed"] == str(seed)
        assert meta["formation.recording"]["fleet"] == fleet
        truth_r1: dict[int, tuple[float, float, float]] = {}
        for _, channel, msg in reader.iter_messages(
            topics=[f"/formation/{fleet}/robot/r1/wheels", f"/formation/{fleet}/robot/r1/truth"]
        ):
            body = json.loads(msg.data)
            assert schema_errors(schemas[channel.topic], body) == [], channel.topic
            assert msg.publish_time == round(body["t"] * 1e9)
            if channel.topic.endswith("/truth"):
                truth_r1[round(body["t"] * 1e6)] = (body["x"], body["y"], body["theta"])

    # formation report on it, as a subprocess.
    rep = spawn("report", str(mcap_path), "--out", str(rep_out), "--compare-sim", "--quiet")
    assert rep.proc.wait(timeout=120) == 0, rep.describe()
    for name in ("trajectories", "motor_power", "formation_error", "roles"):
        assert (rep_out / f"{name}.png").stat().st_size > 10_000, name
    m_rep = json.loads((rep_out / "metrics.json").read_text())
    assert m_rep["robots"] == live["robots"] and m_rep["run"] == live["run"]
    assert m_rep["meta"]["collector"]["first_tick"] == 0
    assert m_rep["recording"]["complete"] is True
    assert m_rep["latency"]["rx_latency_ms"]["n"] > 0
    assert set(m_rep["power_peaks"]) == {"r1", "r2", "r3"}
    cmp = m_rep["simulator_comparison"]
    assert cmp["robots_equal"] and cmp["run_equal"] and cmp["differences"] == []
    assert cmp["every_tick"] is True and cmp["instants"] == cmp["simulator_ticks"] == ticks

    # Truth is on the bus at every tick, bit for bit the simulator's.
    scn = scenario.load("paper-exp2")
    sim = simulate.run(scn, seed=seed, duration_s=duration).log
    assert sim.t_s.size == ticks == counts[f"/formation/{fleet}/robot/r1/truth"]
    assert sorted(truth_r1) == [round(float(t) * 1e6) for t in sim.t_s]
    for k in range(ticks):
        assert truth_r1[round(float(sim.t_s[k]) * 1e6)] == tuple(float(v) for v in sim.truth[k, 0])

    # `formation sim --out DIR` for the same scenario, seed and duration: its metrics.json equals
    # the live run's and the report's, every metric computed from the run (not only a subset).
    sim_out = tmp_path / "sim"
    assert sim_cli.main(
        ["--scenario", "paper-exp2", "--seed", str(seed), "--duration", str(duration),
         "--out", str(sim_out), "--no-figures", "--quiet"]
    ) == 0  # fmt: skip
    m_sim = json.loads((sim_out / "metrics.json").read_text())
    for part in ("robots", "run"):
        assert live[part] == m_sim[part], report_mod.differences(live[part], m_sim[part])
        assert m_rep[part] == m_sim[part], report_mod.differences(m_rep[part], m_sim[part])
    assert m_sim["run"]["ticks"] == ticks and m_sim["run"]["settle_s"] == duration / 2
    assert m_sim["run"]["collisions"] == 0 and m_sim["run"]["role_change_count"] == 0
    assert len(m_sim["run"]["initial_assignments"]) == 3  # the first slots are not changes
    for r in m_sim["robots"].values():  # the settled part and the power peaks are measured
        assert r["formation_error_rms_m"] > 0.0 and r["peak_motor_power"] > 0.0
