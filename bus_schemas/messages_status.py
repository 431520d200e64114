"""The status messages of the fleet's own processes: the coordinator's, the plant's and the camera
tracker's health and counters, as declarative tables like those of ``messages.py`` (see its
docstring for the common fields). The agents' status is ``messages.Status`` (``StatusBatch`` for
an agent host).

Tools read them (``formation fault`` finds a coordinator's process, ``formation estop`` its
latched e-stop, benches the tick timing, recorders and ``formation top`` record and show them);
no controller acts on them. Every class here is importable from ``bus_schemas``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from enum import StrEnum

from bus_schemas import keys
from bus_schemas.messages_fields import _Periodic
from bus_schemas.spec import EPOCH_MAX as _EPOCH_MAX
from bus_schemas.spec import POSITION_MAX_M as _POS
from bus_schemas.spec import TIME_MAX_S as _TMAX
from bus_schemas.spec import (
    FieldSpec,
    f_bool,
    f_count_map,
    f_enum,
    f_float,
    f_int,
    f_name,
    f_name_list,
    f_robot_id,
    f_robot_id_list,
    f_str,
    message,
)


class RunMode(StrEnum):
    """How a process runs: on the plant's clock (lockstep) or on its own (realtime)."""

    LOCKSTEP = "lockstep"
    REALTIME = "realtime"


class CoordinatorRole(StrEnum):
    """Whether a coordinator instance publishes setpoints (active) or watches (standby)."""

    ACTIVE = "active"
    STANDBY = "standby"


class EstopStoreState(StrEnum):
    """Whether a coordinator's ``--estop-state`` file holds its latched e-stop state (issue 30):
    ``saved`` (written and fsynced), ``pending`` (being written), ``failed`` (it cannot be
    written: the coordinator's fault; it refuses releases until it can record them)."""

    SAVED = "saved"
    PENDING = "pending"
    FAILED = "failed"


class PlanState(StrEnum):
    """Where the coordinator's planner is (issue 27, coordinator.core.planning.replan)."""

    PLANNING = "planning"  # a plan is being computed (the leader bridges, no jump)
    FOLLOWING = "following"  # the leader follows a plan
    ARRIVED = "arrived"  # the last plan reached its goal
    NO_WAY = "no_way"  # no plan: the leader decelerated to a stop (`plan_why` says why)


class PlantState(StrEnum):
    """Phase of the plant simulator's run."""

    WAITING = "waiting"
    RUNNING = "running"
    DONE = "done"


@dataclass(frozen=True, slots=True, kw_only=True)
class _NodeStatus(_Periodic):
    """What every node's status starts with: its run mode and its input counters."""

    mode: str = field(metadata=f_enum("lockstep or realtime", RunMode))
    rejected: int = field(metadata=f_int("count of received messages rejected (sum of `rejects`)"))
    rejects: Mapping[str, int] = field(
        metadata=f_count_map("`<message>-<reason>` -> count of inputs dropped; sums to `rejected`")
    )
    internal_errors: int = field(
        metadata=f_int("internal errors caught (a bug, never a bad input); 0 in a healthy run")
    )
    rx: Mapping[str, int] = field(metadata=f_count_map("input name -> count of messages received"))


