"""The bus contract (docs/bus-contract.md, version 1) as seen by an outsider.

A short lockstep run of the real processes (plant, coordinator, one agent per robot, all
``python -m formation ...`` subprocesses on a ``formation router``) is watched by an independent
subscriber: a plain ``zenoh`` session (no ``runtime.transport``) that unpacks every payload
with plain ``msgpack.unpackb`` (no ``bus_schemas`` decoder). It checks, for every key of the
contract: that it was published, the required fields and their types, ``v == 1``, ``seq`` +1 per
message of a key, angles in (-pi, pi], robot ids matching ``[a-z0-9_-]+``, and that every
process's liveliness token appeared.
"""

from __future__ import annotations

import itertools
import json
import math
import re
import threading
import time
import uuid
from collections import defaultdict
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Any

import msgpack
import pytest
import zenoh
from support.routers import RouterHandle, launch_router, stop_router
from support.spawn import Spawner

pytestmark = [pytest.mark.zenoh, pytest.mark.slow, pytest.mark.shares_cpu]

ROBOTS = ("r1", "r2", "r3")
SCENARIO = "paper-exp2"
DURATION_S = 20.0  # sim seconds of the lockstep run
RUN_TIMEOUT_S = 120.0  # wall clock allowed for the run (2-core CI box, five processes)
ROBOT_ID = re.compile(r"[a-z0-9_-]+")
ROLES = {"leader", "subleader", "follower"}
MODES = {"idle", "tracking", "hold", "estop"}
N_SLOTS = 3  # paper-exp2's triangle


@dataclass
class Recording:
    """What the independent subscriber saw, in arrival order."""

    samples: list[tuple[str, bytes]] = field(default_factory=list)
    tokens: list[tuple[str, str]] = field(default_factory=list)  # (key, "PUT"/"DELETE")
    lock: threading.Lock = field(default_factory=threading.Lock)

    def by_key(self) -> dict[str, list[dict[str, Any]]]:
        out: dict[str, list[dict[str, Any]]] = defaultdict(list)
        with self.lock:
            samples = list(self.samples)
        for key, payload in samples:
            obj = msgpack.unpackb(payload, raw=False)
            assert isinstance(obj, dict), f"{key}: payload is not a msgpack map: {obj!r}"
            out[key].append(obj)
        return dict(out)


def _plain_session(endpoint: str) -> zenoh.Session:
    """A client session configured with zenoh's own API only (independent of bus_schemas)."""
    conf = zenoh.Config()
    conf.insert_json5("mode", json.dumps("client"))
    conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    return zenoh.open(conf)


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[Recording, str]]:
    """One lockstep run watched from its very first message; yields (recording, fleet)."""
    spawner = Spawner(tmp_path_factory.mktemp("contract") / "procs")
    fleet = f"contract-{uuid.uuid4().hex[:8]}"
    rec = Recording()
    try:
        router: RouterHandle = launch_router(spawner)
        session = _plain_session(router.endpoint)
        try:

            def on_sample(sample: zenoh.Sample) -> None:  # Zenoh thread: copy and return
                with rec.lock:
                    rec.samples.append((str(sample.key_expr), sample.payload.to_bytes()))

            def on_token(sample: zenoh.Sample) -> None:
                with rec.lock:
                    rec.tokens.append((str(sample.key_expr), str(sample.kind).split(".")[-1]))

            session.declare_subscriber(f"formation/{fleet}/**", on_sample)
            session.liveliness().declare_subscriber(
                f"formation/{fleet}/alive/**", on_token, history=True
            )
            common = ["--endpoint", router.endpoint, "--fleet", fleet]
            plant = spawner(
                "plant", "--scenario", SCENARIO, "--lockstep", "--duration", str(DURATION_S),
                "--wait-robots", *common,
            )  # fmt: skip
            others = [spawner("coordinator", "--scenario", SCENARIO, "--lockstep", *common)]
            others += [
                spawner("agent", "--id", rid, "--scenario", SCENARIO, "--lockstep", *common)
                for rid in ROBOTS
            ]
            plant.wait_for_line("plant ready")
            others[0].wait_for_line("coordinator ready")
            for rid, child in zip(ROBOTS, others[1:], strict=True):
                child.wait_for_line(f"agent {rid} ready")
            plant.proc.wait(timeout=RUN_TIMEOUT_S)
            assert plant.proc.returncode == 0, plant.describe()
            time.sleep(0.3)  # the last answers in flight
            for child in others:
                child.stop()
                assert child.proc.returncode == 0, child.describe()
            time.sleep(0.2)  # token deletions
        finally:
            session.close()
        yield rec, fleet
        stop_router(router)
    finally:
        problems = spawner.cleanup()
        assert not problems, problems


