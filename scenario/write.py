"""Scenario tables written back as TOML (``tomllib`` only reads).

``formation up`` writes the scenario it actually runs (after ``--robots``) next to the run's
logs so every process of the run, and anyone re-running it, reads the same file.
"""

from __future__ import annotations

import re
import tomllib
from collections.abc import Mapping
from typing import Any

__all__ = ["to_toml"]

_BARE_KEY = re.compile(r"[A-Za-z0-9_-]+")


def _toml_str(s: str) -> str:
    out = ['"']
    for ch in s:
        if ch in '"\\':
            out.append("\\" + ch)
        elif ord(ch) < 0x20 or ord(ch) == 0x7F:
            out.append(f"\\u{ord(ch):04x}")
        else:
            out.append(ch)
    out.append('"')
    return "".join(out)


def _toml_key(k: str) -> str:
    return k if _BARE_KEY.fullmatch(k) else _toml_str(k)


def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return repr(v)  # 0.1, 1e-05, inf, nan: all valid TOML floats
    if isinstance(v, str):
        return _toml_str(v)
    if isinstance(v, Mapping):
        return (
            "{" + ", ".join(f"{_toml_key(str(k))} = {_toml_value(x)}" for k, x in v.items()) + "}"
        )
    if isinstance(v, list | tuple):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    raise TypeError(f"cannot write {type(v).__name__} {v!r} as TOML")


def _is_table_array(v: Any) -> bool:
    return isinstance(v, list) and bool(v) and all(isinstance(x, Mapping) for x in v)


def _write_table(
    lines: list[str], table: Mapping[str, Any], path: tuple[str, ...], header: str
) -> None:
    if header:
        lines.append("")
        lines.append(header)
    for k, v in table.items():
        if not isinstance(v, Mapping) and not _is_table_array(v):
            lines.append(f"{_toml_key(k)} = {_toml_value(v)}")
    for k, v in table.items():
        sub = (*path, k)
        dotted = ".".join(_toml_key(p) for p in sub)
        if isinstance(v, Mapping):
            _write_table(lines, v, sub, f"[{dotted}]")
        elif _is_table_array(v):
            for item in v:
                _write_table(lines, item, sub, f"[[{dotted}]]")


def to_toml(data: Mapping[str, Any]) -> str:
    """``data`` (str keys; bool, int, float, str, lists, tables) as TOML text.

    Raises ValueError if the text would not read back as ``data`` (never silently changes it).
    """
    lines: list[str] = []
    _write_table(lines, data, (), "")
    text = "\n".join(lines).lstrip("\n") + "\n"
    if tomllib.loads(text) != data:
        raise ValueError("scenario does not survive a TOML round trip")
    return text
