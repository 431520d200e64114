"""A study file (TOML): a base scenario, the parameters to vary, the seeds; expanded to cases.

A study is read, expanded and every case's scenario validated before any case runs: a mistake
is one :class:`StudyError` naming it (``formation sweep`` prints it as one line, exit 2).

The format (every key but ``study.scenario`` and one ``[[vary]]`` or ``seeds`` optional)::

    [study]
    name = "ref-offset"                  # default: the file's stem
    description = "..."
    scenario = "paper-sim"               # a built-in name or a TOML file (relative to this file)
    duration_s = 60.0                    # override the scenario's duration
    seeds = [1, 2, 3]                    # or {start = 0, count = 5}; default: the scenario's
    metrics = ["err_rms_cm", "peak_power_pct"]   # plotted (the table has every metric)
    reduced = {seeds = 1, values = 2, duration_s = 20.0}   # the size of `--reduced`

    [set]                                # fixed changes of every case, by dotted path
    "camera.pos_std_m" = 0.0

    [[vary]]                             # one axis: a field and its values
    field = "geometry.ref_offset_m"      # any scenario field by dotted path; list items by index
    values = [0.01, 0.02]                # a list ...
    grid = {start = 0.01, stop = 0.10, num = 10}            # ... or an inclusive linear grid
    random = {low = 0.01, high = 0.10, count = 8, seed = 4}  # ... or seeded uniform samples

    [[vary]]                             # an axis that sets several fields together
    name = "start_distance_m"            # the column (a number per case; default: the field)
    values = [0.1, 0.2, 0.4]
    [vary.with]                          # field -> one value per entry of `values`
    "robots.initial" = [[...], [...], [...]]

Two pseudo-fields resize the fleet by the paper's staged rule (``scenario.resize``, what
``formation sim --robots N --spares K`` runs): ``fleet.robots`` and ``fleet.spares``.

Cases are the product of the axes (in file order, the last axis fastest) and the seeds. Each has
a key: a hash of its scenario table, seed and duration, so a results file of an earlier run is
matched case by case (``formation sweep`` skips finished cases) and a changed base scenario
never reuses an old result.
"""

from __future__ import annotations

import copy
import hashlib
import itertools
import json
import math
import random
import tomllib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final

__all__ = [
    "MAX_CASES",
    "Axis",
    "Case",
    "Study",
    "StudyError",
    "expand",
    "load_study",
    "parse_study",
    "set_path",
]

MAX_CASES: Final = 20_000
"""A study expands to at most this many cases (about 2 h on 2 cores at 0.5 s a case)."""
MAX_VALUES: Final = 10_000
"""At most this many values on one axis, and at most this many seeds."""
FLEET_FIELDS: Final = ("fleet.robots", "fleet.spares")
"""Pseudo-fields: the fleet resized by ``scenario.resize.scenario_with_robots``."""

_STUDY_KEYS = {
    "name", "description", "scenario", "duration_s", "seeds", "metrics", "reduced",
}  # fmt: skip
_AXIS_KEYS = {"field", "name", "values", "grid", "random", "with"}
_REDUCED_KEYS = {"seeds", "values", "duration_s"}


class StudyError(ValueError):
    """A study is malformed; the message names the key or the case and what is wrong."""


@dataclass(frozen=True)
class Axis:
    """One varied parameter: its column ``name``, its ``values`` (numbers, or anything TOML for
    a field set directly) and the fields each value sets (``sets[field][i]`` for value ``i``)."""

    name: str
    values: tuple[Any, ...]
    sets: Mapping[str, tuple[Any, ...]]


@dataclass(frozen=True)
class Case:
    """One run of a study: its index in the study's order, the value of every axis, the seed,
    the scenario table it runs (validated) and its key (see the module docstring)."""

    index: int
    params: Mapping[str, Any]
    seed: int
    data: Mapping[str, Any]
    source: str
    duration_s: float | None
    key: str


