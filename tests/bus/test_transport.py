"""runtime.transport, runtime.bridge and formation.launch.router: real Zenoh sessions and real
processes
on loopback (settings, the thread -> loop handoff, pub/sub, session open/retry, liveliness).

No mocks: every session goes through a `formation router` subprocess on a free port (conftest
fixtures), multicast scouting off. Timings are asserted with a margin for a loaded 2-core CI box;
the bench (bench/bench_zenoh_rtt.py) measures, these tests only bound. How processes end
(signals, run_node) is in tests/bus/test_lifecycle.py.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import signal
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import pytest
import zenoh
from support.async_wait import wait_until
from support.routers import RouterHandle
from support.spawn import Child, Spawner, free_port

import runtime as rt

# A client holding one liveliness token; prints "ready" then idles (killed by the test).
HOLDER = """
import sys, time
import runtime as rt
endpoint, key = sys.argv[1], sys.argv[2]
lease = int(sys.argv[3]) if len(sys.argv) > 3 else None
session = rt.open_session(rt.ZenohSettings(connect=(endpoint,), lease_ms=lease))
token = rt.declare_token(session, key)
print("ready", flush=True)
while True:
    time.sleep(1)
"""


def ready_holder(spawn: Spawner, router: RouterHandle, key: str, *extra: str) -> Child:
    return spawn.python(HOLDER, router.endpoint, key, *extra, ready="ready")


# ---------------------------------------------------------------------------------------------
# Settings and config (no network)
# ---------------------------------------------------------------------------------------------


def cfg(config: zenoh.Config, key: str) -> object:
    return json.loads(config.get_json(key))


def test_default_config_is_a_loopback_client_without_multicast() -> None:
    config = rt.make_config(rt.ZenohSettings())
    assert cfg(config, "mode") == "client"
    assert cfg(config, "connect/endpoints") == [rt.DEFAULT_ENDPOINT]
    assert cfg(config, "listen/endpoints") == []
    assert cfg(config, "scouting/multicast/enabled") is False
    assert cfg(config, "transport/link/tx/lease") == 10000  # Zenoh's default left alone
    assert cfg(config, "scouting/delay") is None  # a client waits for its router as usual
    router = rt.make_config(rt.ZenohSettings(mode="router", connect=(), listen=("tcp/[::1]:1",)))
    assert cfg(router, "scouting/delay") == 0  # nothing to scout: open() at once


def test_lease_sets_lease_and_keep_alive() -> None:
    config = rt.make_config(rt.ZenohSettings(lease_ms=1000))
    assert cfg(config, "transport/link/tx/lease") == 1000
    assert cfg(config, "transport/link/tx/keep_alive") == 4


def test_config_file_is_loaded_first_and_cannot_enable_multicast(tmp_path: Path) -> None:
    path = tmp_path / "zenoh.json5"
    path.write_text(
        """{
          mode: "peer",
          connect: { endpoints: ["tcp/10.0.0.1:7447"] },
          listen: { endpoints: ["tcp/127.0.0.1:0"] },
          scouting: { multicast: { enabled: true } },
          namespace: "fromfile",
        }"""
    )
    ns = rt.add_zenoh_arguments(argparse.ArgumentParser()).parse_args(["--zenoh-config", str(path)])
    settings = rt.settings_from_args(ns)
    assert settings.mode is None and settings.connect == () and settings.listen == ()
    config = rt.make_config(settings)
    assert cfg(config, "mode") == "peer"
    assert cfg(config, "connect/endpoints") == ["tcp/10.0.0.1:7447"]
    assert cfg(config, "listen/endpoints") == ["tcp/127.0.0.1:0"]
    assert cfg(config, "namespace") == "fromfile"
    assert cfg(config, "scouting/multicast/enabled") is False  # only an explicit flag enables it

    ns = rt.add_zenoh_arguments(argparse.ArgumentParser()).parse_args(
        ["--zenoh-config", str(path), "--endpoint", "tcp/127.0.0.1:1", "--multicast-scouting"]
    )
    config = rt.make_config(rt.settings_from_args(ns))
    assert cfg(config, "connect/endpoints") == ["tcp/127.0.0.1:1"]
    assert cfg(config, "scouting/multicast/enabled") is True


def test_settings_from_args() -> None:
    parser = rt.add_zenoh_arguments(argparse.ArgumentParser())
    s = rt.settings_from_args(parser.parse_args([]))
    assert s == rt.ZenohSettings()
    s = rt.settings_from_args(
        parser.parse_args(
            [
                *("--endpoint", "tcp/a:1", "--endpoint", "tcp/b:2", "--mode", "peer"),
                *("--listen", "tcp/127.0.0.1:9", "--lease-ms", "1000", "--zenoh-namespace", "run7"),
            ]
        )
    )
    assert s.connect == ("tcp/a:1", "tcp/b:2") and s.listen == ("tcp/127.0.0.1:9",)
    assert (s.mode, s.lease_ms, s.namespace, s.multicast_scouting) == ("peer", 1000, "run7", False)
    assert rt.settings_from_args(parser.parse_args(["--mode", "router"])).connect == ()


@pytest.mark.parametrize(
    ("kwargs", "error"),
    [
        ({"connect": "tcp/127.0.0.1:7447"}, TypeError),
        ({"connect": ("127.0.0.1:7447",)}, ValueError),
        ({"mode": "server"}, ValueError),
        ({"lease_ms": 10}, ValueError),
        ({"namespace": "a/*"}, ValueError),
        ({"open_timeout_s": -1.0}, ValueError),
    ],
)
def test_settings_reject_bad_values(kwargs: dict[str, object], error: type[Exception]) -> None:
    with pytest.raises(error):
        rt.ZenohSettings(**kwargs)  # type: ignore[arg-type]


# ---------------------------------------------------------------------------------------------
# Inbox: the thread -> loop handoff itself (no network, deterministic)
# ---------------------------------------------------------------------------------------------


def push_from_thread(inbox: rt.Inbox, items: list[rt.Received]) -> None:
    def run() -> None:
        for i in items:
            inbox.push(i)

    thread = threading.Thread(target=run)
    thread.start()
    thread.join()


def item(key: str, n: int) -> rt.Received:
    return rt.Received(key=key, payload=str(n).encode(), rx_s=time.monotonic())


async def test_latest_inbox_coalesces_a_burst_into_one_wake_with_newest_values() -> None:
    inbox = rt.Inbox("latest")
    inbox.bind(asyncio.get_running_loop())
    # The loop is not running callbacks while this thread pushes: everything lands in one drain.
    push_from_thread(inbox, [item(k, n) for n in range(500) for k in ("a", "b")])
    assert await inbox.wait(timeout_s=1.0)
    assert not await inbox.wait(timeout_s=0.01)  # one wake for the whole burst
    assert {k: r.payload for k, r in inbox.snapshot().items()} == {"a": b"499", "b": b"499"}
    assert set(inbox.take_updates()) == {"a", "b"} and inbox.take_updates() == {}
    assert inbox.received == 1000 and inbox.dropped == 0
    push_from_thread(inbox, [rt.Received("a", b"", time.monotonic(), deleted=True)])
    assert await inbox.wait(timeout_s=1.0)
    assert inbox.latest("a") is None and inbox.latest("b") is not None


async def test_queue_inbox_keeps_order_and_drops_oldest_beyond_maxlen() -> None:
    inbox = rt.Inbox("queue", maxlen=100)
    inbox.bind(asyncio.get_running_loop())
    push_from_thread(inbox, [item("e", n) for n in range(250)])
    first = await asyncio.wait_for(inbox.get(), timeout=1.0)
    rest = inbox.drain()
    assert [int(r.payload) for r in [first, *rest]] == list(range(150, 250))
    assert inbox.dropped == 150 and inbox.get_nowait() is None


async def test_inbox_without_wake_is_polled_and_never_wakes_the_loop() -> None:
    loop = asyncio.get_running_loop()
    inbox = rt.Inbox("queue", maxlen=100, wake=False)
    inbox.bind(loop)
    scheduled: list[object] = []
    real = loop.call_soon_threadsafe

    def spy(*args: Any, **kwargs: Any) -> Any:
        scheduled.append(args[0])
        return real(*args, **kwargs)

    loop.call_soon_threadsafe = spy  # type: ignore[method-assign, assignment]
    try:
        push_from_thread(inbox, [item("e", n) for n in range(250)])
        await asyncio.sleep(0.01)
    finally:
        del loop.call_soon_threadsafe
    assert scheduled == []  # no push scheduled anything on the loop
    assert inbox.get_nowait() is not None  # the reader takes what accumulated, in order
    assert [int(r.payload) for r in inbox.drain()] == list(range(151, 250))
    assert inbox.dropped == 150 and inbox.drain() == []
    latest = rt.Inbox("latest", wake=False)
    latest.bind(loop)
    push_from_thread(latest, [item(k, n) for n in range(5) for k in ("a", "b")])
    assert {k: r.payload for k, r in latest.snapshot().items()} == {"a": b"4", "b": b"4"}
    with pytest.raises(RuntimeError, match="polled"):
        await inbox.get()
    with pytest.raises(RuntimeError, match="polled"):
        await latest.wait(timeout_s=0.01)


def test_inbox_latest_mode_bounds_distinct_keys() -> None:
    async def run() -> rt.Inbox:
        inbox = rt.Inbox("latest", maxlen=3)
        inbox.bind(asyncio.get_running_loop())
        push_from_thread(inbox, [item(f"k{n}", n) for n in range(10)])
        await inbox.wait(timeout_s=1.0)
        return inbox

    inbox = asyncio.run(run())
    assert len(inbox.snapshot()) == 3 and inbox.dropped == 7


def feed_from_thread(
    jobs: Sequence[tuple[Callable[[rt.Received], object], rt.Received, bool]],
) -> None:
    """Push ``(handler, sample, wake)`` jobs into the running loop's LoopFeed from a thread."""
    feed = rt.loop_feed(asyncio.get_running_loop())

    def run() -> None:
        for fn, rx, wake in jobs:
            feed.push(fn, rx, wake)

    thread = threading.Thread(target=run)
    thread.start()
    thread.join()


