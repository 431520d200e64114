"""Sensor and link emulation: an overhead camera and a lossy, delayed command link.

Both are pure cores: time is passed in (``t_s``, sim seconds) and every random draw comes from the
``numpy.random.Generator`` given at construction, so a seed reproduces a run exactly (for the same
sequence of calls). A generator is only required when some randomness is configured.

Camera
------
The paper's camera hangs above the arena and reports each robot's pose. Here frames are exposed
on the camera's own clock at ``k / rate_hz`` (k = 0, 1, 2, ...). The caller calls
:meth:`Camera.capture` every sim tick with the true poses; the first call at or after a frame
time takes that frame. The measurement is the truth *at that call* plus Gaussian noise, and its
stamp is the time of that call (the instant the truth was sampled), so a stamp never lies about
which pose it describes. When the tick divides the frame period (e.g. 1/300 s ticks for 30 Hz)
the stamps are exactly ``k / rate_hz``; otherwise a stamp is the first tick after the nominal
frame time and the frame count over a long run is still ``rate_hz`` per second. If ticks are
coarser than the frame period, frames that fell between two calls are lost (counted in
:attr:`Camera.frames_missed`); the camera cannot see the past. Each measurement is delivered at
``stamp + latency_s`` by :meth:`Camera.poll`.

CommandLink
-----------
A one-way radio link coordinator -> robots: each message is lost with ``loss_prob``, otherwise
delivered at ``t + latency_s + U(0, jitter_s)``. With ``fifo=True`` (default) a message to robot
``i`` is never delivered before an earlier message to the same robot (a serial stream: a late
packet holds up the ones behind it); ``fifo=False`` lets jitter reorder them, as UDP can.

Small fleets
------------
Up to ``sim_plant.core.plant.SMALL_N`` robots a camera frame is processed in plain Python (numpy's
per-call overhead dominates there), with the same random draws and the same arithmetic as the
vectorised path, so the same bits. :meth:`CommandLink.send_all` sends one command per robot with
one draw of all the tick's random numbers, the same stream as the equivalent :meth:`send` calls.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass
from operator import itemgetter
from typing import Any, Final, Generic, NamedTuple, TypeVar

import numpy as np
import numpy.typing as npt

from sim_plant.core.kinematics import PoseRows, wrap_angles
from sim_plant.core.plant import SMALL_N

__all__ = ["Camera", "CameraFrame", "CommandLink"]

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
CmdT = TypeVar("CmdT")
PoseRow = tuple[float, float, float]

_PI: Final = math.pi
_TWO_PI: Final = 2.0 * math.pi
_tuple_new = tuple.__new__  # a NamedTuple without its generated __new__ frame (hot path)
_deliver_t = itemgetter(0)  # a queued message's delivery time (the sort key of CommandLink.poll)

# Sim times come from sums of float steps; treat anything within this of a deadline as due.
_TIME_EPS_S: Final = 1e-9


def _check_prob(name: str, p: float) -> float:
    x = float(p)
    if not (0.0 <= x <= 1.0):
        raise ValueError(f"{name} must be in [0, 1], got {p!r}")
    return x


def _check_nonneg(name: str, value: float) -> float:
    x = float(value)
    if not math.isfinite(x) or x < 0.0:
        raise ValueError(f"{name} must be finite and >= 0, got {value!r}")
    return x


@dataclass(frozen=True, slots=True)
class CameraFrame:
    """One camera frame as delivered: robots seen and their measured poses.

    ``ids`` is ``(m,)`` robot indices, ``poses`` ``(m, 3)`` ``[x_m, y_m, theta_rad]`` with theta in
    (-pi, pi]; ``stamp_t`` is the exposure time and ``deliver_t`` the delivery time, seconds.
    """

    stamp_t: float
    deliver_t: float
    ids: IntArray
    poses: FloatArray


class _RowFrame(NamedTuple):
    """A frame taken on the small-fleet path: :class:`CameraFrame` with lists instead of arrays
    (a tuple: built once per frame on the hot path)."""

    stamp_t: float
    deliver_t: float
    ids: Sequence[int]
    poses: list[PoseRow]


class Camera:
    """Overhead pose camera: frame clock, Gaussian noise, dropouts, fixed latency.

    Args:
        n: number of robots in view (rows of the truth passed to :meth:`capture`).
        rate_hz: frame rate, frames exposed at ``k / rate_hz`` seconds.
        pos_std_m: standard deviation of the x and y noise, metres.
        theta_std_rad: standard deviation of the heading noise, rad.
        latency_s: delay from exposure to delivery, seconds.
        rng: source of all randomness; may be ``None`` only if no noise or dropout is configured.
        frame_drop_prob: probability that a whole frame is lost.
        miss_prob: probability that one robot is missing from a frame (occlusion, failed detection).
        t0_s: time of frame 0 in seconds.
    """

    def __init__(
        self,
        n: int,
        rate_hz: float = 30.0,
        pos_std_m: float = 0.003,
        theta_std_rad: float = 0.01,
        latency_s: float = 0.03,
        rng: np.random.Generator | None = None,
        *,
        frame_drop_prob: float = 0.0,
        miss_prob: float = 0.0,
        t0_s: float = 0.0,
    ) -> None:
        if int(n) < 0:
            raise ValueError(f"n must be >= 0, got {n}")
        rate = float(rate_hz)
        if not math.isfinite(rate) or rate <= 0.0:
            raise ValueError(f"rate_hz must be finite and > 0, got {rate_hz!r}")
        self._n = int(n)
        self.rate_hz = rate
        self.pos_std_m = _check_nonneg("pos_std_m", pos_std_m)
        self.theta_std_rad = _check_nonneg("theta_std_rad", theta_std_rad)
        self.latency_s = _check_nonneg("latency_s", latency_s)
        self.frame_drop_prob = _check_prob("frame_drop_prob", frame_drop_prob)
        self.miss_prob = _check_prob("miss_prob", miss_prob)
        self._t0_s = float(t0_s)
        random_needed = (
            self.pos_std_m > 0.0
            or self.theta_std_rad > 0.0
            or self.frame_drop_prob > 0.0
            or self.miss_prob > 0.0
        )
        if rng is None and random_needed:
            raise ValueError("rng is required when noise or dropout is configured")
        self._rng = rng
        self._next_k = 0
        self._next_t = self._t0_s  # == next_frame_t, kept current with _next_k
        self._queue: deque[CameraFrame | _RowFrame] = deque()
        self.frames_taken = 0
        self.frames_dropped = 0
        self.frames_missed = 0
        self.measurements_missed = 0
        self.measurements_delivered = 0
        self.measurements_occluded = 0
        self._occluded: dict[int, tuple[float, float]] = {}
        self._noise_buf: FloatArray = np.empty((0, 3), dtype=np.float64)

    def occlude(self, i: int, t0_s: float, t1_s: float) -> None:
        """Robot ``i`` is out of view for captures stamped in ``[t0_s, t1_s)`` (an occlusion, a
        hand over the tag): those measurements are never delivered (counted in
        ``measurements_occluded``). One window per robot; a new one replaces it."""
        self._occluded[int(i)] = (float(t0_s), float(t1_s))

    @property
    def n(self) -> int:
        """Number of robots the camera expects in each truth array."""
        return self._n

    def resize(self, n: int) -> None:
        """Change the number of robots (after ``Plant.add_robot`` / ``remove_robot``).

        Frames already in flight keep the indices they were taken with.
        """
        if int(n) < 0:
            raise ValueError(f"n must be >= 0, got {n}")
        self._n = int(n)

    @property
    def next_frame_t(self) -> float:
        """Nominal exposure time of the next frame, seconds."""
        return self._next_t

    @property
    def in_flight(self) -> int:
        """Frames taken but not yet delivered."""
        return len(self._queue)

    def capture(self, t_s: float, truth: npt.ArrayLike) -> bool:
        """Take a frame of ``truth`` (``(n, 3)``) if one is due at ``t_s``; True if one was taken.

        A frame counts as taken even if it is then dropped (``frame_drop_prob``).
        """
        t = float(t_s)
        if t + _TIME_EPS_S < self._next_t:
            return False
        n = self._n
        rows: Sequence[PoseRow] | None = None
        pose: FloatArray | None = None
        if n <= SMALL_N:
            rows = self._rows_of(truth)
        else:
            pose = np.asarray(truth, dtype=np.float64)
            if pose.shape != (n, 3):
                raise ValueError(f"truth must have shape ({n}, 3), got {pose.shape}")
        # Index of the latest nominal frame time <= t; the ones between were never exposed.
        k_now = math.floor((t - self._t0_s) * self.rate_hz + _TIME_EPS_S * self.rate_hz)
        k_now = max(k_now, self._next_k)
        self.frames_missed += k_now - self._next_k
        self._next_k = k_now + 1
        self._next_t = self._t0_s + self._next_k / self.rate_hz
        self.frames_taken += 1

        rng = self._rng
        if self.frame_drop_prob > 0.0:
            assert rng is not None
            if rng.random() < self.frame_drop_prob:
                self.frames_dropped += 1
                return True
        if rows is not None:
            self._capture_rows(t, rows)
            return True
        assert pose is not None
        meas = pose.copy()
        if self.pos_std_m > 0.0 or self.theta_std_rad > 0.0:
            assert rng is not None
            noise = rng.standard_normal((n, 3))
            meas[:, 0:2] += self.pos_std_m * noise[:, 0:2]
            meas[:, 2] += self.theta_std_rad * noise[:, 2]
        meas[:, 2] = wrap_angles(meas[:, 2])
        ids = np.arange(n, dtype=np.int64)
        if self.miss_prob > 0.0:
            assert rng is not None
            seen = rng.random(n) >= self.miss_prob
            self.measurements_missed += int(n - np.count_nonzero(seen))
            ids = ids[seen]
            meas = meas[seen]
        self._queue.append(CameraFrame(t, t + self.latency_s, ids, meas))
        return True

    def _rows_of(self, truth: npt.ArrayLike) -> Sequence[PoseRow]:
        """``truth`` as ``n`` float triples, or the ValueError of the array path."""
        n = self._n
        if type(truth) is PoseRows and len(truth) == n:
            return truth  # the plant's own float triples, immutable
        if isinstance(truth, np.ndarray) and truth.shape == (n, 3):
            truth = truth.astype(np.float64, copy=False).tolist()
        seq: Any = truth
        try:
            rows = [(float(x), float(y), float(th)) for x, y, th in seq]
        except (TypeError, ValueError):
            rows = []
        if len(rows) != n:
            shape = np.shape(truth) if isinstance(truth, np.ndarray) else "not (n, 3) numbers"
            raise ValueError(f"truth must have shape ({n}, 3), got {shape}")
        return rows

    def _capture_rows(self, t: float, rows: Sequence[PoseRow]) -> None:
        """Noise, wrap and dropouts of one frame in plain Python (the small-fleet path).

        The arithmetic of the array path element by element; the wrap is
        :func:`~sim_plant.core.plant.wrap_angle` inlined (float ``%`` is ``np.mod`` bit for bit).
        """
        rng = self._rng
        ps, ts = self.pos_std_m, self.theta_std_rad
        n = self._n
        meas: list[PoseRow] = []
        # typed: the compiled build (sim_plant.core._accel) keeps these as C doubles
        nx: float
        ny: float
        nt: float
        if ps > 0.0 or ts > 0.0:
            assert rng is not None
            noise: list[list[float]] = rng.standard_normal(out=self._noise_out(n)).tolist()
            # indexed, not zipped: typed views read natively when compiled (no iterator)
            seq: tuple[PoseRow, ...] = rows if isinstance(rows, tuple) else tuple(rows)
            nz: list[float]
            for j in range(n):
                x, y, th = seq[j]
                nz = noise[j]
                nx = nz[0]
                ny = nz[1]
                nt = nz[2]
                r = (_PI - (th + ts * nt)) % _TWO_PI
                meas.append((x + ps * nx, y + ps * ny, _PI - (r if r < _TWO_PI else 0.0)))
        else:
            for x, y, th in rows:
                r = (_PI - th) % _TWO_PI
                meas.append((x, y, _PI - (r if r < _TWO_PI else 0.0)))
        ids: Sequence[int] = range(n)  # immutable, shared by the frames
        if self.miss_prob > 0.0:
            assert rng is not None
            seen = (rng.random(n) >= self.miss_prob).tolist()
            self.measurements_missed += n - sum(seen)
            ids = [i for i, ok in zip(ids, seen, strict=True) if ok]
            meas = [m for m, ok in zip(meas, seen, strict=True) if ok]
        self._queue.append(_tuple_new(_RowFrame, (t, t + self.latency_s, ids, meas)))

    def _noise_out(self, n: int) -> FloatArray:
        """The ``(n, 3)`` array a frame's noise is drawn into (kept: one allocation less a
        frame; ``standard_normal(out=)`` draws the numbers of ``standard_normal((n, 3))``)."""
        buf = self._noise_buf
        if buf.shape[0] != n:
            buf = self._noise_buf = np.empty((n, 3), dtype=np.float64)
        return buf

    def _due(self, t_s: float) -> list[CameraFrame | _RowFrame]:
        t = float(t_s) + _TIME_EPS_S
        out: list[CameraFrame | _RowFrame] = []
        queue = self._queue
        # Constant latency and increasing stamps: the deque is sorted by delivery time.
        while queue and queue[0].deliver_t <= t:
            frame = queue.popleft()
            if self._occluded:
                frame = self._without_occluded(frame)
            self.measurements_delivered += len(frame.ids)
            out.append(frame)
        return out

    def _without_occluded(self, frame: CameraFrame | _RowFrame) -> CameraFrame | _RowFrame:
        stamp = frame.stamp_t
        ids = list(frame.ids) if isinstance(frame, _RowFrame) else frame.ids.tolist()
        keep = [
            j
            for j, i in enumerate(ids)
            if not (i in self._occluded and self._occluded[i][0] <= stamp < self._occluded[i][1])
        ]
        if len(keep) == len(ids):
            return frame
        self.measurements_occluded += len(ids) - len(keep)
        if isinstance(frame, _RowFrame):
            return _RowFrame(
                frame.stamp_t,
                frame.deliver_t,
                [ids[j] for j in keep],
                [frame.poses[j] for j in keep],
            )
        return CameraFrame(
            frame.stamp_t, frame.deliver_t, frame.ids[keep], frame.poses[keep].reshape(-1, 3)
        )

    def poll_frames(self, t_s: float) -> list[CameraFrame]:
        """Frames whose delivery time is <= ``t_s``, oldest first (array form, for large n)."""
        out: list[CameraFrame] = []
        for f in self._due(t_s):
            if isinstance(f, _RowFrame):
                ids = np.array(f.ids, dtype=np.int64)
                poses = np.array(f.poses, dtype=np.float64).reshape(len(f.poses), 3)
                out.append(CameraFrame(f.stamp_t, f.deliver_t, ids, poses))
            else:
                out.append(f)
        return out

    def poll(self, t_s: float) -> list[tuple[int, float, float, float, float]]:
        """Due measurements as ``(i, stamp_t, x_m, y_m, theta_rad)``, oldest frame first."""
        # items typed Any: each tuple is built from the objects as they are (not unboxed and
        # boxed again for a list of typed tuples, when compiled)
        out: list[Any] = []
        for frame in self._due(t_s):
            stamp: Any = frame.stamp_t  # (a float object: passed on, not boxed per robot)
            if isinstance(frame, _RowFrame):
                poses: list[Any] = frame.poses  # (Any: not unboxed when compiled)
                p: tuple[Any, ...]  # (x, y, theta): its numbers passed on as they are
                for i, p in zip(frame.ids, poses, strict=True):
                    out.append((i, stamp, p[0], p[1], p[2]))
            else:  # lists, not tuples: unpacked as such (the compiled build checks the types)
                rows: list[list[float]] = frame.poses.tolist()
                ids: list[int] = frame.ids.tolist()
                out.extend([(i, stamp, r[0], r[1], r[2]) for i, r in zip(ids, rows, strict=True)])
        return out


class _InFlight:
    """Messages sent together (one :meth:`CommandLink.send_all` or one :meth:`CommandLink.send`)
    and not delivered yet, in send order: robot ``dest[j]`` gets ``cmds[j]`` at ``when_s[j]``;
    ``lo_s`` and ``hi_s`` are the earliest and the latest of ``when_s``. Three flat lists and no
    tuple per message (the compiled build would unbox a typed tuple and box it again at each
    step); a batch whose messages are all due is delivered without looking at their times."""

    def __init__(
        self, dest: list[int], cmds: list[Any], when_s: list[float], lo_s: float, hi_s: float
    ) -> None:
        self.dest = dest
        self.cmds = cmds
        self.when_s = when_s
        self.lo_s = lo_s
        self.hi_s = hi_s

    def split(self, t: float) -> tuple[list[int], _InFlight | None]:
        """Positions of the messages due by ``t`` (in send order), and the batch of the rest
        (None if none is left)."""
        due: list[int] = []
        dest: list[int] = []
        cmds: list[Any] = []
        when: list[float] = []
        lo = math.inf
        hi = -math.inf
        w: float
        for j, w in enumerate(self.when_s):
            if w <= t:
                due.append(j)
            else:
                dest.append(self.dest[j])
                cmds.append(self.cmds[j])
                when.append(w)
                if w < lo:
                    lo = w
                if w > hi:
                    hi = w
        return due, (_InFlight(dest, cmds, when, lo, hi) if dest else None)


class CommandLink(Generic[CmdT]):
    """Delayed, jittered, lossy delivery of commands to robots (one-way link).

    Args:
        latency_s: fixed part of the delay, seconds.
        jitter_s: extra delay drawn uniformly from ``[0, jitter_s)`` per message, seconds.
        loss_prob: probability that a message is lost.
        rng: source of all randomness; may be ``None`` only if jitter and loss are zero.
        fifo: keep per-robot order (a message never overtakes an earlier one to the same robot).

    Counters: ``sent`` (every :meth:`send`), ``dropped`` (lost), ``delivered`` (returned by
    :meth:`poll`); ``in_flight`` = sent - dropped - delivered. Robots are indices ``i >= 0``.
    """

    def __init__(
        self,
        latency_s: float = 0.01,
        jitter_s: float = 0.0,
        loss_prob: float = 0.0,
        rng: np.random.Generator | None = None,
        *,
        fifo: bool = True,
    ) -> None:
        self.latency_s = _check_nonneg("latency_s", latency_s)
        self.jitter_s = _check_nonneg("jitter_s", jitter_s)
        self.loss_prob = _check_prob("loss_prob", loss_prob)
        if rng is None and (self.jitter_s > 0.0 or self.loss_prob > 0.0):
            raise ValueError("rng is required when jitter or loss is configured")
        self._rng = rng
        self.fifo = bool(fifo)
        # Messages in flight, in batches in send order (sends append a batch; a poll keeps the
        # order of the rest). Delivery order is the order of (delivery time, send order).
        self._batches: list[_InFlight] = []
        self._in_flight = 0
        # Some message in flight was sent without fifo: per robot, send order may then differ
        # from delivery order (poll_into must sort). Cleared when the link is empty.
        self._unordered = False
        self._last_deliver: list[float] = []  # per robot, its last message's delivery time (fifo)
        self._draws: FloatArray = np.empty(0, dtype=np.float64)
        self.sent = 0
        self.dropped = 0
        self.delivered = 0

    @property
    def in_flight(self) -> int:
        """Messages queued and not yet delivered."""
        return self._in_flight

    def _grow(self, m: int) -> list[float]:
        """The per-robot delivery times, for robots ``0 .. m - 1`` at least."""
        last = self._last_deliver
        if len(last) < m:
            last.extend([-math.inf] * (m - len(last)))
        return last

    def _enqueue(
        self, dest: list[int], cmds: list[Any], when: list[float], lo: float, hi: float
    ) -> None:
        self._batches.append(_InFlight(dest, cmds, when, lo, hi))
        self._in_flight += len(dest)
        if not self.fifo:
            self._unordered = True

    def send(self, t_s: float, i: int, cmd: CmdT) -> float | None:
        """Send ``cmd`` to robot ``i`` at ``t_s``; returns its delivery time, or None if lost."""
        t = float(t_s)
        if not math.isfinite(t):
            raise ValueError(f"t_s must be finite, got {t_s!r}")
        robot = int(i)
        if robot < 0:
            raise ValueError(f"i must be a robot index >= 0, got {i!r}")
        self.sent += 1
        rng = self._rng
        # Draw loss then jitter for every message so the random stream does not depend on outcome.
        lost = False
        if self.loss_prob > 0.0:
            assert rng is not None
            lost = bool(rng.random() < self.loss_prob)
        extra = 0.0
        if self.jitter_s > 0.0:
            assert rng is not None
            extra = float(rng.random()) * self.jitter_s
        if lost:
            self.dropped += 1
            return None
        deliver = t + self.latency_s + extra
        if self.fifo:
            last = self._grow(robot + 1)
            deliver = max(deliver, last[robot])
            last[robot] = deliver
        self._enqueue([robot], [cmd], [deliver], deliver, deliver)
        return deliver

    def send_all(self, t_s: float, cmds: Sequence[CmdT]) -> None:
        """Send ``cmds[i]`` to robot ``i`` for every ``i``, at ``t_s``.

        The same as ``send(t_s, i, cmds[i])`` for i = 0, 1, ... in turn (same random stream,
        same delivery times, same order), with one draw of the random numbers for all of them.
        """
        t = float(t_s)
        if not math.isfinite(t):
            raise ValueError(f"t_s must be finite, got {t_s!r}")
        m = len(cmds)
        self.sent += m
        loss_p = self.loss_prob
        jitter = self.jitter_s
        # per message its loss draw, then its jitter draw: message i's are u[stride * i] and
        # u[stride * i + 1] when both are drawn, else the one drawn is u[i]
        u: list[float] = []
        stride = 2 if loss_p > 0.0 and jitter > 0.0 else 1
        if (loss_p > 0.0 or jitter > 0.0) and m:
            rng = self._rng
            assert rng is not None
            u = rng.random(out=self._draws_out(stride * m)).tolist()
        lossy = loss_p > 0.0
        jittery = jitter > 0.0
        ji = stride - 1  # the jitter draw's offset
        items: list[Any] = cmds if type(cmds) is list else list(cmds)  # (read natively)
        base = t + self.latency_s
        fifo = self.fifo
        last = self._grow(m) if fifo else self._last_deliver
        dest: list[int] = []
        out: list[Any] = []
        when: list[float] = []
        lo = math.inf
        hi = -math.inf
        lost = 0
        for i in range(m):
            if lossy and u[stride * i] < loss_p:
                lost += 1
                continue
            deliver = base + u[stride * i + ji] * jitter if jittery else base
            if fifo:
                prev = last[i]
                if prev > deliver:
                    deliver = prev
                last[i] = deliver
            dest.append(i)
            out.append(items[i])
            when.append(deliver)
            if deliver < lo:
                lo = deliver
            if deliver > hi:
                hi = deliver
        self.dropped += lost
        if dest:
            self._enqueue(dest, out, when, lo, hi)

    def _draws_out(self, size: int) -> FloatArray:
        """The array a tick's ``size`` uniform draws go into (kept: one allocation less a tick;
        ``random(out=)`` draws the numbers of ``random(size)``)."""
        buf = self._draws
        if buf.shape[0] != size:
            buf = self._draws = np.empty(size, dtype=np.float64)
        return buf

    def poll(self, t_s: float) -> list[tuple[int, CmdT]]:
        """Messages due by ``t_s`` as ``(i, cmd)``, in delivery order (ties in send order)."""
        return [(i, cmd) for _, i, cmd in self._take_due(t_s)]

    def poll_into(self, t_s: float, latest: list[CmdT]) -> int:
        """:meth:`poll` written into ``latest``: each due message's command into ``latest[i]``
        in delivery order (the last one delivered to a robot stays); returns how many. The same
        as ``for i, cmd in poll(t_s): latest[i] = cmd``, without a pair per message.

        With fifo, a robot's messages are delivered in the order they were sent, so the last
        one delivered to a robot is the last one sent among its due messages: they are written
        in send order, batch by batch, with no sort (the same final ``latest``)."""
        if self._unordered:
            due = self._take_due(t_s)
            for m in due:
                latest[m[1]] = m[2]
            return len(due)
        t = float(t_s) + _TIME_EPS_S
        batches = self._batches
        if not batches:
            return 0
        keep: list[_InFlight] = []
        count = 0
        for b in batches:
            if b.hi_s <= t:  # all due (the usual case: latency + jitter within a tick)
                dest = b.dest
                cmds = b.cmds
                for j in range(len(dest)):
                    latest[dest[j]] = cmds[j]
                count += len(dest)
            elif b.lo_s > t:  # none due
                keep.append(b)
            else:
                pos, rest = b.split(t)
                for j in pos:
                    latest[b.dest[j]] = b.cmds[j]
                count += len(pos)
                if rest is not None:
                    keep.append(rest)
        self._batches = keep
        self._delivered(count)
        return count

    def _delivered(self, count: int) -> None:
        self._in_flight -= count
        self.delivered += count
        if not self._in_flight:
            self._unordered = False

    def _take_due(self, t_s: float) -> list[tuple[float, int, Any]]:
        """The messages due by ``t_s`` as ``(deliver_t, i, cmd)``, taken out of the queue
        (counted as delivered), in delivery order (ties in send order)."""
        t = float(t_s) + _TIME_EPS_S
        due: list[tuple[float, int, Any]] = []
        keep: list[_InFlight] = []
        for b in self._batches:
            if b.hi_s <= t:
                due.extend(zip(b.when_s, b.dest, b.cmds, strict=True))
            elif b.lo_s > t:
                keep.append(b)
            else:
                pos, rest = b.split(t)
                due.extend([(b.when_s[j], b.dest[j], b.cmds[j]) for j in pos])
                if rest is not None:
                    keep.append(rest)
        if not due:
            return due
        self._batches = keep
        # Delivery order, ties in send order: the messages are collected in send order and the
        # sort is stable, so sorting on deliver_t alone gives exactly that order, comparing C
        # floats instead of tuples (a float key is list.sort's fast path).
        due.sort(key=_deliver_t)
        self._delivered(len(due))
        return due
