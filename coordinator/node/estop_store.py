"""The latched e-stop state on disk: a coordinator restarted *alone* holds what it held.

Part of the coordinator's process shell (``formation coordinator --estop-state FILE``;
docs/faults.md "A coordinator restarted alone"). A coordinator learns the latched state at start
from the other coordinators (coordinator.node.estop_source); one restarted with no other instance
running (systemd's ``Restart=``, a reboot of the coordinator host)
learned nothing and answered "nothing latched": the agents that hold the e-stop stayed stopped
(an answer never releases an engagement it did not see released), but an agent started or
restarted then came up driving. With a state file, every change of the latch is written to disk
(atomically: a temporary file, fsync, rename), and a starting coordinator merges the file after
the other coordinators' answers, so it answers with the engagements it held when it stopped.

The file is read as hostile input (it may be truncated by a power cut, edited by hand, or belong
to another fleet): a container of the bus's own ``Estop`` payloads, each validated by
``bus_schemas.decode_estop_answer``. A file that is missing is a first start (nothing held); one
that cannot be read or validated whole, or was written for another fleet, latches the **fleet**
scope without an id (only an operator's release message clears it: the safe side) and says why
in the log and the node's rejection counters.

Writes never block the thread that changes the latch (Zenoh's network thread): the newest state
is handed to a writer thread, which writes it when it can (a burst of changes is one write).
A coordinator killed between a change and its write (a few milliseconds) restarts from the
state before that change.

A file that cannot be written (a full or read-only disk, the folder gone) is a fault, not a log
line (issue 30: an e-stop reported latched was lost at the next power cut): :meth:`EstopStore.state`
says whether the newest state is on disk (``saved``), on its way (``pending``) or not
(``failed``, with :attr:`EstopStore.error`); the coordinator publishes it in its status, refuses
releases it cannot record (coordinator.node.estop_source) and ``formation fault estop`` reports an
e-stop latched only where it is saved. A failed write is logged once, retried every
:data:`RETRY_S` with the newest state, and its recovery is logged too.
"""

from __future__ import annotations

import os
import tempfile
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, Final

import msgpack

from bus_schemas import DecodeError, Reason, decode_estop_answer
from robot_agent.core.estop import MAX_IDS, MAX_LATCHED, MAX_RELEASED

__all__ = [
    "FAILED",
    "FORMAT",
    "MAX_FILE_BYTES",
    "PENDING",
    "RETRY_S",
    "SAVED",
    "VERSION",
    "EstopStore",
    "Loaded",
    "StoreError",
    "held_fleet_error",
    "read_state",
    "state_bytes",
]

FORMAT: Final = "formation.estop-state"
VERSION: Final = 1
MAX_ENTRIES: Final = 1 + MAX_LATCHED * MAX_IDS + MAX_RELEASED
"""The longest answer an :class:`robot_agent.core.estop.EstopLatch` gives."""
MAX_FILE_BYTES: Final = 8 * 1024 * 1024
"""Larger files are refused unread (MAX_ENTRIES payloads of ~60 bytes fit ~4 times over)."""
CLOSE_WAIT_S: Final = 0.2
"""How long closing waits for the last write (s)."""
RETRY_S: Final = 1.0
"""A state that could not be written is written again this often (s), until it is (or a newer
one replaces it)."""
SAVED: Final = "saved"
PENDING: Final = "pending"
FAILED: Final = "failed"
"""The values of :meth:`EstopStore.state` (bus_schemas.EstopStoreState)."""

Entry = tuple[bool, str | None, int | None]


class StoreError(Exception):
    """The state file cannot be used (the text says why, for the log)."""


class Loaded:
    """What a state file holds: its entries (``EstopLatch.answer`` order), or why it cannot
    be trusted (:attr:`error`; then the fleet must be held)."""

    __slots__ = ("entries", "error", "missing")

    def __init__(
        self, entries: list[Entry], error: str | None = None, missing: bool = False
    ) -> None:
        self.entries = entries
        self.error = error
        self.missing = missing