@message(
    name=keys.COORDINATOR_STATUS,
    publisher="coordinator (each instance, active or standby)",
    periodic=True,
    rate="5 Hz",
)
@dataclass(frozen=True, slots=True, kw_only=True)
class CoordinatorStatus(_NodeStatus):
    """Health and counters of one coordinator instance."""

    name: str = field(metadata=f_name("coordinator instance name (= the key's name)"))
    role: str = field(metadata=f_enum("active: publishes setpoints; standby", CoordinatorRole))
    epoch: int = field(metadata=f_int("leadership epoch (as in its heartbeat)", hi=_EPOCH_MAX))
    takeovers: int = field(metadata=f_int("times this instance took over as active"))
    stepdowns: int = field(metadata=f_int("times this instance stepped down to standby"))
    ticks: int = field(metadata=f_int("control ticks computed so far"))
    alive: tuple[str, ...] = field(metadata=f_robot_id_list("robots whose token is alive"))
    assignment: Mapping[str, int] = field(
        metadata=f_count_map(
            "robot id -> slot of the last tick (encoded sorted by id)",
            key_pattern=keys.ROBOT_ID_PATTERN,
            value_hi=keys.MAX_SLOT,
        )
    )
    leader: str | None = field(
        metadata=f_robot_id("robot holding slot 0 on the last tick, nil if none", nullable=True)
    )
    estop_fleet: bool = field(metadata=f_bool("the fleet-wide e-stop is latched"))
    estop_robots: tuple[str, ...] = field(
        metadata=f_robot_id_list("robots whose own e-stop is latched (sorted, first 64)")
    )
    pid: int = field(metadata=f_int("OS process id of the coordinator", hi=2**31 - 1))
    host: str = field(metadata=f_str("host name the coordinator runs on"))
    tick_p50_ms: float | None = field(
        default=None,
        metadata=f_float(
            "median compute-and-publish time of the recent ticks", "ms", lo=0.0, hi=_TMAX
        ),
    )
    tick_max_ms: float | None = field(
        default=None,
        metadata=f_float(
            "largest compute-and-publish time of the recent ticks", "ms", lo=0.0, hi=_TMAX
        ),
    )
    estop_store: str | None = field(
        default=None,
        metadata=f_enum(
            "its --estop-state file holds estop_fleet/estop_robots (saved), is being written "
            "(pending) or cannot be written (failed); nil without a state file",
            EstopStoreState,
        ),
    )
    estop_store_error: str | None = field(
        default=None,
        metadata=f_str("why the state file cannot be written (with estop_store failed)"),
    )
    # issue 27, the coordinator plans (coordinator.core.planning.replan; docs/planning.md,
    # "Replanning"): all absent until the coordinator makes its first run-time plan
    plan: str | None = field(
        default=None, metadata=f_enum("state of the run-time planner (absent: none yet)", PlanState)
    )
    plan_why: str | None = field(
        default=None,
        metadata=f_str("why the last plan was made (goal, obstacle, stuck, takeover) or, with "
                       "plan no_way, why there is none"),
    )  # fmt: skip
    plans: int | None = field(
        default=None, metadata=f_int("run-time plans made (the first for a goal and every replan)")
    )
    replans: int | None = field(
        default=None,
        metadata=f_int("of those, replans (the world changed, a robot stuck, a takeover)"),
    )
    plan_ms: float | None = field(
        default=None,
        metadata=f_float("compute time of the last plan (off the tick)", "ms", lo=0.0, hi=_TMAX),
    )
    plan_clearance_m: float | None = field(
        default=None,
        metadata=f_float(
            "least planned clearance of the plan followed: distance from a slot point to the "
            "nearest obstacle or wall along it (>= the footprint's slot radius)",
            "m",
            lo=-_POS,
            hi=_POS,
        ),
    )
    plan_late: int | None = field(
        default=None,
        metadata=f_int("realtime: plans not ready at their switch tick (asked again)"),
    )
    obstacles: int | None = field(
        default=None, metadata=f_int("planning obstacles added at run time (operator)")
    )
    stuck: tuple[str, ...] | None = field(
        default=None, metadata=f_robot_id_list("robots the coordinator takes as stuck (sorted)")
    )


@message(name=keys.PLANT_STATUS, publisher="plant only", periodic=True, rate="5 Hz")
@dataclass(frozen=True, slots=True, kw_only=True)
class PlantStatus(_NodeStatus):
    """Health and counters of the plant simulator (its link, camera and separation monitor)."""

    state: str = field(metadata=f_enum("phase of the run", PlantState))
    tick: int = field(metadata=f_int("lockstep: the last clock tick published (0 before any)"))
    sim_t: float = field(
        metadata=f_float("simulated time since the start of the run", "s", lo=-_TMAX, hi=_TMAX)
    )
    timeouts: int = field(metadata=f_int("lockstep: ticks that went on without every answer"))
    alive: tuple[str, ...] = field(metadata=f_robot_id_list("robots whose token is alive"))
    coordinators: tuple[str, ...] = field(
        metadata=f_name_list("coordinator instances whose token is alive")
    )
    link_sent: int = field(metadata=f_int("wheel commands handed to the emulated radio link"))
    link_dropped: int = field(metadata=f_int("of those, dropped by the link (its loss model)"))
    min_separation_m: float | None = field(
        metadata=f_float(
            "least distance between two robots' axle centres so far, nil before two are seen",
            "m",
            lo=0.0,
            hi=4 * _POS,
            nullable=True,
        )
    )
    collisions: int = field(metadata=f_int("bodies touching (events, from the truth)"))
    frames: int = field(metadata=f_int("pose frames published"))
    batch: bool = field(metadata=f_bool("poses and truth are published batched (`poses`)"))
    ignored: int = field(metadata=f_int("valid messages for robots this plant does not simulate"))


