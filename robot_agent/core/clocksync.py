"""Clocks across hosts: a remote stamp on the local clock (one-way-delay lower envelope).

Pure and stdlib only, time passed in (docs/clocks.md). In realtime every ``t`` on the bus is the
publishing host's ``time.monotonic()``: two hosts' monotonic clocks differ by an arbitrary
offset (their boot times) and drift apart slowly (crystal tolerance, tens of ppm). A pose's
capture time is on the camera host's clock; the firmware's estimator needs it on the robot's.

The estimate: for every message from a source, ``rx_local - t_remote = offset + delay`` where
``delay >= 0`` is the one-way transport delay. Over a sliding window the minimum of these
samples is ``offset + d_min``: the lower envelope. :meth:`ClockOffset.to_local` maps a remote
time to ``t_remote + offset_est``, later than the truth by the least delay seen in the window
(sub-millisecond on a LAN, microseconds on one host) and never later than the receipt: the
age ``now - to_local(t)`` is correct within the link's delay above its minimum (its jitter).

Which ``t`` feeds the envelope matters: it must be the *publication* time (the moment the message
left the remote host), not the capture time, or the camera pipeline's own latency would be
taken for clock offset and the latency compensation lost. A ``PoseBatch`` carries both (``t``
published, ``stamp`` captured, one clock); a ``Pose`` carries ``pub_t`` when its publisher
sets it (else its capture ``t`` is the best there is, documented as a fallback).

The window (default 10 s) follows drift: at 50 ppm two clocks move 0.5 ms apart in 10 s. A step
of the remote clock (a restarted publisher: a new monotonic origin) is detected when a sample
lies more than ``step_s`` *below* the envelope (a message cannot arrive before it was sent, so
the envelope must not stay above it): the window restarts from that sample. A step the other
way (the remote clock jumped back, samples suddenly larger) ages out within one window; until
then ages read too small by the step, and the estimator's own ``future_tolerance_s`` and
plausibility checks still apply. Non-finite samples are rejected and counted.
"""

from __future__ import annotations

import math
from collections import deque
from typing import Final

__all__ = ["ClockOffset", "ClockOffsets"]

DEFAULT_WINDOW_S: Final = 10.0
DEFAULT_STEP_S: Final = 0.5
MAX_SOURCES: Final = 1024

_isfinite = math.isfinite


class ClockOffset:
    """Offset of one remote clock to the local one: ``local = remote + offset_s``.

    Args:
        window_s: samples older than this (local receive time) leave the envelope.
        step_s: a sample this far below the envelope restarts it (the remote clock stepped).
    """

    __slots__ = ("_samples", "rejected", "resets", "samples", "step_s", "window_s")

    def __init__(self, window_s: float = DEFAULT_WINDOW_S, step_s: float = DEFAULT_STEP_S) -> None:
        if not window_s > 0.0 or not step_s > 0.0:
            raise ValueError("window_s and step_s must be > 0")
        self.window_s = window_s
        self.step_s = step_s
        # (rx_local, rx_local - t_remote), increasing in the second field: a monotonic deque,
        # so the front is the window's minimum (amortised O(1) per sample)
        self._samples: deque[tuple[float, float]] = deque()
        self.samples = 0
        self.rejected = 0
        self.resets = 0

    def observe(self, t_remote_s: float, rx_local_s: float) -> bool:
        """One message published at ``t_remote_s`` (remote clock), received at ``rx_local_s``
        (local clock). False (counted) if a value is not finite."""
        if not (_isfinite(t_remote_s) and _isfinite(rx_local_s)):
            self.rejected += 1
            return False
        d = rx_local_s - t_remote_s
        q = self._samples
        if q and d < q[0][1] - self.step_s:  # the remote clock stepped: start again
            q.clear()
            self.resets += 1
        while q and q[-1][1] >= d:
            q.pop()
        q.append((rx_local_s, d))
        horizon = rx_local_s - self.window_s
        while len(q) > 1 and q[0][0] < horizon:
            q.popleft()
        self.samples += 1
        return True

    @property
    def offset_s(self) -> float | None:
        """The estimate ``min (rx_local - t_remote)`` over the window, None before a sample."""
        q = self._samples
        return q[0][1] if q else None

    def to_local(self, t_remote_s: float, rx_local_s: float | None = None) -> float | None:
        """``t_remote_s`` on the local clock (None before a sample); with ``rx_local_s`` (the
        receipt of the message that carried it) never later than that receipt."""
        off = self.offset_s
        if off is None:
            return None
        t = t_remote_s + off
        if rx_local_s is not None and t > rx_local_s:
            return rx_local_s
        return t


class ClockOffsets:
    """One :class:`ClockOffset` per source (a key expression), at most ``MAX_SOURCES``."""

    __slots__ = ("_by_source", "step_s", "window_s")

    def __init__(self, window_s: float = DEFAULT_WINDOW_S, step_s: float = DEFAULT_STEP_S) -> None:
        self.window_s = window_s
        self.step_s = step_s
        self._by_source: dict[str, ClockOffset] = {}

    def observe(self, source: str, t_remote_s: float, rx_local_s: float) -> ClockOffset | None:
        """Feed one sample of ``source``; its estimator (None when the table is full)."""
        c = self._by_source.get(source)
        if c is None:
            if len(self._by_source) >= MAX_SOURCES:
                return None
            c = self._by_source[source] = ClockOffset(self.window_s, self.step_s)
        c.observe(t_remote_s, rx_local_s)
        return c

    def capture_to_local(
        self, source: str, pub_t_s: float, capture_t_s: float, rx_local_s: float
    ) -> float:
        """The capture time ``capture_t_s`` of a message published at ``pub_t_s`` (both on the
        source's clock) on the local clock; the receipt ``rx_local_s`` if nothing is known."""
        c = self.observe(source, pub_t_s, rx_local_s)
        if c is None:
            return rx_local_s
        t = c.to_local(capture_t_s, rx_local_s)
        return rx_local_s if t is None else t

    def get(self, source: str) -> ClockOffset | None:
        return self._by_source.get(source)

    def __len__(self) -> int:
        return len(self._by_source)
