"""The latched e-stop on disk: a coordinator restarted alone still holds it
(coordinator.node.estop_store, ``formation coordinator --estop-state FILE``, docs/faults.md).

Before, a coordinator restarted with no other instance running answered "nothing latched": the
agents that held the e-stop stayed stopped (an answer never releases an engagement it did not
see released), but an agent started or restarted then came up driving. Here: the file round
trip, hostile files (truncated at every byte, random bytes, another fleet, duplicate keys, a
forged entry: each latches the fleet, the safe side, until a release message), writes that
coalesce and never leave a half-written file, a hypothesis search over message losses and
restarts (a restarted coordinator holds exactly what it held; an agent is never released without
a release the coordinator saw), and end to end with real processes: a coordinator
stopped while the fleet is e-stopped, a new one started alone on the same file, an agent started
then stays stopped until the operator's release.
"""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import msgpack
import pytest
import zenoh
from hypothesis import given, settings
from hypothesis import strategies as st
from support.agent_io import FLEET, Feeder, nonzero, start_agent
from support.bus_watch import Recorder, decoder_of
from support.estop_checks import answer_of, assert_stopped
from support.estop_checks import rejecting_source as _source
from support.routers import RouterHandle
from support.spawn import REPO_ROOT, Spawner

import runtime as rt
from bus_schemas import (
    Estop,
    Status,
    Wheels,
    decode_estop_answer,
    encode,
    keys,
    new_estop_id,
)
from coordinator.node.estop_source import EstopSource
from coordinator.node.estop_store import (
    MAX_FILE_BYTES,
    EstopStore,
    read_state,
    state_bytes,
)
from robot_agent.core.estop import NO_ID, EstopLatch

pytestmark = pytest.mark.shares_cpu

KEY = "formation/demo/estop"


def _put(source: EstopSource, engage: bool, robot: str | None, eid: int | None) -> None:
    msg = Estop(t=1.0, engage=engage, robot=robot, id=eid)
    source.on_estop(rt.Received(KEY, encode(msg), 1.0))


def _busy_source(rejects: list[str]) -> EstopSource:
    """Fleet released (id 7 in the record), r2 held by two engagements, r5 by one."""
    source = _source(rejects)
    _put(source, True, None, 7)
    _put(source, False, None, None)
    _put(source, True, "r2", 11)
    _put(source, True, "r2", 12)
    _put(source, True, "r5", 13)
    return source


def _restored(path: Path, fleet: str = "demo") -> tuple[EstopSource, list[str]]:
    rejects: list[str] = []
    source = _source(rejects)
    source.restore(read_state(path, fleet), path)
    return source, rejects


def _stored(source: EstopSource, folder: Path, log: list[str]) -> tuple[EstopStore, Path]:
    """``source`` saving every change to ``folder/estop.msgpack``."""
    path = folder / "estop.msgpack"
    source.store = EstopStore(path, "demo", log.append)
    return source.store, path


def _fleet_pinned(source: EstopSource) -> bool:
    return source.latch.held.get(None) == {NO_ID}


# --- the file ---------------------------------------------------------------------------------


def test_a_saved_state_is_restored_whole(tmp_path: Path) -> None:
    rejects: list[str] = []
    source = _busy_source(rejects)
    store, path = _stored(source, tmp_path, rejects)
    store.offer(source.answer)
    assert store.flush(2.0) and store.writes >= 1
    store.close()
    restored, more = _restored(path)
    assert restored.answer == source.answer and not rejects and not more
    assert restored.latch.held == {"r2": {11, 12}, "r5": {13}}
    assert list(restored.latch.released) == [(None, 7)]
    # the restored record still proves the fleet release to an agent that missed it
    assert (False, None, 7) in restored.latch.answer()


def test_every_change_is_saved_and_nothing_half_written_is_left(tmp_path: Path) -> None:
    rejects: list[str] = []
    source = _source(rejects)
    store, path = _stored(source, tmp_path, rejects)
    for i in range(1, 300):  # a burst of changes: coalesced, the last one on disk
        _put(source, i % 2 == 1, f"r{i % 7}", i)
    assert store.flush(5.0)
    store.close()
    assert 1 <= store.writes <= 299 and store.failures == 0
    assert _restored(path)[0].answer == source.answer
    assert [p.name for p in tmp_path.iterdir()] == ["estop.msgpack"]  # no temporary file


