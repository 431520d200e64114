"""Strict decode: its cost, and a long seeded fuzz of the decoder over every message type.

    python bench/bench_decode.py                 # cost table + 200,000 fuzz payloads
    python bench/bench_decode.py --fuzz 2000000  # the long fuzz
    (tests/unit/bus_schemas/test_decode_fuzz.py is
                                                 # the short one that runs in `make test`)

Cost: per message type, the best of 40 interleaved rounds (process CPU time) of msgpack's
``unpackb`` alone, of ``unpackb`` with the duplicate / non-str key check
(``bus_schemas.codec._strict_map``), and of the full ``bus_schemas.decode``.

Fuzz: random bytes, truncations and byte flips of valid payloads, and valid maps with fields
replaced, dropped, duplicated or given non-str keys; every result must be a valid message or a
``DecodeError``; anything raised is a failure (exit 1). Prints the count of each reason.
"""

from __future__ import annotations

import argparse
import collections
import random
import sys
import time
from pathlib import Path
from typing import Any

import msgpack

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from bus_schemas import MESSAGE_TYPES, DecodeError, decode, encode, to_map, validate
from bus_schemas.codec import _strict_map


def samples() -> dict[type, Any]:
    from support.bus_samples import SAMPLES  # one valid message per type (tests/support/)

    return dict(SAMPLES)


def cost(rounds: int = 40, n: int = 5000) -> None:
    print(
        f"{'message':<14} {'unpackb':>9} {'+key check':>11} {'decode':>9}  (us, best of {rounds})"
    )
    unp = msgpack.unpackb
    for cls, msg in samples().items():
        data = encode(msg)
        best = [1e18, 1e18, 1e18]
        calls = (
            lambda d=data: unp(d, use_list=False, strict_map_key=False),
            lambda d=data: unp(
                d, use_list=False, strict_map_key=False, object_pairs_hook=_strict_map
            ),
            lambda d=data, c=cls: decode(d, c),
        )
        for _ in range(rounds):
            for i, call in enumerate(calls):
                t0 = time.process_time_ns()
                for _ in range(n):
                    call()
                best[i] = min(best[i], (time.process_time_ns() - t0) / n / 1000)
        print(f"{cls.__name__:<14} {best[0]:>9.2f} {best[1]:>11.2f} {best[2]:>9.2f}")


def _pack_pairs(pairs: list[tuple[Any, Any]]) -> bytes:
    packer = msgpack.Packer(use_bin_type=True)
    out = packer.pack_map_header(len(pairs))
    for k, v in pairs:
        out += packer.pack(k) + packer.pack(v)
    return out


def _random_value(rnd: random.Random, depth: int = 0) -> Any:
    kind = rnd.randrange(10 if depth < 2 else 8)
    if kind == 0:
        return None
    if kind == 1:
        return rnd.random() < 0.5
    if kind == 2:
        return rnd.randint(-(2**63), 2**64 - 1)
    if kind == 3:
        return rnd.choice(
            [0.0, -0.0, 1e300, -1e300, float("nan"), float("inf"), rnd.uniform(-2e3, 2e3)]
        )
    if kind == 4:
        return "".join(chr(rnd.randrange(32, 0x2FF)) for _ in range(rnd.randrange(12)))
    if kind == 5:
        return rnd.randbytes(rnd.randrange(8))
    if kind in (6, 7):
        return rnd.uniform(-1e3, 1e3)
    if kind == 8:
        return [_random_value(rnd, depth + 1) for _ in range(rnd.randrange(5))]
    keys: list[Any] = ["x", "r1", 1, None, b"k", "t"]
    return {rnd.choice(keys): _random_value(rnd, depth + 1) for _ in range(rnd.randrange(4))}


def fuzz_payload(rnd: random.Random, msg: Any) -> bytes:
    good = encode(msg)
    mode = rnd.randrange(4)
    if mode == 0:
        return rnd.randbytes(rnd.randrange(128))
    if mode == 1:
        data = bytearray(good)
        for _ in range(rnd.randrange(1, 4)):
            data[rnd.randrange(len(data))] = rnd.randrange(256)
        return bytes(data[: len(data) - rnd.randrange(len(data) // 4 + 1)])
    pairs: list[tuple[Any, Any]] = list(to_map(msg).items())
    for _ in range(rnd.randrange(1, 4)):
        action = rnd.randrange(5)
        if action == 0 and pairs:
            i = rnd.randrange(len(pairs))
            pairs[i] = (pairs[i][0], _random_value(rnd))
        elif action == 1 and pairs:
            pairs.pop(rnd.randrange(len(pairs)))
        elif action == 2:
            pairs.append((rnd.choice(["extra", "t", "x", "seq", "v"]), _random_value(rnd)))
        elif action == 3:
            pairs.insert(rnd.randrange(len(pairs) + 1), (rnd.choice([1, None, b"x"]), 0))
        elif pairs:
            pairs.append(pairs[rnd.randrange(len(pairs))])
    return _pack_pairs(pairs)


def fuzz(n: int, seed: int) -> int:
    rnd = random.Random(seed)
    reasons: collections.Counter[str] = collections.Counter()
    valid = 0
    t0 = time.monotonic()
    msgs = list(samples().items())
    for _ in range(n):
        cls, msg = rnd.choice(msgs)
        data = fuzz_payload(rnd, msg)
        try:
            result = decode(data, cls)
        except Exception as exc:  # a failure of the decoder
            print(f"RAISED {type(exc).__name__}: {exc} for {cls.__name__} {data!r}")
            return 1
        if isinstance(result, DecodeError):
            reasons[str(result.reason)] += 1
        else:
            if validate(result) is not None:
                print(f"INVALID message returned for {cls.__name__}: {result}")
                return 1
            valid += 1
    dt = time.monotonic() - t0
    print(f"fuzz: {n} payloads over {len(msgs)} types, seed {seed}, {dt:.1f} s, 0 raised")
    print(f"  accepted (valid): {valid}")
    for reason, count in sorted(reasons.items(), key=lambda kv: -kv[1]):
        print(f"  {reason:<16} {count}")
    return 0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--fuzz", type=int, default=200_000, help="fuzz payloads (0: none)")
    parser.add_argument("--seed", type=int, default=13)
    parser.add_argument("--no-cost", action="store_true")
    ns = parser.parse_args()
    assert set(samples()) == set(MESSAGE_TYPES)
    if not ns.no_cost:
        cost()
    return fuzz(ns.fuzz, ns.seed) if ns.fuzz else 0


if __name__ == "__main__":
    raise SystemExit(main())
