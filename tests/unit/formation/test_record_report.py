"""formation.record.command and formation.record.report fed directly: MCAP recording of a synthetic
stream,
and metrics from it.

The recorder is fed a synthetic lockstep stream (exact checks of channels, schemas, times,
derived channels, raw vs JSON, a torn file); the report's leader-loss recovery is computed on
hand-made run logs. The recorder on a real bus (the ``formation record`` command, next to a real
``formation up --lockstep`` run) is in tests/fleet/test_record_live.py.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from mcap.reader import make_reader
from support.json_schema import schema_errors
from support.record_stream import DT, FLEET, record_items, synthetic_stream

from formation.outputs.bus_json import LIVELINESS_SCHEMA
from formation.outputs.runlog import RunLog
from formation.record import report as report_mod
from formation.record.command import Recorder
from formation.record.replay import LivenessChange, Replay, read_recording
from formation.record.report import leader_losses


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