# ---------------------------------------------------------------------------------------------
# field checks (plain Python types, as any msgpack decoder returns them)
# ---------------------------------------------------------------------------------------------


def is_int(v: Any) -> bool:
    return type(v) is int


def is_float(v: Any) -> bool:
    return type(v) is float and math.isfinite(v)


def is_angle(v: Any) -> bool:
    return is_float(v) and -math.pi < v <= math.pi


def is_id(v: Any) -> bool:
    return type(v) is str and ROBOT_ID.fullmatch(v) is not None


Check = Callable[[Any], bool]
SLOT_FIELDS: dict[str, Check] = {
    "slot": is_int,
    "role": lambda v: v in ROLES,
    "stage": lambda v: is_int(v) and v >= 0,
    "parent": lambda v: v is None or is_int(v),
    "x": is_float,
    "y": is_float,
    "theta": is_angle,
    "vx": is_float,
    "vy": is_float,
}
POSE_FIELDS: dict[str, Check] = {"x": is_float, "y": is_float, "theta": is_angle}
REQUIRED: dict[str, dict[str, Check]] = {
    "leader": {
        "x": is_float,
        "y": is_float,
        "theta": is_angle,
        "v_mps": is_float,
        "omega_radps": is_float,
    },
    "slot": SLOT_FIELDS,
    "setpoint": {**SLOT_FIELDS, "robot": is_id},
    "assignment": {
        "leader": lambda v: v is None or is_id(v),
        "robots": lambda v: (
            isinstance(v, dict) and all(is_id(k) and is_int(s) and s >= 0 for k, s in v.items())
        ),
    },
    "pose": POSE_FIELDS,
    "truth": POSE_FIELDS,
    "wheels": {
        "omega_r": is_float,
        "omega_l": is_float,
        "power_r": lambda v: is_float(v) and -1.0 <= v <= 1.0,
        "power_l": lambda v: is_float(v) and -1.0 <= v <= 1.0,
        "pose_t": lambda v: v is None or (is_float(v) and v >= 0.0),
    },
    "status": {
        "mode": lambda v: v in MODES,
        "slot": lambda v: v is None or (is_int(v) and v >= 0),
        "pid": lambda v: is_int(v) and v > 0,
        "host": lambda v: type(v) is str and v != "",
        "rejected": lambda v: is_int(v) and v >= 0,
    },
    "clock": {"tick": lambda v: is_int(v) and v >= 0},
}


def leaf_of(key: str, fleet: str) -> str:
    rest = key.removeprefix(f"formation/{fleet}/").split("/")
    if rest[0] == "slot":
        return "slot"
    if rest[0] == "robot":
        return rest[2]
    return rest[0]


def expected_keys(fleet: str) -> set[str]:
    base = f"formation/{fleet}"
    out = {f"{base}/leader", f"{base}/assignment", f"{base}/clock"}
    out |= {f"{base}/slot/{k}" for k in range(N_SLOTS)}
    for rid in ROBOTS:
        out |= {f"{base}/robot/{rid}/{leaf}" for leaf in ("setpoint", "pose", "truth")}
        out |= {f"{base}/robot/{rid}/{leaf}" for leaf in ("wheels", "status")}
    return out


# ---------------------------------------------------------------------------------------------
# tests
# ---------------------------------------------------------------------------------------------


def test_every_contract_key_is_published(run: tuple[Recording, str]) -> None:
    rec, fleet = run
    seen = set(rec.by_key())
    missing = expected_keys(fleet) - seen
    assert not missing, f"never published: {sorted(missing)}"


