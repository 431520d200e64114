"""Waiting on an event loop for a condition (tests of runtime.transport and runtime.lifecycle)."""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable


async def wait_until(predicate: Callable[[], bool], timeout_s: float = 5.0) -> float:
    """Yield to the loop until ``predicate()``; return the seconds waited (fails on timeout)."""
    start = time.monotonic()
    while not predicate():
        if time.monotonic() - start > timeout_s:
            raise AssertionError(f"condition not met within {timeout_s} s")
        await asyncio.sleep(0.001)
    return time.monotonic() - start
