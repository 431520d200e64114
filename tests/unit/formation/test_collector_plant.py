"""The plant's status in a run's record: a lockstep run that went on without every answer says
so (``meta.plant.timeouts`` and one warning line), whatever order the statuses came in."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

from support.bus_samples import SAMPLES

from bus_schemas import PlantStatus, Truth, encode, keys, to_map
from formation.launch.results import plant_account
from formation.record.collector import RunCollector, key_patterns
from formation.record.collector_plant import inexact_line

FLEET = keys.DEFAULT_FLEET
STATUS = SAMPLES[PlantStatus]


def collector() -> RunCollector:
    c = RunCollector(["r1"], slot_ids=[0], fleet=FLEET, dt_s=0.02, ref_offset_m=0.05,
                     body_radius_m=0.05)  # fmt: skip
    for k in range(10):
        c.feed(keys.truth_key(FLEET, "r1"),
               encode(Truth(t=k * 0.02, seq=k + 1, x=0.0, y=0.0, theta=0.0)))  # fmt: skip
    return c


def status(seq: int, t: float, timeouts: int, state: str = "running") -> bytes:
    return encode(replace(STATUS, seq=seq, t=t, tick=round(t / 0.02), timeouts=timeouts,
                          state=state))  # fmt: skip


def test_the_collector_subscribes_to_the_plant_status() -> None:
    assert keys.plant_status_key(FLEET) in key_patterns(FLEET)


def test_no_plant_status_leaves_the_record_without_it() -> None:
    log = collector().build()
    assert "plant" not in log.meta


def test_the_newest_status_and_the_most_timeouts_are_kept() -> None:
    c = collector()
    key = keys.plant_status_key(FLEET)
    assert c.feed(key, status(1, 0.2, 0))
    assert c.feed(key, status(3, 0.6, 2))
    assert c.feed(key, status(2, 0.4, 1))  # late: older than the newest
    assert c.feed(key, status(4, 0.8, 2, state="done"))
    assert not c.feed(key, b"\x81\xa1v\x01")  # a bad payload: rejected, counted
    assert c.rejected == 1 and [r.split(":")[0] for r in c.reject_reasons] == ["plant status"]
    plant = c.build().meta["plant"]
    assert plant == {"mode": "lockstep", "state": "done", "tick": 40, "timeouts": 2,
                     "rejected": 0, "internal_errors": 0, "source": "status"}  # fmt: skip


def test_a_respawned_plant_counting_from_zero_keeps_the_timeouts_seen() -> None:
    c = collector()
    key = keys.plant_status_key(FLEET)
    c.feed(key, status(9, 0.4, 3))
    c.feed(key, status(1, 0.6, 0))  # the new plant's first status: seq again from 1, later t
    plant = c.build().meta["plant"]
    assert plant["timeouts"] == 3 and plant["tick"] == 30


def test_a_lockstep_run_with_timeouts_says_so_on_one_line() -> None:
    assert inexact_line(None) is None and inexact_line({"timeouts": 0}) is None
    one, many = inexact_line({"timeouts": 1}), inexact_line({"timeouts": 81})
    assert one is not None and many is not None and "\n" not in one + many
    assert one.startswith("lockstep: the plant went on 1 time without every answer")
    assert many.startswith("lockstep: the plant went on 81 times without every answer")
    assert "not formation sim's" in many and "--lockstep-timeout" in many


def test_the_plants_own_last_word_is_put_over_its_status(tmp_path: Path) -> None:
    seen = {"mode": "lockstep", "state": "running", "tick": 390, "timeouts": 1, "rejected": 0,
            "internal_errors": 0, "source": "status"}  # fmt: skip
    stats = tmp_path / "plant_stats.json"
    assert plant_account(stats, None) is None  # neither: nothing known
    assert plant_account(stats, seen) == seen  # no file (the plant could not write it)
    stats.write_text("{not json")
    assert plant_account(stats, seen) == seen
    stats.write_text(json.dumps({"state": "done", "timeouts": "many"}))
    assert plant_account(stats, seen) == seen  # not the plant's fields
    stats.write_text(json.dumps({**to_map(STATUS), "state": "done", "tick": 400, "timeouts": 2,
                                 "latency_ms": None, "n_robots": 3}))  # fmt: skip
    assert plant_account(stats, seen) == {
        "mode": "lockstep", "state": "done", "tick": 400, "timeouts": 2, "rejected": 0,
        "internal_errors": 0, "source": "plant_stats.json",
    }  # fmt: skip
    stats.write_text(json.dumps({**to_map(STATUS), "timeouts": 0}))
    account = plant_account(stats, seen)  # the file is the plant's word; a status can be forged
    assert account is not None and account["timeouts"] == 0
