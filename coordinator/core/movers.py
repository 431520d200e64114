"""Movers (issue 30): robots the coordinator sees moving in a way their own wheels cannot
explain, so they are moving obstacles and not members of the formation for now.

Pure, stdlib only, time passed in. ``CoordinatorCore.tick`` runs one :class:`MoverDetector`, so
the in-process simulator, lockstep and realtime coordinators decide from the same poses the same
way (no input beyond the ones ``tick`` already has: the poses, the e-stopped robots and its own
previous assignment).

Theory of operation
===================
Each robot's axle centre is sampled on every tick (the centre, not the reference point: a turn
in place moves the reference point at up to ``l omega`` while the robot stays put). Its
speed is the distance to the oldest sample at least ``window_s`` old, over the time between
(a mean over the window, so camera noise of 3 mm per axis reads as about 0.01 m/s, not as
the 0.1 m/s one frame's jitter would; ``still_mps`` is about 5 standard deviations of it). A
robot is a mover on a tick when

* its speed exceeds ``fast_mps`` (above what its wheels can drive: it is carried, pushed, or
  its pose is not its own), or
* it is not driven toward a slot (no slot in the coordinator's previous assignment: a spare or
  an unassigned robot, or it is e-stopped) and its speed exceeds ``still_mps``: its firmware
  commands no motion of its own (IDLE, HOLD, ESTOP; an IDLE or HOLD robot may only evade, and
  a robot evading a body is a fine thing to keep out of the formation for a moment too).

It stays a mover until ``hold_s`` after the last tick on which either held (with ``still_mps``
halved for a robot that is a mover already: hysteresis). While a robot is a
mover the coordinator gives it no slot, and the slot it held when it became one is kept for it
(no other robot is sent into its way: ``reserved``); when it is no longer a mover it is a
robot like any other and the assignment takes it back.

Making room (``yielding``): a robot whose centre is within ``yield_m + lead_s * speed`` of a
mover, and every
robot within ``chain_m`` of a yielding one (the formation around it), yields for ``hold_s``:
the slot it had is kept for it (given to no one else) and its setpoint is a refuge
(``refuge``) beside the movers' lines of motion instead of the slot, so the formation steps
aside together, its robots tracking (cooperative with one another) and their filters keeping
them apart and away from the body. Without this, a body carried head-on at a formation's
leader pinned it against its own followers, which kept advancing to their slots (the
cooperative barrier, issue 30 (b)): the leader's filter found no admissible command and its
wheels sat at zero until contact. A yielding robot that had no slot (a spare) gets no setpoint:
its firmware evades on a zero nominal command (robot_agent's ``SafetyFilter.evade``).
A refuge setpoint carries a feed-forward toward the refuge at ``aside_mps`` (``aside_rows``):
the slot tracking gain alone moved a robot aside too slowly for a body at the robots' top
speed. A robot ``keep_side_m`` or more from a mover's line steps away on its own side; nearer,
out of the formation.

What the robots learn (``moving``): each mover's id, centre and velocity, which
``CoordinatorOutput.movers`` carries to their filters (a non-cooperative neighbour with that
velocity: rule 4 of ``robot_agent.core.neighbours``; over Zenoh the ``movers`` message).

What it cannot see: a robot carried while it tracks a slot, slower than ``fast_mps``, looks
like a robot driving (only its wheels' encoders could tell; docs/faults.md).
"""

from __future__ import annotations

import math
from collections.abc import Collection, Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Final

__all__ = ["MoverDetector", "MoverParams", "MoverRow"]

MoverRow = tuple[str, float, float, float, float]
"""A moving obstacle: ``(id, x, y, vx, vy)``, its centre (m) and velocity (m/s)."""

_EMPTY: frozenset[str] = frozenset()
_SURE: Final = 0.999999
"""``_slower``'s margin on the squared distance: far above the rounding of either side."""
_NORMAL_SQ: Final = 1e-290
"""``_slower`` decides nothing below this squared limit (m^2: products near underflow)..."""
_HUGE_SQ: Final = 1e290
"""... nor above this one (m^2: products near overflow)."""