@dataclass(frozen=True)
class Study:
    name: str
    description: str
    path: Path | None
    scenario: str
    base: Mapping[str, Any]
    base_source: str
    fixed: Mapping[str, Any]
    axes: tuple[Axis, ...]
    seeds: tuple[int, ...]
    duration_s: float | None
    metrics: tuple[str, ...]
    reduced: Mapping[str, Any] = field(default_factory=dict)

    @property
    def n_cases(self) -> int:
        return math.prod(len(a.values) for a in self.axes) * len(self.seeds)

    def reduce(self) -> Study:
        """The study at its ``reduced`` size (for ``make test``): the first ``seeds`` seeds, at
        most ``values`` values of each axis (first and last kept) and ``duration_s``."""
        r = self.reduced
        n_seeds = int(r.get("seeds", 1))
        n_values = int(r.get("values", 2))
        axes = tuple(_thin(a, n_values) for a in self.axes)
        return Study(
            name=self.name,
            description=self.description,
            path=self.path,
            scenario=self.scenario,
            base=self.base,
            base_source=self.base_source,
            fixed=self.fixed,
            axes=axes,
            seeds=self.seeds[:n_seeds],
            duration_s=float(r.get("duration_s", self.duration_s or 0.0)) or self.duration_s,
            metrics=self.metrics,
            reduced=self.reduced,
        )


def _thin(axis: Axis, n: int) -> Axis:
    if len(axis.values) <= n:
        return axis
    if n == 1:
        picks = [0]
    else:
        step = (len(axis.values) - 1) / (n - 1)
        picks = sorted({round(i * step) for i in range(n)})
    return Axis(
        name=axis.name,
        values=tuple(axis.values[i] for i in picks),
        sets={f: tuple(v[i] for i in picks) for f, v in axis.sets.items()},
    )


# -- reading ---------------------------------------------------------------------------------


def load_study(path: str | Path) -> Study:
    """Read and validate a study file; raises :class:`StudyError`."""
    p = Path(path)
    try:
        data = tomllib.loads(p.read_text())
    except OSError as exc:
        raise StudyError(f"{p}: cannot read: {exc.strerror or exc}") from exc
    except tomllib.TOMLDecodeError as exc:
        raise StudyError(f"{p}: not valid TOML: {exc}") from exc
    return parse_study(data, path=p)


def _number(v: Any, where: str) -> float:
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(float(v)):
        raise StudyError(f"{where}: expected a finite number, got {v!r}")
    return float(v)


def _count(v: Any, where: str, lo: int = 1, hi: int = MAX_VALUES) -> int:
    if isinstance(v, bool) or not isinstance(v, int):
        raise StudyError(f"{where}: expected an integer, got {v!r}")
    if not lo <= v <= hi:
        if v < lo and lo == 1:
            raise StudyError(f"{where}: {v} gives an empty range (must be >= 1)")
        raise StudyError(f"{where}: {v} out of range ({lo}..{hi})")
    return v


def _only(d: Mapping[str, Any], allowed: set[str], where: str) -> None:
    unknown = set(d) - allowed
    if unknown:
        raise StudyError(
            f"{where}: unknown key(s) {', '.join(sorted(unknown))}; allowed: "
            f"{', '.join(sorted(allowed))}"
        )


def _table(d: Mapping[str, Any], key: str, where: str) -> dict[str, Any]:
    v = d.get(key, {})
    if not isinstance(v, dict):
        raise StudyError(f"{where}: expected a table, got {type(v).__name__}")
    return v


def _grid(g: Any, where: str) -> tuple[float, ...]:
    if not isinstance(g, dict):
        raise StudyError(f"{where}: expected a table {{start, stop, num}}")
    _only(g, {"start", "stop", "num"}, where)
    for k in ("start", "stop", "num"):
        if k not in g:
            raise StudyError(f"{where}.{k}: required")
    start = _number(g["start"], f"{where}.start")
    stop = _number(g["stop"], f"{where}.stop")
    num = _count(g["num"], f"{where}.num")
    if num == 1:
        return (start,)
    # exact end points; the same values on every machine (no accumulated step)
    return tuple(round(start + (stop - start) * i / (num - 1), 12) for i in range(num))


