"""runtime.lifecycle and formation.launch.router: processes end promptly and cleanly on signals.

Real processes on loopback: the router and nodes written the documented way (``run_node`` +
session in try/finally) with misbehaviours (a forgotten session, a main that ignores the stop,
one blocked in sync code, a second signal), each watched through its liveliness token; and
``run_node`` in this process (status, signals restored, exceptions, only its own sessions).
"""

from __future__ import annotations

import asyncio
import os
import signal
import threading
from collections.abc import Callable
from pathlib import Path

import pytest
import zenoh
from support.async_wait import wait_until
from support.routers import RouterHandle
from support.spawn import Child, Spawner, free_port

import runtime as rt
from runtime.lifecycle import stop_trace

EXIT_BOUND_S = 1.5  # requirement: exit within 1 s of the signal; 0.5 s margin for CI noise

# A node written the documented way (run_node + session in try/finally), with misbehaviours.
NODE = """
import asyncio, sys, time
import runtime as rt
endpoint, behaviour = sys.argv[1], sys.argv[2]
opened = []

async def main(stop):
    loop = asyncio.get_running_loop()
    session = await rt.open_session_async(rt.ZenohSettings(connect=(endpoint,)))
    opened.append(session)
    try:
        token = rt.declare_token(session, "test/alive/node")
        rt.subscribe(session, "test/data/**", loop, rt.Inbox("latest"))
        print("ready", flush=True)
        if behaviour == "ignore-stop":
            await asyncio.sleep(3600)
        elif behaviour == "block":
            time.sleep(30)
        else:
            await stop.wait()
        return 0
    finally:
        if behaviour != "forget-close":
            session.close()

code = rt.run_node(main)
print(f"run_node returned {code}; session closed: {opened[0].is_closed()}", flush=True)
raise SystemExit(code)
"""


# ---------------------------------------------------------------------------------------------
# Process lifecycle: router and nodes exit promptly on signals
# ---------------------------------------------------------------------------------------------


@pytest.mark.zenoh
@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT], ids=["SIGTERM", "SIGINT"])
def test_router_exits_cleanly_within_a_second_of_a_signal(
    start_router: Callable[..., RouterHandle], sig: signal.Signals
) -> None:
    router = start_router()
    with rt.open_session(rt.ZenohSettings(connect=(router.endpoint,))) as client:
        token = rt.declare_token(client, "test/alive/client")  # a connected, declaring client
        elapsed = router.child.stop(sig)
        del token
    print(f"router exit {elapsed * 1e3:.0f} ms after {sig.name}")
    assert router.proc.returncode == 0, router.child.describe()
    assert elapsed < EXIT_BOUND_S
    assert router.child.stdout().splitlines() == [f"router listening on {router.endpoint}"]


@pytest.mark.zenoh
def test_router_reports_a_port_in_use(spawn: Spawner, router: RouterHandle) -> None:
    second = spawn("router", "--listen", router.endpoint)
    assert second.proc.wait(timeout=10) == 2  # a busy port is the caller's mistake
    err = second.stderr()
    assert "address already in use" in err and router.endpoint in err, err
    assert len(err.splitlines()) == 1 and ".rs" not in err, err  # one line, no Rust paths


@pytest.mark.zenoh
@pytest.mark.parametrize("value", ["", "  ", "(bogus: 1)"], ids=["empty", "blank", "bad-field"])
def test_a_zenoh_runtime_zenoh_cannot_parse_is_one_line_naming_it(
    spawn: Spawner, value: str
) -> None:
    """``ZENOH_RUNTIME`` (Zenoh's threads; ``formation up --lockstep`` sets it for its children)
    is read at the first open, and one Zenoh cannot parse makes it panic: a router (any node)
    exits 2 with a line naming the variable and its value instead of a Python traceback."""
    port = free_port()
    child = spawn("router", "--listen", f"tcp/127.0.0.1:{port}", env={"ZENOH_RUNTIME": value})
    assert child.proc.wait(timeout=10) == 2, child.describe()
    err = child.stderr()
    lines = [ln for ln in err.splitlines() if ln.startswith("formation router:")]
    assert len(lines) == 1, err
    assert f"ZENOH_RUNTIME={value!r}" in lines[0] and "Traceback" not in err, err


