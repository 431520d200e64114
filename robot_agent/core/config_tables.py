"""The tables of a robot's parameters, read the same way from a robot's config file
(``scenario.robot_config``) and from a scenario (``scenario.load``): one validator.

:func:`build_section` builds one parameter dataclass (``[geometry]``, ``[safety_filter]``, ...,
or a motor backend's settings) from its TOML table: unknown keys, wrong types and values outside
the range declared with the field (``robot_agent.core.params.ranged``) are each reported,
naming ``section.key``. :func:`world_map` reads ``[arena]`` and ``[[obstacle]]``. Pure: the
caller has already parsed the TOML.
"""

from __future__ import annotations

import dataclasses
import math
import re
import typing
from collections.abc import Mapping
from typing import Any

from robot_agent.core.params import (
    AgentConfig,
    Arena,
    CircleObstacle,
    SegmentObstacle,
    WorldMap,
    declared_range,
)

__all__ = ["ID_PATTERN", "agent_sections", "build_section", "identifier", "read_table", "world_map"]

ID_PATTERN = re.compile(r"[a-z0-9_-]+")
"""A robot's or a fleet's id: the ``<id>`` and ``<fleet>`` of every bus key."""


def agent_sections() -> dict[str, type]:
    """AgentConfig's parameter fields: section name -> dataclass (e.g. geometry); the world map
    is read from ``[arena]`` and ``[[obstacle]]`` instead (``_world``)."""
    hints = typing.get_type_hints(AgentConfig)
    return {f.name: hints[f.name] for f in dataclasses.fields(AgentConfig) if f.name != "world"}


_OBSTACLE_KEYS = {
    "circle": ("x", "y", "radius_m"),
    "segment": ("x1", "y1", "x2", "y2", "radius_m"),
    "polygon": ("points", "radius_m"),
}


def _finite_number(value: Any) -> float | None:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    f = float(value)
    return f if math.isfinite(f) else None


def world_map(data: Mapping[str, Any], problems: list[str]) -> WorldMap | None:  # noqa: PLR0915 (a validator: one check per obstacle kind and key)
    """``[arena]`` and ``[[obstacle]]`` as a WorldMap, or None with problems appended."""
    start = len(problems)
    arena: Arena | None = None
    if "arena" in data:
        table = read_table(data, "arena", problems)
        if table is not None:
            keys = ("x_min", "y_min", "x_max", "y_max")
            vals: dict[str, float] = {}
            for key in table:
                if key not in keys:
                    problems.append(f"arena.{key}: unknown key (allowed: {', '.join(keys)})")
            for key in keys:
                if key not in table:
                    problems.append(f"arena.{key}: required")
                    continue
                f = _finite_number(table[key])
                if f is None:
                    problems.append(f"arena.{key}: expected a finite number, got {table[key]!r}")
                else:
                    vals[key] = f
            if len(vals) == 4 and len(problems) == start:
                try:
                    arena = Arena(**vals)
                except ValueError as exc:
                    problems.append(f"arena: {exc}")
    obstacles: list[CircleObstacle | SegmentObstacle] = []
    raw = data.get("obstacle", [])
    if not isinstance(raw, list):
        problems.append("obstacle: expected an array of tables [[obstacle]]")
        raw = []
    for j, item in enumerate(raw):
        where = f"obstacle[{j}]"
        if not isinstance(item, Mapping):
            problems.append(f"{where}: expected a table")
            continue
        kind = item.get("kind")
        if kind not in _OBSTACLE_KEYS:
            problems.append(
                f"{where}.kind: must be one of {', '.join(_OBSTACLE_KEYS)}, got {kind!r}"
            )
            continue
        allowed = ("kind", *_OBSTACLE_KEYS[kind])
        bad = False
        for key in item:
            if key not in allowed:
                problems.append(f"{where}.{key}: unknown key (allowed: {', '.join(allowed)})")
                bad = True
        nums: dict[str, float] = {}
        for key in _OBSTACLE_KEYS[kind]:
            if key == "points" or (key == "radius_m" and kind != "circle" and key not in item):
                continue
            if key not in item:
                problems.append(f"{where}.{key}: required")
                bad = True
                continue
            f = _finite_number(item[key])
            if f is None or (key == "radius_m" and f < 0.0):
                problems.append(f"{where}.{key}: expected a finite number (>= 0 for a radius), "
                                f"got {item[key]!r}")  # fmt: skip
                bad = True
            else:
                nums[key] = f
        if bad:
            continue
        if kind == "circle":
            obstacles.append(CircleObstacle(nums["x"], nums["y"], nums["radius_m"]))
        elif kind == "segment":
            obstacles.append(SegmentObstacle(**nums))
        else:
            pts = item.get("points")
            coords: list[tuple[float, float]] = []
            if isinstance(pts, list) and len(pts) >= 3:
                for p in pts:
                    if isinstance(p, list) and len(p) == 2:
                        x, y = _finite_number(p[0]), _finite_number(p[1])
                        if x is not None and y is not None:
                            coords.append((x, y))
            if len(coords) < 3 or len(coords) != len(pts):  # type: ignore[arg-type]
                problems.append(f"{where}.points: expected >= 3 points [x, y] of finite numbers")
                continue
            r = nums.get("radius_m", 0.0)
            for (x1, y1), (x2, y2) in zip(coords, coords[1:] + coords[:1], strict=True):
                obstacles.append(SegmentObstacle(x1, y1, x2, y2, r))
    if len(problems) > start:
        return None
    return WorldMap(obstacles=tuple(obstacles), arena=arena)


