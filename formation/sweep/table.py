"""The study's table: one row per case, in the study's order; CSV and Parquet.

Columns: ``case`` (its index), one per varied parameter, ``seed``, ``status`` (``ok`` /
``failed`` / ``missing`` when it has not run yet), ``error`` (one line, failed cases) and one per
metric of :data:`formation.sweep.case_metrics.METRICS`. No wall-clock time is in it, so the same
study gives the same table byte for byte whatever the machine's load or the number of workers.
A missing value (a failed case, a metric that does not apply) is an empty CSV field and a null
in Parquet (pandas and polars read both as missing).
"""

from __future__ import annotations

import csv
import json
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from formation.sweep.case_metrics import METRICS
from formation.sweep.study import Case, Study

__all__ = ["TEXT_METRICS", "Table", "build_table", "write_csv", "write_parquet"]

TEXT_METRICS = ("final_leader",)
INT_METRICS = ("unsettled_robots", "collisions", "role_changes")

Table = tuple[list[str], list[list[Any]]]
"""(column names, rows)."""


def _cell(v: Any) -> Any:
    if isinstance(v, bool | int | float | str) or v is None:
        return v
    return json.dumps(v, separators=(",", ":"))  # a list or table value of a field


def build_table(study: Study, cases: Sequence[Case], records: Mapping[str, Any]) -> Table:
    """The table of ``cases`` with the ``records`` found (by case key)."""
    names = [a.name for a in study.axes]
    columns = ["case", *names, "seed", "status", "error", *METRICS]
    rows: list[list[Any]] = []
    for c in cases:
        rec = records.get(c.key)
        status = "missing" if rec is None else str(rec.get("status", "failed"))
        metrics = rec.get("metrics", {}) if rec is not None else {}
        row = [c.index, *(_cell(c.params[n]) for n in names), c.seed, status]
        row.append("" if rec is None else str(rec.get("error", "")))
        row += [metrics.get(m) for m in METRICS]
        rows.append(row)
    return columns, rows


def _csv_cell(v: Any) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return ""
    if isinstance(v, float):
        return repr(v)
    return str(v)


def write_csv(table: Table, path: Path) -> Path:
    columns, rows = table
    with path.open("w", newline="") as f:
        w = csv.writer(f, lineterminator="\n")
        w.writerow(columns)
        for r in rows:
            w.writerow([_csv_cell(v) for v in r])
    return path


def _arrow_type(values: list[Any]) -> Any:
    import pyarrow as pa

    present = [v for v in values if v is not None]
    if present and all(isinstance(v, bool) for v in present):
        return pa.bool_()
    if present and all(isinstance(v, int) and not isinstance(v, bool) for v in present):
        return pa.int64()
    if present and all(isinstance(v, int | float) and not isinstance(v, bool) for v in present):
        return pa.float64()
    return pa.string()


def write_parquet(table: Table, path: Path) -> Path:
    """The table as Parquet (pyarrow): numbers typed, missing values null."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    columns, rows = table
    arrays = []
    for j, name in enumerate(columns):
        values = [r[j] for r in rows]
        if name in METRICS:
            typ = (
                pa.string()
                if name in TEXT_METRICS
                else pa.int64()
                if name in INT_METRICS
                else pa.float64()
            )
        else:
            typ = _arrow_type(values)
        if typ == pa.float64():
            values = [None if v is None else float(v) for v in values]
        elif typ == pa.string():
            values = [None if v is None else str(v) for v in values]
        arrays.append(pa.array(values, type=typ))
    pq.write_table(
        pa.table(arrays, names=columns),
        path,
        compression="zstd",
        # no creation time or library version varies the bytes between two runs
        write_statistics=False,
        store_schema=True,
    )
    return path