def _slower(dx_m: float, dy_m: float, dt_s: float, limit_mps: float) -> bool:
    """``hypot(dx_m, dy_m) / dt_s <= limit_mps`` for certain, decided without ``math.hypot``
    (in the compiled build a Python call: the largest cost of a robot's pass in
    ``MoverDetector.update``). True only when the squared distance is below the squared limit
    by the margin ``_SURE``: ``math.hypot`` is within one ulp of the exact norm and the products
    and sums round by a few ulps, so the exact speed is then ``(1 - 5e-7)`` of the limit or
    less, and its rounded quotient can only be at most the limit (rounding is monotone). False
    when unsure or out of the normal range (overflow, underflow): the caller then computes the
    speed itself, as before, so every decision is the one the speed gives."""
    lim_m = limit_mps * dt_s
    lim_sq = lim_m * lim_m
    if not _NORMAL_SQ < lim_sq < _HUGE_SQ:
        return False
    return dx_m * dx_m + dy_m * dy_m < _SURE * lim_sq


class _Sample:
    """One sample of a centre: time ``t`` (s), ``x``, ``y`` (m). A class of its own, not a
    tuple: compiled, its floats are read in place (a tuple's are checked and unboxed, all three
    at each read) and it is one object, not four."""

    __slots__ = ("t", "x", "y")

    def __init__(self, t_s: float, x_m: float, y_m: float) -> None:
        self.t = t_s
        self.x = x_m
        self.y = y_m


class _Track:
    """One robot's (or object's) centre: the latest ``x``, ``y`` (m) and its samples over the
    window. One object per robot, updated in place each tick (compiled: the floats unboxed), so
    a tick stores no new pair per robot beside the sample."""

    __slots__ = ("samples", "x", "y")

    def __init__(self, t_s: float, x_m: float, y_m: float) -> None:
        self.x = x_m
        self.y = y_m
        # its samples, oldest first: a list, which mypyc indexes, appends to and pops in C (a
        # deque's every operation is a Python call compiled); some 26 samples; never empty: it
        # starts with a sample and keeps 2
        self.samples: list[_Sample] = [_Sample(t_s, x_m, y_m)]


@dataclass(frozen=True, slots=True)
class MoverParams:
    """Thresholds of :class:`MoverDetector`.

    Attributes:
        fast_mps: a centre faster than this (m/s) is a mover whatever its mode: above the
            robots' top speed (``max_wheel_radps * wheel_radius_m``, 0.3 m/s) with a margin
            for noise over the window.
        still_mps: a robot that is not driven (no slot, e-stopped) faster than this (m/s) is a
            mover: above what 3 mm camera noise reads as over ``window_s``.
        window_s: the speed is measured over at least this long (s).
        hold_s: a mover stays one this long (s) after it was last seen moving so; a robot
            making room for one yields this long after it was last near one.
        yield_m: a robot whose centre is this close (m) to a mover's yields (makes room).
        chain_m: a robot this close (m) to a yielding robot yields too.
        clear_m: a yielding robot steps sideways until its reference point is this far (m)
            from the line a mover moves along (``refuge``).
        side_tol_m: a robot this close (m) to that line steps to its left.
        side_turn_rad: the side a robot steps to is chosen again when the mover's direction
            of motion turned more than this (rad) since it was chosen.
        keep_side_m: a robot this far (m) from that line or farther steps away from it on the
            side it is on (a robot behind the line was sent across the body's path, in front
            of it, when every robot stepped out of the formation: issue 30, 0.3 m/s).
        spacing_m: refuges at least this far apart (m; the cooperative barrier between two
            reference points is ``Ds + 2 l`` = 0.29 m with the defaults).
        lead_s: a mover's reach grows by what it covers in this long (s) at its speed: a
            robot within ``yield_m + lead_s * speed`` of it yields.
        aside_mps: the speed (m/s) of a refuge setpoint's feed-forward toward the refuge
            (``aside_rows``): the robots' reference-point top speed (``max_ref_speed_mps``).
            The slot tracking law's gain alone (eqs 21-22, ``kp`` 0.21 /s) moves a robot
            0.35 m from its refuge at 0.07 m/s: a body at 0.3 m/s arrives first.
        aside_gain_per_s: within ``aside_mps / aside_gain_per_s`` of its refuge the feed-forward
            is this gain (1/s) times the distance, so the robot settles there.
    """

    fast_mps: float = 0.4
    still_mps: float = 0.04
    window_s: float = 0.5
    hold_s: float = 1.0
    yield_m: float = 0.6
    chain_m: float = 0.45
    clear_m: float = 0.4
    side_tol_m: float = 0.03
    keep_side_m: float = 0.1
    side_turn_rad: float = 0.35
    spacing_m: float = 0.35
    lead_s: float = 2.0
    aside_mps: float = 0.25
    aside_gain_per_s: float = 2.0

    def __post_init__(self) -> None:
        names = (
            "fast_mps", "still_mps", "window_s", "hold_s", "yield_m", "chain_m", "clear_m",
            "side_tol_m", "keep_side_m", "side_turn_rad",
            "lead_s", "spacing_m", "aside_mps", "aside_gain_per_s",
        )  # fmt: skip
        for name in names:
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value > 0.0):
                raise ValueError(f"MoverParams.{name} must be a positive finite number: {value!r}")
        if not self.still_mps < self.fast_mps:
            raise ValueError("MoverParams: still_mps must be below fast_mps")

    @classmethod
    def for_top_speed(cls, top_speed_mps: float) -> MoverParams:
        """Defaults with ``fast_mps`` a third above ``top_speed_mps`` (the robots' top speed)."""
        return cls(fast_mps=max(2.0 * cls().still_mps, 4.0 / 3.0 * top_speed_mps))