def test_a_missing_file_is_a_first_start(tmp_path: Path) -> None:
    source, rejects = _restored(tmp_path / "none.msgpack")
    assert source.latch.held == {} and not rejects


def test_a_failed_write_is_logged_not_raised(tmp_path: Path) -> None:
    logged: list[str] = []
    folder = tmp_path / "gone"
    folder.mkdir()
    store = EstopStore(folder / "estop.msgpack", "demo", logged.append)
    folder.rmdir()
    store.offer((encode(Estop(t=1.0, engage=True, robot=None, id=3)),))
    assert store.flush(2.0)
    store.close()
    assert store.failures == 1 and store.writes == 0
    assert logged and "estop state not saved" in logged[0]


def _valid_bytes() -> bytes:
    return state_bytes("demo", _busy_source([]).answer, 1.0)


def _assert_held_safe(path: Path) -> None:
    source, rejects = _restored(path)
    assert _fleet_pinned(source), source.latch.held
    assert [r.split(":")[0] for r in rejects] == ["estop_state_file"], rejects
    # only an operator's release message clears it
    source.on_state([encode(Estop(t=1.0, engage=False, robot=None))])
    assert _fleet_pinned(source)
    _put(source, False, None, None)
    assert None not in source.latch.held


@pytest.mark.parametrize(
    "content",
    [
        b"",
        b"\x00",
        b"not msgpack at all",
        msgpack.packb([1, 2, 3]),
        state_bytes("other-fleet", [], 1.0),
        msgpack.packb({"format": "formation.estop-state", "version": 2, "fleet": "demo",
                       "saved_t": 1.0, "answer": []}),
        msgpack.packb({"format": "something.else", "version": 1, "fleet": "demo",
                       "saved_t": 1.0, "answer": []}),
        msgpack.packb({"format": "formation.estop-state", "version": 1, "fleet": "demo",
                       "saved_t": 1.0, "answer": [], "extra": 1}),
        msgpack.packb({"format": "formation.estop-state", "version": 1, "fleet": "demo",
                       "saved_t": 1.0, "answer": "x"}),
        # an empty answer (not even the fleet entry) is not a state this coordinator wrote
        state_bytes("demo", [], 1.0),
        # a forged entry among good ones: the whole file is distrusted
        state_bytes("demo", [*_busy_source([]).answer, msgpack.packb({"v": 1, "t": 1.0,
                    "engage": True, "robot": "R 1", "id": 5})], 1.0),
        # a robot's release record without an id
        state_bytes("demo", [encode(Estop(t=1.0, engage=False, robot=None)),
                             encode(Estop(t=1.0, engage=False, robot="r1"))], 1.0),
        # a duplicated key (the same bytes as a good file with "fleet" twice)
        _valid_bytes().replace(b"\xa5fleet\xa4demo", b"\xa5fleet\xa4demo\xa5fleet\xa4demo")
        .replace(b"\x85", b"\x86", 1),
    ],
    ids=[
        "empty", "nul", "text", "array", "other-fleet", "version-2", "format", "extra-key",
        "answer-not-list", "empty-answer", "forged-entry", "release-no-id", "duplicate-key",
    ],
)  # fmt: skip
def test_a_file_that_cannot_be_trusted_holds_the_fleet(tmp_path: Path, content: bytes) -> None:
    path = tmp_path / "estop.msgpack"
    path.write_bytes(content)
    _assert_held_safe(path)


def test_a_file_cut_at_any_byte_holds_the_fleet(tmp_path: Path) -> None:
    whole = _valid_bytes()
    path = tmp_path / "estop.msgpack"
    for cut in range(len(whole)):  # a power cut mid-write (were the rename not atomic)
        path.write_bytes(whole[:cut])
        _assert_held_safe(path)


