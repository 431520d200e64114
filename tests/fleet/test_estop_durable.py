"""Durable safety state (issue 30, deliverable 2): an e-stop is reported latched only once it is
durable where the fleet relies on it.

Before: with the coordinator's ``--estop-state`` file on a full disk, ``formation fault estop``
printed "latched by coordinator main" and exited 0, the failed save was one log line, and after
the coordinator and the robots restarted every robot drove. Now a state file that cannot be
written is the coordinator's fault: its status says ``estop_store`` ``failed`` with the error,
it logs it, retries, refuses releases it cannot record (counted ``estop-unrecorded``), and the
tool names what is not durable and exits 1. On a real small filesystem (a tmpfs filled to the
last byte, then remounted read-only; skipped with the reason where mounting is refused).
"""

from __future__ import annotations

import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import pytest
import zenoh
from support.agent_io import FLEET, start_agent
from support.estop_checks import rejecting_source
from support.routers import RouterHandle
from support.small_fs import fill, free, read_only, small_fs
from support.spawn import REPO_ROOT, Spawner, child_env

import runtime as rt
from bus_schemas import CoordinatorStatus, Estop, decode_or_raise, encode, keys
from coordinator.node.estop_source import EstopSource
from coordinator.node.estop_store import FAILED, RETRY_S, SAVED, EstopStore, read_state

pytestmark = pytest.mark.shares_cpu

KEY = "formation/demo/estop"


def _put(source: EstopSource, engage: bool, robot: str | None, eid: int | None) -> None:
    source.on_estop(rt.Received(KEY, encode(Estop(t=1.0, engage=engage, robot=robot, id=eid)), 1.0))


def _until(ok: Callable[[], bool], timeout_s: float, what: str) -> None:
    deadline = time.monotonic() + timeout_s
    while not ok():
        assert time.monotonic() < deadline, f"not within {timeout_s} s: {what}"
        time.sleep(0.02)


def test_a_full_then_read_only_disk_is_a_fault_that_refuses_releases(tmp_path: Path) -> None:
    with small_fs(tmp_path / "disk") as disk:
        rejects: list[str] = []
        logged: list[str] = []
        source = rejecting_source(rejects)
        path = disk / "estop.msgpack"
        store = source.store = EstopStore(path, "demo", logged.append)
        try:
            _put(source, True, None, 5)
            assert store.flush(2.0) and store.state() == SAVED
            assert source.status()["estop_store"] == SAVED and not store.failing

            fill(disk)
            _put(source, True, "r2", 6)  # held in memory and answered, not on disk
            assert store.flush(2.0)
            assert store.state() == FAILED and store.failing
            st = source.status()
            assert st["estop_store"] == FAILED and st["estop_robots"] == ("r2",)
            assert "No space left on device" in (st["estop_store_error"] or "")
            assert [m for m in logged if m.startswith("FAULT")], logged
            assert (True, "r2", 6) in source.latch.answer()
            # the old file is whole (temporary file + rename): the fleet's engagement only
            on_disk = read_state(path, "demo")
            assert on_disk.error is None and on_disk.entries[0] == (True, None, 5)
            assert all(e[1] != "r2" for e in on_disk.entries)

            # a release it cannot record is refused, counted and logged; the latch holds
            _put(source, False, None, None)
            assert source.latch.fleet and (True, None, 5) in source.latch.answer()
            assert any("refused" in r and "cannot be written" in r for r in rejects), rejects
            # a release of a scope it does not hold records nothing: not refused
            before = len(rejects)
            _put(source, False, "r7", None)
            assert len(rejects) == before

            # space back: the newest state is written by the retry, the fault clears
            free(disk)
            _until(lambda: store.state() == SAVED, 3 * RETRY_S + 2.0, "the retry saved it")
            assert any("again" in m for m in logged), logged
            assert (True, "r2", 6) in read_state(path, "demo").entries
            _put(source, False, None, None)  # now recorded
            assert store.flush(2.0) and store.state() == SAVED
            assert not source.latch.fleet
            assert (False, None, 5) in read_state(path, "demo").entries

            read_only(disk)
            _put(source, True, "r3", 9)
            assert store.flush(2.0) and store.state() == FAILED
            assert "Read-only file system" in (store.error or "")
            _put(source, False, "r3", None)
            assert "r3" in source.latch.robots  # refused again
            read_only(disk, on=False)
            _until(lambda: store.state() == SAVED, 3 * RETRY_S + 2.0, "saved after remount")
            assert (True, "r3", 9) in read_state(path, "demo").entries
        finally:
            store.close()