def identifier(
    data: Mapping[str, Any], key: str, default: str | None, problems: list[str]
) -> str | None:
    if key not in data:
        if default is None:
            problems.append(f'{key}: required (e.g. {key} = "r1")')
        return default
    value = data[key]
    if not isinstance(value, str):
        problems.append(f"{key}: expected a string, got {value!r} ({type(value).__name__})")
        return None
    if not ID_PATTERN.fullmatch(value):
        problems.append(f"{key}: {value!r} must match [a-z0-9_-]+ (lower case, no spaces)")
        return None
    return value


def read_table(data: Mapping[str, Any], key: str, problems: list[str]) -> Mapping[str, Any] | None:
    value = data.get(key, {})
    if not isinstance(value, Mapping):
        problems.append(f"{key}: expected a table [{key}], got {type(value).__name__}")
        return None
    return value


_BAD = object()


def _coerce(value: Any, annotation: Any) -> Any:
    """``value`` converted to the field's type, or ``_BAD``. bool is never a number."""
    if annotation is float:
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            f = float(value)
            return f if math.isfinite(f) else _BAD
        return _BAD
    if annotation is int:
        return value if isinstance(value, int) and not isinstance(value, bool) else _BAD
    if annotation is bool:
        return value if isinstance(value, bool) else _BAD
    if annotation is str:
        return value if isinstance(value, str) else _BAD
    return value  # a type this loader does not know: the dataclass validates it


def _type_name(annotation: Any) -> str:
    return {float: "a number", int: "an integer", bool: "true or false", str: "a string"}.get(
        annotation, getattr(annotation, "__name__", str(annotation))
    )


def build_section(
    cls: type,
    table: Mapping[str, Any],
    section: str,
    problems: list[str],
    skip: tuple[str, ...] = (),
) -> Any:
    """An instance of dataclass ``cls`` from ``table``, or None with problems appended."""
    hints = typing.get_type_hints(cls)
    fields = [f for f in dataclasses.fields(cls) if f.name not in skip]
    names = [f.name for f in fields]
    start = len(problems)
    kwargs: dict[str, Any] = {}
    for key, value in table.items():
        if key in skip:
            continue
        if key not in names:
            problems.append(f"{section}.{key}: unknown key (allowed: {', '.join([*skip, *names])})")
            continue
        coerced = _coerce(value, hints[key])
        if coerced is _BAD:
            problems.append(
                f"{section}.{key}: expected {_type_name(hints[key])}, "
                f"got {value!r} ({type(value).__name__})"
            )
            continue
        rng = declared_range(cls, key)  # robot_agent.core.params.ranged
        if rng is not None and isinstance(coerced, (int, float)) and not isinstance(coerced, bool):
            lo, hi = rng
            if not lo <= coerced <= hi:
                problems.append(
                    f"{section}.{key}: {value!r} is outside the plausible range [{lo:g}, {hi:g}]"
                )
                continue
        kwargs[key] = coerced
    for f in fields:
        no_default = f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING
        if no_default and f.name not in kwargs and f.name not in table:
            problems.append(f"{section}.{f.name}: required")
    if len(problems) > start:
        return None
    try:
        return cls(**kwargs)
    except (ValueError, TypeError) as exc:
        problems.append(_dotted(section, str(exc), names))
        return None


def _dotted(section: str, message: str, names: list[str]) -> str:
    """``section.field: message`` when the dataclass's message starts with one of its field
    names (they do: ``kp must be > 0``), else ``section: message``."""
    first = re.split(r"[\s:=,(]", message.strip(), maxsplit=1)[0]
    if first in names:
        return f"{section}.{first}: {message}"
    return f"{section}: {message}"