async def test_loop_feed_runs_every_handler_in_arrival_order_once_per_burst() -> None:
    feed = rt.loop_feed(asyncio.get_running_loop())
    assert rt.loop_feed(asyncio.get_running_loop()) is feed  # one per loop: one order
    got: list[tuple[str, int]] = []

    def a(r: rt.Received) -> None:
        got.append(("a", int(r.payload)))

    def b(r: rt.Received) -> None:
        got.append(("b", int(r.payload)))

    jobs = [(a if n % 3 else b, item("k", n), True) for n in range(300)]
    feed_from_thread(jobs)  # the loop runs nothing while the thread pushes: one burst
    await asyncio.sleep(0)
    assert got == [("a" if n % 3 else "b", n) for n in range(300)]
    assert (feed.drains, feed.handled) == (1, 300)


async def test_loop_feed_without_wake_waits_in_its_place_for_the_next_wake() -> None:
    feed = rt.loop_feed(asyncio.get_running_loop())
    got: list[int] = []

    def on(r: rt.Received) -> None:
        got.append(int(r.payload))

    feed_from_thread([(on, item("lazy", n), False) for n in range(3)])
    await asyncio.sleep(0.02)
    assert got == [] and feed.drains == 0  # nothing scheduled: the loop slept on
    feed_from_thread([(on, item("clock", 3), True), (on, item("lazy", 4), False)])
    await asyncio.sleep(0)
    assert got == [0, 1, 2, 3, 4]  # the waiting samples first, in their order
    feed_from_thread([(on, item("lazy", 5), False)])
    feed.flush()  # a reader that wants them now
    assert got == [0, 1, 2, 3, 4, 5] and feed.drains == 2


