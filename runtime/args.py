"""The command line of every process shell: value parsers (one rule per kind of value) and the
checks made after parsing, before any session is opened.

A mistake found after argparse (a bad name, scenario, fleet file or Zenoh option) raises
:class:`UsageError`; the shell writes its message as one line and returns :data:`USAGE_EXIT`::

    try:
        rt.check_names(("--fleet", ns.fleet))
        scenario = rt.load_scenario(ns.scenario)
        settings = rt.zenoh_settings(ns)
    except rt.UsageError as exc:
        log.info(str(exc))
        return rt.USAGE_EXIT
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable
from typing import TYPE_CHECKING, Final

from bus_schemas import keys
from runtime.transport import ZenohSettings, settings_from_args

if TYPE_CHECKING:
    from scenario import Scenario
    from scenario.fleet import Fleet

__all__ = ["MAX_RATE_HZ", "MIN_RATE_HZ", "USAGE_EXIT", "HelpFormatter", "UsageError",
           "check_names", "finite_or_none", "load_fleet_file", "load_scenario",
           "non_negative_int", "positive_float", "rate_hz", "zenoh_settings"]  # fmt: skip

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


# --------------------------------------------------------------------------------------------
# Checks after parsing: one line naming the option, exit status 2, before any session
# --------------------------------------------------------------------------------------------

USAGE_EXIT: Final = 2
"""Exit status of a command-line mistake (argparse's own)."""


class UsageError(ValueError):
    """A command-line mistake found after parsing; the message is the one line to show."""


def check_names(*options: tuple[str, str]) -> None:
    """Each ``(option, value)``, e.g. ``("--fleet", ns.fleet)``, is a name usable in a key
    (``keys.NAME_PATTERN``); else :class:`UsageError` naming the first bad option."""
    for option, value in options:
        if not keys.is_name(value):
            raise UsageError(f"invalid {option} {value!r}: must match {keys.NAME_PATTERN}")


def zenoh_settings(ns: argparse.Namespace) -> ZenohSettings:
    """:func:`runtime.transport.settings_from_args`, a bad value as :class:`UsageError`."""
    try:
        return settings_from_args(ns)
    except (TypeError, ValueError) as exc:
        raise UsageError(f"zenoh settings: {exc}") from None


def load_scenario(spec: str, check: Callable[[Scenario], object] | None = None) -> Scenario:
    """The scenario ``spec`` (a built-in name or a file), passed to ``check`` if given (e.g. the
    coordinator builds its core from it, so a bad trajectory fails before the ready line); a
    bad one, or one ``check`` refuses with a ValueError, KeyError or TypeError, as
    :class:`UsageError`."""
    from scenario import load

    try:
        scenario = load(spec)
        if check is not None:
            check(scenario)
    except (OSError, ValueError, KeyError, TypeError) as exc:  # ScenarioError is a ValueError
        raise UsageError(f"scenario: {exc}") from None
    return scenario


def load_fleet_file(path: str) -> Fleet:
    """The fleet file at ``path`` (``--fleet-file``); a bad one as :class:`UsageError`."""
    from scenario.fleet import load_fleet

    try:
        return load_fleet(path)
    except ValueError as exc:  # FleetError, every problem listed
        raise UsageError(str(exc)) from None
