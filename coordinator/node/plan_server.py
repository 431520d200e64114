"""The coordinator's planning process: ``python -m coordinator.node.plan_server`` (issue 27).

Started by :class:`coordinator.node.plan_worker.PlanWorker` as its own child, never by hand.
Reads plan requests on stdin and writes answers on stdout, each frame a 4-byte big-endian
length and a pickle (the two ends are the same program: a request is
``coordinator.core.planning.replan.PlanRequest``, an answer ``(request id, plan or the reason
there is none, compute ms)``). One plan at a time; exits 0 at the end of its input (the
coordinator closed it or died). Its BLAS/OpenMP pools run one thread (the plan is one core's
work, docs/planning.md), and the terminal's Ctrl-C is the coordinator's to handle.
"""

from __future__ import annotations

import os
import pickle
import signal
import struct
import sys
import time
from typing import IO, Any

FRAME = struct.Struct(">I")


def timed_solve(request: Any) -> tuple[Any, float]:
    """The answer to ``request`` (``coordinator.core.planning.replan.solve``, imported here so
    the thread pools are set first) and its compute time (ms)."""
    from coordinator.core.planning.replan import solve

    started = time.perf_counter()
    answer = solve(request)
    return answer, 1e3 * (time.perf_counter() - started)


def read_frame(stream: IO[bytes]) -> bytes | None:
    """One frame's payload, or None at the end of the input."""
    head = stream.read(FRAME.size)
    if len(head) < FRAME.size:
        return None
    (n,) = FRAME.unpack(head)
    body = stream.read(n)
    return body if len(body) == n else None


def write_frame(stream: IO[bytes], payload: bytes) -> None:
    stream.write(FRAME.pack(len(payload)) + payload)
    stream.flush()


def main() -> int:
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ[var] = "1"
    src, dst = sys.stdin.buffer, sys.stdout.buffer
    while (frame := read_frame(src)) is not None:
        request = pickle.loads(frame)
        answer, ms = timed_solve(request)
        write_frame(dst, pickle.dumps((request.id, answer, ms), protocol=pickle.HIGHEST_PROTOCOL))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
