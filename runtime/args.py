"""Command-line value parsers shared by every process shell (one rule per kind of value)."""

from __future__ import annotations

import argparse
import math
from typing import Final

__all__ = ["MAX_RATE_HZ", "MIN_RATE_HZ", "HelpFormatter", "finite_or_none", "non_negative_int",
           "positive_float", "rate_hz"]  # fmt: skip

MIN_RATE_HZ: Final = 0.5
MAX_RATE_HZ: Final = 2000.0


class HelpFormatter(argparse.RawDescriptionHelpFormatter):
    """--help with each option's default shown and the description/epilog kept as written.

    Adds ``(default: X)`` to an option's help unless the help already says "default" or the
    default is None/False (a flag, or "not set"), so examples in an epilog keep their layout.
    """

    def _get_help_string(self, action: argparse.Action) -> str | None:
        text = action.help or ""
        if (
            "default" in text
            or str(action.default) in text
            or action.default in (None, False, argparse.SUPPRESS)
            or (not action.option_strings and action.nargs not in ("?", "*"))
        ):
            return action.help
        return text + " (default: %(default)s)"


def rate_hz(text: str) -> float:
    """A loop rate in Hz, within [:data:`MIN_RATE_HZ`, :data:`MAX_RATE_HZ`] (argparse type)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not MIN_RATE_HZ <= value <= MAX_RATE_HZ:
        raise argparse.ArgumentTypeError(
            f"rate must be in [{MIN_RATE_HZ:g}, {MAX_RATE_HZ:g}] Hz, got {text}"
        )
    return value


def positive_float(text: str) -> float:
    """A finite number > 0 (argparse type)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not (math.isfinite(value) and value > 0.0):
        raise argparse.ArgumentTypeError(f"must be a finite number > 0, got {text}")
    return value


def non_negative_int(text: str) -> int:
    """An integer >= 0, e.g. a random seed (argparse type)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not an integer: {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be >= 0, got {text}")
    return value


def finite_or_none(value: float | None) -> float | None:
    """``value`` if it is a finite float, else None (for optional message fields)."""
    if value is None or not math.isfinite(value):
        return None
    return float(value)
