"""The operator's commands to the virtual leader (issue 28): a teleop twist, a goal, a path, a
new shape for the formation, and a planning obstacle added, moved or removed at run time
(issue 27: the coordinator replans around it).

Published by the operator's tools (``formation teleop``, ``formation goal``, ``formation path``)
on ``formation/<fleet>/operator/*``; every coordinator instance reads them (the active one
applies them at its next tick, a standby keeps them to continue after a takeover). Under
``--secure`` only an operator identity may publish them (``bus_schemas.acl_rules``).

The ranges here are the contract's (bus_schemas.fields: a twist of 1e300 is refused at decode);
the coordinator refuses or clamps what is beyond the scenario's ``[leader]`` limits and counts
it (coordinator.core.leader).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import StrEnum

from bus_schemas import keys
from bus_schemas.messages_fields import _T, _V, ShapeKind, _Periodic
from bus_schemas.spec import (
    META_KEY,
    FieldSpec,
    Kind,
    RequiredWhen,
    SameLength,
    f_angle,
    f_enum,
    f_float,
    f_float_list,
    f_int,
    f_name,
    message,
)
from bus_schemas.spec import POSITION_MAX_M as _POS
from bus_schemas.spec import SPEED_MAX_MPS as _SPEED
from bus_schemas.spec import TURN_RATE_MAX_RADPS as _TURN

CMD_RATE_HZ = 20.0
"""How often the operator's tools send a twist while teleop runs (Hz): the deadman
(coordinator.core.leader.DEADMAN_S, 0.4 s) is 8 periods."""


@message(name=keys.CMD_VEL, publisher="operator (formation teleop)", periodic=True, rate="20 Hz")
@dataclass(frozen=True, slots=True, kw_only=True)
class CmdVel(_Periodic):
    """Teleop twist for the virtual leader, repeated while the operator drives (a deadman
    stops the leader when it stops coming)."""

    v_mps: float = field(
        metadata=f_float(
            "forward speed asked of the virtual leader",
            "m/s",
            lo=-_SPEED,
            hi=_SPEED,
        )
    )
    omega_radps: float = field(
        metadata=f_float(
            "turn rate asked of the virtual leader (counter-clockwise positive)",
            "rad/s",
            lo=-_TURN,
            hi=_TURN,
        )
    )


@message(name=keys.GOAL, publisher="operator (formation goal)", periodic=False)
@dataclass(frozen=True, slots=True, kw_only=True)
class Goal:
    """Drive the virtual leader to `(x, y)` from where it is, then turn to `heading` if given;
    replaces its plan with a continuous join."""

    v: int = field(default=1, metadata=_V)
    t: float = field(metadata=_T)
    x: float = field(metadata=f_float("goal x, world frame", "m", lo=-_POS, hi=_POS))
    y: float = field(metadata=f_float("goal y, world frame", "m", lo=-_POS, hi=_POS))
    heading: float | None = field(
        default=None, metadata=f_angle("heading to turn to at the goal (absent: any)")
    )


@message(
    name=keys.PATH,
    publisher="operator (formation path)",
    periodic=False,
    rules=(SameLength(("xs", "ys")),),
)
@dataclass(frozen=True, slots=True, kw_only=True)
class Path:
    """Drive the virtual leader through waypoints `(xs[i], ys[i])` from where it is; replaces
    its plan with a continuous join."""

    v: int = field(default=1, metadata=_V)
    t: float = field(metadata=_T)
    xs: tuple[float, ...] = field(
        metadata=f_float_list("waypoint x, world frame", "m", lo=-_POS, hi=_POS)
    )
    ys: tuple[float, ...] = field(
        metadata=f_float_list("waypoint y, world frame", "m", lo=-_POS, hi=_POS)
    )
    heading: float | None = field(
        default=None, metadata=f_angle("heading to turn to at the last point (absent: any)")
    )


SPACING_MAX_M = 5.0
"""Largest spacing on the wire (m); the coordinator refuses a shape under
:data:`SPACING_MIN_M` or one that does not keep the safety distance (coordinator.core.reshape),
and counts it."""
SPACING_MIN_M = 0.1
"""Smallest spacing the coordinator reshapes to (m): ``coordinator.core.reshape.SPACING_RANGE_M``
is (SPACING_MIN_M, SPACING_MAX_M) (tests/unit/formation/test_operate_drive.py compares);
``formation shape`` refuses less before it sends anything."""
PATH_POINTS_MAX = 256
"""Most waypoints the coordinator follows (``coordinator.core.leader.MAX_PATH_POINTS``, compared
by the same test); ``formation path`` refuses more before it sends anything."""
SLOTS_MAX = 1024
"""Most slots a reshape may ask on the wire; the coordinator refuses more than the robots
alive (``shape-too_many_slots``) and counts it."""


@message(name=keys.SHAPE, publisher="operator (formation shape)", periodic=False)
@dataclass(frozen=True, slots=True, kw_only=True)
class Shape:
    """Reshape the running formation into `kind` of `slots` slots (absent: as many as now),
    `spacing_m` apart (absent: as now); the slots move there over a transition time, never closer
    than the safety distance. Fewer slots drop the rearmost at the end of the transition; more
    add slots that robots without one (spares) take."""

    v: int = field(default=1, metadata=_V)
    t: float = field(metadata=_T)
    kind: str = field(metadata=f_enum("the new shape", ShapeKind))
    spacing_m: float | None = field(
        default=None,
        metadata=f_float("distance between neighbouring slots", "m", lo=0.0, hi=SPACING_MAX_M),
    )
    slots: int | None = field(
        default=None,
        metadata=f_int("number of slots of the new shape, leader included", lo=1, hi=SLOTS_MAX),
    )


class ObstacleAction(StrEnum):
    """What an ``Obstacle`` message does to the coordinator's planning map."""

    ADD = "add"
    MOVE = "move"
    REMOVE = "remove"


