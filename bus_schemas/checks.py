"""Per-field validators compiled from the field specs (:func:`compile_check`).

A validator takes a raw value (from msgpack, or from a dataclass being encoded) and returns the
normalised value or raises ``Invalid``; compiled once per message type, so a decode does no
reflection.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable, Mapping
from typing import Any

from bus_schemas import keys
from bus_schemas.errors import Invalid, Reason
from bus_schemas.fields import (
    FLOAT64_MAX,
    INT64_MIN,
    MAX_LIST_LEN,
    MAX_MAP_LEN,
    MAX_STR_LEN,
    UINT64_MAX,
    FieldSpec,
    Kind,
)

# --- per-field validators --------------------------------------------------------------------
# A validator takes a raw value (from msgpack, or from a dataclass being encoded) and returns the
# normalised value (ints in float fields -> float, lists -> tuples, str subclasses -> str, maps
# sorted by key) or raises Invalid. The fast path tests exact types; subclasses (numpy.float64,
# StrEnum members, IntEnum) take a slow path so publishers can pass them; bool is never a number.

Check = Callable[[Any], Any]


def wrong_type(name: str, expected: str, raw: object) -> Invalid:
    return Invalid(Reason.WRONG_TYPE, f"expected {expected}, got {type(raw).__name__}", name)


def _float_slow(raw: object, name: str) -> float:
    if isinstance(raw, bool) or not isinstance(raw, float | int):
        raise wrong_type(name, "float", raw)
    try:
        return float(raw)
    except OverflowError:
        raise Invalid(Reason.OUT_OF_RANGE, "int too large for a float64", name) from None


def _float_error(name: str, x: float, lo: float, hi: float) -> Invalid:
    if not math.isfinite(x):
        return Invalid(Reason.NON_FINITE, f"{x!r} is not finite", name)
    return Invalid(Reason.OUT_OF_RANGE, f"{x!r} not in [{lo!r}, {hi!r}]", name)


def _float_check(name: str, lo: float, hi: float) -> Check:
    def check(raw: Any) -> float:
        x = raw if type(raw) is float else _float_slow(raw, name)  # ints converted here
        if lo <= x <= hi:  # also False for NaN; +-inf fails the +-FLOAT64_MAX default bounds
            return x
        raise _float_error(name, x, lo, hi)

    return check


def _int_check(name: str, lo: int, hi: int) -> Check:
    def check(raw: Any) -> int:
        if type(raw) is not int:
            if isinstance(raw, bool) or not isinstance(raw, int):
                raise wrong_type(name, "int", raw)
            raw = int(raw)
        if lo <= raw <= hi:
            return raw
        raise Invalid(Reason.OUT_OF_RANGE, f"{raw!r} not in [{lo}, {hi}]", name)

    return check


def _bool_check(name: str) -> Check:
    def check(raw: Any) -> bool:
        if raw is True or raw is False:
            return raw
        raise wrong_type(name, "bool", raw)

    return check


_KNOWN_MAX = 4096
_known_good: dict[str, set[str]] = {}  # pattern -> strings that matched it (ids repeat a lot)


def _plain_str(raw: object, name: str) -> str:
    if not isinstance(raw, str):
        raise wrong_type(name, "str", raw)
    return str.__str__(raw)  # plain str with the same characters (e.g. a StrEnum member)


def _str_check(
    name: str,
    max_len: int,
    pattern: str | None,
    choices: tuple[str, ...],
) -> Check:
    if choices:
        allowed = frozenset(choices)

        def check_enum(raw: Any) -> str:
            if type(raw) is not str:
                raw = _plain_str(raw, name)
            if raw in allowed:
                return raw
            raise Invalid(Reason.OUT_OF_RANGE, f"{raw[:80]!r} not one of {sorted(allowed)}", name)

        return check_enum

    if pattern is not None:
        match = re.compile(pattern).fullmatch
        # A regex match costs ~0.5 us; ids repeat, so remember (a bounded number of) good ones.
        known = _known_good.setdefault(pattern, set())

        def check_pattern(raw: Any) -> str:
            if type(raw) is not str:
                raw = _plain_str(raw, name)
            if raw in known:
                return raw
            if len(raw) > max_len:
                raise Invalid(Reason.OUT_OF_RANGE, f"longer than {max_len} characters", name)
            if match(raw) is None:
                raise Invalid(Reason.OUT_OF_RANGE, f"{raw[:80]!r} does not match {pattern}", name)
            if len(known) < _KNOWN_MAX:
                known.add(raw)
            return raw

        return check_pattern

    def check_text(raw: Any) -> str:
        if type(raw) is not str:
            raw = _plain_str(raw, name)
        if len(raw) > max_len:
            raise Invalid(Reason.OUT_OF_RANGE, f"longer than {max_len} characters", name)
        return raw

    return check_text


def _sequence(raw: Any, name: str, expected: str, max_len: int) -> tuple[Any, ...] | list[Any]:
    if type(raw) is not tuple and not isinstance(raw, tuple | list):
        raise wrong_type(name, expected, raw)
    if len(raw) > max_len:
        raise Invalid(Reason.OUT_OF_RANGE, f"{len(raw)} elements, at most {max_len}", name)
    seq: tuple[Any, ...] | list[Any] = raw
    return seq


def _float_list_check(name: str, lo: float, hi: float, max_len: int) -> Check:
    element = _float_check(name, lo, hi)

    def check(raw: Any) -> tuple[float, ...]:
        seq = _sequence(raw, name, "list[float]", max_len)
        for e in seq:  # fast path: every element an in-range float64
            if type(e) is not float or not lo <= e <= hi:
                break
        else:
            return seq if type(seq) is tuple else tuple(seq)
        return tuple(_elements(element, seq, name))

    return check


def _str_list_check(name: str, pattern: str | None, max_len: int) -> Check:
    element_max = keys.ID_MAX_LEN if pattern is not None else MAX_STR_LEN
    element = _str_check(name, element_max, pattern, ())

    def check(raw: Any) -> tuple[str, ...]:
        return tuple(_elements(element, _sequence(raw, name, "list[str]", max_len), name))

    return check


def _int_list_check(name: str, lo: int, hi: int, max_len: int) -> Check:
    element = _int_check(name, lo, hi)

    def check(raw: Any) -> tuple[int, ...]:
        seq = _sequence(raw, name, "list[int]", max_len)
        for e in seq:  # fast path: every element an in-range int
            if type(e) is not int or not lo <= e <= hi:
                break
        else:
            return seq if type(seq) is tuple else tuple(seq)
        return tuple(_elements(element, seq, name))

    return check


def _elements(element: Check, seq: tuple[Any, ...] | list[Any], name: str) -> list[Any]:
    """Validate each element; an error names the element (``x[3]``)."""
    out: list[Any] = []
    for i, e in enumerate(seq):
        try:
            out.append(element(e))
        except Invalid as exc:
            raise Invalid(exc.error.reason, exc.error.detail, f"{name}[{i}]") from None
    return out


def _str_int_map_check(
    name: str, key_pattern: str | None, value_lo: int, value_hi: int, max_len: int
) -> Check:
    key_check = _str_check(f"{name} key", keys.ID_MAX_LEN, key_pattern, ())
    value_check = _int_check(f"{name} value", value_lo, value_hi)

    def check(raw: Any) -> dict[str, int]:
        if type(raw) is not dict and not isinstance(raw, Mapping):
            raise wrong_type(name, "map", raw)
        if len(raw) > max_len:
            raise Invalid(Reason.OUT_OF_RANGE, f"{len(raw)} entries, at most {max_len}", name)
        items = [(key_check(k), value_check(v)) for k, v in raw.items()]
        items.sort()
        return dict(items)

    return check


def compile_check(name: str, fs: FieldSpec) -> Check:
    """Build the validator of one field from its spec (done once per field, at import)."""
    lo = float(fs.lo) if fs.lo is not None else -FLOAT64_MAX
    hi = float(fs.hi) if fs.hi is not None else FLOAT64_MAX
    if fs.kind is Kind.FLOAT:
        return _float_check(name, lo, hi)
    if fs.kind is Kind.INT:
        ilo = int(fs.lo) if fs.lo is not None else INT64_MIN
        ihi = int(fs.hi) if fs.hi is not None else UINT64_MAX
        return _int_check(name, ilo, ihi)
    if fs.kind is Kind.BOOL:
        return _bool_check(name)
    if fs.kind in (Kind.STR, Kind.ENUM):
        return _str_check(name, fs.max_len or MAX_STR_LEN, fs.pattern, fs.choices)
    if fs.kind is Kind.FLOAT_LIST:
        return _float_list_check(name, lo, hi, fs.max_len or MAX_LIST_LEN)
    if fs.kind is Kind.STR_LIST:
        return _str_list_check(name, fs.pattern, fs.max_len or MAX_LIST_LEN)
    if fs.kind is Kind.INT_LIST:
        ilo = int(fs.lo) if fs.lo is not None else INT64_MIN
        ihi = int(fs.hi) if fs.hi is not None else UINT64_MAX
        return _int_list_check(name, ilo, ihi, fs.max_len or MAX_LIST_LEN)
    if fs.kind is Kind.STR_INT_MAP:
        vlo = fs.value_lo if fs.value_lo is not None else INT64_MIN
        vhi = fs.value_hi if fs.value_hi is not None else UINT64_MAX
        return _str_int_map_check(name, fs.pattern, vlo, vhi, fs.max_len or MAX_MAP_LEN)
    raise TypeError(f"unhandled field kind {fs.kind}")  # pragma: no cover
