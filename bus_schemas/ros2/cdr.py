"""CDR (OMG XCDR1, "plain CDR") primitives: the byte layer of every ROS 2 message.

A serialized ROS 2 message is a 4-byte encapsulation header followed by the CDR body:

- header: ``00 01 00 00`` (CDR little endian) or ``00 00 00 00`` (CDR big endian), the last two
  bytes are options (0 for plain CDR);
- body: fields in declaration order, each primitive aligned to its own size (at most 8) counted
  from the start of the body (the byte after the header);
- string: uint32 length *including* the terminating NUL, the UTF-8 bytes, the NUL;
- sequence: uint32 element count, then the elements; fixed arrays: the elements only;
- bool: one byte (0 or 1).

The writer always produces little endian (what every ROS 2 platform of note sends); the reader
accepts both byte orders. Errors never escape as Python exceptions: the reader raises the
package's internal :class:`~bus_schemas.errors.Invalid`, which the decoders turn into a
:class:`~bus_schemas.errors.DecodeError` value. Standard library only (this runs on a robot).
"""

from __future__ import annotations

import math
import struct

from bus_schemas.errors import Invalid, Reason

__all__ = [
    "CDR_BE",
    "CDR_LE",
    "MAX_SEQUENCE_LEN",
    "MAX_STRING_BYTES",
    "Reader",
    "Writer",
]

CDR_LE = b"\x00\x01\x00\x00"
"""Encapsulation header of a little-endian plain CDR payload (what the writer emits)."""
CDR_BE = b"\x00\x00\x00\x00"
"""Encapsulation header of a big-endian plain CDR payload (accepted by the reader)."""

MAX_STRING_BYTES = 4096
"""Longest string accepted by the reader (bytes, NUL included): frame ids and names are short."""
MAX_SEQUENCE_LEN = 65536
"""Most elements accepted in one sequence (also bounded by the bytes actually present)."""

_FLOAT32_MAX = 3.4028234663852886e38


class Writer:
    """Appends CDR little-endian fields to a buffer that starts with the encapsulation header.

    Every ``put_*`` validates its value and raises :class:`Invalid` (the encoders turn it into
    a ``SchemaError``): a publisher must never put a NaN or an out-of-range integer on the wire.
    """

    __slots__ = ("buf",)

    def __init__(self) -> None:
        self.buf = bytearray(CDR_LE)

    def _align(self, size: int) -> None:
        pad = (-(len(self.buf) - 4)) % size
        if pad:
            self.buf += b"\x00" * pad

    def u8(self, value: int, field: str) -> None:
        _check_int(value, 0, 0xFF, field)
        self.buf.append(value)

    def boolean(self, value: bool, field: str) -> None:
        if type(value) is not bool:
            raise Invalid(Reason.WRONG_TYPE, f"expected bool, got {type(value).__name__}", field)
        self.buf.append(1 if value else 0)

    def i32(self, value: int, field: str) -> None:
        _check_int(value, -(2**31), 2**31 - 1, field)
        self._align(4)
        self.buf += struct.pack("<i", value)

    def u32(self, value: int, field: str) -> None:
        _check_int(value, 0, 2**32 - 1, field)
        self._align(4)
        self.buf += struct.pack("<I", value)

    def f32(self, value: float, field: str) -> None:
        value = _check_float(value, field)
        if abs(value) > _FLOAT32_MAX:
            raise Invalid(Reason.OUT_OF_RANGE, f"{value!r} does not fit a float32", field)
        self._align(4)
        self.buf += struct.pack("<f", value)

    def f64(self, value: float, field: str) -> None:
        value = _check_float(value, field)
        self._align(8)
        self.buf += struct.pack("<d", value)

    def f64s(self, values: tuple[float, ...], count: int, field: str) -> None:
        """A fixed-size float64 array (``float64[count]``)."""
        if len(values) != count:
            raise Invalid(Reason.OUT_OF_RANGE, f"{len(values)} values, expected {count}", field)
        checked = [_check_float(v, field) for v in values]
        self._align(8)
        self.buf += struct.pack(f"<{count}d", *checked)

    def string(self, value: str, field: str) -> None:
        if type(value) is not str:
            raise Invalid(Reason.WRONG_TYPE, f"expected str, got {type(value).__name__}", field)
        try:
            raw = value.encode("utf-8")
        except UnicodeEncodeError as exc:
            raise Invalid(Reason.WRONG_TYPE, f"not encodable as UTF-8: {exc}", field) from None
        if b"\x00" in raw:
            raise Invalid(Reason.OUT_OF_RANGE, "a NUL inside a string", field)
        if len(raw) + 1 > MAX_STRING_BYTES:
            raise Invalid(Reason.OUT_OF_RANGE, f"{len(raw)} bytes, too long", field)
        self.u32(len(raw) + 1, field)
        self.buf += raw
        self.buf.append(0)

    def count(self, n: int, field: str) -> None:
        """The element count that starts a sequence."""
        if n > MAX_SEQUENCE_LEN:
            raise Invalid(Reason.OUT_OF_RANGE, f"{n} elements, at most {MAX_SEQUENCE_LEN}", field)
        self.u32(n, field)

    def octets(self, value: bytes, field: str) -> None:
        """A ``uint8[]`` sequence."""
        if not isinstance(value, bytes | bytearray):
            raise Invalid(Reason.WRONG_TYPE, f"expected bytes, got {type(value).__name__}", field)
        self.count(len(value), field)
        self.buf += value

    def done(self) -> bytes:
        return bytes(self.buf)


