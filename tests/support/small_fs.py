"""A real small filesystem for the full- and read-only-disk tests (issue 30): a tmpfs of a few
hundred KiB mounted on a folder of the test, that the test fills up (:func:`fill`), frees
(:func:`free`) or remounts read-only (:func:`read_only`). Mounting needs root (CAP_SYS_ADMIN);
elsewhere the test is skipped with the reason. The mount is lazily unmounted when the context
ends, whatever happened (a process that still has a file open there keeps it until it exits).
"""

from __future__ import annotations

import contextlib
import errno
import subprocess
from collections.abc import Iterator
from pathlib import Path

import pytest

FILLER = ".filler"


@contextlib.contextmanager
def small_fs(folder: Path, size: str = "256k") -> Iterator[Path]:
    """A tmpfs of ``size`` mounted on ``folder`` (created) for the duration of the context."""
    folder.mkdir(parents=True, exist_ok=True)
    cmd = ["mount", "-t", "tmpfs", "-o", f"size={size},mode=0755", "tmpfs", str(folder)]
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=10)
    except FileNotFoundError:
        pytest.skip("no mount(8) here: cannot make a small filesystem to fill")
    if proc.returncode != 0:
        why = proc.stderr.strip() or f"status {proc.returncode}"
        pytest.skip(f"cannot mount a small tmpfs here ({why}): the full-disk case is not tested")
    try:
        yield folder
    finally:
        subprocess.run(["umount", "-l", str(folder)], capture_output=True, timeout=10)


def fill(folder: Path) -> Path:
    """Fill the filesystem of ``folder`` to the last byte; the filler file's path."""
    path = folder / FILLER
    with path.open("ab", buffering=0) as f:  # unbuffered: closing has nothing left to write
        for block in (b"\0" * 4096, b"\0"):  # whole blocks, then the last bytes
            while True:
                try:
                    f.write(block)
                except OSError as exc:
                    if exc.errno != errno.ENOSPC:
                        raise
                    break
    return path


def free(folder: Path) -> None:
    """Give the filesystem of ``folder`` its space back (remove :func:`fill`'s file)."""
    (folder / FILLER).unlink(missing_ok=True)


def read_only(folder: Path, on: bool = True) -> None:
    """Remount the tmpfs on ``folder`` read-only (``on``) or read-write."""
    mode = "ro" if on else "rw"
    subprocess.run(["mount", "-o", f"remount,{mode}", str(folder)], check=True, timeout=10)