async def test_loop_feed_a_raising_handler_does_not_stop_the_others() -> None:
    loop = asyncio.get_running_loop()
    errors: list[dict[str, Any]] = []
    loop.set_exception_handler(lambda _loop, ctx: errors.append(ctx))
    got: list[int] = []

    def bad(r: rt.Received) -> None:
        raise ValueError(f"bad {int(r.payload)}")

    def good(r: rt.Received) -> None:
        got.append(int(r.payload))

    feed_from_thread(
        [(good, item("k", 0), True), (bad, item("x", 1), True), (good, item("k", 2), True)]
    )
    await asyncio.sleep(0)
    assert got == [0, 2]
    assert len(errors) == 1 and "'x'" in errors[0]["message"]
    assert str(errors[0]["exception"]) == "bad 1"


def test_loop_feed_push_after_the_loop_closed_is_dropped_quietly() -> None:
    loop = asyncio.new_event_loop()
    feed = rt.LoopFeed(loop)
    loop.close()
    feed.push(lambda r: None, item("k", 0))  # the node is exiting: no exception escapes
    assert feed.drains == 0


# ---------------------------------------------------------------------------------------------
# Pub/sub through a router subprocess
# ---------------------------------------------------------------------------------------------


@pytest.mark.zenoh
async def test_pub_sub_round_trip_through_the_asyncio_bridge(
    session: Callable[..., zenoh.Session],
) -> None:
    loop = asyncio.get_running_loop()
    sub_session, pub_session = session(), session()
    got: list[tuple[rt.Received, bool]] = []
    queue = rt.Inbox("queue")
    rt.subscribe(
        sub_session,
        "test/rt/**",
        loop,
        lambda r: got.append((r, threading.current_thread() is threading.main_thread())),
    )
    rt.subscribe(sub_session, "test/rt/**", loop, queue)
    await asyncio.sleep(0.05)  # let the subscriptions reach the router
    pubs = rt.Publishers(pub_session)
    payloads = [bytes([n]) * 100 for n in range(50)]
    before = time.monotonic()
    for p in payloads:
        pubs.put("test/rt/x", p, rt.QOS_CONTROL)
    await wait_until(lambda: len(got) == 50)
    assert [r.payload for r, _ in got] == payloads  # every sample, in order, intact
    assert all(on_loop_thread for _, on_loop_thread in got)  # delivered on the loop thread
    assert all(r.key == "test/rt/x" and not r.deleted and r.rx_s >= before for r, _ in got)
    await wait_until(lambda: queue.received == 50)
    assert [r.payload for r in queue.drain()] == payloads
    assert len(pubs) == 1  # one publisher declared, reused


