"""CommandLink delivers in the order a heap of (delivery time, send number) would pop: the link
keeps its messages in batches in send order, sorts the due ones for a poll and writes them in
send order for a FIFO poll_into (sim_plant/core/sensors.py), which must give exactly the order,
the times and the counters of the textbook priority queue, for any mix of sends, lossy and
jittered, FIFO or not (switched mid-run too), and polls (as pairs or into a list) at any
times."""

from __future__ import annotations

import heapq
import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from sim_plant.core.sensors import CommandLink


class HeapLink:
    """The reference: CommandLink.send's arithmetic with a heap (one pop per message)."""

    def __init__(self, latency_s: float, jitter_s: float, loss_prob: float, fifo: bool, seed: int):
        self.latency_s, self.jitter_s, self.loss_prob, self.fifo = (
            latency_s,
            jitter_s,
            loss_prob,
            fifo,
        )
        self.rng = np.random.default_rng(seed)
        self.heap: list[tuple[float, int, int, str]] = []
        self.seq = 0
        self.last: dict[int, float] = {}

    def send(self, t: float, i: int, cmd: str) -> None:
        lost = self.loss_prob > 0.0 and bool(self.rng.random() < self.loss_prob)
        extra = float(self.rng.random()) * self.jitter_s if self.jitter_s > 0.0 else 0.0
        if lost:
            return
        deliver = t + self.latency_s + extra
        if self.fifo:
            deliver = max(deliver, self.last.get(i, -math.inf))
            self.last[i] = deliver
        heapq.heappush(self.heap, (deliver, self.seq, i, cmd))
        self.seq += 1

    def poll(self, t: float) -> list[tuple[int, str]]:
        out = []
        while self.heap and self.heap[0][0] <= t + 1e-9:
            _, _, i, cmd = heapq.heappop(self.heap)
            out.append((i, cmd))
        return out


steps = st.lists(
    st.tuples(
        st.sampled_from(["send", "send_all", "poll", "poll_into", "fifo"]),
        st.floats(0.0, 0.05),  # time advance, s
        st.integers(0, 5),  # robot or fleet size
    ),
    max_size=60,
)


@settings(max_examples=150, deadline=None)
@given(
    steps,
    st.sampled_from([0.0, 0.01]),
    st.sampled_from([0.0, 0.005, 0.05]),
    st.sampled_from([0.0, 0.3]),
    st.booleans(),
    st.integers(0, 2**32 - 1),
)
def test_the_link_delivers_as_a_heap_would(
    script: list[tuple[str, float, int]],
    latency_s: float,
    jitter_s: float,
    loss_prob: float,
    fifo: bool,
    seed: int,
) -> None:
    rng = np.random.default_rng(seed) if jitter_s > 0.0 or loss_prob > 0.0 else None
    link: CommandLink[str] = CommandLink(latency_s, jitter_s, loss_prob, rng, fifo=fifo)
    ref = HeapLink(latency_s, jitter_s, loss_prob, fifo, seed)
    t = 0.0
    for k, (what, dt, j) in enumerate(script):
        t += dt
        if what == "send":
            link.send(t, j, f"{k}")
            ref.send(t, j, f"{k}")
        elif what == "send_all":
            cmds = [f"{k}.{i}" for i in range(j)]
            link.send_all(t, cmds)
            for i, cmd in enumerate(cmds):
                ref.send(t, i, cmd)
        elif what == "poll_into":  # the due commands written into a list by robot index
            latest = ["", "held", "", "", "", ""]
            expected = list(latest)
            due = ref.poll(t)
            for i, cmd in due:
                expected[i] = cmd
            assert link.poll_into(t, latest) == len(due)
            assert latest == expected
        elif what == "fifo":  # switched with messages in flight
            link.fifo = ref.fifo = not ref.fifo
        else:
            assert link.poll(t) == ref.poll(t)
        assert link.in_flight == len(ref.heap)
    assert link.poll(t + 1.0) == ref.poll(t + 1.0)
    assert link.in_flight == 0
    assert link.sent - link.dropped == link.delivered