def state_bytes(fleet: str, answer: Sequence[bytes], saved_t: float) -> bytes:
    """The file's content: ``answer`` (the coordinator's ``Estop`` payloads) for ``fleet``."""
    data = {
        "format": FORMAT,
        "version": VERSION,
        "fleet": fleet,
        "saved_t": saved_t,
        "answer": list(answer),
    }
    out: bytes = msgpack.packb(data, use_bin_type=True)
    return out


def _pairs(pairs: list[tuple[Any, Any]]) -> dict[Any, Any]:
    obj = dict(pairs)
    if len(obj) != len(pairs):
        raise StoreError("a key appears twice")
    return obj


def _parse(raw: bytes, fleet: str) -> list[Entry]:
    try:
        obj = msgpack.unpackb(
            raw, raw=False, strict_map_key=True, object_pairs_hook=_pairs,
            max_array_len=MAX_ENTRIES, max_bin_len=MAX_FILE_BYTES,
        )  # fmt: skip
    except StoreError:
        raise
    except Exception as exc:  # truncated, not msgpack, too long
        raise StoreError(f"not a state file ({type(exc).__name__}: {str(exc)[:80]})") from None
    if not isinstance(obj, dict):
        raise StoreError(f"not a state file (a {type(obj).__name__})")
    if set(obj) != {"format", "version", "fleet", "saved_t", "answer"}:
        raise StoreError(f"not a state file (keys {sorted(map(str, obj))[:8]})")
    if obj["format"] != FORMAT:
        raise StoreError(f"not a state file (format {str(obj['format'])[:40]!r})")
    if type(obj["version"]) is not int or obj["version"] != VERSION:
        raise StoreError(f"version {str(obj['version'])[:20]!r}, this coordinator reads {VERSION}")
    if obj["fleet"] != fleet:
        raise StoreError(f"written for fleet {str(obj['fleet'])[:40]!r}, not {fleet!r}")
    answer = obj["answer"]
    if not isinstance(answer, list) or not all(type(p) is bytes for p in answer):
        raise StoreError("its answer is not a list of payloads")
    bad: list[DecodeError] = []
    entries = decode_estop_answer(answer, bad.append)
    if bad:
        raise StoreError(f"{len(bad)} invalid entries (first: {bad[0]})")
    if not entries or entries[0][1] is not None:
        raise StoreError("its answer does not start with the fleet scope")
    return entries


def read_state(path: Path, fleet: str) -> Loaded:
    """Read the state file ``path`` of ``fleet``; never raises (a file that cannot be trusted
    is counted once, by the caller, as :func:`held_fleet_error`)."""
    try:
        with path.open("rb") as f:
            raw = f.read(MAX_FILE_BYTES + 1)
    except FileNotFoundError:
        return Loaded([], missing=True)
    except OSError as exc:
        return Loaded([], f"cannot read it ({type(exc).__name__}: {exc.strerror or exc})")
    if len(raw) > MAX_FILE_BYTES:
        return Loaded([], f"larger than {MAX_FILE_BYTES} bytes")
    try:
        return Loaded(_parse(raw, fleet))
    except StoreError as exc:
        return Loaded([], str(exc))


def held_fleet_error(why: str) -> DecodeError:
    """The rejection counted for a state file that cannot be trusted."""
    return DecodeError(Reason.INCONSISTENT, f"e-stop state file: {why}"[:200], None)


