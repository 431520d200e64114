"""The lockstep floor: how fast the lockstep's traffic alone can go on this machine.

The same processes as ``formation up --lockstep`` with one process per robot (a router, a plant,
a coordinator, ``--robots`` agents) and the same shape of a tick, with none of this project's
cores: the plant publishes a truth and the clock; the coordinator answers each clock with one
setpoints message and a leader; each agent reads the setpoints, answers each clock with its
wheels; the plant waits for every answer, then goes on. Each process does ``--work-us`` of busy
work a tick (a stand-in for its decode, step and encode). Receive designs:

* ``loop``: every process receives through this project's bridge into its asyncio loop
  (``runtime.subscribe``: a callback on Zenoh's thread, the loop's feed, one wake of the loop
  per burst; the setpoints ``wake=False``), as the coordinator and the plant do today;
* ``pump``: the agents and the coordinator take their ticks on a thread of their own
  (``runtime.TickPump``: Zenoh-side rings, a blocking ``recv()``), the plant its answers with
  blocking ``recv()`` on rings, no Python on Zenoh's threads;
* ``agents``: the agents on ``TickPump``, the plant and the coordinator on their loops (what
  ``formation up --lockstep`` did with the agents' tick thread);
* ``plant``: as ``agents``, and the plant ticks on a thread of its own, woken once a tick by its
  answers' handlers on Zenoh's thread (``subscribe_on_thread``: what ``formation up
  --lockstep`` does since the plant's tick thread); the coordinator on its loop.

Prints, for each design, the speed at 50 Hz (sim seconds per wall second) and the CPU
milliseconds a tick of each process kind over the timed ticks: what the real lockstep
(``bench/bench_lockstep.py``) could reach if its processes did no more than this.

Each design runs with Zenoh's default threads and with one Zenoh thread a process (what ``formation
up --lockstep`` gives its children: ``runtime.transport.LOCKSTEP_ZENOH_RUNTIME``).

Usage: ``python bench/bench_lockstep_floor.py [--ticks 3000] [--robots 3] [--work-us 50]
[--zenoh-runtime both|default|one-thread]``.
Prints; asserts nothing.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import os
import subprocess
import sys
import threading
import time

import zenoh
from common import cpu_s, free_port, running, stop_process

import runtime as rt
from runtime.transport import LOCKSTEP_ZENOH_RUNTIME, ZENOH_RUNTIME_ENV

DESIGNS = ("loop", "agents", "plant", "pump")
READY = "floor child ready"
DT_S = 0.02  # 50 Hz, as paper-exp2
WARMUP = 100
PAD = bytes(150)
STOP = (1 << 63) - 1


def _tick_of(payload: bytes) -> int:
    return int.from_bytes(payload[:8], "little")


def _msg(tick: int) -> bytes:
    return tick.to_bytes(8, "little") + PAD


def _work(us: float) -> None:
    end = time.perf_counter() + us * 1e-6
    while time.perf_counter() < end:
        pass


class Child:
    """One process of the floor: its session, publishers and CPU over the timed ticks."""

    def __init__(self, endpoint: str, work_us: float, ticks: int) -> None:
        self.session = rt.open_session(rt.ZenohSettings(connect=(endpoint,)), timeout_s=10.0)
        self.pubs = rt.Publishers(self.session, default_qos=rt.QOS_CRITICAL)
        self.work_us = work_us
        self.ticks = ticks
        self.cpu0: float | None = None
        self.done = threading.Event()

    def seen(self, tick: int) -> bool:
        """Mark the timed window; False once the stop tick came."""
        if tick == WARMUP:
            self.cpu0 = time.process_time()
        if tick == STOP:
            self.done.set()
            return False
        return True

    def report(self) -> None:
        cpu = time.process_time() - (self.cpu0 or 0.0)
        print(f"cpu {cpu / self.ticks * 1e3:.4f}", flush=True)


def run_answerer(role: str, design: str, child: Child) -> None:
    """An agent (``role`` its robot id: answers clock k with its wheels) or the coordinator
    (setpoints, then leader)."""

    def on_clock(rx: rt.Received) -> None:
        k = _tick_of(rx.payload)
        if not child.seen(k):
            return
        _work(child.work_us)
        if role == "coordinator":
            child.pubs.put("floor/setpoints", _msg(k))
            child.pubs.put("floor/leader", _msg(k))
        else:
            child.pubs.put(f"floor/wheels/{role}", _msg(k))

    def on_setpoints(rx: rt.Received) -> None:
        pass  # read and dropped: its cost is the delivery

    if design == "loop" or (design in ("agents", "plant") and role == "coordinator"):

        async def main() -> None:
            loop = asyncio.get_running_loop()
            if role != "coordinator":
                rt.subscribe(child.session, "floor/setpoints", loop, on_setpoints, wake=False)
            rt.subscribe(child.session, "floor/clock", loop, on_clock)
            print(READY, flush=True)
            await asyncio.to_thread(child.done.wait)

        asyncio.run(main())
    else:
        pump = rt.TickPump(child.session, contextlib.nullcontext(), name="floor-ticks")
        if role != "coordinator":
            pump.side("floor/setpoints", on_setpoints)
        pump.start("floor/clock", on_clock)
        print(READY, flush=True)
        child.done.wait()
    child.report()


def run_plant(design: str, child: Child, robots: int) -> None:
    """Tick ``child.ticks + WARMUP`` times; print the timed ticks' wall seconds."""
    child.pubs.get("floor/truth")
    child.pubs.get("floor/clock")
    time.sleep(0.5)  # the others' subscriptions reach the router
    wall: list[float] = []

    def publish(k: int) -> None:
        if k == WARMUP:
            wall.append(time.perf_counter())
            child.cpu0 = time.process_time()
        _work(child.work_us)
        child.pubs.put("floor/truth", _msg(k))
        child.pubs.put("floor/clock", _msg(k))

    total = WARMUP + child.ticks
    if design == "pump":
        wheels = child.session.declare_subscriber("floor/wheels/*", _ring())
        leader = child.session.declare_subscriber("floor/leader", _ring())
        time.sleep(0.3)
        for k in range(total):
            publish(k)
            got = 0
            while got < robots:
                got += _tick_of(wheels.recv().payload.to_bytes()) == k
            while _tick_of(leader.recv().payload.to_bytes()) != k:
                pass
    elif design == "plant":
        answers_in = threading.Event()
        lock = threading.Lock()
        expect = [0, 0]  # tick, answers of it

        def on_answer_thread(rx: rt.Received) -> None:  # Zenoh's thread
            with lock:
                if _tick_of(rx.payload) == expect[0]:
                    expect[1] += 1
                    if expect[1] == robots + 1:
                        answers_in.set()

        rt.subscribe_on_thread(child.session, "floor/wheels/*", on_answer_thread)
        rt.subscribe_on_thread(child.session, "floor/leader", on_answer_thread)
        time.sleep(0.3)
        for k in range(total):
            with lock:
                expect[0], expect[1] = k, 0
                answers_in.clear()
                publish(k)
            answers_in.wait()
    else:

        async def main() -> None:
            loop = asyncio.get_running_loop()
            answered = asyncio.Event()
            count = [0, 0]  # tick, answers of it

            def on_answer(rx: rt.Received) -> None:
                if _tick_of(rx.payload) == count[0]:
                    count[1] += 1
                    if count[1] == robots + 1:
                        answered.set()

            rt.subscribe(child.session, "floor/wheels/*", loop, on_answer)
            rt.subscribe(child.session, "floor/leader", loop, on_answer)
            await asyncio.sleep(0.3)
            for k in range(total):
                count[0], count[1] = k, 0
                answered.clear()
                publish(k)
                await answered.wait()

        asyncio.run(main())
    wall.append(time.perf_counter())
    child.pubs.put("floor/clock", _msg(STOP))
    print(f"wall {wall[1] - wall[0]:.6f}", flush=True)
    child.report()