class MoverDetector:
    """Which robots are movers now (see the module docstring)."""

    __slots__ = (
        "_cos_turn",
        "_objects",
        "_params",
        "_reserved",
        "_side",
        "_tracks",
        "_until",
        "_yield_until",
        "rejected",
    )

    def __init__(self, params: MoverParams | None = None) -> None:
        self._params = params if params is not None else MoverParams()
        # robot -> its latest centre and its samples over the window
        self._tracks: dict[str, _Track] = {}
        self._until: dict[str, float] = {}
        self._yield_until: dict[str, float] = {}
        self._reserved: dict[str, int] = {}
        # (robot, mover) -> side (+1 left of the motion), the motion's unit vector it was for
        self._side: dict[tuple[str, str], tuple[float, float, float]] = {}
        self._objects: frozenset[str] = _EMPTY  # the tracked objects now
        self._cos_turn = math.cos(self._params.side_turn_rad)
        self.rejected = 0
        """Poses or times skipped as non-finite."""

    @property
    def params(self) -> MoverParams:
        return self._params

    @property
    def movers(self) -> frozenset[str]:
        """The robots that were movers on the last ``update``."""
        return frozenset(self._until)

    @property
    def yielding(self) -> frozenset[str]:
        """The robots making room for a mover on the last ``update`` (no mover among them)."""
        if not self._yield_until:  # (every tick without a mover: no set to build)
            return _EMPTY
        return frozenset(r for r in self._yield_until if r not in self._until)

    @property
    def excluded(self) -> frozenset[str]:
        """Movers and the robots making room for them: no slot for any of them now."""
        if not self._until and not self._yield_until:
            return _EMPTY
        return frozenset(self._until) | frozenset(self._yield_until)

    @property
    def reserved(self) -> Mapping[str, int]:
        """Mover or yielding robot -> the slot it held when it became one (kept for it, given
        to no one else)."""
        return dict(self._reserved)

    def moving(self) -> tuple[MoverRow, ...]:
        """The movers now as ``(id, x, y, vx, vy)``: the latest centre and the velocity over the
        window, by id (empty without movers)."""
        if not self._until:
            return ()
        rows: list[MoverRow] = []
        for mid in sorted(self._until):
            c = self._tracks.get(mid)
            if c is not None:
                rows.append((mid, c.x, c.y, *self.velocity(mid)))
        return tuple(rows)

    def speed_mps(self, robot: str) -> float:
        """The robot's centre speed over the window (m/s), NaN until it has one."""
        track = self._tracks.get(robot)
        hist = track.samples if track is not None else None
        if not hist or len(hist) < 2:
            return math.nan
        last, first = hist[-1], hist[0]
        t1, x1, y1 = last.t, last.x, last.y
        t0, x0, y0 = first.t, first.x, first.y
        if not t1 - t0 >= self._params.window_s:
            return math.nan
        return math.hypot(x1 - x0, y1 - y0) / (t1 - t0)

    def velocity(self, robot: str) -> tuple[float, float]:
        """The robot's centre velocity over the window (m/s), ``(0, 0)`` until it has one."""
        track = self._tracks.get(robot)
        hist = track.samples if track is not None else None
        if not hist or len(hist) < 2:
            return 0.0, 0.0
        last, first = hist[-1], hist[0]
        t1, x1, y1 = last.t, last.x, last.y
        t0, x0, y0 = first.t, first.x, first.y
        if not t1 - t0 >= self._params.window_s:
            return 0.0, 0.0
        return (x1 - x0) / (t1 - t0), (y1 - y0) / (t1 - t0)

    def refuges(self, points: Mapping[str, tuple[float, float]]) -> dict[str, tuple[float, float]]:
        """The refuges of several robots making room (reference points ``points``), spaced:
        each robot's own ``refuge``, then, the robots that must move farthest first, one whose
        refuge is within ``spacing_m`` of a refuge already placed is pushed on (along its own
        sideways direction, or the other robot's when it had none) until it is not. So the
        robots stepping aside do not ask for the same place (a robot pinned between a
        neighbour holding its refuge and the body: issue 30)."""
        p = self._params
        base: dict[str, tuple[float, float, float, float]] = {}
        for rid in sorted(points):
            qx, qy = points[rid]
            rx, ry = self.refuge(rid, qx, qy)
            d = math.hypot(rx - qx, ry - qy)
            nx, ny = ((rx - qx) / d, (ry - qy) / d) if d > 1e-9 else (0.0, 0.0)
            base[rid] = (rx, ry, nx, ny)
        order = sorted(base, key=lambda r: (-math.hypot(base[r][0] - points[r][0],
                                                       base[r][1] - points[r][1]), r))  # fmt: skip
        placed: dict[str, tuple[float, float, float, float]] = {}
        for rid in order:
            rx, ry, nx, ny = base[rid]
            for _ in range(2 * len(placed) + 1):
                clash = None
                for px, py, pnx, pny in placed.values():
                    if math.hypot(rx - px, ry - py) < p.spacing_m:
                        clash = (px, py, pnx, pny)
                        break
                if clash is None:
                    break
                px, py, pnx, pny = clash
                dx, dy = (nx, ny) if nx or ny else (pnx, pny)
                if not (dx or dy):
                    break
                # along (dx, dy) until spacing_m from the clashing refuge
                ox, oy = rx - px, ry - py
                along = ox * dx + oy * dy
                perp2 = ox * ox + oy * oy - along * along
                step = math.sqrt(max(0.0, p.spacing_m**2 - perp2)) - along + 1e-3
                rx += dx * step
                ry += dy * step
            placed[rid] = (rx, ry, nx, ny)
        return {rid: (v[0], v[1]) for rid, v in placed.items()}

    def aside_rows(
        self, points: Mapping[str, tuple[float, float]]
    ) -> dict[str, tuple[float, float, float, float]]:
        """The setpoint rows ``(x, y, vx, vy)`` of robots making room (reference points
        ``points``): each one's refuge (``refuges``) with a feed-forward velocity toward it,
        ``aside_mps`` far from it and ``aside_gain_per_s`` times the distance near it. Eq 21's
        feed-forward term carries the robot there at its top speed (recomputed every tick
        from where it is), where the slot gain alone would take seconds."""
        p = self._params
        out: dict[str, tuple[float, float, float, float]] = {}
        for rid, (rx, ry) in self.refuges(points).items():
            qx, qy = points[rid]
            dx, dy = rx - qx, ry - qy
            d = math.hypot(dx, dy)
            speed = min(p.aside_mps, p.aside_gain_per_s * d)
            k = speed / d if d > 1e-9 else 0.0
            out[rid] = (rx, ry, k * dx, k * dy)
        return out

    def refuge(self, robot: str, qx: float, qy: float) -> tuple[float, float]:
        """Where ``robot`` making room, with its reference point at ``(qx, qy)``, goes now: off
        the movers' paths. For each mover that comes at it (or stands, within ``clear_m``), the
        point is pushed sideways from the mover's line of motion until it is ``clear_m`` from
        that line, on a side chosen when it started to make room for that mover and kept
        while it yields (a noisy velocity must not flip it): ``_choose_side``. ``(qx, qy)``
        itself when nothing asks it to move (it holds its place, tracking)."""
        p = self._params
        rx, ry = qx, qy
        for mid in sorted(self._until):
            c = self._tracks.get(mid)
            if c is None:
                continue
            vx, vy = self.velocity(mid)
            sp = math.hypot(vx, vy)
            dx, dy = qx - c.x, qy - c.y
            if sp > p.still_mps:
                ux, uy = vx / sp, vy / sp
            else:  # a mover standing: away from it
                d = math.hypot(dx, dy)
                if not d > 0.0:
                    continue
                ux, uy = dx / d, dy / d
            along = dx * ux + dy * uy
            if along < -p.clear_m:  # behind it and it moves away
                continue
            cross = ux * dy - uy * dx  # > 0: left of the motion
            kept = self._side.get((robot, mid))
            # a side is kept while the motion keeps its direction within side_turn_rad (a
            # noisy velocity must not flip it); chosen again when it turned more: the first
            # estimate of a body that just started, 2 cm over the window, can be 35 degrees
            # off through 3 mm camera noise, and a side chosen for that line crossed the real
            # one (issue 30, the chevron at 0.3 m/s)
            if kept is None or kept[1] * ux + kept[2] * uy < self._cos_turn:
                side = self._choose_side(qx, qy, ux, uy, cross)
                self._side[robot, mid] = (side, ux, uy)
            else:
                side = kept[0]
            nx, ny = -uy * side, ux * side
            w = cross * side  # distance from the line, toward the side kept
            if w >= p.clear_m:
                continue
            rx += nx * (p.clear_m - w)
            ry += ny * (p.clear_m - w)
        return rx, ry

    def _choose_side(self, qx: float, qy: float, ux: float, uy: float, cross: float) -> float:
        """The side (+1: left of the motion ``u``) a robot at ``(qx, qy)`` steps to: the side of
        the mover's line it is on when it is ``keep_side_m`` or more from that line (never
        across the body's path: the way is shorter and the body is not in it); else away from
        the centre of the other robots (out of the formation, not across it) when that is
        clear by ``side_tol_m``, else the side of the line it is on, else the left."""
        tol = self._params.side_tol_m
        if abs(cross) >= self._params.keep_side_m:
            return 1.0 if cross > 0.0 else -1.0
        pts = [
            (c.x, c.y)
            for rid, c in self._tracks.items()
            if rid not in self._objects and rid not in self._until
        ]
        if pts:
            cx = sum(x for x, _ in pts) / len(pts)
            cy = sum(y for _, y in pts) / len(pts)
            out = ux * (qy - cy) - uy * (qx - cx)
            if abs(out) > tol:
                return 1.0 if out > 0.0 else -1.0
        return -1.0 if cross < -tol else 1.0

    def update(
        self,
        now_s: float,
        poses: Mapping[str, tuple[float, float, float]],
        assignment: Mapping[str, int],
        held: Collection[str] = (),
        objects: Mapping[str, tuple[float, float]] | None = None,
    ) -> frozenset[str]:
        """One tick: ``poses`` the latest pose of each live robot (axle centre x, y, theta),
        ``assignment`` the coordinator's previous assignment (robot -> slot), ``held`` the
        e-stopped robots, ``objects`` the tracked bodies that are not counted robots (centre x,
        y; ids distinct from the robots': a cart's tag, a robot whose agent is dead, hung or cut
        off, its wheels stopped; such a robot's history restarts when it becomes one, so its
        own driving before is not motion of an object): never driven, so a mover whenever one
        moves faster than ``still_mps``. Returns the robots that get no slot now
        (``excluded``: the movers and the robots making room for them; an object among them is
        given no slot anyway)."""
        p = self._params
        if math.isinf(now_s) or math.isnan(now_s):  # (math.isfinite: a Python call compiled)
            self.rejected += 1
            return self.excluded
        seen, present = self._observed(poses, objects)
        # The per-tick hot path (one pass per robot): locals, the speed of speed_mps inline
        # (the same arithmetic), and the bookkeeping below only when there is something to do.
        tracks = self._tracks
        until = self._until
        window_s = p.window_s
        fast_mps = p.fast_mps
        n_ok = 0
        for rid, pose in seen:
            x, y = float(pose[0]), float(pose[1])
            # math.isfinite, in the calls mypyc makes C's (isfinite is a Python call compiled)
            if math.isinf(x) or math.isnan(x) or math.isinf(y) or math.isnan(y):
                self.rejected += 1
                continue
            n_ok += 1
            track = tracks.get(rid)
            if track is None:  # a first sample: no speed yet (speed_mps is NaN)
                tracks[rid] = _Track(now_s, x, y)
                continue
            # one sample per tick (a pose that did not change is a robot that did not move
            # as far as the coordinator knows; over the window that averages out)
            track.x = x
            track.y = y
            hist = track.samples
            last = hist[-1]  # (a history is never empty: it starts with a sample, keeps 2)
            if now_s > last.t:
                last = _Sample(now_s, x, y)
                hist.append(last)
            # keep the newest sample at least window_s before the latest one, and after it
            n = len(hist)
            while n > 2 and now_s - hist[1].t >= window_s:
                hist.pop(0)
                n -= 1
            if n < 2:  # speed_mps: NaN until there is a window
                continue
            first = hist[0]
            dt_s = last.t - first.t
            if not dt_s >= window_s:
                continue
            dx_m, dy_m = last.x - first.x, last.y - first.y
            if _slower(dx_m, dy_m, dt_s, fast_mps) and rid in assignment and rid not in held:
                continue  # driven and not faster than its wheels drive: not a mover (below)
            speed = math.hypot(dx_m, dy_m) / dt_s
            if speed != speed:
                continue
            if speed > fast_mps:
                mover = True
            else:
                driven = rid in assignment and rid not in held
                # (hysteresis: a mover stays one down to half of still_mps, so a slow body
                # read through the camera's noise does not flicker in and out)
                still = 0.5 * p.still_mps if rid in until else p.still_mps
                mover = not driven and speed > still
            if mover:
                if rid in assignment:
                    self._reserved.setdefault(rid, assignment[rid])
                until[rid] = now_s + p.hold_s
        self._expire(now_s, n_ok, present, poses, assignment)
        return self.excluded

    def _observed(
        self,
        poses: Mapping[str, tuple[float, float, float]],
        objects: Mapping[str, tuple[float, float]] | None,
    ) -> tuple[Iterable[tuple[str, Sequence[float]]], Mapping[str, object]]:
        """Start of ``update``: the poses to sample (the robots', then the objects' not among
        them) and every id present now; the tracked objects taken."""
        was_objects = self._objects
        self._objects = frozenset(objects) if objects else _EMPTY
        if not objects:
            return poses.items(), poses
        # a robot that has just become an object (its agent died: the plant stopped its
        # wheels) is measured from now on: its own driving before does not make it a mover
        for oid in self._objects - was_objects:
            if oid not in poses:
                self._tracks.pop(oid, None)
        seen = [
            *poses.items(),
            *[(oid, (xy[0], xy[1], 0.0)) for oid, xy in objects.items() if oid not in poses],
        ]
        return seen, {**poses, **objects}

    def _expire(
        self,
        now_s: float,
        n_seen: int,
        present: Mapping[str, object],
        poses: Mapping[str, object],
        assignment: Mapping[str, int],
    ) -> None:
        """End of ``update``: forget the robots gone (``n_seen`` finite poses were taken now),
        end the movers and yields whose hold is over, mark the robots making room now."""
        tracks, until, ylds = self._tracks, self._until, self._yield_until
        # every track is of a robot seen now unless the table holds more ids than that
        if len(tracks) != n_seen:
            for rid in [r for r in tracks if r not in present]:  # gone: forget it
                del tracks[rid]
        if until:
            for rid in [r for r, t in until.items() if now_s >= t or r not in present]:
                del until[rid]
            if until:
                self._make_room(now_s, assignment)
        if ylds:
            for rid in [r for r, t in ylds.items() if now_s >= t or r not in poses]:
                del ylds[rid]
        if self._reserved:
            for rid in [r for r in self._reserved if r not in until and r not in ylds]:
                del self._reserved[rid]
        if self._side:
            for key in [k for k in self._side if k[0] not in ylds or k[1] not in until]:
                del self._side[key]

    def _make_room(self, now_s: float, assignment: Mapping[str, int]) -> None:
        """Mark the robots near a mover, and those near them in turn, as yielding now (a
        breadth-first walk over centre distances; O(n^2) in the robots, only with a mover)."""
        p = self._params
        tracks = self._tracks
        # (x, y, radius): a mover reaches yield_m plus what it covers in lead_s
        frontier = [
            (tracks[m].x, tracks[m].y, p.yield_m + p.lead_s * math.hypot(*self.velocity(m)))
            for m in sorted(self._until)
            if m in tracks
        ]
        seen = set(self._until)
        while frontier:
            nxt: list[tuple[float, float, float]] = []
            for rid, track in tracks.items():
                if rid in seen or rid in self._objects:
                    continue
                x, y = track.x, track.y
                for fx, fy, radius in frontier:
                    if math.hypot(x - fx, y - fy) <= radius:
                        seen.add(rid)
                        nxt.append((x, y, p.chain_m))
                        if rid not in self._yield_until and rid in assignment:
                            self._reserved.setdefault(rid, assignment[rid])
                        self._yield_until[rid] = now_s + p.hold_s
                        break
            frontier = nxt

    def reset(self) -> None:
        """Forget every history and mover."""
        self._tracks.clear()
        self._until.clear()
        self._yield_until.clear()
        self._reserved.clear()
        self._side.clear()