class Reader:
    """Reads CDR fields from a payload (header included), validating as it goes.

    ``Reader(data)`` checks the encapsulation header; every read checks that the bytes are there,
    floats are finite, strings are NUL-terminated valid UTF-8 of bounded length and sequence
    counts are plausible for the bytes left. :meth:`finish` refuses trailing bytes other than
    alignment padding (at most 7 zero bytes).
    """

    __slots__ = ("_end", "_le", "_mv", "pos")

    def __init__(self, data: bytes | bytearray | memoryview, max_bytes: int) -> None:
        if not isinstance(data, bytes | bytearray | memoryview):
            raise Invalid(Reason.MALFORMED, f"payload of type {type(data).__name__}")
        mv = memoryview(data).cast("B")
        if len(mv) > max_bytes:
            raise Invalid(Reason.TOO_LARGE, f"{len(mv)} bytes, at most {max_bytes}")
        if len(mv) < 4:
            raise Invalid(Reason.MALFORMED, f"{len(mv)} bytes: no encapsulation header")
        header = bytes(mv[:4])
        if header[0] != 0 or header[1] not in (0, 1):
            raise Invalid(Reason.MALFORMED, f"encapsulation {header[:2].hex()} is not plain CDR")
        self._mv = mv
        self._le = header[1] == 1
        self._end = len(mv)
        self.pos = 4

    def _take(self, size: int, align: int, field: str) -> int:
        start = self.pos + ((-(self.pos - 4)) % align)
        stop = start + size
        if stop > self._end:
            raise Invalid(Reason.MALFORMED, "truncated", field)
        self.pos = stop
        return start

    def _unpack(self, fmt: str, size: int, field: str) -> tuple[object, ...]:
        start = self._take(size, min(size, 8), field)
        return struct.unpack_from(("<" if self._le else ">") + fmt, self._mv, start)

    def u8(self, field: str) -> int:
        start = self._take(1, 1, field)
        return int(self._mv[start])

    def boolean(self, field: str) -> bool:
        value = self.u8(field)
        if value > 1:
            raise Invalid(Reason.OUT_OF_RANGE, f"bool byte {value}", field)
        return value == 1

    def i32(self, field: str) -> int:
        return int(self._unpack("i", 4, field)[0])  # type: ignore[call-overload]

    def u32(self, field: str) -> int:
        return int(self._unpack("I", 4, field)[0])  # type: ignore[call-overload]

    def f32(self, field: str) -> float:
        return _finite(float(self._unpack("f", 4, field)[0]), field)  # type: ignore[arg-type]

    def f64(self, field: str) -> float:
        return _finite(float(self._unpack("d", 8, field)[0]), field)  # type: ignore[arg-type]

    def f64s(self, count: int, field: str) -> tuple[float, ...]:
        start = self._take(8 * count, 8, field)
        values = struct.unpack_from(("<" if self._le else ">") + f"{count}d", self._mv, start)
        for v in values:
            _finite(v, field)
        return values

    def string(self, field: str) -> str:
        size = self.u32(field)
        if size == 0:
            # Some writers send 0 for an empty string; accept it as "".
            return ""
        if size > MAX_STRING_BYTES:
            raise Invalid(Reason.TOO_LARGE, f"string of {size} bytes", field)
        start = self._take(size, 1, field)
        raw = bytes(self._mv[start : start + size])
        if raw[-1] != 0:
            raise Invalid(Reason.MALFORMED, "string not NUL-terminated", field)
        if 0 in raw[:-1]:
            raise Invalid(Reason.MALFORMED, "a NUL inside a string", field)
        try:
            return raw[:-1].decode("utf-8")
        except UnicodeDecodeError:
            raise Invalid(Reason.MALFORMED, "string is not valid UTF-8", field) from None

    def count(self, min_elem_bytes: int, field: str) -> int:
        """A sequence's element count, checked against the bytes left (no huge allocations)."""
        n = self.u32(field)
        if n > MAX_SEQUENCE_LEN:
            raise Invalid(Reason.TOO_LARGE, f"sequence of {n} elements", field)
        if n * min_elem_bytes > self._end - self.pos:
            raise Invalid(Reason.MALFORMED, f"sequence of {n} elements, truncated", field)
        return n

    def octets(self, field: str) -> bytes:
        n = self.count(1, field)
        start = self._take(n, 1, field)
        return bytes(self._mv[start : start + n])

    def finish(self) -> None:
        rest = self._mv[self.pos : self._end]
        if len(rest) > 7 or any(rest):
            raise Invalid(Reason.MALFORMED, f"{len(rest)} trailing bytes")


def _check_int(value: int, lo: int, hi: int, field: str) -> None:
    if type(value) is not int:
        raise Invalid(Reason.WRONG_TYPE, f"expected int, got {type(value).__name__}", field)
    if not lo <= value <= hi:
        raise Invalid(Reason.OUT_OF_RANGE, f"{value} outside [{lo}, {hi}]", field)


def _check_float(value: float, field: str) -> float:
    if type(value) is bool or not isinstance(value, int | float):
        raise Invalid(Reason.WRONG_TYPE, f"expected float, got {type(value).__name__}", field)
    try:
        value = float(value)
    except OverflowError:
        raise Invalid(Reason.OUT_OF_RANGE, "an int too large for a float64", field) from None
    if not math.isfinite(value):
        raise Invalid(Reason.NON_FINITE, f"{value!r}", field)
    return value


def _finite(value: float, field: str) -> float:
    if not math.isfinite(value):
        raise Invalid(Reason.NON_FINITE, f"{value!r}", field)
    return value
