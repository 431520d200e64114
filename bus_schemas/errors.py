"""Decode errors as values, and the one exception type for tools and publishers.

A subscriber in a control loop must never be knocked over by a bad payload, so `decode` returns a
`DecodeError` value instead of raising. Publishing an invalid message, on the other hand, is a bug
in the publisher: `encode` raises `SchemaError` so it is found at once and never reaches the bus.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum


class Reason(StrEnum):
    """Why a payload was rejected. Values are stable strings (logged, counted, compared)."""

    MALFORMED = "malformed"
    NOT_A_MAP = "not_a_map"
    MISSING_FIELD = "missing_field"
    WRONG_TYPE = "wrong_type"
    NON_FINITE = "non_finite"
    OUT_OF_RANGE = "out_of_range"
    UNKNOWN_VERSION = "unknown_version"
    TOO_LARGE = "too_large"
    INCONSISTENT = "inconsistent"
    NON_STRING_KEY = "non_string_key"
    DUPLICATE_KEY = "duplicate_key"


REASON_HELP: dict[Reason, str] = {
    Reason.MALFORMED: "not exactly one MessagePack object (truncated, trailing bytes, invalid "
    "UTF-8, too deeply nested, not bytes)",
    Reason.NOT_A_MAP: "valid MessagePack whose top-level object is not a map",
    Reason.MISSING_FIELD: "a required field is absent (or an optional one a rule requires)",
    Reason.WRONG_TYPE: "a field has the wrong type, including nil where nil is not allowed, a "
    "bool for an int or an int for a bool",
    Reason.NON_FINITE: "NaN or +-inf in a float field or a float list element",
    Reason.OUT_OF_RANGE: "a number outside its range, an unknown enum value, an id not matching "
    "its pattern, a str, list or map longer than its bound",
    Reason.UNKNOWN_VERSION: "`v` is an int other than the version this decoder implements",
    Reason.TOO_LARGE: "the payload is longer than the maximum payload size",
    Reason.INCONSISTENT: "fields disagree with each other (parallel lists of different lengths)",
    Reason.NON_STRING_KEY: "a map (top-level or nested) has a key that is not a str (int, bin, "
    "nil, ...); such a payload is refused whole, never read past",
    Reason.DUPLICATE_KEY: "a map (top-level or nested) has the same key twice; a generic decoder "
    "would keep one of them silently, so the payload is refused whole",
}
"""What each reason means (rendered in docs/bus.md)."""


@dataclass(frozen=True, slots=True)
class DecodeError:
    """A rejected payload: `reason` (machine readable), `detail` (for humans), `field` (or None)."""

    reason: Reason
    detail: str
    field: str | None = None

    def __str__(self) -> str:
        where = f" [{self.field}]" if self.field is not None else ""
        return f"{self.reason}{where}: {self.detail}"


class RejectCounts:
    """Rejected inputs counted by reason, for a node's status (``rejected`` and its breakdown).

    ``add(error_or_reason)`` takes a DecodeError, a Reason, or a node's own reason string
    (``"misaddressed"``, ``"stale"``, ...). Memory is bounded: at most :attr:`MAX_REASONS`
    distinct reasons are kept apart, any further ones are counted under ``"other"``.
    """

    MAX_REASONS = 64
    __slots__ = ("by_reason", "total")

    def __init__(self) -> None:
        self.total = 0
        self.by_reason: dict[str, int] = {}

    def add(self, why: DecodeError | Reason | str) -> None:
        """Count one rejected input."""
        reason = str(why.reason) if isinstance(why, DecodeError) else str(why)
        self.total += 1
        if reason not in self.by_reason and len(self.by_reason) >= self.MAX_REASONS:
            reason = "other"
        self.by_reason[reason] = self.by_reason.get(reason, 0) + 1

    def as_dict(self) -> dict[str, int]:
        """Reason -> count, sorted by reason (a Status ``rx``-like map)."""
        return dict(sorted(self.by_reason.items()))


class SchemaError(ValueError):
    """Raised by `encode` for an invalid message and by `decode_or_raise`; carries the error."""

    def __init__(self, error: DecodeError) -> None:
        super().__init__(str(error))
        self.error = error


class Invalid(Exception):
    """Internal control flow of the validators; never escapes `decode` (converted to a value)."""

    __slots__ = ("error",)

    def __init__(self, reason: Reason, detail: str, field: str | None = None) -> None:
        super().__init__(detail)
        self.error = DecodeError(reason, detail, field)
