"""Every output of a run on a full or read-only disk (issue 30, deliverable 2): the run stops
within its bounds, writes what it can, names what it could not and exits non-zero; nothing
hangs.

Before: ``formation up --record`` on a disk that filled up finished its fleet, then closing the
recorder raised during the shutdown, the router was never stopped and the launcher was still
hung 600 s later (no metrics.json, a plant_stats.json of 0 bytes, an MCAP without its footer).
On a real small filesystem (a tmpfs; skipped with the reason where mounting is refused).
"""

from __future__ import annotations

import json
import socket
import subprocess
import sys
import time
import uuid
from pathlib import Path

import pytest
from support.small_fs import fill, read_only, small_fs
from support.spawn import REPO_ROOT, Spawner, child_env, free_port

from bus_schemas import Pose, encode, keys
from formation.record.writer import Recorder
from runtime.files import write_atomic
from runtime.tap import BusItem

pytestmark = pytest.mark.shares_cpu

FLEET = "demo"
UP_BOUND_S = 120.0
"""A short run's whole life, start to exit, on a loaded 2-core machine: a bound, not a speed."""


def _pose_item(k: int) -> BusItem:
    msg = Pose(t=0.02 * k, seq=k, x=0.001 * k, y=0.0, theta=0.0)
    return BusItem("put", keys.pose_key(FLEET, "r1"), encode(msg), 10**9 + k)


def test_a_recorder_on_a_full_disk_stops_writing_names_why_and_closes(tmp_path: Path) -> None:
    with small_fs(tmp_path / "disk", size="128k") as disk:
        rec = Recorder(disk / "run.mcap", FLEET, chunk_bytes=4096, scene_hz=None)
        for k in range(20_000):  # ~1 MB of JSON: far more than the disk holds
            rec.write(_pose_item(k))
        stats = rec.close()  # never raises
        assert stats.error is not None and "No space left on device" in stats.error
        assert stats.unwritten > 0 and stats.samples > 0
        assert stats.samples + stats.unwritten == 20_000
        assert rec.close() is stats  # idempotent


def test_a_recorder_that_only_cannot_finalize_says_so(tmp_path: Path) -> None:
    with small_fs(tmp_path / "disk", size="64k") as disk:
        rec = Recorder(disk / "run.mcap", FLEET, scene_hz=None)  # 256 KiB chunks: in memory
        for k in range(200):
            rec.write(_pose_item(k))
        assert rec.stats.error is None
        fill(disk)
        stats = rec.close()
        assert stats.error is not None and "No space left on device" in stats.error
        assert stats.unwritten == 0 and stats.samples == 200


def test_a_recorder_cannot_start_on_a_read_only_disk(tmp_path: Path) -> None:
    with small_fs(tmp_path / "disk") as disk:
        read_only(disk)
        with pytest.raises(OSError, match="Read-only file system"):
            Recorder(disk / "run.mcap", FLEET, scene_hz=None)


def test_an_output_is_written_whole_or_not_at_all(tmp_path: Path) -> None:
    with small_fs(tmp_path / "disk", size="64k") as disk:
        target = disk / "metrics.json"
        write_atomic(target, b'{"old": true}\n')
        fill(disk)
        with pytest.raises(OSError, match="No space left on device"):
            write_atomic(target, b"x" * 100_000)
        assert target.read_bytes() == b'{"old": true}\n'  # the old file, whole
        assert sorted(p.name for p in disk.iterdir()) == [".filler", "metrics.json"]