@pytest.mark.zenoh
async def test_matching_follows_the_subscribers_of_a_key_through_a_router(
    session: Callable[..., zenoh.Session],
) -> None:
    """``Publishers.matching`` (what a lockstep plant asks before it puts a robot's own truth
    and pose): False while nobody subscribes, True once a subscriber on another session
    matches the key (a wildcard too), False again when it is gone; a lookup after the first
    call, kept by Zenoh's matching listener."""
    pub_session, sub_session = session(), session()
    pubs = rt.Publishers(pub_session)
    key, other = "test/match/robot/r1/truth", "test/match/robot/r2/truth"
    assert pubs.matching(key, rt.QOS_TELEMETRY) is False
    assert pubs.matching(other, rt.QOS_TELEMETRY) is False
    sub = sub_session.declare_subscriber("test/match/robot/r1/*", lambda _s: None)
    await wait_until(lambda: pubs.matching(key))
    assert pubs.matching(other) is False  # another robot's key: nobody reads it
    wide = sub_session.declare_subscriber("test/match/**", lambda _s: None)
    await wait_until(lambda: pubs.matching(other))
    sub.undeclare()
    wide.undeclare()
    await wait_until(lambda: not pubs.matching(key) and not pubs.matching(other))
    assert len(pubs) == 2  # one publisher a key, declared by the first call
    pubs.undeclare_all()
    assert len(pubs) == 0


