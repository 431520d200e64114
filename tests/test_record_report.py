"""formation.record and formation.report: MCAP recording of the bus, and metrics from it.

The recorder is exercised three ways: fed directly with a synthetic lockstep stream (exact
checks of channels, schemas, times, derived channels, raw vs JSON, a torn file); as the
``formation record`` command on a real router (ready line, SIGINT, finalized file); and next to
a real ``formation up --lockstep`` run, whose own live collector's metrics.json the report must
reproduce exactly from the recording.
"""

from __future__ import annotations

import json
import shutil
import signal
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import msgpack
import numpy as np
import pytest
import zenoh
from conftest import RouterHandle, Spawner, free_port
from mcap.reader import make_reader
from test_bus_json_schema import schema_errors

import runtime as rt
from bus_schemas import (
    Assignment,
    Clock,
    Leader,
    Pose,
    Slot,
    Status,
    Truth,
    Wheels,
    encode,
    keys,
    message_type_for_key,
)
from formation import report as report_mod
from formation.bus_json import LIVELINESS_SCHEMA
from formation.record import READY_PREFIX, Recorder, start_recorder
from formation.replay import LivenessChange, Replay, read_recording
from formation.report import leader_losses
from formation.runlog import RunLog
from runtime.tap import BusItem, BusTap

FLEET = "demo"
DT = 0.02
EXIT_BOUND_S = 1.5  # requirement: exit within 1 s of SIGINT; 0.5 s margin for a loaded CI box


# ---------------------------------------------------------------------------------------------
# The recorder fed directly: a synthetic lockstep stream
# ---------------------------------------------------------------------------------------------


def synthetic_stream(ticks: int = 100) -> list[BusItem]:
    """Two robots in lockstep: clock, truth, pose, slots, leader, setpoints, wheels, status,
    assignment, liveliness (r2 lost at the end), one malformed payload, one unknown key."""
    items: list[BusItem] = []
    rx = 1_000_000_000_000

    def put(key: str, msg: Any) -> None:
        nonlocal rx
        rx += 200_000  # 0.2 ms apart
        items.append(BusItem("put", key, encode(msg), rx))

    for name in ("robot/r1", "robot/r2", "plant"):
        rx += 1000
        items.append(BusItem("alive", f"formation/{FLEET}/alive/{name}", b"", rx))
    for k in range(ticks):
        t = k * DT
        for j, rid in enumerate(("r1", "r2")):
            x, y = 0.1 + 0.02 * t - 0.3 * j, 0.2 * j
            put(keys.truth_key(FLEET, rid), Truth(t=t, seq=k, x=x, y=y, theta=0.0))
            put(keys.pose_key(FLEET, rid), Pose(t=t, seq=k, x=x, y=y, theta=0.0, robot=rid))
        put(keys.clock_key(FLEET), Clock(t=t, seq=k, tick=k))
        for s in (0, 1):
            put(
                keys.slot_key(FLEET, s),
                Slot(
                    t=t,
                    seq=k,
                    slot=s,
                    role="leader" if s == 0 else "follower",
                    stage=s,
                    parent=None if s == 0 else 0,
                    x=0.15 + 0.02 * t - 0.3 * s,
                    y=0.2 * s,
                    theta=0.0,
                    vx=0.02,
                    vy=0.0,
                ),
            )
        if k % 25 == 0:
            put(
                keys.assignment_key(FLEET),
                Assignment(t=t, seq=k, leader="r1", robots={"r1": 0, "r2": 1}),
            )
        put(
            keys.leader_key(FLEET),
            Leader(t=t, seq=k, x=0.15 + 0.02 * t, y=0.0, theta=0.0, v_mps=0.02, omega_radps=0.0),
        )
        for rid in ("r1", "r2"):
            put(
                keys.wheels_key(FLEET, rid),
                Wheels(
                    t=t,
                    seq=k,
                    omega_r=1.0,
                    omega_l=0.5,
                    power_r=0.1 + k / 1000,
                    power_l=0.05,
                    pose_t=t,
                    tick=k,
                ),
            )
            if k % 10 == 0:
                put(
                    keys.status_key(FLEET, rid),
                    Status(
                        t=t,
                        seq=k // 10,
                        mode="tracking",
                        slot=0 if rid == "r1" else 1,
                        pid=1,
                        host="h",
                        rejected=0,
                        ex=0.03,
                        ey=0.04,
                    ),
                )
    rx += 1000
    items.append(BusItem("put", keys.pose_key(FLEET, "r1"), b"\xc1", rx))  # malformed
    rx += 1000
    items.append(
        BusItem("put", f"formation/{FLEET}/lidar/c1/status", msgpack.packb({"v": 1, "t": 2.0}), rx)
    )
    rx += 1000
    items.append(BusItem("dead", f"formation/{FLEET}/alive/robot/r2", b"", rx))
    return items