def test_an_oversized_or_unreadable_file_holds_the_fleet(tmp_path: Path) -> None:
    path = tmp_path / "estop.msgpack"
    with path.open("wb") as f:
        f.truncate(MAX_FILE_BYTES + 1)
    _assert_held_safe(path)
    folder = tmp_path / "a-directory.msgpack"
    folder.mkdir()
    _assert_held_safe(folder)


@settings(max_examples=300, deadline=None)
@given(noise=st.binary(max_size=300), flips=st.lists(st.integers(0, 10_000), max_size=4))
def test_random_and_bit_flipped_files_never_raise_and_never_release(
    tmp_path_factory: pytest.TempPathFactory, noise: bytes, flips: list[int]
) -> None:
    path = tmp_path_factory.mktemp("estop") / "estop.msgpack"
    whole = bytearray(_valid_bytes())
    for f in flips:
        whole[f % len(whole)] ^= 1 << (f % 8)
    for content in (noise, bytes(whole)):
        path.write_bytes(content)
        source, rejects = _restored(path)
        assert not [r for r in rejects if r.startswith("internal")], rejects
        # either the file was read whole (an intact or harmlessly flipped file) or the fleet is
        # held; a file never releases anything (nothing was held before it)
        assert _fleet_pinned(source) or not rejects


SCOPES: tuple[str | None, ...] = (None, "r1", "r2")


def _answer_of(coord: EstopSource, rejects: list[str]) -> list[tuple[bool, str | None, int | None]]:
    return decode_estop_answer(coord.answer, lambda e: rejects.append(str(e)))


@st.composite
def lives(draw: st.DrawFn) -> list[tuple[object, ...]]:
    """``("msg", engage, scope, id, to_agent, to_coord)``: an ``estop`` message the agent and
    the coordinator each receive or miss; ``("restart",)``: the coordinator stops and a new
    one starts alone on the same file; ``("ask",)``: the agent merges the coordinator's
    answer."""
    ops: list[tuple[object, ...]] = []
    next_id = 1
    for _ in range(draw(st.integers(0, 24))):
        kind = draw(st.sampled_from(["engage", "engage", "release", "legacy", "restart", "ask"]))
        if kind in ("restart", "ask"):
            ops.append((kind,))
            continue
        eid: int | None = None
        if kind == "engage":
            eid, next_id = next_id, next_id + 1
        scope = draw(st.sampled_from(SCOPES))
        ops.append(("msg", kind != "release", scope, eid, draw(st.booleans()), draw(st.booleans())))
    return ops


@settings(max_examples=150, deadline=None)
@given(ops=lives())
def test_a_restarted_coordinator_holds_exactly_what_it_held_and_never_releases(
    tmp_path_factory: pytest.TempPathFactory, ops: list[tuple[object, ...]]
) -> None:
    """Across any number of restarts (each alone, on the file): the new coordinator's latch
    (held engagements and release record, in order) equals the old one's; an agent merging its
    answers is released from an engagement only if the coordinator saw that very engagement
    released (before or across a restart); a robot started after the last restart is stopped
    exactly where the coordinator holds an e-stop."""
    folder = tmp_path_factory.mktemp("lives")
    rejects: list[str] = []
    coord = _source(rejects)
    store, path = _stored(coord, folder, rejects)
    agent = EstopLatch()
    saw_released: set[tuple[str | None, int]] = set()
    try:
        for op in ops:
            if op[0] == "msg":
                _, engage, scope, eid, to_agent, to_coord = op
                assert isinstance(engage, bool) and (scope is None or isinstance(scope, str))
                assert eid is None or isinstance(eid, int)
                if to_agent:
                    agent.apply(engage, scope, eid)
                if to_coord:
                    if not engage:
                        held = coord.latch.held.get(scope, set())
                        saw_released |= {(scope, i) for i in held if i != NO_ID}
                    elif eid is not None:
                        saw_released.discard((scope, eid))
                    _put(coord, engage, scope, eid)
            elif op[0] == "restart":
                assert store.flush(5.0)
                store.close()
                before = (dict(coord.latch.held), list(coord.latch.released))
                coord = _source(rejects)
                coord.restore(read_state(path, "demo"), path)
                store, path = _stored(coord, folder, rejects)
                assert (dict(coord.latch.held), list(coord.latch.released)) == before
            else:
                held_before = {(s, i) for s, ids in agent.held.items() for i in ids}
                agent.merge_answer(_answer_of(coord, rejects))
                held_after = {(s, i) for s, ids in agent.held.items() for i in ids}
                gone = held_before - held_after
                assert gone <= saw_released, (gone, saw_released)
        fresh = EstopLatch()  # a robot started now
        fresh.merge_answer(_answer_of(coord, rejects))
        for robot in ("r1", "r2"):
            assert fresh.stopped(robot) == coord.latch.stopped(robot)
        assert not rejects, rejects
    finally:
        store.close()


