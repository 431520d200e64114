"""A run's result files, each whole or not at all: a full or read-only disk leaves no cut file
(``formation sim`` and ``formation up`` write them the same way)."""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from formation.outputs.runlog import RunLog
from runtime.files import write_atomic

__all__ = ["save_npz_atomic", "write_metrics"]


def write_metrics(out_dir: Path, m: Mapping[str, Any]) -> None:
    """``metrics.json``, whole or not at all (runtime.files.write_atomic); raises OSError."""
    out_dir.mkdir(parents=True, exist_ok=True)
    data = (json.dumps(m, indent=2, sort_keys=True) + "\n").encode()
    write_atomic(out_dir / "metrics.json", data)


def save_npz_atomic(log: RunLog, path: Path) -> None:
    """``run.npz`` through a temporary file: a full disk leaves no cut archive."""
    tmp = path.with_name(f".{path.name}.tmp.npz")  # numpy adds .npz to other names
    try:
        log.save_npz(str(tmp))
        tmp.replace(path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