@pytest.mark.zenoh
async def test_a_sample_without_wake_is_handled_before_the_next_waking_one_over_zenoh(
    session: Callable[..., zenoh.Session],
) -> None:
    loop = asyncio.get_running_loop()
    sub_session, pub_session = session(), session()
    got: list[tuple[str, bytes]] = []
    rt.subscribe(sub_session, "test/lazy/pose", loop, lambda r: got.append(("pose", r.payload)),
                 wake=False)  # fmt: skip
    rt.subscribe(sub_session, "test/lazy/clock", loop, lambda r: got.append(("clock", r.payload)))
    with pytest.raises(ValueError, match="callables"):
        rt.subscribe(sub_session, "test/lazy/x", loop, rt.Inbox("queue"), wake=False)
    await asyncio.sleep(0.05)  # let the subscriptions reach the router
    pubs = rt.Publishers(pub_session)
    for n in range(5):
        pubs.put("test/lazy/pose", bytes([n]), rt.QOS_CRITICAL)
    await asyncio.sleep(0.2)
    assert got == []  # delivered to this process, waiting for a sample that wakes the loop
    pubs.put("test/lazy/clock", b"k", rt.QOS_CRITICAL)
    await wait_until(lambda: len(got) == 6)
    assert got == [*(("pose", bytes([n])) for n in range(5)), ("clock", b"k")]


@pytest.mark.zenoh
async def test_tick_pump_hands_the_sides_then_the_trigger_on_its_own_thread_under_the_guard(
    session: Callable[..., zenoh.Session],
) -> None:
    sub_session, pub_session = session(), session()
    guard = threading.RLock()
    got: list[tuple[str, bytes, bool, bool]] = []

    def on(name: str) -> Callable[[rt.Received], None]:
        def handle(r: rt.Received) -> None:
            mine = threading.current_thread().name == "pump-under-test"
            got.append((name, r.payload, mine, guard._is_owned()))  # type: ignore[attr-defined]
            if r.payload == b"raise":
                raise ValueError("a handler that raises")

        return handle

    pump = rt.TickPump(sub_session, guard, capacity=4, name="pump-under-test")
    pump.side("test/pump/fault", on("fault"))
    pump.side("test/pump/pose", on("pose"))
    pump.start("test/pump/clock", on("clock"))
    with pytest.raises(RuntimeError, match="after start"):
        pump.side("test/pump/late", on("late"))
    with pytest.raises(RuntimeError, match="twice"):
        pump.start("test/pump/clock", on("clock"))
    await asyncio.sleep(0.05)  # let the subscriptions reach the router
    pubs = rt.Publishers(pub_session, default_qos=rt.QOS_CRITICAL)
    for n in range(6):  # more than the ring holds: the oldest two are dropped
        pubs.put("test/pump/pose", bytes([n]))
    pubs.put("test/pump/fault", b"raise")
    await asyncio.sleep(0.2)
    assert got == []  # the sides wait for the trigger
    pubs.put("test/pump/clock", b"k1")
    await wait_until(lambda: len(got) == 6)
    # sides in declaration order (each key in its own order), then the trigger; every call on
    # the pump's thread with the guard held; the raising handler is counted, the rest still ran
    assert [(n, p) for n, p, _, _ in got] == [
        ("fault", b"raise"),
        *(("pose", bytes([n])) for n in range(2, 6)),
        ("clock", b"k1"),
    ]
    assert all(mine and held for _, _, mine, held in got)
    assert (pump.ticks, pump.handled, pump.errors) == (1, 6, 1)
    with guard:  # the loop holds the guard: the next tick waits for it
        pubs.put("test/pump/clock", b"k2")
        await asyncio.sleep(0.2)
        assert len(got) == 6
    await wait_until(lambda: len(got) == 7)
    assert got[-1][:2] == ("clock", b"k2")
    pump.undeclare()
    assert await asyncio.to_thread(pump.join, 2.0)  # the thread ends
    pubs.put("test/pump/clock", b"k3")
    await asyncio.sleep(0.1)
    assert len(got) == 7 and pump.ticks == 2


@pytest.mark.zenoh
async def test_tick_pump_thread_ends_when_its_session_closes(
    session: Callable[..., zenoh.Session],
) -> None:
    own = session()
    pump = rt.TickPump(own, contextlib.nullcontext(), name="pump-closed")
    pump.side("test/pumpc/pose", lambda r: None)
    pump.start("test/pumpc/clock", lambda r: None)
    with pytest.raises(ValueError, match="capacity"):
        rt.TickPump(own, contextlib.nullcontext(), capacity=0)
    own.close()
    assert await asyncio.to_thread(pump.join, 2.0)