def test_the_coordinator_refuses_an_unusable_state_path(tmp_path: Path) -> None:
    for path, why in (
        (tmp_path / "no-dir" / "estop.msgpack", "does not exist"),
        (tmp_path, "is not a regular file"),
    ):
        result = subprocess.run(
            [sys.executable, "-m", "formation", "coordinator", "--scenario", "paper-exp1",
             "--estop-state", str(path)],
            cwd=REPO_ROOT, capture_output=True, text=True, timeout=60,
        )  # fmt: skip
        assert result.returncode == 2, result.stderr
        lines = result.stderr.strip().splitlines()
        assert len(lines) == 1 and "--estop-state" in lines[0] and why in lines[0], lines


# --- end to end -------------------------------------------------------------------------------


@pytest.mark.zenoh
@pytest.mark.alone
def test_a_coordinator_restarted_alone_keeps_the_fleet_stopped(
    spawn: Spawner,
    router: RouterHandle,
    session: Callable[..., zenoh.Session],
    tmp_path: Path,
) -> None:
    client = session()
    pubs = rt.Publishers(client)
    key = keys.estop_key(FLEET)
    state = tmp_path / "estop-main.msgpack"
    coord_args = (
        "coordinator", "--scenario", "paper-exp1", "--fleet", FLEET,
        "--endpoint", router.endpoint, "--estop-state", str(state),
    )  # fmt: skip
    first = spawn(*coord_args, ready="coord")
    eid = new_estop_id()
    pubs.put(
        key, encode(Estop(t=time.monotonic(), engage=True, robot=None, id=eid)), rt.QOS_CRITICAL
    )
    deadline = time.monotonic() + 5.0
    while time.monotonic() < deadline:
        loaded = read_state(state, FLEET)
        if (True, None, eid) in loaded.entries:
            break
        time.sleep(0.05)
    else:
        pytest.fail(f"the engagement never reached {state}")
    first.send_signal(signal.SIGTERM)
    assert first.proc.wait(timeout=5.0) == 0, first.stderr()

    # A new instance, alone on the bus, on the same file: it answers with the engagement.
    second = spawn(*coord_args, ready="coord")
    answer_of(client, key, lambda a: any(e.engage and e.id == eid for e in a))
    assert "estop state restored" in second.stderr()

    # An agent started now comes up stopped and stays stopped until the operator's release.
    start_agent(spawn, router)
    wheels = Recorder(client, keys.wheels_key(FLEET, "r1"), decoder_of(Wheels))
    status = Recorder(client, keys.status_key(FLEET, "r1"), decoder_of(Status))
    with Feeder(pubs, "r1", pose=lambda: (0.0, 0.0, 0.0), setpoint=lambda: (0.45, 0.0)):
        t0 = time.monotonic()
        time.sleep(2.2)  # two refresh periods (ESTOP_REFRESH_S)
        assert_stopped(wheels, status, t0, time.monotonic(), min_wheels=20, min_status=5)

        t_release = time.monotonic()
        pubs.put(key, encode(Estop(t=t_release, engage=False, robot=None)), rt.QOS_CRITICAL)
        wheels.wait_for(lambda r, _k, w: r > t_release and nonzero(w), timeout_s=3.0)
    # the release is on disk too: a third start holds nothing
    deadline = time.monotonic() + 5.0
    while (True, None, eid) in read_state(state, FLEET).entries:
        assert time.monotonic() < deadline, "the release never reached the file"
        time.sleep(0.05)
    assert (False, None, eid) in read_state(state, FLEET).entries
