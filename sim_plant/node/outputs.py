"""The plant process's outputs: truth, the emulated camera's frames (``poses`` batches, then
each robot's ``pose``; lockstep: each robot's ``truth`` and ``pose`` only while someone
subscribes to it) and, in realtime, the bookkeeping of each published frame that gives the
control-loop latency (frame published -> command received) and the frames' lateness.

:class:`PlantOutputs` is a part the plant (:class:`sim_plant.node.plant.PlantNode`) builds and
owns, as it owns its :class:`~sim_plant.node.inputs.PlantInputs`: it is given the keys' fleet, the
robots and the ``publish`` callable, and keeps the sequence numbers and the latency bookkeeping.
The publication order is the in-process simulator's (docs/process-shells.md): lockstep runs over the
bus reproduce it bit for bit (tests/bus/test_node_plant.py).
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Callable, Sequence
from typing import Any, Final

import numpy as np
import numpy.typing as npt

import runtime as rt
from bus_schemas import BATCH_CHUNK, Pose, PoseBatch, Truth, TruthBatch, encode, keys
from sim_plant.core.sensors import Camera

__all__ = [
    "FRAMES_REMEMBERED",
    "LATENCY_SAMPLES",
    "STEADY_TAIL_S",
    "STEADY_WARMUP_S",
    "PlantOutputs",
]

FRAMES_REMEMBERED: Final = 64
"""Published frames whose stamps a returning command may still name (2 s at 30 Hz)."""
STEADY_WARMUP_S: Final = 2.0
"""Steady-state latency excludes frames published in the first 2 s after the first answer (the
agents' start: imports, first assignment, first-call costs) ..."""
LATENCY_SAMPLES: Final = 500_000
"""Realtime latency / lateness samples kept (the newest)."""
STEADY_TAIL_S: Final = 0.5
"""... and in the last 0.5 s of frames (the run's shutdown: agents stop before the plant)."""


def _percentiles_ms(samples_s: Any) -> dict[str, float] | None:
    """p50 / p99 / max of a numpy array of seconds, in ms (None when empty)."""
    if not samples_s.size:
        return None
    arr = samples_s * 1e3
    p50, p99 = np.percentile(arr, [50.0, 99.0])
    return {"p50": float(p50), "p99": float(p99), "max": float(arr.max())}


class PlantOutputs:
    """Truth and camera-frame publication of the plant, and the realtime latency bookkeeping.

    Args:
        ids: the simulated robots, in robot order.
        fleet: the fleet name (the keys).
        publish: ``publish(key, payload, qos)``.
        batch: truth as TruthBatch and frames as PoseBatch only (agent hosts, ``--batch``).
        poses: publish camera frames (False: a real tracker publishes the poses).
        lockstep: every output must arrive and keep its order (QoS); no latency bookkeeping;
            and truth and frames as the batches (:attr:`batched`), which every node of a
            lockstep run reads (the agents take their own pose from the frame); each robot's
            ``truth`` and ``pose`` only while ``wanted(key, qos)`` says a subscriber matches it
            (a recorder, a bridge, an outsider): a tick then puts two messages where it put
            2n + 2 (docs/benchmarks.md, "Lockstep on the batched plant outputs").
        wanted: ``wanted(key, qos)``, whether anyone subscribes to ``key`` now
            (``runtime.Publishers.matching``); None: nobody (lockstep only).
    """

    def __init__(
        self,
        ids: Sequence[str],
        fleet: str,
        publish: Any,
        *,
        batch: bool,
        poses: bool,
        lockstep: bool,
        wanted: Callable[[str, rt.QoS], bool] | None = None,
    ) -> None:
        self.ids = list(ids)
        self._wanted = wanted
        self._publish = publish
        self.batch = batch
        self.batched = batch or lockstep  # truth as TruthBatch (frames are batched always)
        self.poses = poses
        self.lockstep = lockstep
        self.poses_key = keys.poses_key(fleet)
        self.truths_key = keys.truths_key(fleet)
        self.pose_keys = [keys.pose_key(fleet, r) for r in self.ids]
        self.truth_keys = [keys.truth_key(fleet, r) for r in self.ids]
        # Lockstep: poses must precede the clock (same session, same priority) and arrive.
        self.data_qos = rt.QOS_CRITICAL if lockstep else rt.QOS_CONTROL
        self.truth_qos = rt.QOS_CRITICAL if lockstep else rt.QOS_TELEMETRY
        self._seq: dict[str, int] = {}
        # Realtime control-loop latency (docs/scale.md): frame stamp -> when its poses were
        # published; a command whose pose_t is such a stamp came back after rx - published.
        self._frame_pub: dict[float, float] = {}
        self._frame_order: deque[float] = deque()
        self.latencies_s: deque[float] = deque(maxlen=LATENCY_SAMPLES)
        self.latency_pub_s: deque[float] = deque(maxlen=LATENCY_SAMPLES)  # when each frame left
        self.frames_published = 0
        self._answered: list[float | None] = [None] * len(self.ids)  # last frame stamp answered
        self.frame_lateness_s: deque[float] = deque(maxlen=LATENCY_SAMPLES)

    def next_seq(self, key: str) -> int:
        """The next sequence number on ``key`` (every key the plant publishes on)."""
        n = self._seq.get(key, 0) + 1
        self._seq[key] = n
        return n

    def command_answered(self, i: int, pose_t: float | None, rx_s: float) -> None:
        """Realtime: robot ``i``'s command computed from the frame stamped ``pose_t`` arrived at
        ``rx_s``: the first one for that frame is a latency sample."""
        if pose_t is not None and pose_t != self._answered[i]:
            published = self._frame_pub.get(pose_t)
            if published is not None:  # the first command computed from this frame
                self._answered[i] = pose_t
                self.latencies_s.append(rx_s - published)
                self.latency_pub_s.append(published)

    def publish_truth(self, t_s: float, truth: npt.NDArray[np.float64]) -> None:
        t = max(t_s, 0.0)
        if self.batched:
            self._publish_truth_batch(t, truth)
        if self.batch:
            return
        for i, row in enumerate(truth.tolist()):
            key = self.truth_keys[i]
            if self.lockstep and not self._read(key, self.truth_qos):
                continue
            msg = Truth(
                t=t, seq=self.next_seq(key), x=row[0], y=row[1], theta=row[2], robot=self.ids[i]
            )
            self._publish(key, encode(msg), self.truth_qos)

    def _publish_truth_batch(self, t: float, truth: npt.NDArray[np.float64]) -> None:
        """``--batch`` and lockstep: truth as TruthBatch chunks on ``truths`` instead of one key
        per robot."""
        rows = truth.tolist()
        for start in range(0, len(rows), BATCH_CHUNK):
            chunk = rows[start : start + BATCH_CHUNK]
            msg = TruthBatch(
                t=t,
                seq=self.next_seq(self.truths_key),
                robots=tuple(self.ids[start : start + len(chunk)]),
                x=tuple(r[0] for r in chunk),
                y=tuple(r[1] for r in chunk),
                theta=tuple(r[2] for r in chunk),
                stamp=t,
            )
            self._publish(self.truths_key, encode(msg), self.truth_qos)

    def _publish_frame(
        self,
        t_s: float,
        stamp_t: float,
        rows: list[tuple[int, float, float, float, float]],
        latency_s: float,
    ) -> None:
        """One camera frame: the batch first, then each robot's pose (``t`` = capture time)."""
        if not self.poses:
            return  # --no-poses: the camera emulation is off (localization/core/rendered.py)
        stamp = max(stamp_t, 0.0)
        for start in range(0, len(rows), BATCH_CHUNK):
            chunk = rows[start : start + BATCH_CHUNK]
            batch = PoseBatch(
                t=max(t_s, 0.0),
                seq=self.next_seq(self.poses_key),
                robots=tuple(self.ids[r[0]] for r in chunk),
                x=tuple(r[2] for r in chunk),
                y=tuple(r[3] for r in chunk),
                theta=tuple(r[4] for r in chunk),
                stamp=stamp,
            )
            self._publish(self.poses_key, encode(batch), self.data_qos)
        if not self.lockstep:
            # due: when the camera model delivers it (exposure + latency, sensors.Camera)
            self._frame_published(stamp, stamp + latency_s)
        if self.batch:
            return  # agent hosts and a --batch coordinator read the batches only
        for i, _, x, y, theta in rows:
            key = self.pose_keys[i]
            if self.lockstep and not self._read(key, self.data_qos):
                continue  # (every lockstep node reads the batch)
            msg = Pose(
                t=stamp,
                seq=self.next_seq(key),
                x=x,
                y=y,
                theta=theta,
                robot=self.ids[i],
                pub_t=max(t_s, 0.0),
            )
            self._publish(key, encode(msg), self.data_qos)

    def _read(self, key: str, qos: rt.QoS) -> bool:
        """Lockstep: whether a subscriber matches a per-robot ``key`` now."""
        return self._wanted is not None and self._wanted(key, qos)

    def _frame_published(self, stamp: float, due_s: float) -> None:
        """Realtime bookkeeping of a published frame (latency and lateness, see status)."""
        now = time.monotonic()
        self.frames_published += 1
        self.frame_lateness_s.append(max(0.0, now - due_s))
        self._frame_pub[stamp] = now
        self._frame_order.append(stamp)
        while len(self._frame_order) > FRAMES_REMEMBERED:
            self._frame_pub.pop(self._frame_order.popleft(), None)

    def latency_stats(self) -> dict[str, Any]:
        """Control-loop latency (frame published -> command received, ms) and frame lateness
        (frame published after its due time, ms), p50/p99/max over the run (realtime).

        ``latency_steady_ms`` is the same over the steady state: frames published from
        STEADY_WARMUP_S after the first answered frame to STEADY_TAIL_S before the last one.
        """
        out: dict[str, Any] = {"frames": self.frames_published, "commands": len(self.latencies_s)}
        for name, samples in (
            ("latency_ms", self.latencies_s),
            ("lateness_ms", self.frame_lateness_s),
        ):
            out[name] = _percentiles_ms(np.fromiter(samples, dtype=float))
        lat = np.fromiter(self.latencies_s, dtype=float)
        pub = np.fromiter(self.latency_pub_s, dtype=float)
        if lat.size and pub.size == lat.size:
            lo, hi = pub.min() + STEADY_WARMUP_S, pub.max() - STEADY_TAIL_S
            steady = lat[(pub >= lo) & (pub <= hi)]
            out["latency_steady_ms"] = _percentiles_ms(steady)
            out["steady_window_s"] = [STEADY_WARMUP_S, STEADY_TAIL_S]
        else:
            out["latency_steady_ms"] = None
        return out

    def publish_due_frames(self, camera: Camera, t_s: float) -> None:
        """Publish every camera frame delivered by ``t_s`` (``Camera.poll``, as the simulator)."""
        due = camera.poll(t_s)
        start = 0
        while start < len(due):  # oldest frame first; the entries of one frame share a stamp
            stamp = due[start][1]
            end = start + 1
            while end < len(due) and due[end][1] == stamp:
                end += 1
            self._publish_frame(t_s, stamp, due[start:end], camera.latency_s)
            start = end