def _random(r: Any, where: str) -> tuple[float, ...]:
    if not isinstance(r, dict):
        raise StudyError(f"{where}: expected a table {{low, high, count, seed}}")
    _only(r, {"low", "high", "count", "seed"}, where)
    for k in ("low", "high", "count", "seed"):
        if k not in r:
            raise StudyError(f"{where}.{k}: required")
    low = _number(r["low"], f"{where}.low")
    high = _number(r["high"], f"{where}.high")
    if not low < high:
        raise StudyError(f"{where}: empty range (low {low:g} must be < high {high:g})")
    count = _count(r["count"], f"{where}.count")
    seed = _count(r["seed"], f"{where}.seed", lo=0, hi=2**63 - 1)
    gen = random.Random(seed)  # Mersenne Twister: the same samples on every platform
    return tuple(round(gen.uniform(low, high), 12) for _ in range(count))


def _axis(j: int, a: Any) -> Axis:
    where = f"vary[{j}]"
    if not isinstance(a, dict):
        raise StudyError(f"{where}: expected a table [[vary]]")
    _only(a, _AXIS_KEYS, where)
    sources = [k for k in ("values", "grid", "random") if k in a]
    if len(sources) != 1:
        raise StudyError(f"{where}: give exactly one of values, grid, random")
    src = sources[0]
    if src == "values":
        raw = a["values"]
        if not isinstance(raw, list):
            raise StudyError(f"{where}.values: expected a list")
        if not raw:
            raise StudyError(f"{where}.values: empty list (nothing to vary)")
        if len(raw) > MAX_VALUES:
            raise StudyError(f"{where}.values: {len(raw)} values, more than {MAX_VALUES}")
        values: tuple[Any, ...] = tuple(raw)
    elif src == "grid":
        values = _grid(a["grid"], f"{where}.grid")
    else:
        values = _random(a["random"], f"{where}.random")
    fld = a.get("field")
    if fld is not None and (not isinstance(fld, str) or not fld):
        raise StudyError(f"{where}.field: expected a dotted path such as 'gains.kp'")
    with_ = a.get("with", {})
    if not isinstance(with_, dict):
        raise StudyError(f"{where}.with: expected a table of field -> list of values")
    if fld is None and not with_:
        raise StudyError(f"{where}: give a field, or a name and a [vary.with] table")
    name = a.get("name", fld)
    if not isinstance(name, str) or not name:
        raise StudyError(f"{where}.name: expected a non-empty string")
    if len(set(map(repr, values))) != len(values):
        raise StudyError(f"{where}: {name} has a repeated value")
    sets: dict[str, tuple[Any, ...]] = {}
    if fld is not None:
        sets[fld] = values
    for f, vs in with_.items():
        if not isinstance(vs, list) or len(vs) != len(values):
            raise StudyError(
                f"{where}.with.{f}: expected a list of {len(values)} values, one per value"
            )
        sets[f] = tuple(vs)
    if fld is None and not all(isinstance(v, int | float) for v in values):
        raise StudyError(f"{where}.values: the values of a named axis must be numbers")
    return Axis(name=name, values=values, sets=sets)


def _seeds(v: Any) -> tuple[int, ...]:
    where = "study.seeds"
    if isinstance(v, dict):
        _only(v, {"start", "count"}, where)
        start = _count(v.get("start", 0), f"{where}.start", lo=0, hi=2**32 - 1)
        count = _count(v.get("count", 1), f"{where}.count")
        return tuple(range(start, start + count))
    if not isinstance(v, list) or not v:
        raise StudyError(f"{where}: expected a non-empty list of integers or {{start, count}}")
    out = tuple(_count(s, f"{where}[{i}]", lo=0, hi=2**32 - 1) for i, s in enumerate(v))
    if len(set(out)) != len(out):
        raise StudyError(f"{where}: repeated seed")
    if len(out) > MAX_VALUES:
        raise StudyError(f"{where}: {len(out)} seeds, more than {MAX_VALUES}")
    return out


def _base(name: str, path: Path | None) -> tuple[dict[str, Any], str]:
    """The base scenario's table and source path (a file relative to the study, or built-in)."""
    from scenario import ScenarioError, resolve

    candidates = [name]
    if path is not None and not Path(name).is_absolute():
        candidates.insert(0, str(path.parent / name))
    for c in candidates:
        try:
            src = resolve(c)
        except ScenarioError:
            continue
        try:
            return tomllib.loads(src.read_text()), str(src)
        except tomllib.TOMLDecodeError as exc:
            raise StudyError(f"study.scenario: {src}: not valid TOML: {exc}") from exc
    from scenario import builtin_names

    raise StudyError(
        f"study.scenario: no scenario {name!r} (not a file, nor one of "
        f"{', '.join(builtin_names())})"
    )


