"""Scripted operator commands of a scenario (``[[operator]]``, issue 28): what an operator does
at run time (``formation shape``, ``teleop``, ``goal``, ``path``), at given times, so a run with
an operator in the loop is reproducible. The in-process simulator and the coordinator (lockstep
and realtime) apply them through one pure player (coordinator.core.operator_script) at the
same ticks, so a lockstep run equals ``formation sim`` bit for bit::

    [[operator]]
    t_s = 2.0
    command = "shape"        # shape | teleop | goal | path | stop
    kind = "column"          # shape: triangle | column | line | chevron
    spacing_m = 0.4          # shape: optional (default: as now)
    slots = 4                # shape: optional (default: as many as now)

    [[operator]]
    t_s = 6.0
    command = "teleop"
    v_mps = 0.05             # the twist, sent every tick for duration_s; then the deadman
    omega_radps = 0.1
    duration_s = 2.0

    [[operator]]
    t_s = 10.0
    command = "goal"
    x = 1.0
    y = 0.5
    heading = 1.57           # goal, path: optional

    [[operator]]
    t_s = 12.0
    command = "path"
    waypoints = [[1.0, 0.0], [1.5, 0.5]]

    [[operator]]
    t_s = 14.0
    command = "obstacle"     # a planning obstacle (issue 27), as `formation obstacle` sends it
    id = "box"
    action = "add"           # add | move | remove
    shape = "circle"         # add, move: circle (x, y, radius_m) | polygon (points)
    x = 2.0
    y = 0.5
    radius_m = 0.25          # a polygon: points = [[x, y], [x, y], [x, y], ...]

A bad entry is refused with one line naming it (``operator[2].slots: ...``): an unknown command
or key, a time outside the run, a non-finite number, a shape kind not known, fewer than one slot
or more than the scenario's robots, an obstacle without its geometry, with a radius <= 0 or
fewer than 3 points. What only the running coordinator can judge (a shape it cannot make safe,
more slots than robots alive, a goal outside the arena, a degenerate polygon, an obstacle added
twice or moved before it is added) is refused and counted when the command is due. Stdlib only
(the agents import ``scenario``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Final

from bus_schemas.messages_fields import ShapeKind

__all__ = ["COMMANDS", "SHAPE_KINDS", "OperatorEvent", "OperatorSpecError", "parse_operator"]

COMMANDS: Final = ("shape", "teleop", "goal", "path", "stop", "obstacle")
OBSTACLE_ACTIONS: Final = ("add", "move", "remove")
OBSTACLE_SHAPES: Final = ("circle", "polygon")
SHAPE_KINDS: Final = tuple(k.value for k in ShapeKind)
_KEYS: Final = {
    "shape": {"kind", "spacing_m", "slots"},
    "teleop": {"v_mps", "omega_radps", "duration_s"},
    "goal": {"x", "y", "heading"},
    "path": {"waypoints", "heading"},
    "stop": set(),
    "obstacle": {"id", "action", "shape", "x", "y", "radius_m", "points"},
}
_REQUIRED: Final = {
    "shape": {"kind"},
    "teleop": {"v_mps", "omega_radps", "duration_s"},
    "goal": {"x", "y"},
    "path": {"waypoints"},
    "stop": set(),
    "obstacle": {"id", "action"},
}
_SHAPE_KEYS: Final = {"circle": {"x", "y", "radius_m"}, "polygon": {"points"}}


class OperatorSpecError(ValueError):
    """An ``[[operator]]`` entry that cannot run (one line naming it)."""


@dataclass(frozen=True, slots=True)
class OperatorEvent:
    """One scripted operator command (module docstring); the fields of other commands None."""

    t_s: float
    command: str
    kind: str | None = None
    spacing_m: float | None = None
    slots: int | None = None
    v_mps: float | None = None
    omega_radps: float | None = None
    duration_s: float | None = None
    x: float | None = None
    y: float | None = None
    heading: float | None = None
    waypoints: tuple[tuple[float, float], ...] = ()
    oid: str | None = None
    """obstacle: the obstacle's name (the ``id`` key)."""
    action: str | None = None
    shape: str | None = None
    radius_m: float | None = None
    points: tuple[tuple[float, float], ...] = ()
    """obstacle: a polygon's vertices (m)."""

    def as_dict(self) -> dict[str, Any]:
        """The fields given (for logs and metadata)."""
        out: dict[str, Any] = {"t_s": self.t_s, "command": self.command}
        for name in ("kind", "spacing_m", "slots", "v_mps", "omega_radps", "duration_s", "x",
                     "y", "heading", "action", "shape", "radius_m"):  # fmt: skip
            value = getattr(self, name)
            if value is not None:
                out[name] = value
        if self.oid is not None:
            out["id"] = self.oid
        if self.waypoints:
            out["waypoints"] = [list(p) for p in self.waypoints]
        if self.points:
            out["points"] = [list(p) for p in self.points]
        return out