def _fault(endpoint: str, *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "formation", "fault", "--fleet", FLEET, "--endpoint", endpoint,
         *args],
        cwd=REPO_ROOT, capture_output=True, text=True, timeout=30, env=child_env(),
    )  # fmt: skip


def _coordinator_status(client: zenoh.Session) -> CoordinatorStatus:
    got: list[CoordinatorStatus] = []
    sub = client.declare_subscriber(
        keys.coordinator_status_key(FLEET, "main"),
        lambda s: got.append(decode_or_raise(s.payload.to_bytes(), CoordinatorStatus)),
    )
    try:
        _until(lambda: bool(got), 5.0, "a coordinator status")
    finally:
        sub.undeclare()
    return got[-1]


@pytest.mark.zenoh
@pytest.mark.slow
def test_estop_on_a_full_disk_is_reported_not_durable_and_exits_1(
    spawn: Spawner,
    router: RouterHandle,
    session: Callable[..., zenoh.Session],
    tmp_path: Path,
) -> None:
    """The issue's case with real processes: the coordinator's state file on a full disk.
    ``formation fault estop`` says NOT DURABLE, names the coordinator and the error, exits 1;
    the coordinator's status says ``failed``; a release is refused there (exit 1 again); once
    the disk has room the state is saved by the retry and both commands succeed."""
    client = session()
    with small_fs(tmp_path / "disk") as disk:
        state = disk / "estop-main.msgpack"
        coordinator = spawn(
            "coordinator", "--scenario", "paper-exp1", "--fleet", FLEET,
            "--endpoint", router.endpoint, "--estop-state", str(state), ready="coord",
        )  # fmt: skip
        start_agent(spawn, router)
        _until(lambda: state.exists(), 5.0, "the first save")
        fill(disk)

        proc = _fault(router.endpoint, "estop")
        assert proc.returncode == 1, proc.stdout + proc.stderr
        err = proc.stderr
        assert "acknowledged by r1" in err, err
        assert "NOT DURABLE" in err and "coordinator main has NOT saved it" in err, err
        assert "No space left on device" in err and "a power cut loses it" in err, err
        st = _coordinator_status(client)
        assert st.estop_fleet and st.estop_store == "failed", st
        assert "No space left on device" in (st.estop_store_error or "")
        assert "FAULT: estop state not saved" in coordinator.stderr()

        proc = _fault(router.endpoint, "release")
        assert proc.returncode == 1, proc.stdout + proc.stderr
        assert "NOT RELEASED" in proc.stderr and "coordinator main" in proc.stderr, proc.stderr
        st = _coordinator_status(client)
        assert st.estop_fleet and st.rejects.get("estop-unrecorded", 0) >= 1, st

        free(disk)
        _until(lambda: _coordinator_status(client).estop_store == "saved", 5.0, "saved again")
        assert read_state(state, FLEET).entries[0][0]  # the engagement is on disk now
        proc = _fault(router.endpoint, "estop")
        assert proc.returncode == 0, proc.stdout + proc.stderr
        assert "latched by coordinator main (saved to its state file)" in proc.stdout
        assert "held by r1 (estop/held)" in proc.stdout, proc.stdout
        proc = _fault(router.endpoint, "release")
        assert proc.returncode == 0, proc.stdout + proc.stderr
        assert not read_state(state, FLEET).entries[0][0]  # the release is on disk
        coordinator.stop()
