"""The agent's motor seam: ``MotorOutput`` hands each tick's wheel command to the motor backend
(the RoboClaw driver, the emulator, or the bus in simulation) and reads back the encoder speeds.

Split out of node.py (issue 12) so the node reads as its bus handlers and timers; still
importable from ``robot_agent.node.agent``. It imports no bus or runtime code, so it sits on the
cores
floor of tests/repo/test_layers.py.
"""

from __future__ import annotations

import threading
from collections.abc import Callable

from robot_agent.motors import MotorBackend, MotorStatus


class MotorOutput:
    """Where the wheel command goes besides the bus: the seam for ``robot_agent.motors``.

    With the ``bus`` backend (simulation) the published ``wheels`` message *is* the output and
    the backend is called inline (it only records). Any other backend (``roboclaw``) may block
    for a serial round trip, so a worker thread owns it: :meth:`command` stores the newest
    command and returns at once; the worker applies the newest one (older unapplied commands
    are superseded, counted in :attr:`superseded`). A zero command (every mode but TRACKING) is
    sent as ``stop()``. Never raises into the control loop.
    """

    def __init__(self, backend: MotorBackend) -> None:
        self.backend = backend
        self.threaded = backend.name != "bus"
        self.superseded = 0
        self.faults = 0
        self._cond = threading.Condition()
        self._pending: tuple[float, float, float, bool] | None = None
        self._closing = False
        # encoder speeds (omega_r, omega_l) read after the last command, not yet taken
        read = getattr(backend, "read_wheel_speeds", None)
        self._read_speeds: Callable[[], tuple[float, float] | None] | None = (
            read if callable(read) else None
        )
        self._speeds: tuple[float, float] | None = None
        self._thread: threading.Thread | None = None

    def start(self) -> None:
        """Open the backend (in the worker thread when threaded)."""
        if not self.threaded:
            self._guard(self.backend.open)
            return
        self._thread = threading.Thread(target=self._run, name="motor-output", daemon=True)
        self._thread.start()

    def command(self, omega_r: float, omega_l: float, now_s: float, zero: bool) -> None:
        """Hand one command over (rad/s); ``zero``: stop the wheels."""
        if not self.threaded:
            if zero:
                self._guard(self.backend.stop)
            else:
                self._guard(self.backend.apply, omega_r, omega_l, now_s)
            return
        with self._cond:
            if self._pending is not None:
                self.superseded += 1
            self._pending = (omega_r, omega_l, now_s, zero)
            self._cond.notify()

    @property
    def has_encoders(self) -> bool:
        """The backend has ``read_wheel_speeds()`` (the estimator gets measured speeds)."""
        return self._read_speeds is not None

    def take_wheel_speeds(self) -> tuple[float, float] | None:
        """The encoder speeds read since the last call (rad/s), once; None if none (the
        firmware's estimator then predicts from the commanded speeds). Inline backends are
        read here; a threaded backend is read by its worker after each command."""
        if self._read_speeds is None:
            return None
        if not self.threaded:
            try:
                return self._read_speeds()
            except Exception:
                self.faults += 1
                return None
        with self._cond:
            got, self._speeds = self._speeds, None
        return got

    def status(self) -> MotorStatus | None:
        """The backend's status snapshot, or None if it failed."""
        try:
            return self.backend.status()
        except Exception:
            return None

    def close(self, timeout_s: float = 0.2) -> None:
        """Stop the wheels and release the backend (bounded by ``timeout_s`` when threaded)."""
        if not self.threaded:
            self._guard(self.backend.close)
            return
        with self._cond:
            self._closing = True
            self._cond.notify()
        if self._thread is not None:
            self._thread.join(timeout_s)

    def _guard(self, fn: Callable[..., object], *args: float) -> None:
        try:
            fn(*args)
        except Exception:  # the contract says backends never raise; count it if one does
            self.faults += 1

    def _run(self) -> None:  # worker thread
        self._guard(self.backend.open)
        while True:
            with self._cond:
                while self._pending is None and not self._closing:
                    self._cond.wait()
                item, self._pending = self._pending, None
                closing = self._closing
            if closing:
                break
            if item is None:
                continue
            omega_r, omega_l, now_s, zero = item
            if zero:
                self._guard(self.backend.stop)
            else:
                self._guard(self.backend.apply, omega_r, omega_l, now_s)
            if self._read_speeds is not None:
                try:
                    speeds = self._read_speeds()
                except Exception:
                    self.faults += 1
                    speeds = None
                if speeds is not None:
                    with self._cond:
                        self._speeds = speeds
        self._guard(self.backend.close)
