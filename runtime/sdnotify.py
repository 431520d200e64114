"""systemd service notification (``sd_notify``) without libsystemd.

The protocol (sd_notify(3)): a service started with ``Type=notify`` finds the path of a
``AF_UNIX``/``SOCK_DGRAM`` socket in ``$NOTIFY_SOCKET`` and sends it newline-separated
``KEY=VALUE`` assignments, one datagram per notification:

- ``READY=1``     start-up finished (systemd moves the unit from *activating* to *active*);
- ``WATCHDOG=1``  keep-alive; with ``WatchdogSec=`` set, systemd kills and restarts the
  service when none arrives within that time (``$WATCHDOG_USEC`` tells the service);
- ``STOPPING=1``  shutdown begun;
- ``STATUS=...``  one line of free text shown by ``systemctl status``.

A path starting with ``@`` names a socket in the Linux abstract namespace: the ``@`` is
replaced by a NUL byte. ``$WATCHDOG_PID``, when set, names the process the watchdog is meant
for; another process (a child) must not ping it.

Outside systemd (``NOTIFY_SOCKET`` unset) every call is a no-op, so the agent runs unchanged
from a shell or a test. Sending never raises: a notification that cannot be delivered is
counted in :attr:`Notifier.errors` (the control loop must never die because systemd is away).
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import socket
from collections.abc import Mapping

__all__ = ["Notifier", "pet_watchdog"]


class Notifier:
    """Sends ``sd_notify`` datagrams to the socket named by ``$NOTIFY_SOCKET``.

    ``environ`` defaults to ``os.environ`` read once at construction; tests pass their own
    mapping. ``pid`` (default ``os.getpid()``) is compared with ``$WATCHDOG_PID``.
    """

    def __init__(self, environ: Mapping[str, str] | None = None, *, pid: int | None = None):
        env = os.environ if environ is None else environ
        self._pid = os.getpid() if pid is None else pid
        self._address: str | bytes | None = _parse_address(env.get("NOTIFY_SOCKET", ""))
        self._watchdog_s = _parse_watchdog(env, self._pid)
        self._sock: socket.socket | None = None
        self.sent = 0
        """Notifications delivered to the socket."""
        self.errors = 0
        """Notifications that could not be delivered (socket gone, permission, ...)."""

    @property
    def enabled(self) -> bool:
        """True when ``$NOTIFY_SOCKET`` names a socket (running under ``Type=notify``)."""
        return self._address is not None

    def ready(self, status: str | None = None) -> bool:
        """Tell systemd start-up is complete (``READY=1``), optionally with a status line."""
        return self.notify("READY=1", status=status)

    def watchdog(self) -> bool:
        """Pet the watchdog (``WATCHDOG=1``); call at least every ``watchdog_interval_s()``."""
        return self.notify("WATCHDOG=1")

    def stopping(self, status: str | None = None) -> bool:
        """Tell systemd the service is shutting down (``STOPPING=1``)."""
        return self.notify("STOPPING=1", status=status)

    def status(self, text: str) -> bool:
        """Set the one-line status shown by ``systemctl status`` (``STATUS=...``)."""
        return self.notify(status=text)

    def watchdog_interval_s(self) -> float | None:
        """How often to call :meth:`watchdog`, in seconds: half of ``$WATCHDOG_USEC``.

        None when no watchdog is configured for this process (``WATCHDOG_USEC`` unset,
        invalid or zero, or ``WATCHDOG_PID`` names another process). Half the timeout is the
        margin sd_watchdog_enabled(3) recommends.
        """
        return None if self._watchdog_s is None else self._watchdog_s / 2.0

    def watchdog_timeout_s(self) -> float | None:
        """The watchdog timeout systemd enforces (``$WATCHDOG_USEC``), in seconds, or None."""
        return self._watchdog_s

    def notify(self, *assignments: str, status: str | None = None) -> bool:
        """Send one datagram of ``KEY=VALUE`` lines; returns True when it was delivered.

        ``status`` is appended as ``STATUS=`` with newlines replaced by spaces (a newline
        would end the assignment). Returns False, without raising, when notifications are
        disabled or the send failed (counted in :attr:`errors`).
        """
        if self._address is None:
            return False
        lines = list(assignments)
        if status is not None:
            lines.append("STATUS=" + status.replace("\n", " ").replace("\r", " "))
        if not lines:
            return False
        payload = "\n".join(lines).encode("utf-8", "replace")
        try:
            if self._sock is None:
                self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC)
            self._sock.sendto(payload, self._address)
        except OSError:
            self.errors += 1
            self._close_socket()  # a fresh socket next time (systemd may have been restarted)
            return False
        self.sent += 1
        return True

    def close(self) -> None:
        """Release the sending socket (notifications may still be sent afterwards)."""
        self._close_socket()

    def _close_socket(self) -> None:
        if self._sock is not None:
            try:
                self._sock.close()
            finally:
                self._sock = None

    def __enter__(self) -> Notifier:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _parse_address(value: str) -> str | bytes | None:
    """``$NOTIFY_SOCKET`` to a ``sendto`` address: a path, or ``b"\\0name"`` for ``@name``."""
    if not value:
        return None
    if value.startswith("@"):
        return b"\0" + value[1:].encode("utf-8")
    if value.startswith("/"):
        return value
    # systemd also allows vsock: addresses (VMs); the agent runs on the host it controls,
    # so anything else is treated as "not under systemd" rather than guessed at.
    return None


def _parse_watchdog(env: Mapping[str, str], pid: int) -> float | None:
    """The watchdog timeout in seconds from ``$WATCHDOG_USEC``/``$WATCHDOG_PID``, or None."""
    usec_text = env.get("WATCHDOG_USEC", "")
    if not usec_text:
        return None
    try:
        usec = int(usec_text)
    except ValueError:
        return None
    if usec <= 0:
        return None
    pid_text = env.get("WATCHDOG_PID", "")
    if pid_text:
        try:
            if int(pid_text) != pid:
                return None
        except ValueError:
            return None
    return usec / 1_000_000.0


async def pet_watchdog(notifier: Notifier, stop: asyncio.Event) -> None:
    """Send ``WATCHDOG=1`` every :meth:`Notifier.watchdog_interval_s` until ``stop`` (no-op
    without a watchdog). Run it as a task on the node's event loop: it proves that loop turns
    (a loop stuck in blocking code misses the pings and systemd restarts the service). The
    agent pets from its control loop instead (runtime.timers)."""
    period = notifier.watchdog_interval_s()
    if period is None:
        return
    while not stop.is_set():
        notifier.watchdog()
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(stop.wait(), period)
