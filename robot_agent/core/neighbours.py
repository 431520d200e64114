"""What a robot knows of the other robots, as the safety filter wants it: the one rule.

Pure and stdlib only, time passed in. Both runtimes build the firmware's
:class:`~robot_agent.core.safety_filter.Neighbour` list with these functions, so a lockstep run over
Zenoh equals the in-process simulator bit for bit (``formation/sim/simulate.py``,
``robot_agent/node/agent.py``, ``robot_agent/node/host.py``; docs/runtime.md):

1. **Which robots.** Every other robot whose latest pose was *received* within
   :data:`NEIGHBOUR_STALE_S` of now (:func:`is_current`; receive times are local). Older entries
   are dropped (a robot that left the arena, or a made-up id, does not stay an obstacle forever).
2. **Position and age.** The latest measured axle centre and heading, with
   ``age_s = now - capture`` (:func:`neighbour`), the capture time on the *local* clock: the
   pose's stamp in lockstep (sim time, shared by every node), in realtime the stamp converted by
   :class:`robot_agent.core.clocksync.ClockOffset` (never a remote clock compared with the local one
   blindly). A capture in the future (clock noise) counts as age 0.
3. **Cooperative.** The neighbour's firmware was TRACKING on the previous control tick (then it
   runs the same filter and takes half the responsibility). In-process: the mode of its previous
   tick's command. Over Zenoh in lockstep: the plant relays, in clock ``k``, the robots whose
   wheels answering tick ``k - 1`` said ``mode: tracking`` (``Clock.tracking``), so every agent
   learns exactly what the simulator knows. In realtime: its latest status says ``tracking`` and
   was received within :data:`COOPERATIVE_STATUS_S` (:func:`is_cooperative`). A wrong
   "cooperative" is still safe (the filter's reciprocal barrier keeps ``h >= 0`` against a robot
   that stands still, see ``safety_filter.py``); it only matters for how fast robots pass.
4. **Movers** (issue 30). A robot or tracked object the coordinator reports as a moving obstacle
   (``coordinator.core.movers``: carried, pushed, moving without a slot; the coordinator's tick
   k - 1 in lockstep, as the setpoints; its latest report within :data:`MOVERS_STALE_S` in
   realtime) is NOT cooperative whatever its mode (it is not moving the way its filter says)
   and carries the coordinator's velocity estimate (:func:`mover`): the filter takes the whole
   barrier against it, plus its motion (``n . v``).
5. **Motion.** With motion bounds (``SafetyFilterParams.accel_bound_mps2``) each robot's claims
   (its commands' reference-point velocities and the bound its firmware enforces,
   ``robot_agent.core.neighbour_motion``) are kept per robot (:class:`ClaimRing`, tick times on
   the local clock); the entry carries :func:`~robot_agent.core.neighbour_motion.motion_view`
   of them, or none (the worst case) when they are missing, stale or absurd. In-process: the
   claims of the previous ticks' commands. Over Zenoh: the ``wheels`` messages, their ``t``
   through :class:`robot_agent.core.clocksync.ClockOffset` in realtime.
"""

from __future__ import annotations

from collections import deque
from typing import Any, Final

from robot_agent.core.neighbour_motion import Claim, MotionView, motion_view
from robot_agent.core.safety_filter import Neighbour

__all__ = [
    "CLAIMS_KEPT",
    "COOPERATIVE_STATUS_S",
    "MOVERS_STALE_S",
    "NEIGHBOUR_STALE_S",
    "ClaimRing",
    "is_cooperative",
    "is_current",
    "mover",
    "neighbour",
    "neighbours_at",
]

NEIGHBOUR_STALE_S: Final = 1.0
"""A neighbour whose latest pose was received longer ago than this (s) is dropped."""
COOPERATIVE_STATUS_S: Final = 0.5
"""Realtime: a status older than this (s, receive time; 2.5 periods of the 5 Hz status) no
longer makes its robot cooperative."""

MOVERS_STALE_S: Final = 0.5
"""Realtime: the coordinator's movers (4. below) older than this (s, receive time) are
dropped (the robots are neighbours as rule 3 says again)."""

CLAIMS_KEPT: Final = 32
"""Claims kept per robot: the newest at or before a pose's capture must be among them. A
realtime agent ticks on each pose and on its 50 Hz timer between them (~60 claims a second);
32 cover ~0.5 s, the neighbours' largest age (``max_age_s``), under load too (8 covered
~0.13 s: a capture older than that under load lost its claims and fell back to ``V a``)."""

_tuple_new: Final = tuple.__new__
# (compiled: the class and the zero fields held as the module's objects, read from static
# slots, instead of a look-up of the imported name and three new floats an entry)
_NEIGHBOUR: Final = Neighbour
_ZERO: Final[object] = 0.0