async def node_exit(
    spawn: Spawner,
    router: RouterHandle,
    watcher: zenoh.Session,
    behaviour: str,
) -> tuple[Child, float, list[bool]]:
    """Start NODE with ``behaviour``, SIGTERM it once ready; (child, seconds to exit, token log)."""
    alive: list[bool] = []
    rt.watch_liveliness(
        watcher, "test/alive/node", asyncio.get_running_loop(), lambda k, a: alive.append(a)
    )
    node = spawn.python(NODE, router.endpoint, behaviour, ready="ready")
    await wait_until(lambda: alive == [True])
    elapsed = node.stop(signal.SIGTERM, timeout_s=5.0)
    await wait_until(lambda: alive == [True, False], timeout_s=2.0)
    print(f"node ({behaviour}) exit {elapsed * 1e3:.0f} ms after SIGTERM")
    return node, elapsed, alive


@pytest.mark.zenoh
async def test_node_exits_within_a_second_of_sigterm_with_its_session_closed(
    spawn: Spawner, router: RouterHandle, session: Callable[..., zenoh.Session]
) -> None:
    node, elapsed, _ = await node_exit(spawn, router, session(), "well-behaved")
    assert node.proc.returncode == 0, node.describe()
    assert elapsed < EXIT_BOUND_S
    assert "run_node returned 0; session closed: True" in node.stdout()
    # nothing but, on a stop slower than 0.5 s (a loaded machine), its stop trace
    assert [ln for ln in node.stderr().splitlines() if not ln.startswith("stop trace:")] == []


@pytest.mark.zenoh
def test_a_node_asked_for_its_stop_trace_writes_the_phases_in_order(
    spawn: Spawner, router: RouterHandle
) -> None:
    node = spawn.python(
        NODE, router.endpoint, "well-behaved", ready="ready", env={"FORMATION_STOP_TRACE": "1"}
    )
    node.stop(signal.SIGTERM, timeout_s=5.0)
    assert node.proc.returncode == 0, node.describe()
    lines = [ln for ln in node.stderr().splitlines() if ln.startswith("stop trace: signal at ")]
    assert len(lines) == 1, node.describe()
    phases = [part.rsplit(" ", 2)[0] for part in lines[0].split(", ")[1:]]
    assert phases == ["loop", "main", "sessions", "loop closed", "run_node"], lines[0]
    assert all(part.endswith(" ms") for part in lines[0].split(", ")[1:]), lines[0]


@pytest.mark.zenoh
async def test_run_node_closes_a_session_main_forgot(
    spawn: Spawner, router: RouterHandle, session: Callable[..., zenoh.Session]
) -> None:
    node, elapsed, _ = await node_exit(spawn, router, session(), "forget-close")
    assert node.proc.returncode == 0, node.describe()
    assert elapsed < EXIT_BOUND_S
    assert "session closed: True" in node.stdout()
    assert "closed 1 session(s) main left open" in node.stderr()


@pytest.mark.zenoh
async def test_run_node_cancels_a_main_that_ignores_stop(
    spawn: Spawner, router: RouterHandle, session: Callable[..., zenoh.Session]
) -> None:
    node, elapsed, _ = await node_exit(spawn, router, session(), "ignore-stop")
    assert node.proc.returncode == 1, node.describe()
    assert elapsed < EXIT_BOUND_S
    assert "session closed: True" in node.stdout()
    assert "cancelling" in node.stderr()


@pytest.mark.zenoh
async def test_watchdog_forces_out_a_node_blocked_in_sync_code(
    spawn: Spawner, router: RouterHandle, session: Callable[..., zenoh.Session]
) -> None:
    node, elapsed, _ = await node_exit(spawn, router, session(), "block")
    assert node.proc.returncode == rt.FORCED_EXIT_CODE, node.describe()
    assert elapsed < EXIT_BOUND_S
    assert "forcing exit" in node.stderr()


@pytest.mark.zenoh
async def test_a_second_signal_forces_an_immediate_exit(
    spawn: Spawner, router: RouterHandle
) -> None:
    node = spawn.python(NODE, router.endpoint, "ignore-stop", ready="ready")
    node.send_signal(signal.SIGTERM)
    await asyncio.sleep(0.05)  # inside the 0.4 s grace period
    elapsed = node.stop(signal.SIGTERM)
    assert node.proc.returncode == rt.FORCED_EXIT_CODE, node.describe()
    assert elapsed < 0.3  # not the grace period nor the watchdog deadline
    assert "second stop signal" in node.stderr()