def record_items(path: Path, items: list[BusItem], **kwargs: Any) -> Recorder:
    rec = Recorder(path, FLEET, **kwargs)
    for item in items:
        rec.write(item)
    rec.close()
    return rec


def test_recorder_writes_one_json_channel_per_key_with_schemas_and_times(tmp_path: Path) -> None:
    items = synthetic_stream()
    path = tmp_path / "run.mcap"
    rec = record_items(path, items)
    assert rec.stats.rejected == 1 and rec.stats.unknown == 1 and rec.stats.liveliness == 4
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None and summary.statistics is not None
        by_topic = {ch.topic: ch for ch in summary.channels.values()}
        counts = {
            summary.channels[cid].topic: n
            for cid, n in summary.statistics.channel_message_counts.items()
        }
        for rid in ("r1", "r2"):
            for leaf, n in (("truth", 100), ("pose", 100), ("wheels", 100), ("status", 10)):
                topic = f"/formation/{FLEET}/robot/{rid}/{leaf}"
                assert counts[topic] == n, topic
                ch = by_topic[topic]
                sch = summary.schemas[ch.schema_id]
                assert ch.message_encoding == "json" and sch.encoding == "jsonschema"
                assert sch.name == f"formation.{leaf.capitalize()}"
                assert ch.metadata["key"] == topic[1:]
        assert counts[f"/formation/{FLEET}/clock"] == 100
        assert counts[f"/formation/{FLEET}/alive/robot/r2"] == 2  # alive, then lost
        assert counts["/recorder/rejected"] == 1
        assert counts[f"/formation/{FLEET}/lidar/c1/status"] == 1  # unknown key: schemaless
        assert counts["/derived/robot/r1/tracking_error"] == 10
        assert counts["/derived/robot/r2/latency"] == 100
        assert counts["/scene"] > 0 and counts["/tf"] > 0
        assert summary.schemas[by_topic["/scene"].schema_id].name == "foxglove.SceneUpdate"
        meta = {m.name: m.metadata for m in reader.iter_metadata()}
        assert meta["formation.recording"]["fleet"] == FLEET
        assert meta["formation.recording.stats"]["rejected"] == "1"

        # Every JSON message validates against its channel's schema; times are right.
        schemas = {
            sid: json.loads(s.data)
            for sid, s in summary.schemas.items()
            if s.encoding == "jsonschema"
        }
        first_rx = items[0].rx_ns
        first_log: int | None = None
        checked = 0
        for _, ch, msg in reader.iter_messages():
            if ch.message_encoding != "json":
                continue
            body = json.loads(msg.data)
            if ch.schema_id:
                assert schema_errors(schemas[ch.schema_id], body) == [], ch.topic
            if first_log is None:
                first_log = msg.log_time
            if ch.topic.endswith("/robot/r1/wheels"):
                assert msg.publish_time == round(body["t"] * 1e9)
                checked += 1
        assert checked == 100 and first_log is not None
    # log_time = recorder's receive time: differences are the monotonic differences exactly
    with open(path, "rb") as f:
        alive_r2_dead = [
            m
            for _, _, m in make_reader(f).iter_messages(
                topics=[f"/formation/{FLEET}/alive/robot/r2"]
            )
        ]
    assert alive_r2_dead[-1].log_time - first_log == items[-1].rx_ns - first_rx
    assert json.loads(alive_r2_dead[-1].data) == {
        "alive": False,
        "kind": "robot",
        "id": "r2",
        "key": f"formation/{FLEET}/alive/robot/r2",
    }
    assert schema_errors(LIVELINESS_SCHEMA, json.loads(alive_r2_dead[0].data)) == []


