"""How a ``formation up`` run is asked to stop: SIGINT or SIGTERM to the launcher.

:class:`StopRequest` owns the stop event, the signals received and whether a second one asked to
kill everything at once; the other parts of the launcher only wait on it (:meth:`or_stop`) or
read it."""

from __future__ import annotations

import asyncio
import contextlib
import signal
from collections.abc import Awaitable, Callable
from typing import Any, Final

__all__ = ["Interrupted", "StopRequest"]

_SIGNALS: Final = (signal.SIGINT, signal.SIGTERM)


class Interrupted(Exception):
    """The launcher was asked to stop (SIGINT/SIGTERM)."""


class StopRequest:
    """The run's stop signals. The first SIGINT/SIGTERM sets :attr:`event` (the run stops and
    shuts down in order); a second one sets :attr:`kill_now` and calls ``kill_all`` (every
    process of the run is SIGKILLed now) and so does every later one."""

    def __init__(self, kill_all: Callable[[], None], warn: Callable[[str], None]) -> None:
        self._kill_all = kill_all
        self._warn = warn
        self.event = asyncio.Event()
        self.signals: list[int] = []
        self.kill_now = False

    def install(self, loop: asyncio.AbstractEventLoop) -> None:
        for sig in _SIGNALS:
            loop.add_signal_handler(sig, self.on_signal, sig)

    def remove(self, loop: asyncio.AbstractEventLoop) -> None:
        for sig in _SIGNALS:
            loop.remove_signal_handler(sig)

    def on_signal(self, signum: int) -> None:
        self.signals.append(signum)
        if self.event.is_set():
            if not self.kill_now:
                self.kill_now = True
                self._warn("second signal: killing every process of the run now")
            self._kill_all()
            return
        self.event.set()

    def first_name(self) -> str:
        """The first signal's name (``SIGINT``), for the line that says the run stops."""
        return signal.Signals(self.signals[0]).name if self.signals else "signal"

    async def or_stop(self, aw: Awaitable[Any]) -> Any:
        """Await ``aw`` unless a stop signal comes first (then raise :class:`Interrupted`)."""
        task = asyncio.ensure_future(aw)
        stopper = asyncio.ensure_future(self.event.wait())
        try:
            await asyncio.wait({task, stopper}, return_when=asyncio.FIRST_COMPLETED)
        finally:
            stopper.cancel()
        if not task.done():
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await task
            raise Interrupted
        return task.result()
