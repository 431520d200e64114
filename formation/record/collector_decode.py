"""The streams a :class:`formation.record.collector.RunCollector` reads, from key to a checked
observation: which samples are the collector's (:class:`SampleGate`: this fleet, a leaf it
reads, a robot of the run; every sample counted as received, ignored or rejected with its
reason) and what each one says (:func:`decode_sample`: the strict ``bus_schemas`` decoder, then
the per-robot and the batched form of each stream as one observation in the run's robot
indices).

A batched message (``truths``, a host's ``wheels`` and ``status``, ``setpoints``: a large
fleet's keys) becomes the same observation as the per-robot messages it stands for, so the
collector stores both forms by one rule."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, Final, NamedTuple

from bus_schemas import (
    Assignment,
    Clock,
    CoordinatorStatus,
    DecodeError,
    Fault,
    Leader,
    PlantStatus,
    SetpointBatch,
    Slot,
    Status,
    StatusBatch,
    Truth,
    TruthBatch,
    Wheels,
    WheelsBatch,
    decode,
    keys,
)

__all__ = [
    "LEAVES",
    "Admitted",
    "Observation",
    "Rejected",
    "RobotStatuses",
    "SampleGate",
    "SlotPositions",
    "TruthFrame",
    "WheelPowers",
    "decode_sample",
]

Pose = tuple[float, float, float]

LEAVES: Final = frozenset(
    {
        keys.TRUTH, keys.LEADER, keys.SLOT, keys.ASSIGNMENT, keys.WHEELS, keys.STATUS, keys.CLOCK,
        # the batched forms of a large fleet (plant/coordinator --batch, agent hosts)
        keys.TRUTHS, keys.HOST_WHEELS, keys.HOST_STATUS, keys.SETPOINTS,
        keys.FAULT,  # the scripted faults' notices: metrics.json "faults"
        keys.COORDINATOR_STATUS,  # its run-time plans (issue 27): metrics.json "plan"
        keys.PLANT_STATUS,  # its lockstep timeouts: metrics.json "meta.plant"
    }
)  # fmt: skip


class Admitted(NamedTuple):
    """A sample the collector reads: its leaf, the robot's index (robot keys) and the slot
    (slot keys) its key names."""

    leaf: str
    robot: int | None
    slot: int | None


class Rejected(NamedTuple):
    """A bad payload (counted with its reason)."""

    reason: str


@dataclass(frozen=True, slots=True)
class TruthFrame:
    """Truth poses at bus time ``t`` (a per-robot truth or a batch: known robots only)."""

    t: float
    poses: tuple[tuple[int, Pose], ...]  # (robot index, (x, y, theta))


@dataclass(frozen=True, slots=True)
class WheelPowers:
    """Wheel commands at ``t`` (``tick``: the lockstep tick they answer, if given)."""

    t: float
    tick: int | None
    powers: tuple[tuple[int, tuple[float, float]], ...]  # (robot index, (power_r, power_l))


@dataclass(frozen=True, slots=True)
class RobotStatuses:
    """Statuses at ``t`` and the safety filter counters some of them carry."""

    t: float
    statuses: tuple[tuple[int, Status], ...]
    filters: tuple[tuple[int, dict[str, Any]], ...]


@dataclass(frozen=True, slots=True)
class SlotPositions:
    """Slot positions at ``t`` (``tick``: the coordinator's tick, batched form only)."""

    t: float
    tick: int | None
    positions: tuple[tuple[int, tuple[float, float]], ...]  # (slot, (x, y))


Observation = (
    TruthFrame
    | WheelPowers
    | RobotStatuses
    | SlotPositions
    | Leader
    | Assignment
    | Clock
    | Fault
    | CoordinatorStatus
    | PlantStatus
)


class SampleGate:
    """Which samples are the collector's, and the counters of what it was fed: per leaf
    ``received``, ``ignored`` (another fleet, an unknown robot or leaf) and ``rejected`` (a bad
    payload; ``reject_reasons``: per reason)."""

    def __init__(self, fleet: str, index: Mapping[str, int]) -> None:
        self.fleet = fleet
        self._index = index
        self.received: dict[str, int] = {}
        self.rejected = 0
        self.ignored = 0
        self.reject_reasons: dict[str, int] = {}

    def admit(self, key: str) -> Admitted | None:
        """The sample of ``key`` if the collector reads it (counted as received), else None
        (counted as ignored)."""
        info = keys.parse_key(key)
        if info is None or info.fleet != self.fleet or info.leaf not in LEAVES:
            self.ignored += 1
            return None
        i: int | None = None
        if info.robot is not None:
            i = self._index.get(info.robot)
            if i is None:
                self.ignored += 1
                return None
        self.received[info.leaf] = self.received.get(info.leaf, 0) + 1
        return Admitted(info.leaf, i, info.slot)

    def reject(self, reason: str) -> bool:
        """Count a rejection; returns False (the sample was not used)."""
        self.rejected += 1
        self.reject_reasons[reason] = self.reject_reasons.get(reason, 0) + 1
        return False


Payload = bytes | bytearray | memoryview
_Decoder = Callable[[Admitted, Payload, Mapping[str, int]], "Observation | Rejected"]


def _truth(sample: Admitted, payload: Payload, index: Mapping[str, int]) -> Any:
    msg = decode(payload, Truth)
    if isinstance(msg, DecodeError):
        return Rejected(f"truth: {msg.reason}")
    assert sample.robot is not None
    return TruthFrame(msg.t, ((sample.robot, (msg.x, msg.y, msg.theta)),))


def _truths(sample: Admitted, payload: Payload, index: Mapping[str, int]) -> Any:
    msg = decode(payload, TruthBatch)
    if isinstance(msg, DecodeError):
        return Rejected(f"truths: {msg.reason}")
    rows = zip(msg.robots, msg.x, msg.y, msg.theta, strict=True)
    return TruthFrame(
        msg.stamp, tuple((index[r], (x, y, th)) for r, x, y, th in rows if r in index)
    )


def _wheels(sample: Admitted, payload: Payload, index: Mapping[str, int]) -> Any:
    msg = decode(payload, Wheels)
    if isinstance(msg, DecodeError):
        return Rejected(f"wheels: {msg.reason}")
    assert sample.robot is not None
    return WheelPowers(msg.t, msg.tick, ((sample.robot, (msg.power_r, msg.power_l)),))


def _host_wheels(sample: Admitted, payload: Payload, index: Mapping[str, int]) -> Any:
    msg = decode(payload, WheelsBatch)
    if isinstance(msg, DecodeError):
        return Rejected(f"host wheels: {msg.reason}")
    rows = zip(msg.robots, msg.power_r, msg.power_l, strict=True)
    return WheelPowers(
        msg.t, msg.tick, tuple((index[r], (pr, pl)) for r, pr, pl in rows if r in index)
    )


def _status(sample: Admitted, payload: Payload, index: Mapping[str, int]) -> Any:
    msg = decode(payload, Status)
    if isinstance(msg, DecodeError):
        return Rejected(f"status: {msg.reason}")
    assert sample.robot is not None
    filters: tuple[tuple[int, dict[str, Any]], ...] = ()
    if msg.filter is not None:
        filters = ((sample.robot, {**msg.filter, "min_clearance_m": msg.min_clearance_m}),)
    return RobotStatuses(msg.t, ((sample.robot, msg),), filters)


def _host_status(sample: Admitted, payload: Payload, index: Mapping[str, int]) -> Any:
    sb = decode(payload, StatusBatch)
    if isinstance(sb, DecodeError):
        return Rejected(f"host status: {sb.reason}")
    statuses = tuple(
        (index[rid], Status(
            t=sb.t, seq=sb.seq, mode=mode, slot=None if slot < 0 else slot, pid=sb.pid,
            host=sb.host, rejected=rejected, ex=ex, ey=ey, robot=rid,
        ))
        for rid, mode, slot, rejected, ex, ey in zip(
            sb.robots, sb.mode, sb.slot, sb.rejected, sb.ex, sb.ey, strict=True
        )
        if rid in index
    )  # fmt: skip
    filters: tuple[tuple[int, dict[str, Any]], ...] = ()
    if sb.filter_active is not None:  # no tick count in the batched form
        rows = zip(
            sb.robots, sb.filter_active, sb.filter_violations or (),
            sb.filter_infeasible or (), sb.filter_tiebreaks or (), strict=False,
        )  # fmt: skip
        filters = tuple(
            (index[rid], {"active": active, "violations": violations,
                          "infeasible": infeasible, "tiebreaks": tiebreaks})
            for rid, active, violations, infeasible, tiebreaks in rows
            if rid in index
        )  # fmt: skip
    return RobotStatuses(sb.t, statuses, filters)


def _slot(sample: Admitted, payload: Payload, index: Mapping[str, int]) -> Any:
    msg = decode(payload, Slot)
    if isinstance(msg, DecodeError):
        return Rejected(f"slot: {msg.reason}")
    if msg.slot != sample.slot:
        return Rejected("slot: field does not match the key")
    return SlotPositions(msg.t, None, ((msg.slot, (msg.x, msg.y)),))


def _setpoints(sample: Admitted, payload: Payload, index: Mapping[str, int]) -> Any:
    # the assigned slots' positions of every tick (slot keys come at 1 Hz)
    msg = decode(payload, SetpointBatch)
    if isinstance(msg, DecodeError):
        return Rejected(f"setpoints: {msg.reason}")
    rows = zip(msg.slot, msg.x, msg.y, strict=True)
    return SlotPositions(msg.t, msg.tick, tuple((s, (x, y)) for s, x, y in rows))


def _message(cls: type[Any], name: str) -> _Decoder:
    """A stream whose message is the observation itself."""

    def decode_one(sample: Admitted, payload: Payload, index: Mapping[str, int]) -> Any:
        msg = decode(payload, cls)
        return Rejected(f"{name}: {msg.reason}") if isinstance(msg, DecodeError) else msg

    return decode_one


_DECODERS: Final[Mapping[str, _Decoder]] = {
    keys.TRUTH: _truth,
    keys.TRUTHS: _truths,
    keys.WHEELS: _wheels,
    keys.HOST_WHEELS: _host_wheels,
    keys.STATUS: _status,
    keys.HOST_STATUS: _host_status,
    keys.SLOT: _slot,
    keys.SETPOINTS: _setpoints,
    keys.LEADER: _message(Leader, "leader"),
    keys.ASSIGNMENT: _message(Assignment, "assignment"),
    keys.CLOCK: _message(Clock, "clock"),
    keys.FAULT: _message(Fault, "fault"),
    keys.COORDINATOR_STATUS: _message(CoordinatorStatus, "coordinator status"),
    keys.PLANT_STATUS: _message(PlantStatus, "plant status"),
}
assert frozenset(_DECODERS) == LEAVES


def decode_sample(
    sample: Admitted, payload: Payload, index: Mapping[str, int]
) -> Observation | Rejected:
    """What an admitted sample says (``index``: robot id -> the run's robot index; robots of a
    batch that are not the run's are left out), or why it is rejected."""
    result: Observation | Rejected = _DECODERS[sample.leaf](sample, payload, index)
    return result