def parse_study(data: Mapping[str, Any], path: Path | None = None) -> Study:
    """Validate a study table, expand it and validate every case; raises :class:`StudyError`."""
    from formation.sweep.case_metrics import METRICS

    _only(data, {"study", "set", "vary"}, "study file")
    s = _table(data, "study", "study")
    _only(s, _STUDY_KEYS, "study")
    if "scenario" not in s or not isinstance(s["scenario"], str):
        raise StudyError("study.scenario: required (a built-in name or a TOML file)")
    name = s.get("name", path.stem if path is not None else "study")
    if not isinstance(name, str) or not name or "/" in name:
        raise StudyError("study.name: expected a non-empty string without '/'")
    description = s.get("description", "")
    if not isinstance(description, str):
        raise StudyError("study.description: expected a string")
    duration = None
    if "duration_s" in s:
        duration = _number(s["duration_s"], "study.duration_s")
        if not 0.0 < duration <= 1e5:
            raise StudyError(f"study.duration_s: {duration:g} out of range (0, 1e5]")
    base, base_source = _base(s["scenario"], path)
    seeds = _seeds(s["seeds"]) if "seeds" in s else (int(base.get("seed", 0)),)
    metrics_raw = s.get("metrics", list(METRICS))
    if not isinstance(metrics_raw, list) or not metrics_raw:
        raise StudyError("study.metrics: expected a non-empty list of metric names")
    for m in metrics_raw:
        if m not in METRICS:
            raise StudyError(f"study.metrics: unknown metric {m!r}; known: {', '.join(METRICS)}")
    reduced = _table(s, "reduced", "study.reduced")
    _only(reduced, _REDUCED_KEYS, "study.reduced")
    for k in ("seeds", "values"):
        if k in reduced:
            _count(reduced[k], f"study.reduced.{k}", hi=1000)
    if "duration_s" in reduced:
        d = _number(reduced["duration_s"], "study.reduced.duration_s")
        if d <= 0.0:
            raise StudyError("study.reduced.duration_s: must be > 0")
    fixed = _table(data, "set", "set")
    vary = data.get("vary", [])
    if not isinstance(vary, list):
        raise StudyError("vary: expected an array of tables [[vary]]")
    axes = tuple(_axis(j, a) for j, a in enumerate(vary))
    names = [a.name for a in axes]
    for n in names:
        if n in ("case", "seed", "status", "error", *METRICS) or names.count(n) > 1:
            raise StudyError(f"vary: the column name {n!r} is repeated or reserved")
    fields = [f for a in axes for f in a.sets]
    for f in fields:
        if fields.count(f) > 1 or f in fixed:
            raise StudyError(f"vary: field {f!r} is set twice")
    study = Study(
        name=name,
        description=description,
        path=path,
        scenario=s["scenario"],
        base=base,
        base_source=base_source,
        fixed=fixed,
        axes=axes,
        seeds=seeds,
        duration_s=duration,
        metrics=tuple(metrics_raw),
        reduced=reduced,
    )
    if study.n_cases > MAX_CASES:
        sizes = " x ".join(f"{len(a.values)} {a.name}" for a in axes)
        raise StudyError(
            f"study: {study.n_cases} cases ({sizes} x {len(seeds)} seeds) is more than the "
            f"{MAX_CASES} a study may have"
        )
    expand(study)  # validates every case before anything runs
    return study


# -- cases -----------------------------------------------------------------------------------


