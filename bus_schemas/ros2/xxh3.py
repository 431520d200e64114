"""XXH3-128 (seed 0, default secret) in the standard library: how rmw_zenoh derives a GID.

rmw_zenoh hashes an entity's liveliness key string with XXH3-128 and uses the 16 bytes
(low 64 bits then high 64 bits, each little endian) as the entity's GID. A robot has no
``xxhash`` wheel to rely on, and the keys are short (one hash per entity at start-up), so the
portable scalar algorithm of the xxHash specification is written out here. It equals
``xxhash.xxh3_128_intdigest`` for every length (tests/unit/bus_schemas/test_ros2_wire.py
checks 0..1100 bytes).
"""

from __future__ import annotations

import struct

__all__ = ["xxh3_128"]

_M64 = (1 << 64) - 1

_SECRET = bytes.fromhex(
    "b8fe6c3923a44bbe7c01812cf721ad1cded46de9839097db7240a4a4b7b3671f"
    "cb79e64eccc0e578825ad07dccff7221b8084674f743248ee03590e6813a264c"
    "3c2852bb91c300cb88d0658b1b532ea371644897a20df94e3819ef46a9deacd8"
    "a8fa763fe39c343ff9dcbbc7c70b4f1d8a51e04bcdb45931c89f7ec9d9787364"
    "eac5ac8334d3ebc3c581a0fffa1363eb170ddd51b7f0da49d316552629d4689e"
    "2b16be587d47a1fc8ff8b8d17ad031ce45cb3a8f95160428afd7fbcabb4b407e"
)
_P32_1 = 0x9E3779B1
_P32_2 = 0x85EBCA77
_P32_3 = 0xC2B2AE3D
_P64_1 = 0x9E3779B185EBCA87
_P64_2 = 0xC2B2AE3D27D4EB4F
_P64_3 = 0x165667B19E3779F9
_P64_4 = 0x85EBCA77C2B2AE63
_P64_5 = 0x27D4EB2F165667C5
_MX1 = 0x165667919E3779F9
_MX2 = 0x9FB21C651E98DF25
_STRIPE = 64
_SECRET_CONSUME = 8


def _r64(b: bytes, i: int) -> int:
    return int(struct.unpack_from("<Q", b, i)[0])


def _r32(b: bytes, i: int) -> int:
    return int(struct.unpack_from("<I", b, i)[0])


def _avalanche(h: int) -> int:
    h ^= h >> 37
    h = (h * _MX1) & _M64
    return h ^ (h >> 32)


def _xxh64_avalanche(h: int) -> int:
    h ^= h >> 33
    h = (h * _P64_2) & _M64
    h ^= h >> 29
    h = (h * _P64_3) & _M64
    return h ^ (h >> 32)


def _fold(a: int, b: int) -> int:
    p = (a & _M64) * (b & _M64)
    return (p & _M64) ^ (p >> 64)


def _mix16(data: bytes, i: int, s: int) -> int:
    return _fold(_r64(data, i) ^ _r64(_SECRET, s), _r64(data, i + 8) ^ _r64(_SECRET, s + 8))


def _mix32(lo: int, hi: int, data: bytes, i1: int, i2: int, s: int) -> tuple[int, int]:
    lo = (lo + _mix16(data, i1, s)) & _M64
    lo ^= (_r64(data, i2) + _r64(data, i2 + 8)) & _M64
    hi = (hi + _mix16(data, i2, s + 16)) & _M64
    hi ^= (_r64(data, i1) + _r64(data, i1 + 8)) & _M64
    return lo, hi


def _finish_mid(lo: int, hi: int, n: int) -> tuple[int, int]:
    low = _avalanche((lo + hi) & _M64)
    high = (lo * _P64_1 + hi * _P64_4 + n * _P64_2) & _M64
    return low, (-_avalanche(high)) & _M64