def test_required_fields_types_and_version(run: tuple[Recording, str]) -> None:
    rec, fleet = run
    problems: list[str] = []
    checked = 0
    for key, msgs in rec.by_key().items():
        leaf = leaf_of(key, fleet)
        required = REQUIRED.get(leaf)
        for m in msgs:
            if not all(type(k) is str for k in m):
                problems.append(f"{key}: non-string map key in {m!r}")
            if m.get("v") != 1 or not is_int(m.get("v")):
                problems.append(f"{key}: v is {m.get('v')!r}, not the int 1")
            if not (is_float(m.get("t")) and m["t"] >= 0.0):
                problems.append(f"{key}: t is {m.get('t')!r}, not a finite float >= 0")
            if required is None:
                continue  # a key added beyond contract v1: only the common fields apply
            checked += 1
            for name, ok in required.items():
                if name not in m:
                    problems.append(f"{key}: required field {name!r} missing in {m!r}")
                elif not ok(m[name]):
                    problems.append(f"{key}: bad {name} = {m[name]!r}")
            if len(problems) > 20:
                break
    assert checked > 1000
    assert not problems, "\n".join(problems[:20])


def test_ids_and_slots_match_their_keys(run: tuple[Recording, str]) -> None:
    rec, fleet = run
    by_key = rec.by_key()
    for rid in ROBOTS:
        for leaf in ("setpoint", "pose", "truth", "wheels", "status"):
            for m in by_key[f"formation/{fleet}/robot/{rid}/{leaf}"]:
                # `robot` is required on setpoints, optional elsewhere; when present it must match
                assert m.get("robot", rid) == rid, (leaf, m)
    for k in range(N_SLOTS):
        msgs = by_key[f"formation/{fleet}/slot/{k}"]
        assert {m["slot"] for m in msgs} == {k}
        assert all((m["parent"] is None) == (k == 0) for m in msgs)
    for m in by_key[f"formation/{fleet}/assignment"]:
        if m["leader"] is not None:
            assert m["robots"][m["leader"]] == 0, m
        assert set(m["robots"]) <= set(ROBOTS)


def test_seq_increments_by_one_per_key(run: tuple[Recording, str]) -> None:
    rec, _ = run
    for key, msgs in rec.by_key().items():
        raw = [m.get("seq") for m in msgs]
        assert all(is_int(s) for s in raw), f"{key}: seq missing or not an int: {raw[:5]}"
        seqs: list[int] = [int(s) for s in raw if s is not None]
        steps = {b - a for a, b in itertools.pairwise(seqs)}
        assert steps <= {1}, f"{key}: seq steps {sorted(steps)} (expected +1), first {seqs[:10]}"


def test_lockstep_ticks_and_answers(run: tuple[Recording, str]) -> None:
    """Clock ticks go 0, 1, 2, ... (a re-announce repeats one); every agent answers each tick."""
    rec, fleet = run
    by_key = rec.by_key()
    ticks = [m["tick"] for m in by_key[f"formation/{fleet}/clock"]]
    assert ticks[0] == 0
    assert {b - a for a, b in itertools.pairwise(ticks)} <= {0, 1}
    dt = by_key[f"formation/{fleet}/clock"][1]["t"] - by_key[f"formation/{fleet}/clock"][0]["t"]
    assert ticks[-1] * dt == pytest.approx(DURATION_S, abs=2 * dt)
    for rid in ROBOTS:
        answered = {m.get("tick") for m in by_key[f"formation/{fleet}/robot/{rid}/wheels"]}
        assert set(ticks) <= answered, (
            f"{rid} did not answer ticks {sorted(set(ticks) - answered)[:5]}"
        )


def test_liveliness_tokens_of_every_process(run: tuple[Recording, str]) -> None:
    rec, fleet = run
    with rec.lock:
        tokens = list(rec.tokens)
    put = {k for k, kind in tokens if kind == "PUT"}
    base = f"formation/{fleet}/alive"
    expected = {f"{base}/robot/{rid}" for rid in ROBOTS}
    expected |= {f"{base}/coordinator/main", f"{base}/plant"}
    assert expected <= put, f"tokens never seen: {sorted(expected - put)}"
    deleted = {k for k, kind in tokens if kind == "DELETE"}
    assert expected <= deleted, f"tokens not withdrawn at exit: {sorted(expected - deleted)}"