def test_run_node_must_run_on_the_main_thread() -> None:
    async def main(stop: asyncio.Event) -> int:
        return 0

    errors: list[BaseException | None] = []
    thread = threading.Thread(target=lambda: errors.append(_catch(lambda: rt.run_node(main))))
    thread.start()
    thread.join()
    assert isinstance(errors[0], RuntimeError)


def _catch(fn: Callable[[], object]) -> BaseException | None:
    try:
        fn()
    except BaseException as exc:
        return exc
    return None


def test_run_node_in_process_returns_main_status_and_restores_signals() -> None:
    before = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}

    async def main(stop: asyncio.Event) -> int:
        assert not stop.is_set()
        assert signal.getsignal(signal.SIGTERM) != before[signal.SIGTERM]  # installed
        return 3

    assert rt.run_node(main) == 3
    assert {sig: signal.getsignal(sig) for sig in before} == before


def test_stop_signalled_is_true_at_once_before_the_loop_sets_the_stop_event() -> None:
    seen: list[tuple[bool, bool]] = []

    async def main(stop: asyncio.Event) -> int:
        assert not rt.stop_signalled()
        os.kill(os.getpid(), signal.SIGTERM)  # its Python handler runs before os.kill returns
        seen.append((rt.stop_signalled(), stop.is_set()))  # no await yet: the loop has not run
        await stop.wait()
        return 0

    try:
        assert rt.run_node(main) == 0
    finally:
        stop_trace.reset()  # this pytest process is not stopping
    assert seen == [(True, False)]


@pytest.mark.zenoh
def test_run_node_closes_only_the_sessions_its_main_opened(
    router: RouterHandle, session: Callable[..., zenoh.Session]
) -> None:
    outside = session()
    inside: list[zenoh.Session] = []

    async def main(stop: asyncio.Event) -> int:
        inside.append(await rt.open_session_async(rt.ZenohSettings(connect=(router.endpoint,))))
        return 0  # and "forgets" to close it

    assert rt.run_node(main) == 0
    assert inside[0].is_closed()
    assert not outside.is_closed()


def test_run_node_propagates_main_exceptions_after_cleanup() -> None:
    async def main(stop: asyncio.Event) -> int:
        raise KeyError("boom")

    with pytest.raises(KeyError, match="boom"):
        rt.run_node(main)


# ---------------------------------------------------------------------------------------------
# Nothing in the stop waits without a bound (a Zenoh call stuck on a thread, a router that does
# not read): the node still exits 0, and says so. The nodes below get a 20 s watchdog, so what
# is checked is the bounded path itself, never the watchdog's forced exit: no timing assertion.
# ---------------------------------------------------------------------------------------------

STUCK_NODE = """
import asyncio, signal, sys, threading
import runtime as rt
from runtime.lifecycle import exit_fast
endpoint, behaviour = sys.argv[1], sys.argv[2]
opened = []

async def executor(io, stop):
    never = threading.Event()  # a call blocked on the loop's default executor, for ever
    io.loop.run_in_executor(None, never.wait)
    opened.append(io.session)
    print("ready", flush=True)
    await stop.wait()
    return 0

async def flood(io, stop):
    # after SIGUSR1 (the test has stopped the router): fill the session's queue to the router
    pub = io.pubs.get("test/flood", rt.QOS_TELEMETRY)  # DROP: a put never blocks
    async def matched():
        while not pub.matching_status:
            await asyncio.sleep(0.01)
        print("matched", flush=True)
    waiting = asyncio.ensure_future(matched())
    def run():
        for _ in range(3000):  # 60 MB, far more than the socket buffers and Zenoh's queue
            pub.put(bytes(20_000))
        print("flooded", flush=True)
    io.loop.add_signal_handler(
        signal.SIGUSR1, lambda: threading.Thread(target=run, daemon=True).start()
    )
    print("ready", flush=True)
    await stop.wait()
    return 0

body = {"executor": executor, "flood": flood}[behaviour]
code = rt.serve("stuck", rt.ZenohSettings(connect=(endpoint,)), body, hard_exit_s=20.0)
if opened:
    print(f"serve returned {code}; session closed: {opened[0].is_closed()}", flush=True)
exit_fast(code)  # as the `formation` entry point leaves: the executor's thread is not joined
"""