def _ring() -> zenoh.handlers.RingChannel[zenoh.Sample]:
    return zenoh.handlers.RingChannel(256)


def child_main(argv: list[str]) -> int:
    role, design, endpoint, robots, work_us, ticks = argv
    child = Child(endpoint, float(work_us), int(ticks))
    try:
        if role == "plant":
            run_plant(design, child, int(robots))
        else:
            run_answerer(role, design, child)
    finally:
        child.session.close()
    return 0


def _read_rest(proc: subprocess.Popen[bytes]) -> dict[str, float]:
    out: dict[str, float] = {}
    assert proc.stdout is not None
    for line in proc.stdout.read().decode(errors="replace").splitlines():
        parts = line.split()
        if len(parts) == 2 and parts[0] in ("wall", "cpu"):
            out[parts[0]] = float(parts[1])
    return out


def measure(design: str, robots: int, work_us: float, ticks: int) -> dict[str, float]:
    """One floor run; CPU ms a tick by process kind and the speed."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    me = [sys.executable, __file__, "child"]

    def argv(role: str) -> list[str]:
        return [*me, role, design, endpoint, str(robots), str(work_us), str(ticks)]

    router_argv = [sys.executable, "-m", "formation", "router", "--listen", endpoint]
    with contextlib.ExitStack() as stack:
        router = stack.enter_context(running(router_argv, ready="router listening on "))
        answerers = [stack.enter_context(running(argv("coordinator"), ready=READY))]
        answerers += [
            stack.enter_context(running(argv(f"r{i + 1}"), ready=READY)) for i in range(robots)
        ]
        r0 = cpu_s(router.pid)
        with running(argv("plant"), ready=None) as plant:
            plant.wait(timeout=600)
            got = _read_rest(plant)
        r1 = cpu_s(router.pid)
        results = {"plant": got.get("cpu", float("nan")), "router": (r1 - r0) / ticks * 1e3}
        agents = 0.0
        for i, proc in enumerate(answerers):
            proc.wait(timeout=10)
            cpu = _read_rest(proc).get("cpu", float("nan"))
            if i == 0:
                results["coordinator"] = cpu
            else:
                agents += cpu
        results["agents"] = agents
        stop_process(router)
    wall = got.get("wall", float("nan"))
    results["speed"] = ticks * DT_S / wall
    results["wall_us"] = wall / ticks * 1e6
    return results


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    p.add_argument("--ticks", type=int, default=3000, help="timed ticks per design")
    p.add_argument("--robots", type=int, default=3)
    p.add_argument("--work-us", type=float, default=50.0, help="busy work a process and tick")
    p.add_argument("--designs", nargs="+", choices=DESIGNS, default=list(DESIGNS))
    p.add_argument(
        "--zenoh-runtime",
        choices=("both", "default", "one-thread"),
        default="both",
        help="Zenoh's threads in every process: its default, or one thread as `formation up "
        "--lockstep` gives its children (runtime.transport.LOCKSTEP_ZENOH_RUNTIME); both: each",
    )
    args = p.parse_args(argv)
    if args.ticks < 1 or args.robots < 1 or args.work_us < 0:
        p.error("need --ticks >= 1, --robots >= 1, --work-us >= 0")
    print(
        f"lockstep floor: {args.robots} robots, {args.work_us:g} us of work a process and tick, "
        f"{args.ticks} timed ticks at 50 Hz (router, plant, coordinator, one process per robot)"
    )
    runtimes = ("default", "one-thread") if args.zenoh_runtime == "both" else (args.zenoh_runtime,)
    for runtime in runtimes:
        # the children inherit it (common.running); Zenoh reads it at a process's first open
        if runtime == "one-thread":
            os.environ[ZENOH_RUNTIME_ENV] = LOCKSTEP_ZENOH_RUNTIME
        else:
            os.environ.pop(ZENOH_RUNTIME_ENV, None)
        print(f" Zenoh runtime: {runtime}")
        for design in args.designs:
            r = measure(design, args.robots, args.work_us, args.ticks)
            total = r["plant"] + r["coordinator"] + r["agents"] + r["router"]
            print(
                f"  {design:<7} {r['speed']:5.1f}x real time ({r['wall_us']:.0f} us a tick); CPU "
                f"ms a tick: plant {r['plant']:.2f}, coordinator {r['coordinator']:.2f}, agents "
                f"(sum) {r['agents']:.2f}, router {r['router']:.2f}; total {total:.2f}",
                flush=True,
            )
    return 0


if __name__ == "__main__":
    if len(sys.argv) == 8 and sys.argv[1] == "child":
        raise SystemExit(child_main(sys.argv[2:]))
    raise SystemExit(main())