class ClaimRing:
    """One robot's latest :data:`CLAIMS_KEPT` claims, in receive order (oldest first); a claim
    not newer than the last one kept is dropped (counted): a replay or a reordered message."""

    __slots__ = ("claims", "dropped")

    def __init__(self) -> None:
        self.claims: deque[Claim] = deque(maxlen=CLAIMS_KEPT)
        self.dropped = 0

    def add(self, claim: Claim) -> bool:
        """Keep ``claim`` (its ``t_s`` on the local clock); False (counted) if not newer."""
        c = self.claims
        if c and not claim.t_s > c[-1].t_s:
            self.dropped += 1
            return False
        c.append(claim)
        return True


def is_current(now_s: float, rx_s: float) -> bool:
    """A neighbour pose received at ``rx_s`` still counts at ``now_s`` (both local clock)."""
    return -NEIGHBOUR_STALE_S <= now_s - rx_s <= NEIGHBOUR_STALE_S


def is_cooperative(now_s: float, tracking: bool, status_rx_s: float) -> bool:
    """Realtime rule: the latest status, received at ``status_rx_s``, said TRACKING and is fresh."""
    return tracking and -COOPERATIVE_STATUS_S <= now_s - status_rx_s <= COOPERATIVE_STATUS_S


def neighbour(
    x: float,
    y: float,
    theta: float,
    capture_s: float,
    now_s: float,
    cooperative: bool,
    motion: MotionView | None = None,
) -> Neighbour:
    """The safety filter's view of one neighbour measured at ``capture_s`` (local clock), with
    the view of its motion claims if any (rule 4)."""
    return _entry(x, y, theta, capture_s, now_s, cooperative, motion)


def _entry(
    x: object,
    y: object,
    theta: object,
    capture_s: float,
    now_s: float,
    cooperative: bool,
    motion: MotionView | None,
) -> Neighbour:
    """:func:`neighbour` with the position and heading as the float objects they are
    (compiled: put in the entry as given, not unboxed and boxed again)."""
    age = now_s - capture_s
    if age < 0.0:
        age = 0.0
    zero = _ZERO
    if motion is None:
        return _tuple_new(_NEIGHBOUR, (x, y, theta, age, zero, zero, cooperative, zero))
    return _tuple_new(_NEIGHBOUR, (x, y, theta, age, zero, zero, cooperative, zero, motion))


def mover(entry: Neighbour, vx_mps: float, vy_mps: float) -> Neighbour:
    """Rule 4: ``entry`` (a neighbour the coordinator reports as a mover) as the filter must see
    it: not cooperative, moving at ``(vx_mps, vy_mps)`` (the coordinator's estimate; a
    non-finite or absurd one is counted and dropped by the filter), without its motion
    claims (rule 5: its own commands are not how it moves)."""
    x, y, theta, age = entry[0], entry[1], entry[2], entry[3]  # eight fields: no claims
    return _tuple_new(Neighbour, (x, y, theta, age, vx_mps, vy_mps, False, entry[7]))


def neighbours_at(
    poses: list[Any],
    rx_s: list[Any],
    now_s: float,
    cooperative: list[bool],
    rings: list[ClaimRing] | None = None,
    l_m: float = 0.0,
    vmax_mps: float = 0.0,
    claim_max_age_s: float = 0.0,
) -> list[Neighbour | None]:
    """Rules 1, 2, 3 and 5 for a whole fleet in one call: entry ``j`` is :func:`neighbour` of
    robot ``j``'s latest pose ``poses[j]`` (``(x, y, theta, capture_s)``, local clock), received
    at ``rx_s[j]``, if it :func:`is_current` at ``now_s`` (else None, as for no pose), with
    ``cooperative[j]`` and, when ``rings`` is given, the :func:`motion_view` of ``rings[j]``'s
    claims (``l_m``, ``vmax_mps``, ``claim_max_age_s``: its arguments). The same entries as
    those calls one by one (the in-process loop builds every robot's list from them once a
    tick: one call instead of one per robot and check; lists, read by index when compiled)."""
    out: list[Neighbour | None] = []
    for j in range(len(poses)):
        p = poses[j]
        if p is None or not is_current(now_s, rx_s[j]):
            out.append(None)
            continue
        # (typed as a tuple, as a Pose is: compiled, its fields are read in place)
        pose: tuple[Any, ...] = p if isinstance(p, tuple) else tuple(p)
        capture = pose[3]
        view = None
        if rings is not None:
            view = motion_view(rings[j].claims, capture, now_s, l_m, vmax_mps, claim_max_age_s)
        x = pose[0]
        y = pose[1]
        th = pose[2]
        # (floats: the entry holds these objects, as neighbour's holds the same values; a bool,
        # not the test itself: compiled, a narrowed x would be unboxed and boxed again)
        floats = type(x) is float and type(y) is float and type(th) is float
        if floats:
            out.append(_entry(x, y, th, capture, now_s, cooperative[j], view))
        else:
            out.append(neighbour(x, y, th, capture, now_s, cooperative[j], view))
    return out