@pytest.mark.zenoh
async def test_latest_inbox_over_zenoh_keeps_only_the_newest(
    session: Callable[..., zenoh.Session],
) -> None:
    sub_session, pub_session = session(), session()
    inbox = rt.Inbox("latest")
    rt.subscribe(sub_session, "test/pose/*", asyncio.get_running_loop(), inbox)
    await asyncio.sleep(0.05)
    # BLOCK, so that this burst of 400 puts is delivered whole (DROP may shed some of it).
    pubs = rt.Publishers(pub_session, default_qos=rt.QOS_CRITICAL)
    for n in range(200):  # published without yielding: the loop sees one backlog
        for robot in ("r1", "r2"):
            pubs.put(f"test/pose/{robot}", str(n).encode())
    await wait_until(lambda: inbox.received == 400)
    await inbox.wait(timeout_s=1.0)
    snap = inbox.snapshot()
    assert {k: r.payload for k, r in snap.items()} == {
        "test/pose/r1": b"199",
        "test/pose/r2": b"199",
    }


@pytest.mark.zenoh
async def test_publisher_qos_reaches_the_wire(session: Callable[..., zenoh.Session]) -> None:
    sub_session, pub_session = session(), session()
    samples: list[zenoh.Sample] = []
    sub_session.declare_subscriber("test/qos/**", samples.append)
    await asyncio.sleep(0.05)
    pubs = rt.Publishers(pub_session)
    pubs.put("test/qos/wheels", b"w", rt.QOS_CONTROL)
    pubs.put("test/qos/status", b"s")  # default: telemetry
    await wait_until(lambda: len(samples) == 2)
    by_key = {str(s.key_expr): s for s in samples}
    wheels, status = by_key["test/qos/wheels"], by_key["test/qos/status"]
    assert wheels.priority == zenoh.Priority.REAL_TIME and not wheels.express
    assert status.priority == zenoh.Priority.DATA and not status.express
    with pytest.raises(ValueError, match="already declared"):
        pubs.put("test/qos/wheels", b"w", rt.QOS_TELEMETRY)


@pytest.mark.zenoh
async def test_namespace_isolates_sessions_on_one_router(
    session: Callable[..., zenoh.Session],
) -> None:
    loop = asyncio.get_running_loop()
    same, other = rt.Inbox("queue"), rt.Inbox("queue")
    rt.subscribe(session(namespace="runA"), "test/ns", loop, same)
    rt.subscribe(session(namespace="runB"), "test/ns", loop, other)
    await asyncio.sleep(0.05)
    session(namespace="runA").put("test/ns", b"hello")
    await wait_until(lambda: same.received == 1)
    await asyncio.sleep(0.1)
    received = same.drain()
    assert [(r.key, r.payload) for r in received] == [("test/ns", b"hello")]  # prefix stripped
    assert other.received == 0


@pytest.mark.zenoh
async def test_two_isolated_routers_do_not_see_each_other(
    start_router: Callable[..., RouterHandle],
) -> None:
    loop = asyncio.get_running_loop()
    a, b = start_router(), start_router()
    settings_a = rt.ZenohSettings(connect=(a.endpoint,))
    settings_b = rt.ZenohSettings(connect=(b.endpoint,))
    with (
        rt.open_session(settings_a) as on_a,
        rt.open_session(settings_b) as on_b,
        rt.open_session(settings_b) as pub_b,
    ):
        seen_a, seen_b = rt.Inbox("queue"), rt.Inbox("queue")
        rt.subscribe(on_a, "test/iso/**", loop, seen_a)
        rt.subscribe(on_b, "test/iso/**", loop, seen_b)
        await asyncio.sleep(0.1)
        for n in range(10):
            pub_b.put("test/iso/x", str(n).encode())
            await asyncio.sleep(0.02)
        await wait_until(lambda: seen_b.received == 10)  # positive control on router B
        await asyncio.sleep(0.1)
        assert seen_a.received == 0