@pytest.mark.zenoh
def test_a_call_stuck_on_the_default_executor_does_not_hold_the_exit(
    spawn: Spawner, router: RouterHandle
) -> None:
    """asyncio.run joined the loop's executor threads at exit (a query blocked in Zenoh held
    the process until its timeout); run_node's loop leaves them."""
    node = spawn.python(STUCK_NODE, router.endpoint, "executor", ready="ready")
    node.stop(signal.SIGTERM, timeout_s=10.0)  # the old code: blocked until the 20 s watchdog
    assert node.proc.returncode == 0, node.describe()
    assert "serve returned 0; session closed: True" in node.stdout()


@pytest.mark.zenoh
def test_a_session_close_blocked_by_a_stopped_router_is_given_up_and_logged(
    spawn: Spawner, router: RouterHandle, session: Callable[..., zenoh.Session]
) -> None:
    """session.close() flushes what is queued for the router: with the router stopped (as a
    router starved of CPU, for longer) and the queue full, zenoh's close waits 10-17 s. The node
    waits rt.SESSION_CLOSE_S, says so on stderr and exits 0; the kernel closes its socket."""
    # a subscriber, or the client would not send the flood at all (the router tells it nobody
    # is interested): measured, its close then took ~5 ms with the router stopped
    received: list[int] = []
    session().declare_subscriber("test/flood", lambda _s: received.append(1))
    node = spawn.python(STUCK_NODE, router.endpoint, "flood", ready="ready")
    node.wait_for_line("matched")  # the router knows the subscriber, so has the node
    router.proc.send_signal(signal.SIGSTOP)
    try:
        node.send_signal(signal.SIGUSR1)
        node.wait_for_line("flooded")
        node.stop(signal.SIGTERM, timeout_s=8.0)  # the old code: Zenoh's own 10+ s
    finally:
        router.proc.send_signal(signal.SIGCONT)
    assert node.proc.returncode == 0, node.describe()
    assert "stuck: Zenoh session close still blocked after 0.3 s" in node.stderr(), node.describe()


@pytest.mark.zenoh
async def test_a_lockstep_run_gives_its_children_one_zenoh_thread(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """``formation up --lockstep``'s process table hands every child ``ZENOH_RUNTIME`` =
    ``LOCKSTEP_ZENOH_RUNTIME`` (runtime/transport.py): the real router it starts runs Zenoh
    without its receive, transmit, network and accept threads; a value the user set wins."""
    from formation.launch.children import child_env
    from formation.launch.processes import ProcessTable
    from runtime.transport import LOCKSTEP_ZENOH_RUNTIME, ZENOH_RUNTIME_ENV

    monkeypatch.delenv(ZENOH_RUNTIME_ENV, raising=False)
    table = ProcessTable(tmp_path, {ZENOH_RUNTIME_ENV: LOCKSTEP_ZENOH_RUNTIME})
    router = await table.start_router(["router", "--listen", f"tcp/127.0.0.1:{free_port()}"])
    try:
        await router.wait_ready(15.0)
        environ = Path(f"/proc/{router.pid}/environ").read_bytes().split(b"\0")
        assert f"{ZENOH_RUNTIME_ENV}={LOCKSTEP_ZENOH_RUNTIME}".encode() in environ
        names = {p.read_text().strip() for p in Path(f"/proc/{router.pid}/task").glob("*/comm")}
        assert "app-0" in names, names
        assert not [n for n in names if n.startswith(("rx-", "tx-", "net-", "acc-"))], names
    finally:
        router.signal(signal.SIGTERM)
        assert router.proc is not None
        await asyncio.wait_for(router.proc.wait(), 5.0)
        await router.close()
    monkeypatch.setenv(ZENOH_RUNTIME_ENV, "(app: (worker_threads: 2))")
    assert child_env(table.env)[ZENOH_RUNTIME_ENV] == "(app: (worker_threads: 2))"
