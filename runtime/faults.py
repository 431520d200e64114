"""``Faults``: a process shell's count of rejected inputs and internal errors, in one place.

Every shell (coordinator, agent, agent host, plant) treats the two the same way, and this is
that way, owned by the shell as one part:

* a **rejected input** is dropped, counted under ``<message>-<reason>`` (a ``DecodeError``'s
  reason, else the caller's reason, else ``invalid``; spaces in the message name become ``_``)
  in a :class:`bus_schemas.RejectCounts` (bounded: the status ``rejects`` map), and logged
  rate limited (:meth:`runtime.log.NodeLog.limited`, one topic per message);
* an **internal error** (an exception caught in a callback: a bug, never a bad input) is
  counted in ``internal_errors`` and logged the same way, one topic per place.

A shell may do more with a rejection (the agent also tells its firmware); the counting and the
log lines are here.
"""

from __future__ import annotations

from bus_schemas import DecodeError, RejectCounts
from runtime.log import NodeLog

__all__ = ["Faults"]


class Faults:
    """Rejected inputs (``rejects``, ``rejected``) and internal errors of one process shell."""

    __slots__ = ("_log", "internal_errors", "rejects")

    def __init__(self, log: NodeLog) -> None:
        self._log = log
        #: every rejected input by ``<message>-<reason>`` (the status ``rejects`` map)
        self.rejects = RejectCounts()
        #: exceptions caught in the shell's callbacks (0 in a healthy run)
        self.internal_errors = 0

    @property
    def rejected(self) -> int:
        """Inputs rejected so far."""
        return self.rejects.total

    def reject(self, what: str, why: DecodeError | str, reason: str | None = None) -> None:
        """Count a dropped ``what`` message under ``<what>-<reason>`` (``reason``: the
        DecodeError's, else the one given, else ``invalid``) and log it (rate limited)."""
        if reason is None:
            reason = str(why.reason) if isinstance(why, DecodeError) else "invalid"
        self.rejects.add(f"{what.replace(' ', '_')}-{reason}")
        self._log.limited(f"reject-{what}", f"rejected a {what} message: {why}")

    def internal(self, where: str, exc: BaseException) -> None:
        """Count an exception caught in ``where`` and log it (rate limited)."""
        self.internal_errors += 1
        self._log.limited(f"internal-{where}", f"internal error in {where}: {exc!r}")
