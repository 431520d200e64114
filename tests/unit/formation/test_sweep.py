"""``formation sweep``: study files read, expanded and validated before anything runs (a mistake:
one line, exit 2, nothing written); cases run in worker processes into a results file that a
rerun resumes from; a failing case is reported and does not stop the study; the table is the
same whatever the number of workers; the shipped studies run end to end at their reduced size.
"""

from __future__ import annotations

import csv
import json
import math
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from support.spawn import child_env

from formation.sweep import command, study
from formation.sweep.run import RESULTS_FILE, read_results, run_case, run_cases
from formation.sweep.study import MAX_CASES, StudyError, expand, parse_study, set_path

REPO = Path(__file__).resolve().parents[3]
STUDIES = sorted((REPO / "studies").glob("*.toml"))


def _write(tmp: Path, text: str, name: str = "s.toml") -> Path:
    p = tmp / name
    p.write_text(text)
    return p


BASE = """
[study]
scenario = "paper-exp1"
duration_s = 2.0
seeds = [1, 2]
"""


# -- reading and validating ------------------------------------------------------------------


@pytest.mark.parametrize(
    ("vary", "names"),
    [
        ('field = "geometry.ref_ofset_m"\nvalues = [0.02]', "ref_ofset_m"),  # unknown field
        ('field = "gains.kp"\nvalues = []', "empty list"),
        ('field = "gains.kp"\ngrid = {start = 0.1, stop = 0.2, num = 0}', "empty range"),
        ('field = "gains.kp"\nrandom = {low = 0.2, high = 0.2, count = 3, seed = 1}', "empty"),
        ('field = "geometry.ref_offset_m"\nvalues = [0.05, 2.0]', "2.0 is outside the plausible"),
        ('field = "gains.kp"\ngrid = {start = 0.1, stop = 0.2, num = 1000}\n'
         '[[vary]]\nfield = "gains.ti_s"\ngrid = {start = 50, stop = 150, num = 1000}',
         "2000000 cases (1000 gains.kp x 1000 gains.ti_s x 2 seeds)"),
        ('field = "trajectory.speeed_mps"\nvalues = [0.02]', "speeed_mps"),  # the cores' check
        ('field = "camera.rate_hz"\nvalues = ["fast"]', "camera.rate_hz"),
        ('field = "robots.initial.7"\nvalues = [[0, 0, 0]]', "no item 7"),
        ('field = "gains.kp"\nvalues = [0.1, 0.1]', "repeated value"),
        ('values = [1, 2]', "give a field"),
        ('field = "gains.kp"\nvalues = [0.1]\nstep = 2', "unknown key(s) step"),
    ],
)  # fmt: skip
def test_a_bad_study_is_one_line_exit_2_before_any_case_runs(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], vary: str, names: str
) -> None:
    path = _write(tmp_path, BASE + "[[vary]]\n" + vary + "\n")
    out = tmp_path / "out"
    assert command.main([str(path), "--out", str(out), "--jobs", "1"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and names in err, err
    assert not out.exists()


@pytest.mark.parametrize(
    ("extra", "names"),
    [
        ('[study]\nscenario = "nope"\n', "no scenario 'nope'"),
        ('[study]\nscenario = "paper-exp1"\nseeds = []\n', "study.seeds"),
        ('[study]\nscenario = "paper-exp1"\nmetrics = ["speed"]\n', "unknown metric 'speed'"),
        ('[study]\nscenario = "paper-exp1"\n[set]\n"gains.kpp" = 1.0\n', "kpp"),
        ('[study]\nscenario = "paper-exp1"\nduration_s = -1.0\n', "study.duration_s"),
        ("[study\n", "not valid TOML"),
    ],
)
def test_bad_study_keys_are_named(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], extra: str, names: str
) -> None:
    path = _write(tmp_path, extra)
    assert command.main([str(path), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and names in err, err


def test_expansion_order_keys_grids_samples_and_zipped_fields(tmp_path: Path) -> None:
    text = (
        BASE
        + """
[set]
"camera.pos_std_m" = 0.0
[[vary]]
field = "geometry.ref_offset_m"
grid = {start = 0.02, stop = 0.08, num = 4}
[[vary]]
name = "kp_design"
values = [1, 2]
[vary.with]
"gains.kp" = [0.2, 0.4]
"gains.ti_s" = [100.0, 50.0]
"""
    )
    s = study.load_study(_write(tmp_path, text))
    cases = expand(s)
    assert s.n_cases == len(cases) == 4 * 2 * 2
    assert s.axes[0].values == (0.02, 0.04, 0.06, 0.08)
    first, last = cases[0], cases[-1]
    assert (first.params, first.seed) == ({"geometry.ref_offset_m": 0.02, "kp_design": 1}, 1)
    assert (last.params, last.seed) == ({"geometry.ref_offset_m": 0.08, "kp_design": 2}, 2)
    assert last.data["gains"] == {"kp": 0.4, "ti_s": 50.0}
    assert last.data["camera"]["pos_std_m"] == 0.0
    assert [c.index for c in cases] == list(range(len(cases)))
    assert len({c.key for c in cases}) == len(cases)
    # the same study again: the same keys (what resuming relies on); another base: other keys
    assert [c.key for c in expand(study.load_study(tmp_path / "s.toml"))] == [c.key for c in cases]
    other = study.load_study(_write(tmp_path, text.replace("paper-exp1", "paper-exp2"), "t.toml"))
    assert not {c.key for c in expand(other)} & {c.key for c in cases}


def test_random_samples_are_seeded_and_in_range(tmp_path: Path) -> None:
    vary = '[[vary]]\nfield = "gains.kp"\nrandom = {low = 0.1, high = 0.3, count = 5, seed = 7}\n'
    a = study.load_study(_write(tmp_path, BASE + vary)).axes[0].values
    b = study.load_study(_write(tmp_path, BASE + vary, "b.toml")).axes[0].values
    assert a == b and len(set(a)) == 5 and all(0.1 <= v <= 0.3 for v in a)
    c = study.load_study(_write(tmp_path, BASE + vary.replace("seed = 7", "seed = 8"), "c.toml"))
    assert c.axes[0].values != a


def test_fleet_pseudo_field_resizes_by_the_staged_rule(tmp_path: Path) -> None:
    s = study.load_study(
        _write(tmp_path, BASE + '[[vary]]\nfield = "fleet.robots"\nvalues = [3, 7]\n')
    )
    sizes = [len(c.data["robots"]["ids"]) for c in expand(s) if c.seed == 1]
    assert sizes == [3, 7]


def test_the_case_limit_is_checked_before_expanding() -> None:
    data: dict[str, Any] = {
        "study": {"scenario": "paper-exp1", "seeds": {"start": 0, "count": 10}},
        "vary": [
            {"field": "gains.kp", "grid": {"start": 0.1, "stop": 1.0, "num": 100}},
            {"field": "gains.ti_s", "grid": {"start": 50.0, "stop": 150.0, "num": 100}},
        ],
    }
    with pytest.raises(StudyError, match=f"more than the {MAX_CASES}"):
        parse_study(data)


@settings(max_examples=60, deadline=None)
@given(
    st.lists(st.sampled_from(["a", "b", "0", "1"]), min_size=1, max_size=4),
    st.integers(-5, 5),
)
def test_set_path_sets_exactly_one_place(parts: list[str], value: int) -> None:
    data: dict[str, Any] = {"a": {"b": 1}, "b": [{"a": 0}, {"b": 2}]}
    dotted = ".".join(parts)
    try:
        set_path(data, dotted, value)
    except StudyError:
        return
    node: Any = data
    for p in parts:
        node = node[int(p)] if isinstance(node, list) else node[p]
    assert node == value


# -- running ---------------------------------------------------------------------------------


def flaky_runner(spec: Any) -> dict[str, Any]:
    """A case runner whose odd cases fail (module level: it is sent to workers)."""
    if spec[1] % 2:
        return {"key": spec[0], "index": spec[1], "seed": spec[4], "status": "failed",
                "error": "RuntimeError: boom", "metrics": {}, "wall_s": 0.0}  # fmt: skip
    return {"key": spec[0], "index": spec[1], "seed": spec[4], "status": "ok", "error": "",
            "metrics": {"err_rms_cm": float(spec[1])}, "wall_s": 0.0}  # fmt: skip


class Interrupt:
    """A runner that raises KeyboardInterrupt (as Ctrl-C does) at its ``at``-th call."""

    def __init__(self, at: int) -> None:
        self.at, self.calls = at, 0

    def __call__(self, spec: Any) -> dict[str, Any]:
        self.calls += 1
        if self.calls == self.at:
            raise KeyboardInterrupt
        return flaky_runner(spec)


def _study(tmp_path: Path, values: str = "[0.03, 0.05, 0.07]") -> study.Study:
    return study.load_study(
        _write(tmp_path, BASE + f'[[vary]]\nfield = "geometry.ref_offset_m"\nvalues = {values}\n')
    )


def test_interrupted_study_resumes_where_it_stopped_and_failures_do_not_stop_it(
    tmp_path: Path,
) -> None:
    cases = expand(_study(tmp_path))
    results = tmp_path / "out" / RESULTS_FILE
    first = run_cases(cases, results, runner=Interrupt(at=4))
    assert first.interrupted and first.ran == 3
    assert len(read_results(results)) == 3
    second = run_cases(cases, results, runner=flaky_runner)
    assert not second.interrupted and (second.ran, second.skipped) == (3, 3)
    statuses = [second.records[c.key]["status"] for c in cases]
    assert statuses == ["ok", "failed"] * 3
    third = run_cases(cases, results, runner=flaky_runner)
    assert third.ran == 0  # every case finished (failed ones too)
    fourth = run_cases(cases, results, runner=flaky_runner, retry_failed=True)
    assert fourth.ran == 3


def test_a_torn_last_line_is_ignored(tmp_path: Path) -> None:
    cases = expand(_study(tmp_path))
    results = tmp_path / RESULTS_FILE
    run_cases(cases[:2], results, runner=flaky_runner)
    with results.open("a") as f:
        f.write('{"key": "abc", "sta')  # killed mid-write
    assert len(read_results(results)) == 2


def test_a_case_that_raises_is_a_failed_record_with_one_line() -> None:
    rec = run_case(("k", 0, {"name": "x"}, "<dict>", 0, 1.0))
    assert rec["status"] == "failed" and "\n" not in rec["error"]
    assert "duration_s" in rec["error"]  # the scenario validator's message


def test_a_real_case_measures_the_run(tmp_path: Path) -> None:
    (case,) = [c for c in expand(_study(tmp_path, "[0.05]")) if c.seed == 1]
    rec = run_case((case.key, case.index, dict(case.data), case.source, case.seed, 2.0))
    assert rec["status"] == "ok", rec["error"]
    m = rec["metrics"]
    assert m["final_leader"] == "r1" and m["collisions"] == 0
    assert 0.0 < m["peak_power_pct"] <= 100.0
    assert m["min_separation_cm"] > 2 * 7.5


def _table(out: Path) -> list[dict[str, str]]:
    with (out / "table.csv").open() as f:
        return list(csv.DictReader(f))


@pytest.mark.slow
def test_the_table_is_the_same_with_one_worker_or_two_and_parquet_reads_back(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    vary = '[[vary]]\nfield = "geometry.ref_offset_m"\nvalues = [0.03, 0.06]\n'
    path = _write(tmp_path, BASE + 'metrics = ["err_rms_cm", "final_leader"]\n' + vary)
    a, b = tmp_path / "a", tmp_path / "b"
    assert command.main([str(path), "--out", str(a), "--jobs", "1", "--quiet"]) == 0
    # two workers from a fresh process, as a user runs it (this test process has other tests'
    # threads: the sweep would spawn its workers instead of forking them)
    argv = ["sweep", str(path), "--out", str(b), "--jobs", "2", "--quiet", "--no-plots"]
    two = subprocess.run(
        [sys.executable, "-m", "formation", *argv],
        env=child_env(),
        capture_output=True,
        text=True,
        timeout=240,
        check=False,
    )
    assert two.returncode == 0, two.stderr[-2000:]
    assert (a / "table.csv").read_bytes() == (b / "table.csv").read_bytes()
    rows = _table(a)
    assert len(rows) == 4 and {r["status"] for r in rows} == {"ok"}
    import pyarrow.parquet as pq

    t = pq.read_table(a / "table.parquet")
    assert t.num_rows == 4 and t.column("seed").to_pylist() == [1, 2, 1, 2]
    assert t.schema.field("err_rms_cm").type == "double"
    assert t.column("err_rms_cm").to_pylist() == pytest.approx(
        [float(r["err_rms_cm"]) for r in rows], rel=1e-15
    )
    assert sorted(p.name for p in (a / "plots").glob("*.png")) == [
        "err_rms_cm.png",
        "final_leader.png",
    ]
    # a rerun runs nothing and writes the same table
    assert command.main([str(path), "--out", str(a), "--jobs", "2", "--no-plots"]) == 0
    assert "0 case(s) run, 4 already done" in capsys.readouterr().out
    assert (a / "table.csv").read_bytes() == (b / "table.csv").read_bytes()


@pytest.mark.slow
@pytest.mark.parametrize("path", STUDIES, ids=[p.stem for p in STUDIES])
def test_a_shipped_study_runs_end_to_end_at_its_reduced_size(path: Path, tmp_path: Path) -> None:
    s = study.load_study(path).reduce()
    assert 1 <= s.n_cases <= 6
    out = tmp_path / path.stem
    assert command.main([str(path), "--reduced", "--out", str(out), "--jobs", "1", "--quiet"]) == 0
    rows = _table(out)
    assert len(rows) == s.n_cases and {r["status"] for r in rows} == {"ok"}
    for r in rows:
        assert math.isfinite(float(r["peak_power_pct"])) and r["final_leader"]
    assert {p.stem for p in (out / "plots").glob("*.png")} == set(s.metrics)
    recs = [json.loads(ln) for ln in (out / RESULTS_FILE).read_text().splitlines()]
    assert len(recs) == s.n_cases