def test_derived_channels_hold_tracking_error_and_latency(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    record_items(path, synthetic_stream(20))
    msgs: dict[str, list[dict[str, Any]]] = {}
    for topic in ("/derived/robot/r1/tracking_error", "/derived/robot/r1/latency"):
        with open(path, "rb") as f:
            reader = make_reader(f)
            msgs[topic] = [json.loads(m.data) for _, _, m in reader.iter_messages(topics=[topic])]
    err = msgs["/derived/robot/r1/tracking_error"][0]
    assert err["norm_m"] == pytest.approx(0.05) and err["slot"] == 0 and err["mode"] == "tracking"
    lat = msgs["/derived/robot/r1/latency"]
    assert len(lat) == 20
    # r1's wheels come 7 messages (0.2 ms apart) after r1's pose of the same tick (r2's truth
    # and pose, clock, 2 slots, leader); pose_age is sim time (lockstep, clock seen): 0 here
    assert all(x["pose_age_ms"] == pytest.approx(0.0) for x in lat)
    assert {round(x["rx_latency_ms"], 6) for x in lat[1:]} == {round(0.2 * 7, 6)}


def test_raw_and_json_recordings_replay_the_same_payloads_and_metrics(tmp_path: Path) -> None:
    items = synthetic_stream()
    record_items(tmp_path / "json.mcap", items)
    record_items(tmp_path / "raw.mcap", items, raw=True)
    a, b = read_recording(tmp_path / "json.mcap"), read_recording(tmp_path / "raw.mcap")
    assert (a.source, b.source) == ("json", "raw")
    assert a.complete and b.complete and a.bad_json == 0
    # JSON re-encoded with bus_schemas.encode gives the exact bytes that were on the wire
    valid = [
        it
        for it in items
        if it.kind == "put" and it.payload != b"\xc1" and "lidar/c1/status" not in it.key
    ]
    assert [e.payload for e in a.events if e.payload is not None] == [it.payload for it in valid]
    ma = report_mod.analyze(a).metrics
    mb = report_mod.analyze(b).metrics
    assert ma["robots"] == mb["robots"] and ma["run"] == mb["run"]
    assert ma["run"]["ticks"] == 100 and ma["meta"]["mode"] == "lockstep"
    assert ma["meta"]["dt_s"] == pytest.approx(DT)
    assert ma["robots"]["r1"]["final_slot"] == 0 and ma["run"]["final_leader"] == "r1"
    assert ma["robots"]["r1"]["peak_motor_power"] == pytest.approx(0.1 + 99 / 1000)
    peaks = ma["power_peaks"]["r1"]["right"]
    assert peaks["peak"] == pytest.approx(0.199) and peaks["t_s"] == pytest.approx(99 * DT)
    # r2's token vanished at the very end, and r2 was not the leader: no leader loss
    assert ma["leader_loss"] == []
    assert ma["latency"]["rx_latency_ms"]["n"] == 200


def test_a_recording_cut_short_is_read_up_to_its_last_chunk(tmp_path: Path) -> None:
    path = tmp_path / "live.mcap"
    rec = Recorder(path, FLEET, chunk_bytes=4096)
    items = synthetic_stream(60)
    for item in items:
        rec.write(item)
    torn = tmp_path / "torn.mcap"
    shutil.copyfile(path, torn)  # what a SIGKILLed recorder leaves: no summary, no footer
    rec.close()
    cut = read_recording(torn)
    full = read_recording(path)
    assert not cut.complete and full.complete
    assert 0 < len(cut.events) < len(full.events)
    assert [e.payload for e in cut.events] == [e.payload for e in full.events[: len(cut.events)]]


def test_report_rejects_a_file_that_is_not_mcap(tmp_path: Path) -> None:
    bad = tmp_path / "x.mcap"
    bad.write_bytes(b"not an mcap file at all" * 10)
    with pytest.raises(report_mod.ReportError):
        read_recording(bad)
    assert report_mod.main([str(bad), "--quiet"]) == 1


# ---------------------------------------------------------------------------------------------
# Leader-loss recovery
# ---------------------------------------------------------------------------------------------


def test_leader_loss_recovery_is_the_settling_time_after_the_token_vanished() -> None:
    ids = ["r1", "r2", "r3"]
    ticks = 101  # 0 .. 10 s
    log = RunLog.allocate(ids, [0, 1, 2], ticks)
    log.t_s[:] = np.arange(ticks) * 0.1
    log.ref[:] = 0.0
    err = np.full((ticks, 3), 0.01)
    loss_k = 40  # r1 (leader) lost at 4.0 s; r2 takes slot 0, 0.3 m away, converges by 6.5 s
    err[loss_k:, 0] = np.nan
    err[loss_k:, 1] = np.interp(log.t_s[loss_k:], [4.0, 6.5], [0.3, 0.01])
    err[loss_k + 5, 2] = 0.08  # r3 disturbed a little at 4.5 s
    log.target[:, :, 0] = err
    log.target[:, :, 1] = 0.0
    log.slot_of[:] = [0, 1, 2]
    log.slot_of[loss_k:] = [-1, 0, 1]
    alive_after = frozenset(
        {f"formation/{FLEET}/alive/plant", *(f"formation/{FLEET}/alive/robot/{r}" for r in ids[1:])}
    )
    rp = Replay(lockstep=True)
    rp.changes.append(
        LivenessChange(f"formation/{FLEET}/alive/robot/r1", False, 4.0, "r1", alive_after)
    )
    # a follower lost later is not a leader loss; a leader lost during shutdown is not either
    rp.changes.append(
        LivenessChange(f"formation/{FLEET}/alive/robot/r3", False, 9.95, "r2", frozenset())
    )
    (loss,) = leader_losses(log, rp, FLEET, tol_m=0.05, dt_s=0.1)
    # worst remaining error <= 0.05 from t where 0.3 - 0.29 * (t - 4) / 2.5 <= 0.05: t >= 6.155
    assert loss["robot"] == "r1" and loss["t_s"] == 4.0 and loss["tick"] == 40
    assert loss["remaining"] == ["r2", "r3"]
    assert loss["recovered_at_s"] == pytest.approx(6.2) and loss["recovery_s"] == pytest.approx(2.2)
    assert loss["peak_error_m"] == pytest.approx(0.3) and loss["new_leader"] == "r2"


def test_a_leader_that_never_recovers_reports_none() -> None:
    log = RunLog.allocate(["r1", "r2"], [0, 1], 50)
    log.t_s[:] = np.arange(50) * 0.1
    log.ref[:] = 0.0
    log.target[:, :, 0] = 0.5
    log.target[:, :, 1] = 0.0
    rp = Replay(lockstep=True)
    alive = frozenset({f"formation/{FLEET}/alive/plant", f"formation/{FLEET}/alive/robot/r2"})
    rp.changes.append(LivenessChange(f"formation/{FLEET}/alive/robot/r1", False, 1.0, "r1", alive))
    (loss,) = leader_losses(log, rp, FLEET, tol_m=0.05, dt_s=0.1)
    assert loss["recovery_s"] is None and loss["peak_error_m"] == pytest.approx(0.5)


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


# ---------------------------------------------------------------------------------------------
# formation record on a real router
# ---------------------------------------------------------------------------------------------


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
    from formation import record

    assert record.main(["--out", str(tmp_path / "x.mcap"), "--fleet", "a/b"]) == 2
    assert record.main(["--out", str(tmp_path / "x.mcap"), "--duration", "0"]) == 2
    assert record.main(["--out", str(tmp_path / "x.mcap"), "--scenario", "nope"]) == 2


# ---------------------------------------------------------------------------------------------
# Round trip on a real distributed run
# ---------------------------------------------------------------------------------------------


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
        # Samples still in flight to the recorder's session when `up` exits (a starved machine):
        # wait until it has every clock tick the live collector saw before closing it.
        clocks = live["meta"]["collector"]["received"]["clock"]
        deadline = time.monotonic() + 60.0
        while time.monotonic() < deadline:
            if handle.recorder.stats.per_key.get(keys.clock_key(FLEET), 0) >= clocks:
                break
            time.sleep(0.05)
    finally:
        stats = handle.close()
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
    from formation import sim_cli, simulate

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
