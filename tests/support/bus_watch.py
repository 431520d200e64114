"""Watching the bus from a test: :class:`Recorder` keeps every sample of a key expression with its
receive time, decoded by a strict :func:`decoder_of` that fails the test on a node's invalid
message."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Any

import zenoh

from bus_schemas import decode


class Recorder:
    """Every sample of ``key_expr`` as ``(rx monotonic s, key, decoded)``, in arrival order.

    The callback runs on Zenoh's network thread (``indirect=False``): the receive time is taken
    as the sample arrives and samples of different keys keep their order.
    """

    def __init__(
        self, session: zenoh.Session, key_expr: str, decoder: Callable[[bytes], Any]
    ) -> None:
        self.items: list[tuple[float, str, Any]] = []
        self._decoder = decoder
        self._lock = threading.Lock()
        self._sub = session.declare_subscriber(
            key_expr, zenoh.handlers.Callback(self._on_sample, indirect=False)
        )

    def _on_sample(self, sample: zenoh.Sample) -> None:
        rx = time.monotonic()
        msg = self._decoder(sample.payload.to_bytes())
        with self._lock:
            self.items.append((rx, str(sample.key_expr), msg))

    def snapshot(self) -> list[tuple[float, str, Any]]:
        with self._lock:
            return list(self.items)

    def clear(self) -> None:
        with self._lock:
            self.items.clear()

    def wait_for(
        self, predicate: Callable[[float, str, Any], bool], timeout_s: float = 5.0
    ) -> tuple[float, str, Any]:
        """The first recorded item matching ``predicate`` (waits for it; fails on timeout)."""
        deadline = time.monotonic() + timeout_s
        seen = 0
        while True:
            items = self.snapshot()
            for item in items[seen:]:
                if predicate(*item):
                    return item
            seen = len(items)
            if time.monotonic() > deadline:
                tail = [m for _, _, m in items[-3:]]
                raise AssertionError(f"no matching message within {timeout_s} s; last: {tail}")
            time.sleep(0.002)


def decoder_of(cls: Any) -> Callable[[bytes], Any]:
    """Strict decoder for ``cls`` that fails the test on a bad payload from a node."""

    def dec(data: bytes) -> Any:
        msg = decode(data, cls)
        assert not hasattr(msg, "reason"), f"a node published an invalid {cls.__name__}: {msg}"
        return msg

    return dec
