"""``formation sweep STUDY.toml [--out DIR] [--jobs N] [--reduced]``: run a parameter study.

Reads the study (:mod:`formation.sweep.study`), validates every case before any runs (a mistake:
one line naming it, exit 2), runs the cases not yet in ``DIR/cases.jsonl`` over ``--jobs``
worker processes (:mod:`formation.sweep.run`) with a progress line and ETA on stderr, then writes
``DIR/table.csv``, ``DIR/table.parquet`` and ``DIR/plots/<metric>.png``. Ctrl-C stops the
workers; the cases finished so far stay in ``cases.jsonl`` and the same command resumes (exit
130). Failed cases are listed (one line each) and do not stop the study; the exit status is 1
if any case failed, else 0.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

EPILOG = """\
examples:
  formation sweep studies/ref-offset.toml                 # writes runs/sweep/ref-offset/
  formation sweep studies/exp2-ties.toml --jobs 2 --out runs/ties
  formation sweep studies/ref-offset.toml --reduced --no-plots   # a few cases, quick

Rerunning the same command skips the cases already in DIR/cases.jsonl (resume after Ctrl-C)."""


def build_parser() -> argparse.ArgumentParser:
    from runtime.args import HelpFormatter, non_negative_int

    p = argparse.ArgumentParser(
        prog="formation sweep",
        description="Run a parameter study (a TOML file: a base scenario, parameters to vary, "
        "seeds) in-process over the machine's cores; write one table of every case's metrics "
        "(CSV, Parquet) and a plot of each metric against each parameter.",
        epilog=EPILOG,
        formatter_class=HelpFormatter,
    )
    p.add_argument("study", type=Path, help="the study file (TOML)")
    p.add_argument(
        "--out", type=Path, default=None, help="output folder (default: runs/sweep/<name>)"
    )
    p.add_argument(
        "--jobs",
        type=non_negative_int,
        default=0,
        metavar="N",
        help="worker processes (0: one per core of this machine)",
    )
    p.add_argument(
        "--reduced",
        action="store_true",
        help="run the study at its reduced size ([study] reduced: few seeds and values)",
    )
    p.add_argument("--retry-failed", action="store_true", help="run failed cases again")
    p.add_argument("--no-plots", action="store_true", help="skip the PNG plots")
    p.add_argument("--dry-run", action="store_true", help="validate and count the cases only")
    p.add_argument("--quiet", action="store_true", help="print nothing but errors")
    return p


def _jobs(n: int) -> int:
    if n > 0:
        return n
    affinity = getattr(os, "sched_getaffinity", None)
    return len(affinity(0)) if affinity is not None else (os.cpu_count() or 1)


def main(argv: list[str]) -> int:
    args = build_parser().parse_args(argv)
    from formation.sweep.study import StudyError, expand, load_study

    try:
        study = load_study(args.study)
        if args.reduced:
            study = study.reduce()
        cases = expand(study)
    except StudyError as exc:
        print(f"formation sweep: {args.study}: {exc}", file=sys.stderr)
        return 2
    out = args.out or Path("runs") / "sweep" / (study.name + ("-reduced" if args.reduced else ""))
    if out.exists() and not out.is_dir():
        print(f"formation sweep: error: --out: {out} exists and is not a folder", file=sys.stderr)
        return 2
    jobs = _jobs(args.jobs)
    if args.dry_run:
        print(f"study {study.name}: {len(cases)} cases, {jobs} worker(s); nothing run")
        return 0
    from formation.sweep.run import RESULTS_FILE, CaseProgress, run_cases
    from formation.sweep.table import build_table, write_csv, write_parquet

    if not args.quiet:
        print(f"study {study.name}: {len(cases)} cases over {jobs} worker(s) -> {out}/")
    result = run_cases(
        cases,
        out / RESULTS_FILE,
        jobs=jobs,
        retry_failed=args.retry_failed,
        progress=CaseProgress(len(cases), enabled=not args.quiet),
    )
    table = build_table(study, cases, result.records)
    write_csv(table, out / "table.csv")
    write_parquet(table, out / "table.parquet")
    columns, rows = table
    status = columns.index("status")
    failed = [r for r in rows if r[status] == "failed"]
    missing = [r for r in rows if r[status] == "missing"]
    for r in failed:
        params = ", ".join(
            f"{c} = {v}" for c, v in zip(columns[1:status], r[1:status], strict=True)
        )
        print(f"formation sweep: case {r[0]} ({params}) failed: {r[status + 1]}", file=sys.stderr)
    if result.interrupted:
        print(
            f"formation sweep: interrupted: {len(rows) - len(missing)} of {len(rows)} cases "
            f"done in {out / RESULTS_FILE}; run the same command again to resume",
            file=sys.stderr,
        )
        return 130
    if not args.no_plots:
        from formation.sweep.plots import plot_study

        plot_study(study, table, out / "plots")
    if not args.quiet:
        cpu = f"{result.case_wall_s:.1f} s of case time in {result.wall_s:.1f} s"
        print(
            f"{result.ran} case(s) run, {result.skipped} already done, {len(failed)} failed "
            f"({cpu}); table {out / 'table.csv'} and .parquet"
            + ("" if args.no_plots else f", plots in {out / 'plots'}/")
        )
    return 1 if failed else 0
