"""Output files written whole or not at all (issue 30: a full or read-only disk).

:func:`write_atomic` writes a temporary file next to the target, fsyncs it and renames it into
place: a reader sees the old file or the new one, never an empty or cut one (a ``metrics.json``
of 0 bytes, a ``plant_stats.json`` cut at the first full block), and a failed write leaves no
temporary file behind. It raises the ``OSError`` (``No space left on device``, ``Read-only file
system``) for the caller to name what was not written.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

__all__ = ["os_error_text", "write_atomic"]


def write_atomic(path: str | os.PathLike[str], data: bytes) -> None:
    """Replace ``path`` with ``data`` (temporary file, fsync, rename); raises ``OSError``."""
    target = Path(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", dir=target.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, target)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def os_error_text(exc: OSError) -> str:
    """An ``OSError`` as one short line (``OSError: No space left on device``)."""
    return f"{type(exc).__name__}: {exc.strerror or exc}"