# ---------------------------------------------------------------------------------------------
# Sessions: open/retry
# ---------------------------------------------------------------------------------------------


def test_client_open_without_router_fails_clearly_after_timeout() -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    start = time.monotonic()
    with pytest.raises(rt.TransportError, match=endpoint.replace(".", r"\.")):
        rt.open_session(rt.ZenohSettings(connect=(endpoint,)), timeout_s=0.3)
    assert 0.3 <= time.monotonic() - start < 1.5


@pytest.mark.zenoh
def test_client_open_retries_until_the_router_is_up(spawn: Spawner) -> None:
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    result: list[zenoh.Session | BaseException] = []

    def opener() -> None:
        try:
            result.append(rt.open_session(rt.ZenohSettings(connect=(endpoint,)), timeout_s=15))
        except BaseException as exc:
            result.append(exc)

    thread = threading.Thread(target=opener)
    thread.start()
    time.sleep(0.3)  # the client is retrying now
    assert not result
    spawn("router", "--listen", endpoint, ready="router listening on")
    thread.join(timeout=15)
    assert len(result) == 1 and isinstance(result[0], zenoh.Session), result
    result[0].close()


@pytest.mark.zenoh
async def test_open_session_async_is_cancellable() -> None:
    settings = rt.ZenohSettings(connect=(f"tcp/127.0.0.1:{free_port()}",))
    task = asyncio.ensure_future(rt.open_session_async(settings, timeout_s=30))
    await asyncio.sleep(0.25)
    task.cancel()
    with pytest.raises(asyncio.CancelledError):
        await asyncio.wait_for(task, timeout=1.0)


# ---------------------------------------------------------------------------------------------
# Liveliness
# ---------------------------------------------------------------------------------------------


@pytest.mark.zenoh
async def test_liveliness_token_disappears_when_its_process_is_sigkilled(
    spawn: Spawner, router: RouterHandle, session: Callable[..., zenoh.Session]
) -> None:
    holder = ready_holder(spawn, router, "test/alive/holder")
    events: list[tuple[str, bool, float]] = []
    # Declared after the token exists: history=True must report it.
    rt.watch_liveliness(
        session(),
        "test/alive/**",
        asyncio.get_running_loop(),
        lambda key, alive: events.append((key, alive, time.monotonic())),
    )
    await wait_until(lambda: len(events) == 1)
    assert events[0][:2] == ("test/alive/holder", True)
    killed = time.monotonic()
    holder.send_signal(signal.SIGKILL)
    await wait_until(lambda: len(events) == 2, timeout_s=2.0)
    assert events[1][:2] == ("test/alive/holder", False)
    gone_s = events[1][2] - killed
    print(f"token gone {gone_s * 1e3:.1f} ms after SIGKILL")
    assert gone_s < 0.5  # field notes: ~3 ms
    holder.proc.wait(timeout=2)


@pytest.mark.zenoh
async def test_short_lease_detects_a_hung_process_in_about_a_second(
    spawn: Spawner, router: RouterHandle, session: Callable[..., zenoh.Session]
) -> None:
    holder = ready_holder(spawn, router, "test/alive/hung", "1000")
    events: list[tuple[bool, float]] = []
    rt.watch_liveliness(
        session(),
        "test/alive/hung",
        asyncio.get_running_loop(),
        lambda key, alive: events.append((alive, time.monotonic())),
    )
    await wait_until(lambda: len(events) == 1)
    stopped = time.monotonic()
    holder.send_signal(signal.SIGSTOP)
    try:
        await wait_until(lambda: len(events) == 2, timeout_s=4.0)
    finally:
        holder.send_signal(signal.SIGKILL)  # a stopped process would not act on SIGTERM
        holder.proc.wait(timeout=2)
    gone_s = events[1][1] - stopped
    print(f"hung token gone {gone_s:.3f} s after SIGSTOP (lease 1000 ms)")
    assert events[1][0] is False
    assert 0.5 < gone_s < 2.5  # Zenoh's default lease would take ~10 s
