"""Bare Zenoh round-trip floor on this machine: what any latency over the bus is compared with.

Two processes (this one and an echo subprocess started with fork+exec), 100-byte payloads,
``--n`` timed pings after ``--warmup``, one ping in flight at a time. Variants:

* router: both processes are clients of a ``formation router`` subprocess (how the fleet runs);
* peer: the echo listens as a peer and this process connects to it directly, no router;
* callback: the pong is caught in a Zenoh callback (threading.Event);
* asyncio: the pong goes through ``runtime.transport`` (call_soon_threadsafe into an Inbox
  awaited on an event loop), as in every process shell;
* channel: the pong waits in a Zenoh ring and this process's thread takes it with a blocking
  ``recv()``: no Python on Zenoh's thread, no event loop (a lockstep agent's tick thread,
  ``runtime.bridge.TickPump``).

After the table, the CPU time of this process (every thread) per round trip of each variant:
what a delivery costs the receiving process, the figure that bounds the lockstep's speed on a
2-core machine (docs/benchmarks.md).

Usage: ``python bench/bench_zenoh_rtt.py [--n 2000] [--warmup 200] [--payload-bytes 100]``.
Prints results; asserts nothing.
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
from importlib.metadata import version

from common import LatencyStats, measure_floor, print_latency, print_latency_header

VARIANTS = [
    ("router", "callback"),
    ("router", "asyncio"),
    ("router", "channel"),
    ("peer", "callback"),
    ("peer", "asyncio"),
    ("peer", "channel"),
]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    parser.add_argument("--n", type=int, default=2000, help="timed round trips per variant")
    parser.add_argument("--warmup", type=int, default=200, help="untimed round trips first")
    parser.add_argument("--payload-bytes", type=int, default=100)
    args = parser.parse_args(argv)

    print(
        f"zenoh floor: eclipse-zenoh {version('eclipse-zenoh')}, Python "
        f"{platform.python_version()}, {os.cpu_count()} CPUs, {platform.machine()}, "
        f"n={args.n} warmup={args.warmup} payload={args.payload_bytes} B, tcp loopback, "
        "multicast scouting off"
    )
    print_latency_header()
    results: dict[tuple[str, str], LatencyStats] = {}
    for topology, receive in VARIANTS:
        stats = measure_floor(
            n=args.n,
            warmup=args.warmup,
            payload_bytes=args.payload_bytes,
            topology=topology,  # type: ignore[arg-type]
            receive=receive,  # type: ignore[arg-type]
        )
        results[(topology, receive)] = stats
        base = results.get((topology, "callback")) if receive != "callback" else None
        print_latency(f"{topology:<6} {receive:<8} round trip", stats, floor=base)
    print("CPU of this process per round trip (us, every thread):")
    for (topology, receive), stats in results.items():
        print(f"  {topology:<6} {receive:<8} {stats.cpu_us:7.1f}")
    print(
        "reference (docs field notes, same class of machine): peer/callback p50 ~115 us "
        "p99 ~170 us; router p50 ~205 us p99 ~275 us; asyncio bridge adds ~40-60 us"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