class CameraState(StrEnum):
    """Phase of a camera tracker's run."""

    RUNNING = "running"
    DONE = "done"


CAMERA_MS_MAX = _TMAX
"""Bound of ``CameraStatus``'s durations (ms, 11.6 days): a rendered frame's capture time is the
truth's, maybe another host's clock, so the capture -> published latency may be negative."""


def _f_ms(what: str, *, lo: float = 0.0) -> dict[str, FieldSpec]:
    """A duration in ms in [lo, CAMERA_MS_MAX], left out before the first frame."""
    return f_float(what + " (absent before the first frame)", "ms", lo=lo, hi=CAMERA_MS_MAX)


@message(
    name=keys.CAMERA_STATUS,
    publisher="localization (`formation camera`, each tracker by its `--name`)",
    periodic=True,
    rate="2 Hz",
)
@dataclass(frozen=True, slots=True, kw_only=True)
class CameraStatus(_Periodic):
    """Health and counters of one overhead-camera tracker (localization/node/camera.py)."""

    state: str = field(metadata=f_enum("running, or done (a recording's end)", CameraState))
    detector: str = field(metadata=f_str("marker detector in use"))
    source: str = field(metadata=f_str("frame source (device, file, folder, stream, rendered)"))
    frames: int = field(metadata=f_int("frames processed and published"))
    dropped: int = field(metadata=f_int("frames dropped because processing fell behind"))
    fps: float = field(
        metadata=f_float("frames processed per second over the last period", "1/s", lo=0.0, hi=1e6)
    )
    detect_p50_ms: float | None = field(
        default=None, metadata=_f_ms("median detection time over the last 1000 frames")
    )
    detect_p99_ms: float | None = field(
        default=None, metadata=_f_ms("p99 detection time over the last 1000 frames")
    )
    detect_max_ms: float | None = field(
        default=None, metadata=_f_ms("largest detection time over the last 1000 frames")
    )
    latency_p50_ms: float | None = field(
        default=None,
        metadata=_f_ms("median capture -> published time, last 1000 frames", lo=-CAMERA_MS_MAX),
    )
    latency_p99_ms: float | None = field(
        default=None,
        metadata=_f_ms("p99 capture -> published time, last 1000 frames", lo=-CAMERA_MS_MAX),
    )
    latency_max_ms: float | None = field(
        default=None,
        metadata=_f_ms("largest capture -> published time, last 1000 frames", lo=-CAMERA_MS_MAX),
    )
    detections: Mapping[str, int] = field(
        metadata=f_count_map(
            "robot id -> frames its tag was detected in", key_pattern=keys.ROBOT_ID_PATTERN
        )
    )
    published: Mapping[str, int] = field(
        metadata=f_count_map("robot id -> poses published", key_pattern=keys.ROBOT_ID_PATTERN)
    )
    misses: Mapping[str, int] = field(
        metadata=f_count_map(
            "robot id -> frames it was not found in", key_pattern=keys.ROBOT_ID_PATTERN
        )
    )
    rejects: Mapping[str, int] = field(
        metadata=f_count_map(
            "reason (`jump`, `bad_size`, `unknown`, `duplicate`) -> detections dropped"
        )
    )
    reacquired: int = field(
        metadata=f_int("tracks started again (a robot put down elsewhere, lost)")
    )
    internal_errors: int = field(
        metadata=f_int("internal errors caught (a bug, never a bad input); 0 in a healthy run")
    )
    truth_rejected: int = field(
        metadata=f_int("rendered source: truth messages rejected by the decoder")
    )
