"""A thread-safe inbox of received Zenoh samples, with waits (:class:`Inbox`)."""

from __future__ import annotations

import threading
import time


class Inbox:
    """(key, payload) of received samples, thread-safe, with waits."""

    def __init__(self) -> None:
        self.items: list[tuple[str, bytes, str]] = []
        self._lock = threading.Lock()

    def __call__(self, sample) -> None:  # type: ignore[no-untyped-def]
        with self._lock:
            self.items.append((str(sample.key_expr), sample.payload.to_bytes(), str(sample.kind)))

    def has(self, key: str, payload: bytes | None = None) -> bool:
        with self._lock:
            return any(k == key and (payload is None or p == payload) for k, p, _ in self.items)

    def keys(self) -> set[str]:
        with self._lock:
            return {k for k, _, _ in self.items}

    def wait(self, key: str, payload: bytes | None = None, timeout_s: float = 5.0) -> bool:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if self.has(key, payload):
                return True
            time.sleep(0.005)
        return self.has(key, payload)
