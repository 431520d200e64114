"""The vocabulary the bus messages share: the enums (``Role``, ``LeaderMode``, ``ShapeKind``,
``DisturbanceKind``; the firmware's ``Mode`` is in modes.py, which the firmware core imports) and
the field specs used by several message tables (schema version, timestamp, sequence number,
positions, slot geometry), so every message declares them alike.

Split out of messages.py (issue 12); the enums are still importable from
``bus_schemas.messages``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import StrEnum

from bus_schemas.spec import POSITION_MAX_M as _POS
from bus_schemas.spec import SPEED_MAX_MPS as _SPEED
from bus_schemas.spec import TIME_MAX_S as _TMAX
from bus_schemas.spec import (
    f_angle,
    f_enum,
    f_float,
    f_int,
    f_slot,
)


class Role(StrEnum):
    """Role of a formation slot."""

    LEADER = "leader"
    SUBLEADER = "subleader"
    FOLLOWER = "follower"


class LeaderMode(StrEnum):
    """What drives the virtual leader (coordinator.core.leader)."""

    SCRIPT = "script"
    TELEOP = "teleop"
    GOAL = "goal"
    PATH = "path"
    STOP = "stop"


class ShapeKind(StrEnum):
    """A shape a running formation can be reshaped into (coordinator.core.reshape)."""

    TRIANGLE = "triangle"
    COLUMN = "column"
    LINE = "line"
    CHEVRON = "chevron"


class ReshapeSource(StrEnum):
    """What a running reshape started from (coordinator.core.reshaping): a shape, the
    scenario's formation, or where another reshape had brought the slots."""

    TRIANGLE = "triangle"
    COLUMN = "column"
    LINE = "line"
    CHEVRON = "chevron"
    SCENARIO = "scenario"
    RESHAPE = "reshape"


class DisturbanceKind(StrEnum):
    """What a disturbance does to a simulated robot."""

    DRAG = "drag"
    TELEPORT = "teleport"


# Field specs shared by several messages.
_V = f_int("schema version; a decoder rejects any other value", lo=1, hi=1)


_T = f_float(
    "timestamp: sim time in lockstep, the publisher's time.monotonic() in realtime",
    "s",
    lo=0.0,
    hi=_TMAX,
)


_SEQ = f_int("sequence number, +1 per message on this key (per publisher)")


_X = f_float("x position, world frame", "m", lo=-_POS, hi=_POS)


_Y = f_float("y position, world frame", "m", lo=-_POS, hi=_POS)


_SLOT = f_slot("slot number, 0 = virtual leader")


_ROLE = f_enum("role of the slot", Role)


_STAGE = f_int("stage of the slot in the formation tree (0 = leader, 1 = first stage, ...)", hi=255)


_PARENT = f_slot("slot number of the (sub-)leader this slot follows; nil for slot 0", nullable=True)


_SLOT_X = f_float(
    "x where the assigned robot's reference point (eqs 10-11) should be (slot, eqs 1-5)",
    "m",
    lo=-_POS,
    hi=_POS,
)


_SLOT_Y = f_float(
    "y where the assigned robot's reference point (eqs 10-11) should be (slot, eqs 1-5)",
    "m",
    lo=-_POS,
    hi=_POS,
)


_SLOT_THETA = f_angle("heading of the slot (= its parent's heading, rigid formation)")


_SLOT_VX = f_float(
    "feed-forward velocity of the slot point along x (eqs 21-22)", "m/s", lo=-_SPEED, hi=_SPEED
)


_SLOT_VY = f_float(
    "feed-forward velocity of the slot point along y (eqs 21-22)", "m/s", lo=-_SPEED, hi=_SPEED
)


_POSE_X = f_float("x of the robot's axle centre, world frame", "m", lo=-_POS, hi=_POS)


_POSE_Y = f_float("y of the robot's axle centre, world frame", "m", lo=-_POS, hi=_POS)


_POSE_THETA = f_angle("heading of the robot, world frame, counter-clockwise from +x")


@dataclass(frozen=True, slots=True, kw_only=True)
class _Periodic:
    """The head of a periodic message (v, t, seq), for the tables that inherit it."""

    v: int = field(default=1, metadata=_V)
    t: float = field(metadata=_T)
    seq: int = field(metadata=_SEQ)