def _up(spawn: Spawner, *args: str) -> tuple[int, str, str, float]:
    """``formation up`` of paper-exp1 (realtime, 6 s) with ``args``; (status, stdout, stderr,
    wall s). Fails the test if it does not exit within :data:`UP_BOUND_S`."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    started = time.monotonic()
    child = spawn(
        "up", "--scenario", "paper-exp1", "--duration", "6", "--no-figures", "--quiet",
        "--endpoint", endpoint, "--fleet", f"t{uuid.uuid4().hex[:8]}", *args,
    )  # fmt: skip
    try:
        rc = child.proc.wait(timeout=UP_BOUND_S)
    except subprocess.TimeoutExpired:
        pytest.fail(f"formation up did not exit within {UP_BOUND_S} s: {child.describe()}")
    wall = time.monotonic() - started
    port = int(endpoint.rsplit(":", 1)[1])
    with socket.socket() as sock:  # the run's router is gone: its port is free again
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        sock.bind(("127.0.0.1", port))
    return rc, child.stdout(), child.stderr(), wall


@pytest.mark.slow
@pytest.mark.zenoh
def test_up_record_on_a_disk_that_fills_exits_1_and_writes_the_rest(
    spawn: Spawner, tmp_path: Path
) -> None:
    """The issue's hang: the recording fills its disk during the run. The run ends on time,
    the router stops, metrics.json and plant_stats.json (on another disk) are written whole,
    the recording is named incomplete, the status is 1."""
    out = tmp_path / "out"
    with small_fs(tmp_path / "disk", size="192k") as disk:
        mcap = disk / "run.mcap"
        rc, _out, err, _wall = _up(spawn, "--out", str(out), "--record", str(mcap))
        assert rc == 1, err
        assert f"recording {mcap} is incomplete: OSError: No space left on device" in err, err
        m = json.loads((out / "metrics.json").read_text())
        assert any("is incomplete" in f for f in m["meta"]["failures"]), m["meta"]["failures"]
        assert m["run"]["duration_s"] > 4.0 and m["run"]["collisions"] == 0
        assert json.loads((out / "plant_stats.json").read_text())["n_robots"] == 3
        assert mcap.stat().st_size > 0  # what fitted is there


@pytest.mark.slow
@pytest.mark.zenoh
def test_up_on_a_full_out_disk_names_every_output_it_could_not_write(
    spawn: Spawner, tmp_path: Path
) -> None:
    """--out on a disk filled after the start: metrics.json, run.npz and plant_stats.json are
    named as not written, none is left empty or cut, the status is 1."""
    with small_fs(tmp_path / "disk", size="512k") as disk:
        out = disk / "out"
        out.mkdir()
        fill(disk)
        rc, _out, err, _wall = _up(spawn, "--out", str(out))
        assert rc == 1, err
        for name in ("metrics.json", "run.npz", "plant_stats.json"):
            assert f"{out / name} not written" in err, (name, err)
            assert not (out / name).exists()
        assert not [p for p in out.iterdir() if p.name.startswith(".")]  # no temporary file


def test_up_on_a_read_only_out_exits_1_at_once(tmp_path: Path) -> None:
    with small_fs(tmp_path / "disk") as disk:
        read_only(disk)
        proc = subprocess.run(
            [sys.executable, "-m", "formation", "up", "--scenario", "paper-exp1",
             "--duration", "2", "--quiet", "--endpoint", f"tcp/127.0.0.1:{free_port()}",
             "--out", str(disk / "out")],
            cwd=REPO_ROOT, env=child_env(), capture_output=True, text=True, timeout=60,
        )  # fmt: skip
        assert proc.returncode == 1, proc.stderr
        assert f"cannot write to {disk / 'out'}" in proc.stderr, proc.stderr
        assert "Read-only file system" in proc.stderr and "Traceback" not in proc.stderr


def test_sim_on_a_full_disk_exits_1_naming_the_file(tmp_path: Path) -> None:
    with small_fs(tmp_path / "disk", size="64k") as disk:
        out = disk / "out"
        out.mkdir()
        fill(disk)
        proc = subprocess.run(
            [sys.executable, "-m", "formation", "sim", "--scenario", "paper-exp1",
             "--duration", "2", "--no-figures", "--quiet", "--out", str(out)],
            cwd=REPO_ROOT, env=child_env(), capture_output=True, text=True, timeout=120,
        )  # fmt: skip
        assert proc.returncode == 1, proc.stderr
        assert "not written: OSError: No space left on device" in proc.stderr, proc.stderr
        assert "Traceback" not in proc.stderr
        assert list(out.iterdir()) == []  # nothing empty or cut left behind