class ObstacleShape(StrEnum):
    """The geometry of a planning obstacle."""

    CIRCLE = "circle"
    POLYGON = "polygon"


OBSTACLE_POINTS_MAX = 64
"""Most vertices of a polygon obstacle on the wire."""
OBSTACLE_RADIUS_MAX_M = 10.0
"""Largest circle radius (m) on the wire."""


def _f_vertices(what: str) -> dict[str, FieldSpec]:
    return {
        META_KEY: FieldSpec(
            Kind.FLOAT_LIST, what, "m", lo=-_POS, hi=_POS, max_len=OBSTACLE_POINTS_MAX
        )
    }


@message(
    name=keys.OBSTACLE,
    publisher="operator (formation obstacle)",
    periodic=False,
    rules=(
        SameLength(("xs", "ys")),
        RequiredWhen("shape", ObstacleShape.CIRCLE.value, ("x", "y", "radius_m")),
        RequiredWhen("shape", ObstacleShape.POLYGON.value, ("xs", "ys")),
    ),
)
@dataclass(frozen=True, slots=True, kw_only=True)
class Obstacle:
    """Add, move (replace the geometry of) or remove the planning obstacle `id`: the coordinator
    replans the virtual leader around it from where the leader is (no jump). A polygon is filled
    (3 to 64 vertices, not self-intersecting, area > 0: checked by the coordinator, which counts
    a refusal under `obstacle-<reason>`). It is an obstacle of the plan (the first layer) only:
    the robots' safety filters keep the obstacles of their own configuration."""

    v: int = field(default=1, metadata=_V)
    t: float = field(metadata=_T)
    id: str = field(metadata=f_name("the obstacle's name (operator-chosen)"))
    action: str = field(metadata=f_enum("add, move (new geometry) or remove", ObstacleAction))
    shape: str | None = field(
        default=None, metadata=f_enum("circle or polygon (absent for remove)", ObstacleShape)
    )
    x: float | None = field(
        default=None, metadata=f_float("circle centre x, world frame", "m", lo=-_POS, hi=_POS)
    )
    y: float | None = field(
        default=None, metadata=f_float("circle centre y, world frame", "m", lo=-_POS, hi=_POS)
    )
    radius_m: float | None = field(
        default=None,
        metadata=f_float("circle radius", "m", lo=0.0, hi=OBSTACLE_RADIUS_MAX_M),
    )
    xs: tuple[float, ...] | None = field(
        default=None, metadata=_f_vertices("polygon vertex x, world frame")
    )
    ys: tuple[float, ...] | None = field(
        default=None, metadata=_f_vertices("polygon vertex y, world frame")
    )
