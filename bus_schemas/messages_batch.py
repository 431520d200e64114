"""The batched messages of the bus contract: one message carrying many robots' poses, truths,
setpoints, wheel commands or statuses (sent by the processes that serve a whole fleet), as
declarative tables like those of ``messages.py`` (see its docstring for the common fields).

Split out of messages.py (issue 12); every class here is still importable from
``bus_schemas.messages``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from bus_schemas import keys
from bus_schemas.messages_fields import Role, _Periodic
from bus_schemas.modes import Mode
from bus_schemas.spec import POSITION_MAX_M as _POS
from bus_schemas.spec import SPEED_MAX_MPS as _SPEED
from bus_schemas.spec import TIME_MAX_S as _TMAX
from bus_schemas.spec import TURN_RATE_MAX_RADPS as _TURN
from bus_schemas.spec import WHEEL_RATE_MAX_RADPS as _WHEEL
from bus_schemas.spec import (
    SameLength,
    Together,
    f_angle,
    f_angle_list,
    f_enum_list,
    f_float,
    f_float_list,
    f_int,
    f_int_list,
    f_robot_id_list,
    f_str,
    message,
)


@dataclass(frozen=True, slots=True, kw_only=True)
class _PoseFrame(_Periodic):
    """Poses of many robots as parallel arrays (PoseBatch, TruthBatch)."""

    robots: tuple[str, ...] = field(metadata=f_robot_id_list("robot ids, one per pose"))
    x: tuple[float, ...] = field(
        metadata=f_float_list("x of each axle centre", "m", lo=-_POS, hi=_POS)
    )
    y: tuple[float, ...] = field(
        metadata=f_float_list("y of each axle centre", "m", lo=-_POS, hi=_POS)
    )
    theta: tuple[float, ...] = field(metadata=f_angle_list("heading of each robot"))


_FRAME_RULES = (SameLength(("robots", "x", "y", "theta")),)


@message(
    name=keys.POSES,
    publisher="localization (batched frame)",
    periodic=True,
    rules=_FRAME_RULES,
)
@dataclass(frozen=True, slots=True, kw_only=True)
class PoseBatch(_PoseFrame):
    """Poses of many robots measured at one instant `stamp`, as parallel arrays (one frame).

    `t` is when the frame was published. A fleet larger than the list bound is sent as several
    frames with the same `stamp`. Every node of a lockstep run reads its frames in this form
    (each agent takes its own entry as its pose); the plant puts each robot's `pose` there only
    while someone subscribes to it.
    """

    stamp: float = field(
        metadata=f_float(
            "measurement (capture) time of the frame, same clock as t", "s", lo=0.0, hi=_TMAX
        )
    )


@message(
    name=keys.TRUTHS,
    publisher="plant only (batched frame)",
    periodic=True,
    rules=_FRAME_RULES,
)
@dataclass(frozen=True, slots=True, kw_only=True)
class TruthBatch(_PoseFrame):
    """True poses of many simulated robots at one instant `stamp`, as parallel arrays.

    The batched form of `robot/<id>/truth`, for large fleets (`--batch`) and in every lockstep
    run (a lockstep plant puts each robot's own key only while someone subscribes to it); a
    fleet larger than the list bound (or than :data:`BATCH_CHUNK`) is sent as several messages
    with the same `stamp`.
    """

    stamp: float = field(
        metadata=f_float("sim time of these true poses, same clock as t", "s", lo=0.0, hi=_TMAX)
    )


@message(
    name=keys.SETPOINTS,
    publisher="coordinator (batched)",
    periodic=True,
    rules=(SameLength(("robots", "slot", "role", "stage", "x", "y", "vx", "vy")),),
)
@dataclass(frozen=True, slots=True, kw_only=True)
class SetpointBatch(_Periodic):
    """The setpoints of many robots of one coordinator tick, as parallel arrays.

    The batched form of `robot/<id>/setpoint` for large fleets (agent hosts read it); the
    meaning of each entry is that of `Setpoint` (where the reference point should be, eqs 10-11,
    and the feed-forward velocity). Every slot of a formation shares one heading, `theta`. Sent
    as several messages (same `t`, consecutive `seq`) when the fleet exceeds one batch.
    """

    robots: tuple[str, ...] = field(metadata=f_robot_id_list("robot ids, one per setpoint"))
    slot: tuple[int, ...] = field(
        metadata=f_int_list("assigned slot of each robot", hi=keys.MAX_SLOT)
    )
    role: tuple[str, ...] = field(metadata=f_enum_list("role of each robot's slot", Role))
    stage: tuple[int, ...] = field(
        metadata=f_int_list("formation stage of each slot (0 = leader)", hi=keys.MAX_SLOT)
    )
    x: tuple[float, ...] = field(
        metadata=f_float_list("x of each slot (reference point)", "m", lo=-_POS, hi=_POS)
    )
    y: tuple[float, ...] = field(
        metadata=f_float_list("y of each slot (reference point)", "m", lo=-_POS, hi=_POS)
    )
    theta: float = field(metadata=f_angle("heading of the formation (every slot's)"))
    vx: tuple[float, ...] = field(
        metadata=f_float_list("feed-forward velocity x of each slot", "m/s", lo=-_SPEED, hi=_SPEED)
    )
    vy: tuple[float, ...] = field(
        metadata=f_float_list("feed-forward velocity y of each slot", "m/s", lo=-_SPEED, hi=_SPEED)
    )
    tick: int | None = field(
        default=None, metadata=f_int("lockstep: the clock `tick` these setpoints were computed on")
    )


@message(
    name=keys.MOVERS,
    publisher="coordinator",
    periodic=True,
    rules=(SameLength(("robots", "x", "y", "vx", "vy")),),
)
@dataclass(frozen=True, slots=True, kw_only=True)
class Movers(_Periodic):
    """The moving obstacles of one coordinator tick (issue 30, `coordinator/core/movers.py`):
    fleet robots carried, pushed or moving without a slot, and tracked bodies that are not
    fleet robots, with their centre and the velocity estimated from their pose history.

    Sent on the ticks that have movers (none: no message). The robots' safety filters take
    each one as a non-cooperative neighbour moving at that velocity (rule 4 of
    `robot_agent/core/neighbours.py`): in lockstep the message of tick k - 1 at clock k, as the
    setpoints; in realtime the latest one received within 0.5 s.
    """

    robots: tuple[str, ...] = field(
        metadata=f_robot_id_list("ids of the movers (fleet robots or tracked tag ids)")
    )
    x: tuple[float, ...] = field(
        metadata=f_float_list("x of each mover's centre", "m", lo=-_POS, hi=_POS)
    )
    y: tuple[float, ...] = field(
        metadata=f_float_list("y of each mover's centre", "m", lo=-_POS, hi=_POS)
    )
    vx: tuple[float, ...] = field(
        metadata=f_float_list("velocity x of each mover", "m/s", lo=-_SPEED, hi=_SPEED)
    )
    vy: tuple[float, ...] = field(
        metadata=f_float_list("velocity y of each mover", "m/s", lo=-_SPEED, hi=_SPEED)
    )
    tick: int | None = field(
        default=None, metadata=f_int("lockstep: the clock `tick` these movers were computed on")
    )


@message(
    name=keys.HOST_WHEELS,
    publisher="agent host (batched)",
    periodic=True,
    rules=(SameLength(("robots", "omega_r", "omega_l", "power_r", "power_l", "pose_t", "mode")),),
)
@dataclass(frozen=True, slots=True, kw_only=True)
class WheelsBatch(_Periodic):
    """Wheel commands of the robots an agent host runs, from one control step, parallel arrays.

    The batched form of `robot/<id>/wheels` (same meaning per entry). `pose_t` of an entry is
    negative when no pose was used (the robot is idle): `Wheels.pose_t` nil.
    """

    robots: tuple[str, ...] = field(metadata=f_robot_id_list("robot ids, one per command"))
    omega_r: tuple[float, ...] = field(
        metadata=f_float_list("right wheel angular speed command", "rad/s", lo=-_WHEEL, hi=_WHEEL)
    )
    omega_l: tuple[float, ...] = field(
        metadata=f_float_list("left wheel angular speed command", "rad/s", lo=-_WHEEL, hi=_WHEEL)
    )
    power_r: tuple[float, ...] = field(
        metadata=f_float_list("right wheel command as a fraction of max", "1", lo=-1.0, hi=1.0)
    )
    power_l: tuple[float, ...] = field(
        metadata=f_float_list("left wheel command as a fraction of max", "1", lo=-1.0, hi=1.0)
    )
    pose_t: tuple[float, ...] = field(
        metadata=f_float_list(
            "`t` of the pose each command was computed from; -1 if none was used (idle)",
            "s",
            lo=-1.0,
            hi=_TMAX,
        )
    )
    tick: int | None = field(
        default=None, metadata=f_int("lockstep: the clock `tick` these commands answer")
    )
    mode: tuple[str, ...] | None = field(
        default=None, metadata=f_enum_list("firmware mode of each robot after its step", Mode)
    )


_TWIST = ("twist_robots", "v_mps", "omega_radps")


@message(
    name=keys.HOST_STATUS,
    publisher="agent host (batched), >= 5 Hz",
    periodic=True,
    rate=">= 5 Hz",
    rules=(
        SameLength(
            (
                "robots", "mode", "slot", "rejected", "ex", "ey",
                "filter_active", "filter_violations", "filter_infeasible", "filter_tiebreaks",
            )
        ),
        Together(_TWIST),
        SameLength(_TWIST),
    ),
)  # fmt: skip
@dataclass(frozen=True, slots=True, kw_only=True)
class StatusBatch(_Periodic):
    """Health of the robots an agent host runs (the batched form of `robot/<id>/status`)."""

    pid: int = field(metadata=f_int("OS process id of the agent host", hi=2**31 - 1))
    host: str = field(metadata=f_str("host name the agent host runs on"))
    robots: tuple[str, ...] = field(metadata=f_robot_id_list("robot ids"))
    mode: tuple[str, ...] = field(metadata=f_enum_list("firmware mode of each robot", Mode))
    slot: tuple[int, ...] = field(
        metadata=f_int_list("assigned slot of each robot, -1 if none", lo=-1, hi=keys.MAX_SLOT)
    )
    rejected: tuple[int, ...] = field(
        metadata=f_int_list("messages rejected by each robot's firmware")
    )
    ex: tuple[float, ...] = field(
        metadata=f_float_list(
            "tracking error along x (eq 17), 0 without a setpoint", "m", lo=-2 * _POS, hi=2 * _POS
        )
    )
    ey: tuple[float, ...] = field(
        metadata=f_float_list(
            "tracking error along y (eq 18), 0 without a setpoint", "m", lo=-2 * _POS, hi=2 * _POS
        )
    )
    filter_active: tuple[int, ...] | None = field(
        default=None,
        metadata=f_int_list("safety filter: ticks its output differed from the nominal command"),
    )
    filter_violations: tuple[int, ...] | None = field(
        default=None,
        metadata=f_int_list("safety filter: ticks a barrier was already below zero at the input"),
    )
    filter_infeasible: tuple[int, ...] | None = field(
        default=None,
        metadata=f_int_list(
            "safety filter: ticks with no feasible command (the least-violation fallback: out "
            "of the barriers it is inside, never toward one it is outside)"
        ),
    )
    filter_tiebreaks: tuple[int, ...] | None = field(
        default=None, metadata=f_int_list("safety filter: deadlock tie-breaks triggered")
    )
    # issue 29: the estimator's twist of the robots that know it (formation/live/ros2_bridge.py)
    twist_robots: tuple[str, ...] | None = field(
        default=None,
        metadata=f_robot_id_list(
            "robots whose estimator twist follows (`v_mps`, `omega_radps`): those of `robots` "
            "with a valid estimate; a robot not listed: unknown"
        ),
    )
    v_mps: tuple[float, ...] | None = field(
        default=None,
        metadata=f_float_list(
            "estimator: forward speed of each one's axle centre (body frame, eq 9's v) at `t`",
            "m/s",
            lo=-_SPEED,
            hi=_SPEED,
        ),
    )
    omega_radps: tuple[float, ...] | None = field(
        default=None,
        metadata=f_float_list(
            "estimator: turn rate of each one (eq 9's omega) at `t`", "rad/s", lo=-_TURN, hi=_TURN
        ),
    )