def _len_0to16(data: bytes, n: int) -> tuple[int, int]:
    if n > 8:
        bitflipl = _r64(_SECRET, 32) ^ _r64(_SECRET, 40)
        bitfliph = _r64(_SECRET, 48) ^ _r64(_SECRET, 56)
        in_lo = _r64(data, 0)
        in_hi = _r64(data, n - 8)
        m = ((in_lo ^ in_hi ^ bitflipl) & _M64) * _P64_1
        m_lo, m_hi = m & _M64, m >> 64
        m_lo = (m_lo + ((n - 1) << 54)) & _M64
        in_hi ^= bitfliph
        m_hi = (m_hi + in_hi + (in_hi & 0xFFFFFFFF) * (_P32_2 - 1)) & _M64
        m_lo ^= int.from_bytes(m_hi.to_bytes(8, "little"), "big")
        h = m_lo * _P64_2
        h_lo, h_hi = h & _M64, ((h >> 64) + m_hi * _P64_2) & _M64
        return _avalanche(h_lo), _avalanche(h_hi)
    if n >= 4:
        in_lo = _r32(data, 0)
        in_hi = _r32(data, n - 4)
        in64 = in_lo + (in_hi << 32)
        keyed = in64 ^ (_r64(_SECRET, 16) ^ _r64(_SECRET, 24))
        m = keyed * ((_P64_1 + (n << 2)) & _M64)
        m_lo, m_hi = m & _M64, m >> 64
        m_hi = (m_hi + (m_lo << 1)) & _M64
        m_lo ^= m_hi >> 3
        m_lo ^= m_lo >> 35
        m_lo = (m_lo * _MX2) & _M64
        m_lo ^= m_lo >> 28
        return m_lo, _avalanche(m_hi)
    if n:
        c1, c2, c3 = data[0], data[n >> 1], data[n - 1]
        combl = (c1 << 16) | (c2 << 24) | c3 | (n << 8)
        swapped = int.from_bytes(combl.to_bytes(4, "little"), "big")
        combh = ((swapped << 13) | (swapped >> 19)) & 0xFFFFFFFF
        keyed_lo = combl ^ (_r32(_SECRET, 0) ^ _r32(_SECRET, 4))
        keyed_hi = combh ^ (_r32(_SECRET, 8) ^ _r32(_SECRET, 12))
        return _xxh64_avalanche(keyed_lo), _xxh64_avalanche(keyed_hi)
    return (
        _xxh64_avalanche(_r64(_SECRET, 64) ^ _r64(_SECRET, 72)),
        _xxh64_avalanche(_r64(_SECRET, 80) ^ _r64(_SECRET, 88)),
    )


def _len_17to128(data: bytes, n: int) -> tuple[int, int]:
    lo, hi = (n * _P64_1) & _M64, 0
    if n > 32:
        if n > 64:
            if n > 96:
                lo, hi = _mix32(lo, hi, data, 48, n - 64, 96)
            lo, hi = _mix32(lo, hi, data, 32, n - 48, 64)
        lo, hi = _mix32(lo, hi, data, 16, n - 32, 32)
    lo, hi = _mix32(lo, hi, data, 0, n - 16, 0)
    return _finish_mid(lo, hi, n)


def _len_129to240(data: bytes, n: int) -> tuple[int, int]:
    lo, hi = (n * _P64_1) & _M64, 0
    for i in range(32, 160, 32):
        lo, hi = _mix32(lo, hi, data, i - 32, i - 16, i - 32)
    lo, hi = _avalanche(lo), _avalanche(hi)
    for i in range(160, n + 1, 32):
        lo, hi = _mix32(lo, hi, data, i - 32, i - 16, 3 + i - 160)
    lo, hi = _mix32(lo, hi, data, n - 16, n - 32, 136 - 17 - 16)
    return _finish_mid(lo, hi, n)


def _accumulate(acc: list[int], data: bytes, i: int, s: int) -> None:
    for lane in range(8):
        val = _r64(data, i + 8 * lane)
        key = val ^ _r64(_SECRET, s + 8 * lane)
        acc[lane ^ 1] = (acc[lane ^ 1] + val) & _M64
        acc[lane] = (acc[lane] + (key & 0xFFFFFFFF) * (key >> 32)) & _M64


def _long(data: bytes, n: int) -> tuple[int, int]:
    acc = [_P32_3, _P64_1, _P64_2, _P64_3, _P64_4, _P32_2, _P64_5, _P32_1]
    stripes_per_block = (len(_SECRET) - _STRIPE) // _SECRET_CONSUME
    block = _STRIPE * stripes_per_block
    blocks = (n - 1) // block
    for b in range(blocks):
        for s in range(stripes_per_block):
            _accumulate(acc, data, b * block + s * _STRIPE, s * _SECRET_CONSUME)
        scramble = len(_SECRET) - _STRIPE
        for lane in range(8):
            a = acc[lane]
            a ^= a >> 47
            a ^= _r64(_SECRET, scramble + 8 * lane)
            acc[lane] = (a * _P32_1) & _M64
    stripes = ((n - 1) - block * blocks) // _STRIPE
    for s in range(stripes):
        _accumulate(acc, data, blocks * block + s * _STRIPE, s * _SECRET_CONSUME)
    _accumulate(acc, data, n - _STRIPE, len(_SECRET) - _STRIPE - 7)

    def merge(secret_at: int, start: int) -> int:
        result = start
        for i in range(4):
            result = (
                result
                + _fold(
                    acc[2 * i] ^ _r64(_SECRET, secret_at + 16 * i),
                    acc[2 * i + 1] ^ _r64(_SECRET, secret_at + 16 * i + 8),
                )
            ) & _M64
        return _avalanche(result)

    low = merge(11, (n * _P64_1) & _M64)
    high = merge(len(_SECRET) - 64 - 11, ~(n * _P64_2) & _M64)
    return low, high


def xxh3_128(data: bytes) -> tuple[int, int]:
    """XXH3-128 of ``data`` (seed 0) as ``(low64, high64)``."""
    n = len(data)
    if n <= 16:
        return _len_0to16(data, n)
    if n <= 128:
        return _len_17to128(data, n)
    if n <= 240:
        return _len_129to240(data, n)
    return _long(data, n)