def _number(where: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise OperatorSpecError(f"{where}: expected a number, got {value!r}")
    if not math.isfinite(value):
        raise OperatorSpecError(f"{where}: must be finite, got {value!r}")
    return float(value)


def _entry(j: int, d: Any, n_robots: int, duration_s: float) -> OperatorEvent:
    where = f"operator[{j}]"
    if not isinstance(d, dict):
        raise OperatorSpecError(f"{where}: expected a table")
    command = d.get("command")
    if command not in COMMANDS:
        raise OperatorSpecError(f"{where}.command: {command!r} is not one of {', '.join(COMMANDS)}")
    allowed = {"t_s", "command"} | _KEYS[command]
    unknown = sorted(str(k) for k in d if k not in allowed)
    if unknown:
        raise OperatorSpecError(
            f"{where}: unknown key(s) {', '.join(unknown)} for {command!r}; "
            f"allowed: {', '.join(sorted(allowed))}"
        )
    missing = sorted((_REQUIRED[command] | {"t_s"}) - set(d))
    if missing:
        raise OperatorSpecError(f"{where}: {command!r} needs {', '.join(missing)}")
    t_s = _number(f"{where}.t_s", d["t_s"])
    if not 0.0 <= t_s <= duration_s:
        raise OperatorSpecError(f"{where}.t_s: {t_s:g} is outside the run [0, {duration_s:g}] s")
    fields: dict[str, Any] = {}
    for name in ("spacing_m", "v_mps", "omega_radps", "duration_s", "x", "y", "heading",
                 "radius_m"):  # fmt: skip
        if name in d:
            fields[name] = _number(f"{where}.{name}", d[name])
    if any(fields.get(k, 1.0) <= 0.0 for k in ("spacing_m", "duration_s", "radius_m")):
        raise OperatorSpecError(f"{where}: spacing_m, duration_s and radius_m must be > 0")
    if command == "shape":
        if d["kind"] not in SHAPE_KINDS:
            raise OperatorSpecError(
                f"{where}.kind: {d['kind']!r} is not one of {', '.join(SHAPE_KINDS)}"
            )
        fields["kind"] = d["kind"]
        if "slots" in d:
            n = d["slots"]
            if isinstance(n, bool) or not isinstance(n, int) or not 1 <= n <= n_robots:
                raise OperatorSpecError(
                    f"{where}.slots: must be a whole number in [1, {n_robots}] (the robots), "
                    f"got {n!r}"
                )
            fields["slots"] = n
    if command == "path":
        fields["waypoints"] = _points(f"{where}.waypoints", d["waypoints"], 1)
    if command == "obstacle":
        fields.update(_obstacle(where, d))
    return OperatorEvent(t_s=t_s, command=command, **fields)


def _points(where: str, pts: Any, least: int) -> tuple[tuple[float, float], ...]:
    if not isinstance(pts, list) or len(pts) < least:
        raise OperatorSpecError(f"{where}: expected an array of at least {least} [x, y]")
    out = []
    for k, p in enumerate(pts):
        if not isinstance(p, list) or len(p) != 2:
            raise OperatorSpecError(f"{where}[{k}]: expected [x, y]")
        out.append((_number(f"{where}[{k}]", p[0]), _number(f"{where}[{k}]", p[1])))
    return tuple(out)


def _obstacle(where: str, d: dict[str, Any]) -> dict[str, Any]:
    """The fields of an ``obstacle`` entry (the geometry's own checks, a polygon that crosses
    itself or has no area, are the coordinator's: refused and counted when due)."""
    oid, action = d["id"], d["action"]
    if not isinstance(oid, str) or not oid or len(oid) > 64:
        raise OperatorSpecError(f"{where}.id: expected a name of 1 to 64 characters, got {oid!r}")
    if action not in OBSTACLE_ACTIONS:
        raise OperatorSpecError(
            f"{where}.action: {action!r} is not one of {', '.join(OBSTACLE_ACTIONS)}"
        )
    shape = d.get("shape")
    given = _KEYS["obstacle"] & set(d) - {"id", "action"}
    if action == "remove":
        if given:
            raise OperatorSpecError(f"{where}: remove takes no {', '.join(sorted(given))}")
        return {"oid": oid, "action": action}
    if shape not in OBSTACLE_SHAPES:
        raise OperatorSpecError(
            f"{where}.shape: {shape!r} is not one of {', '.join(OBSTACLE_SHAPES)}"
        )
    need = _SHAPE_KEYS[shape]
    wrong = sorted(given - need - {"shape"})
    missing = sorted(need - given)
    if wrong or missing:
        raise OperatorSpecError(
            f"{where}: a {shape} needs {', '.join(sorted(need))}"
            + (f"; not {', '.join(wrong)}" if wrong else "")
        )
    out: dict[str, Any] = {"oid": oid, "action": action, "shape": shape}
    if shape == "polygon":
        out["points"] = _points(f"{where}.points", d["points"], 3)
    return out


def parse_operator(raw: Any, n_robots: int, duration_s: float) -> tuple[OperatorEvent, ...]:
    """The ``operator`` array of a scenario dictionary, validated, in time order (a stable sort:
    entries at the same time keep their file order). Raises OperatorSpecError."""
    if raw is None:
        return ()
    if not isinstance(raw, list):
        raise OperatorSpecError("operator: expected an array of tables [[operator]]")
    events = [_entry(j, d, n_robots, duration_s) for j, d in enumerate(raw)]
    return tuple(sorted(events, key=lambda e: e.t_s))