class EstopStore:
    """Writes the newest state to ``path`` on a writer thread (:meth:`offer` never blocks on
    the disk); ``log(text)`` reports a failed write and its recovery (called on the writer
    thread). A failed state is written again every :data:`RETRY_S` until it is on disk."""

    def __init__(self, path: Path, fleet: str, log: Callable[[str], None]) -> None:
        self.path = path
        self.fleet = fleet
        self._log = log
        self._cond = threading.Condition()
        self._pending: tuple[bytes, ...] | None = None
        self._busy = False
        self._closed = False
        self._offered = 0  # generation of the newest offered state
        self._saved = 0  # generation of the newest state on disk
        self.error: str | None = None
        """Why the last write failed (None once a write succeeds): the store's fault."""
        self.writes = 0
        self.failures = 0
        self._thread = threading.Thread(target=self._run, name="estop-store", daemon=True)
        self._thread.start()

    def offer(self, answer: tuple[bytes, ...]) -> None:
        """Write ``answer`` soon (replacing one not written yet)."""
        with self._cond:
            if self._closed:
                return
            self._offered += 1
            self._pending = answer
            self._cond.notify()

    @property
    def failing(self) -> bool:
        """The newest state is not on disk and the last attempt to write it failed."""
        with self._cond:
            return self.error is not None and self._saved < self._offered

    def state(self) -> str:
        """:data:`SAVED` (every offered state is on disk, fsynced), :data:`PENDING` (the newest
        is being written) or :data:`FAILED` (it could not be: :attr:`error` says why)."""
        with self._cond:
            if self._saved >= self._offered:
                return SAVED
            return FAILED if self.error is not None else PENDING

    def _run(self) -> None:
        unsaved: tuple[tuple[bytes, ...], int] | None = None  # a failed state, to retry
        while True:
            with self._cond:
                if self._pending is None and not self._closed:
                    self._cond.wait(RETRY_S if unsaved is not None else None)
                if self._pending is not None:
                    job = (self._pending, self._offered)
                    self._pending = None
                elif self._closed or unsaved is None:
                    if self._closed:
                        return
                    continue
                else:
                    job = unsaved
                self._busy = True
            answer, generation = job
            try:
                self._write(answer)
            except OSError as exc:
                unsaved = job
                with self._cond:
                    self.failures += 1
                    first = self.error is None
                    self.error = f"{type(exc).__name__}: {exc.strerror or exc}"[:200]
                if first:
                    self._log(
                        f"FAULT: estop state not saved to {self.path} ({self.error}): an e-stop "
                        f"engaged now is not durable, releases are refused; retrying every "
                        f"{RETRY_S:g} s"
                    )
            else:
                unsaved = None
                with self._cond:
                    self.writes += 1
                    self._saved = max(self._saved, generation)
                    recovered = self.error is not None
                    self.error = None
                if recovered:
                    self._log(f"estop state saved to {self.path} again: fault cleared")
            finally:
                with self._cond:
                    self._busy = False
                    self._cond.notify_all()

    def _write(self, answer: tuple[bytes, ...]) -> None:
        # saved_t is informational only (never read back): wall clock, whatever its zone
        data = state_bytes(self.fleet, answer, time.time())
        folder = self.path.parent
        fd, tmp = tempfile.mkstemp(prefix=f".{self.path.name}.", dir=folder)
        try:
            with os.fdopen(fd, "wb") as f:
                f.write(data)
                f.flush()
                os.fsync(f.fileno())
            os.replace(tmp, self.path)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise
        try:  # the rename itself survives a power cut
            dfd = os.open(folder, os.O_RDONLY)
        except OSError:
            return
        try:
            os.fsync(dfd)
        except OSError:
            pass
        finally:
            os.close(dfd)

    def flush(self, timeout_s: float = CLOSE_WAIT_S) -> bool:
        """Wait until every offered state was tried (at most ``timeout_s``); True if it was
        (then :meth:`state` says whether it is on disk)."""
        deadline = time.monotonic() + timeout_s
        with self._cond:
            while self._pending is not None or self._busy:
                left = deadline - time.monotonic()
                if left <= 0:
                    return False
                self._cond.wait(left)
        return True

    def close(self) -> None:
        """Write what is pending (bounded: :data:`CLOSE_WAIT_S`) and stop the writer."""
        self.flush()
        with self._cond:
            self._closed = True
            self._cond.notify_all()
        self._thread.join(CLOSE_WAIT_S)
