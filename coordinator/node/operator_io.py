"""The operator's inputs to the coordinator (issue 28): teleop twists, goals and paths on
``formation/<fleet>/operator/*``, the e-stopped robots a waiting leader stops for, and the
continuation of the virtual leader at a takeover.

A part the coordinator node builds and owns (:class:`OperatorInputs`); the decisions are
:mod:`coordinator.core.leader`'s. Handlers decode, validate, count every rejection (in the node's
``rejects`` under ``cmd_vel-<reason>``, ``goal-<reason>``, ``path-<reason>``) and queue the
command in the leader core, which applies it at its next tick (lockstep: the next clock), so the
same inputs at the same ticks give the same leader. Handlers never raise.

**Takeover.** Every instance, active or standby, reads the operator's commands: a standby keeps
the route and the last twist (:meth:`LeaderCore.remember`). A realtime standby also keeps the
last ``leader`` messages of the active one; when it becomes active and the leader it takes over
is no longer the scripted trajectory at ``t - leader_t0`` (an operator drove it, or it waited
for its team: its ``leader`` messages carry ``progress_s`` then, and only then), it adopts the
newest leader state that continues the ones before it (position, velocity, mode, progress,
rate, next waypoint: :meth:`LeaderCore.adopt`), so the leader goes on from where it was. A
scripted leader that never deviated continues from its origin as before
(coordinator.core.election verifies that origin). A single forged ``leader`` message does not
continue the messages before it and is not adopted; under ``--secure`` only coordinators may
publish ``leader`` at all.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable, Collection
from typing import Any, Final

import runtime as rt
from bus_schemas import (
    CmdVel,
    DecodeError,
    Goal,
    Leader,
    Obstacle,
    Path,
    ReshapeSource,
    Shape,
    decode,
    keys,
)
from coordinator.core.coordinator import CoordinatorCore
from coordinator.core.leader import LeaderMode
from coordinator.core.planning.replan import obstacle_table
from coordinator.core.reshaping import ReshapeState
from coordinator.core.trajectory import LeaderState
from robot_agent.core.estop import EstopLatch

__all__ = [
    "BURST_MAX",
    "CMD_RATE_MAX_HZ",
    "LEADER_ADOPT_AGE_S",
    "OperatorInputs",
    "reshape_fields",
    "reshape_state",
]

CMD_RATE_MAX_HZ: Final = 50.0
"""Long-run rate of operator commands accepted (per second, a token bucket; realtime): the tools
send 20 twists per second; a flood beyond this is refused as ``burst``."""
BURST_MAX: Final = 10.0
"""Depth of that bucket (commands)."""
LEADER_ADOPT_AGE_S: Final = 2.0
"""A standby adopts only a ``leader`` message received this recently (s) at its takeover."""
_JUMP_SLACK_M: Final = 0.005
_FRACTION_TOL: Final = 1e-6


class OperatorInputs:
    """The operator's commands, the held robots, and the leader's continuation at a takeover."""

    def __init__(
        self,
        fleet: str,
        core: CoordinatorCore,
        *,
        safety_m: float,
        lockstep: bool,
        now: Callable[[], float],
        is_active: Callable[[], bool],
        robots: Callable[[], Collection[str]],
        reject: Callable[[str, DecodeError | str, str | None], None],
        internal: Callable[[str, BaseException], None],
        log: rt.NodeLog,
    ) -> None:
        self.core = core
        self.leader = core.leader
        self.safety_m = safety_m
        """Least distance (m) between two slots along a reshape (the robots' safety distance)."""
        self.lockstep = lockstep
        self.cmd_vel_key = keys.cmd_vel_key(fleet)
        self.goal_key = keys.goal_key(fleet)
        self.path_key = keys.path_key(fleet)
        self.shape_key = keys.shape_key(fleet)
        self.obstacle_key = keys.obstacle_key(fleet)
        self.command_keys = (
            self.cmd_vel_key, self.goal_key, self.path_key, self.shape_key, self.obstacle_key,
        )  # fmt: skip
        """The keys of the operator's commands (each subscribed on its own: a declaration on
        ``operator/*`` is refused by the router's access control under ``--secure``)."""
        self._now = now
        self._is_active = is_active
        self._robots = robots
        self._reject = reject
        self._internal = internal
        self.log = log
        self.rx: dict[str, int] = {
            "cmd_vel": 0, "goal": 0, "path": 0, "shape": 0, "obstacle": 0,
        }  # fmt: skip
        self._bucket = BURST_MAX
        self._bucket_s: float | None = None
        self._last_seq: int | None = None
        self._last_twist_s: float | None = None
        self._leaders: deque[tuple[float, Leader]] = deque(maxlen=8)
        self.adopted = 0
        self.reshape_takeovers: dict[str, int] = {}
        """What takeovers did with a reshape the previous active ran, by outcome
        (coordinator.core.reshaping.Reshaper.take_over)."""

    # -- inputs --------------------------------------------------------------------------------

    def on_command(self, rx: rt.Received) -> None:
        """Any key under ``operator/``: dispatched by its leaf."""
        try:
            info = keys.parse_key(rx.key)
            leaf = None if info is None else info.leaf
            if leaf == keys.CMD_VEL:
                self._on_cmd_vel(rx)
            elif leaf == keys.GOAL:
                self._on_goal(rx)
            elif leaf == keys.PATH:
                self._on_path(rx)
            elif leaf == keys.SHAPE:
                self._on_shape(rx)
            elif leaf == keys.OBSTACLE:
                self._on_obstacle(rx)
            else:
                self._reject("operator", f"not an operator key: {rx.key[:100]!r}", "bad_key")
        except Exception as exc:
            self._internal("operator", exc)

    def _admit(self, what: str, now_s: float) -> bool:
        """The token bucket (realtime): False (counted) for a command beyond the rate."""
        self.rx[what] += 1
        if self.lockstep:
            return True  # sim time: the plant paces the run; the last command of a tick wins
        if self._bucket_s is not None and now_s > self._bucket_s:
            self._bucket = min(BURST_MAX, self._bucket + CMD_RATE_MAX_HZ * (now_s - self._bucket_s))
        if self._bucket_s is None or now_s > self._bucket_s:
            self._bucket_s = now_s
        if self._bucket < 1.0:
            self._reject(what, f"more than {CMD_RATE_MAX_HZ:g} commands per second", "burst")
            return False
        self._bucket -= 1.0
        return True

    def _refused(self, what: str, why: str | None) -> None:
        if why is not None:
            self._reject(what, f"refused by the leader: {why}", why)
        elif not self._is_active():
            self.leader.remember()  # a standby continues it after a takeover

    def _on_cmd_vel(self, rx: rt.Received) -> None:
        now = self._now()
        if not self._admit("cmd_vel", now):
            return
        msg = decode(rx.payload, CmdVel)
        if isinstance(msg, DecodeError):
            self._reject("cmd_vel", msg, None)
            return
        # an older twist (reordered) must not replace a newer one; a new session (seq from 0)
        # is accepted once the last one is past the deadman
        last, last_s = self._last_seq, self._last_twist_s
        fresh = last_s is not None and now - last_s <= self.leader.config.deadman_s
        if last is not None and fresh and msg.seq <= last:
            self._reject("cmd_vel", f"seq {msg.seq} after {last}", "reordered")
            return
        clamped = self.leader.rejects.get("clamped", 0)
        why = self.leader.command_twist(msg.v_mps, msg.omega_radps, now)
        if why is None:
            self._last_seq, self._last_twist_s = msg.seq, now
            if self.leader.rejects.get("clamped", 0) != clamped:  # obeyed within the limits
                self._reject("cmd_vel", "beyond the leader's limits: clamped", "clamped")
        self._refused("cmd_vel", why)

    def _on_goal(self, rx: rt.Received) -> None:
        if not self._admit("goal", self._now()):
            return
        msg = decode(rx.payload, Goal)
        if isinstance(msg, DecodeError):
            self._reject("goal", msg, None)
            return
        why = self.leader.command_goal(msg.x, msg.y, msg.heading)
        if why is None:
            self.log.info(f"goal ({msg.x:.3f}, {msg.y:.3f}) from the operator")
        self._refused("goal", why)

    def _on_path(self, rx: rt.Received) -> None:
        if not self._admit("path", self._now()):
            return
        msg = decode(rx.payload, Path)
        if isinstance(msg, DecodeError):
            self._reject("path", msg, None)
            return
        why = self.leader.command_path(list(zip(msg.xs, msg.ys, strict=True)), msg.heading)
        if why is None:
            self.log.info(f"path of {len(msg.xs)} points from the operator")
        self._refused("path", why)

    def _on_shape(self, rx: rt.Received) -> None:
        if not self._admit("shape", self._now()):
            return
        msg = decode(rx.payload, Shape)
        if isinstance(msg, DecodeError):
            self._reject("shape", msg, None)
            return
        spacing = msg.spacing_m if msg.spacing_m is not None else self.core.reshaper.spacing_m
        # the active starts it at its next tick; a standby keeps it planned, not started, to
        # continue it at a takeover (coordinator.core.reshaping)
        reshaper = self.core.reshaper
        ask = reshaper.ask if self._is_active() else reshaper.ask_standby
        why = ask(msg.kind, spacing, self.safety_m, msg.slots, len(self._robots()))
        if why is not None:
            self._reject("shape", f"refused: {msg.kind} at {spacing:.3g} m: {why}", why)
            return
        self.log.info(f"reshape into a {msg.kind} of {reshaper.slots} slots {spacing:.3g} m apart")

    def _on_obstacle(self, rx: rt.Received) -> None:
        """A planning obstacle added, moved or removed (issue 27): every instance keeps the
        map; the active one replans a goal it follows (coordinator.core.planning.replan)."""
        if not self._admit("obstacle", self._now()):
            return
        msg = decode(rx.payload, Obstacle)
        if isinstance(msg, DecodeError):
            self._reject("obstacle", msg, None)
            return
        table = None
        if msg.action != "remove":
            try:
                table = obstacle_table(
                    msg.shape or "", x=msg.x, y=msg.y, radius_m=msg.radius_m, xs=msg.xs, ys=msg.ys
                )
            except ValueError as exc:
                self._reject("obstacle", f"{msg.id}: {exc}", "degenerate")
                return
        why = self.core.obstacle(msg.action, msg.id, table)
        if why is not None:
            self._reject("obstacle", f"{msg.action} {msg.id}: {why}", why)
            return
        self.log.info(f"obstacle {msg.id}: {msg.action} ({msg.shape or '-'})")

    def on_leader(self, rx: rt.Received) -> None:
        """The active instance's ``leader`` (a realtime standby keeps the last few)."""
        try:
            if self._is_active():
                return
            msg = decode(rx.payload, Leader)
            if isinstance(msg, DecodeError):
                return  # counted by the election's handler of the same messages
            self._leaders.append((self._now(), msg))
        except Exception as exc:
            self._internal("operator-leader", exc)

    # -- the tick ------------------------------------------------------------------------------

    def held(self, estop: EstopLatch, robots: Collection[str]) -> set[str]:
        """The robots of ``robots`` an e-stop holds (a waiting leader stops for them)."""
        if estop.fleet:
            return set(robots)
        return {r for r in robots if r in estop.robots}

    def took_over(self, now_s: float, leader_t0: float | None) -> bool:
        """This instance just became active at ``now_s`` continuing origin ``leader_t0``: adopt
        the previous active's leader if it is not the script at that origin (module docstring).
        True if it adopted one."""
        msg = self._continuable(now_s)
        self._continue_reshape(msg)
        self._leaders.clear()
        if msg is None or msg.mode is None:
            return False
        if msg.progress_s is None:
            return False  # the script at t - leader_t0: the origin continues it (election)
        mode = LeaderMode(msg.mode)
        progress = msg.progress_s
        rate = msg.rate if msg.rate is not None else 1.0
        state = LeaderState(progress, msg.x, msg.y, msg.theta, msg.v_mps, msg.omega_radps)
        self.leader.adopt(now_s, state, mode, progress, rate, msg.target or 0)
        self.adopted += 1
        if self.core.continue_goal():  # a planned goal: planned again from here, no jump
            self.log.info("replanning the goal from the continued leader (takeover)")
        self.log.info(
            f"continuing the leader in mode {mode.value} at ({msg.x:.3f}, {msg.y:.3f}), "
            f"rate {rate:.2f}"
        )
        return True

    def _continue_reshape(self, msg: Leader | None) -> None:
        """At a takeover: continue the reshape the previous active's last ``leader`` message
        ``msg`` (one that continues the one before it) says was running (its fields
        ``reshape_t0``, ...), or settle the one this standby kept."""
        state = None if msg is None else reshape_state(msg)
        outcome = self.core.reshaper.take_over(state, self.safety_m)
        self.reshape_takeovers[outcome] = self.reshape_takeovers.get(outcome, 0) + 1
        if outcome != "none":
            self.log.info(f"the reshape at the takeover: {outcome}")
            if outcome == "finished" and state is not None:
                self._reject("shape", "a running reshape could not be continued", "takeover")

    def _continuable(self, now_s: float) -> Leader | None:
        """The newest recent ``leader`` message that continues the one before it (no jump)."""
        recent = [m for rx_s, m in self._leaders if 0.0 <= now_s - rx_s <= LEADER_ADOPT_AGE_S]
        vmax = self.leader.config.max_speed_mps
        for a, b in zip(reversed(recent[:-1]), reversed(recent), strict=False):
            dt = b.t - a.t
            if not dt > 0.0:
                continue
            reach = (max(abs(a.v_mps), abs(b.v_mps), vmax)) * dt + _JUMP_SLACK_M
            if math.hypot(b.x - a.x, b.y - a.y) <= reach:
                return b
        return None


def reshape_state(msg: Leader) -> ReshapeState | None:
    """The running reshape a ``leader`` message describes (None: none, or an older
    coordinator's message without the fields)."""
    if msg.reshape is None or msg.shape is None:
        return None
    if msg.slots is None or msg.spacing_m is None or msg.reshape_t0 is None:
        return None
    if msg.reshape_s is None or msg.reshape_from is None or not msg.reshape_s > 0.0:
        return None
    done = min(max((msg.t - msg.reshape_t0) / msg.reshape_s, 0.0), 1.0)
    if abs(done - msg.reshape) > _FRACTION_TOL:  # its fields do not agree: not a reshape's
        return None
    source = None if msg.reshape_from == ReshapeSource.SCENARIO else msg.reshape_from
    return ReshapeState(msg.shape, msg.spacing_m, msg.slots, msg.reshape_t0, msg.reshape_s, source)


def reshape_fields(state: ReshapeState | None) -> dict[str, Any]:
    """The ``leader`` message's fields of a running reshape (the inverse of
    :func:`reshape_state`)."""
    if state is None:
        return {}
    return {
        "slots": state.slots,
        "spacing_m": state.spacing_m,
        "reshape_from": ReshapeSource.SCENARIO.value if state.source is None else state.source,
        "reshape_t0": state.t0_s,
        "reshape_s": state.duration_s,
    }