def set_path(data: dict[str, Any], dotted: str, value: Any) -> None:
    """Set ``data[a][b]...`` for ``dotted = "a.b..."`` in place: missing tables are created, an
    integer part indexes a list (``disturbance.0.dx``). Raises :class:`StudyError` when a part
    goes through something that is neither a table nor a list."""
    parts = dotted.split(".")
    if any(not p for p in parts):
        raise StudyError(f"{dotted!r}: not a dotted path such as 'gains.kp'")
    node: Any = data
    for i, part in enumerate(parts):
        last = i == len(parts) - 1
        here = ".".join(parts[: i + 1])
        if isinstance(node, list):
            if not part.isdigit() or int(part) >= len(node):
                raise StudyError(f"{here}: no item {part} in a list of {len(node)}")
            if last:
                node[int(part)] = copy.deepcopy(value)
            else:
                node = node[int(part)]
        elif isinstance(node, dict):
            if last:
                node[part] = copy.deepcopy(value)
            else:
                node = node.setdefault(part, {})
        else:
            raise StudyError(f"{here}: {'.'.join(parts[:i])} is a value, not a table or list")


def _case_key(data: Mapping[str, Any], seed: int, duration_s: float | None) -> str:
    blob = json.dumps([data, seed, duration_s], sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(blob.encode()).hexdigest()[:16]


def _apply(base: Mapping[str, Any], changes: Sequence[tuple[str, Any]]) -> dict[str, Any]:
    from scenario import ScenarioError, scenario_with_robots

    data = copy.deepcopy(dict(base))
    fleet: dict[str, int] = {}
    for f, v in changes:
        if f in FLEET_FIELDS:
            if isinstance(v, bool) or not isinstance(v, int) or not 0 <= v <= 10000:
                raise StudyError(f"{f}: expected an integer 0..10000, got {v!r}")
            fleet[f] = v
        else:
            set_path(data, f, v)
    if fleet:
        try:
            data = scenario_with_robots(
                data, fleet.get("fleet.robots"), fleet.get("fleet.spares", 0)
            )
        except ScenarioError as exc:
            raise StudyError(str(exc)) from exc
    return data


def expand(study: Study) -> list[Case]:
    """Every case of ``study`` in order, each scenario validated by the scenario validator
    (``scenario.parse`` and the cores' own checks); raises :class:`StudyError` naming the case's
    parameter values and the field."""
    from scenario import ScenarioError, parse
    from scenario.check import check_cores

    cases: list[Case] = []
    checked: set[str] = set()
    combos = itertools.product(*(range(len(a.values)) for a in study.axes))
    index = 0
    for combo in combos:
        params = {a.name: a.values[i] for a, i in zip(study.axes, combo, strict=True)}
        changes = list(study.fixed.items())
        for a, i in zip(study.axes, combo, strict=True):
            changes += [(f, vs[i]) for f, vs in a.sets.items()]
        what = ", ".join(f"{k} = {_short(v)}" for k, v in params.items()) or "the base scenario"
        try:
            data = _apply(study.base, changes)
            if study.duration_s is not None:
                data["duration_s"] = study.duration_s
                # disturbances after the end do not happen in the shortened run
                if isinstance(data.get("disturbance"), list):
                    data["disturbance"] = [
                        d
                        for d in data["disturbance"]
                        if not (isinstance(d, dict) and _after(d.get("t_s"), study.duration_s))
                    ]
                settle = data.get("settle_s")
                if isinstance(settle, int | float) and settle > study.duration_s:
                    data["settle_s"] = study.duration_s / 2.0
            scn = parse(data, source=study.base_source)
            # the cores' checks (trajectory, formation) once per distinct pair of tables
            cores_key = json.dumps([data.get("trajectory"), data.get("formation")], sort_keys=True)
            if cores_key not in checked:
                check_cores(scn)
                checked.add(cores_key)
        except (StudyError, ScenarioError) as exc:
            msg = str(exc).replace(f"{study.base_source}: ", "")
            raise StudyError(f"case {what}: {msg}") from exc
        for seed in study.seeds:
            cases.append(
                Case(
                    index=index,
                    params=params,
                    seed=seed,
                    data=data,
                    source=study.base_source,
                    duration_s=study.duration_s,
                    key=_case_key(data, seed, study.duration_s),
                )
            )
            index += 1
    return cases


def _after(t_s: Any, duration_s: float) -> bool:
    return isinstance(t_s, int | float) and not isinstance(t_s, bool) and t_s > duration_s


def _short(v: Any) -> str:
    text = json.dumps(v)
    return text if len(text) <= 40 else text[:37] + "..."
