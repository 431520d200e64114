"""A process shell's fault counters: rejected inputs by reason and internal errors.

Every node owns one :class:`Faults` and hands its parts (the neighbour status inputs, the e-stop
witness, the election's I/O, the plant's inputs) only the two callables they need,
:meth:`Faults.reject` and :meth:`Faults.internal`. Both count, then log at most once a second per
topic (:meth:`runtime.log.NodeLog.limited`); neither raises.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol

from bus_schemas import DecodeError, RejectCounts
from runtime.log import NodeLog

__all__ = ["Faults", "Internal", "Reject"]


class Reject(Protocol):
    """``reject(what, why, reason=None)``: count and log a dropped ``what`` message."""

    def __call__(self, what: str, why: DecodeError | str, reason: str | None = None) -> None: ...


Internal = Callable[[str, BaseException], None]
"""``internal(where, exc)``: count and log an internal error caught in ``where``."""


class Faults:
    """Rejected inputs (:attr:`rejects`, by ``"<message>-<reason>"``) and internal errors.

    Args:
        log: where the rate-limited lines go.
        on_reject: also told of each rejection (``"<what>: <why>"``): an agent's firmware counts
            it in its own status (``Firmware.reject``).
    """

    __slots__ = ("_on_reject", "internal_errors", "log", "rejects")

    def __init__(self, log: NodeLog, on_reject: Callable[[str], None] | None = None) -> None:
        self.log = log
        self._on_reject = on_reject
        self.rejects = RejectCounts()
        self.internal_errors = 0

    @property
    def rejected(self) -> int:
        """Inputs rejected so far."""
        return self.rejects.total

    def reject(self, what: str, why: DecodeError | str, reason: str | None = None) -> None:
        """Count a dropped ``what`` message under ``<what>-<reason>`` (spaces of ``what`` as
        ``_``; the reason a DecodeError's, else ``reason``, else ``invalid``) and log it."""
        if reason is None:
            reason = str(why.reason) if isinstance(why, DecodeError) else "invalid"
        self.rejects.add(f"{what.replace(' ', '_')}-{reason}")
        if self._on_reject is not None:
            self._on_reject(f"{what}: {why}")
        self.log.limited(f"reject-{what}", f"rejected a {what} message: {why}")

    def internal(self, where: str, exc: BaseException) -> None:
        """Count an internal error caught in ``where`` and log it."""
        self.internal_errors += 1
        self.log.limited(f"internal-{where}", f"internal error in {where}: {exc!r}")
